"""No input causes a 500: schemathesis generates requests from the OpenAPI schema.

Every operation, DELETE included, is called with generated bodies, queries and headers
(``Idempotency-Key`` among them) against a server with keys configured, on SQLite and on
PostgreSQL, with all of schemathesis' phases (its coverage phase adds the schema's boundary
cases). Requests carry the write key, except where schemathesis generates the key header
itself; a separate property fuzzes the key header with arbitrary bytes. Operations on a
model run against one that exists and has fitted perception, so the feature and raw levels
run their real code; a DELETE of a model deletes a throwaway one. ``fit`` is fuzzed on a
model without training objects: a real fit clusters for about a second, and
test_service_training covers it. Every response must be a documented status with its
documented shape (``response_schema_conformance``).

Stateful links (schemathesis' state machine over create → learn → read → delete) are not
used: the model ids that link operations are random, so each step would have to be wired by
hand, and the single-operation runs above already reach every route with a live model.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import pytest
import schemathesis
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from schemathesis.checks import not_a_server_error
from schemathesis.specs.openapi.checks import response_schema_conformance

from app.main import create_app
from sim.world import World
from tests.conftest import make_settings, migrated_database, synthetic_training_objects

EXAMPLES_PER_OPERATION = 6
FIT_PATH = "/v1/models/{model_id}/fit"
_OPENAPI = create_app(make_settings("sqlite://")).openapi()

WRITE_KEY = "fuzz-write-key"
DELETE_MODEL_PATH = "/v1/models/{model_id}"
full_schema = schemathesis.openapi.from_dict(_OPENAPI)


@dataclass(frozen=True)
class Target:
    client: TestClient
    fitted_model: str
    empty_model: str


def _target(request: pytest.FixtureRequest, directory, backend: str) -> Iterator[Target]:
    url = migrated_database(backend, request, directory)
    settings = make_settings(url, write_key=WRITE_KEY, read_key="fuzz-read-key")
    with TestClient(create_app(settings), headers={"X-API-Key": WRITE_KEY}) as client:
        body = {"name": "fuzzed", "hyperparameters": {"sampler": {"sweeps": 5}, "k_rule": {"birth_window": 5}}}
        fitted, empty = (client.post("/v1/models", json=body).json()["id"] for _ in range(2))
        client.post(
            f"/v1/models/{fitted}/training-objects",
            json={"objects": synthetic_training_objects(World.paper(0), seed=1)},
        )
        client.post(f"/v1/models/{fitted}/fit", json={"method": "kmeans"})
        client.post(f"/v1/models/{fitted}/scenes", json={"objects": [{"concepts": ["cup", "grasp"]}]})
        yield Target(client, fitted, empty)


@pytest.fixture(scope="module")
def on_sqlite(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Target]:
    yield from _target(request, tmp_path_factory.mktemp("fuzz"), "sqlite")


@pytest.fixture(scope="module")
def on_postgresql(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Target]:
    yield from _target(request, tmp_path_factory.mktemp("fuzz"), "postgresql")


def _call_and_validate(case: schemathesis.Case, target: Target) -> None:
    if "model_id" in (case.path_parameters or {}):
        if case.method == "DELETE" and case.path == DELETE_MODEL_PATH:
            model_id = target.client.post("/v1/models", json={"name": "throwaway"}).json()["id"]
        else:
            model_id = target.empty_model if case.path == FIT_PATH else target.fitted_model
        case.path_parameters["model_id"] = model_id
    request = case.as_transport_kwargs(base_url="http://testserver")
    headers = {name: value.encode("latin-1", "replace") for name, value in (request.get("headers") or {}).items()}
    if not any(name.lower() == "x-api-key" for name in headers):
        headers["X-API-Key"] = WRITE_KEY.encode()
    response = target.client.request(
        request["method"],
        request["url"],
        headers=headers,
        params=request.get("params"),
        json=request.get("json"),
        content=request.get("data"),
    )
    case.validate_response(response, checks=[not_a_server_error, response_schema_conformance])


@full_schema.parametrize()
@settings(max_examples=EXAMPLES_PER_OPERATION, deadline=None, suppress_health_check=list(HealthCheck))
def test_no_generated_request_causes_a_server_error(case: schemathesis.Case, on_sqlite: Target) -> None:
    _call_and_validate(case, on_sqlite)


@pytest.mark.postgres
@full_schema.parametrize()
@settings(max_examples=EXAMPLES_PER_OPERATION, deadline=None, suppress_health_check=list(HealthCheck))
def test_no_generated_request_causes_a_server_error_on_postgresql(
    case: schemathesis.Case, on_postgresql: Target
) -> None:
    _call_and_validate(case, on_postgresql)


@given(key=st.binary(max_size=64).filter(lambda key: b"\r" not in key and b"\n" not in key))
@settings(max_examples=60, deadline=None, suppress_health_check=list(HealthCheck))
def test_any_key_header_is_a_401_never_a_server_error(key: bytes, on_sqlite: Target) -> None:
    if key == WRITE_KEY.encode() or key == b"fuzz-read-key":
        return
    for method, path in (("GET", "/v1/models"), ("POST", f"/v1/models/{on_sqlite.fitted_model}/scenes")):
        response = on_sqlite.client.request(
            method, path, headers={"X-API-Key": key, "Idempotency-Key": key or b"k"}, json={"objects": []}
        )
        assert response.status_code in (401, 422), (key, response.status_code, response.text)
        assert set(response.json()) == {"error", "detail", "field"}
