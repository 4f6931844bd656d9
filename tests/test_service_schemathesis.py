"""No input causes a 500: schemathesis generates requests from the OpenAPI schema.

Every operation but DELETE is called with generated bodies, queries and headers
against a model that exists and has fitted perception, so the feature and raw
levels run their real code. On SQLite all of schemathesis' phases run (its
coverage phase adds the schema's boundary cases: about 2,000 requests); on
PostgreSQL the generated examples only, since the validation in front of the
database is the same code. ``fit`` is fuzzed on a model without training
objects: a real fit clusters for about a second, and test_service_training
covers it.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import pytest
import schemathesis
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, settings
from schemathesis.checks import not_a_server_error
from schemathesis.config import SchemathesisConfig
from schemathesis.specs.openapi.checks import response_schema_conformance

from app.main import create_app
from core.world import World
from tests.conftest import make_settings, migrated_database, synthetic_training_objects

EXAMPLES_PER_OPERATION = 6
FIT_PATH = "/v1/models/{model_id}/fit"
_OPENAPI = create_app(make_settings("sqlite://")).openapi()

full_schema = schemathesis.openapi.from_dict(_OPENAPI).exclude(method="DELETE")
examples_only = schemathesis.openapi.from_dict(
    _OPENAPI, config=SchemathesisConfig.from_dict({"phases": {"coverage": {"enabled": False}}})
).exclude(method="DELETE")


@dataclass(frozen=True)
class Target:
    client: TestClient
    fitted_model: str
    empty_model: str


def _target(request: pytest.FixtureRequest, directory, backend: str) -> Iterator[Target]:
    url = migrated_database(backend, request, directory)
    with TestClient(create_app(make_settings(url))) as client:
        body = {"name": "fuzzed", "hyperparameters": {"sweeps": 5, "birth_window": 5}}
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
        case.path_parameters["model_id"] = target.empty_model if case.path == FIT_PATH else target.fitted_model
    request = case.as_transport_kwargs(base_url="http://testserver")
    headers = {name: value.encode("latin-1", "replace") for name, value in (request.get("headers") or {}).items()}
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
@examples_only.parametrize()
@settings(max_examples=EXAMPLES_PER_OPERATION, deadline=None, suppress_health_check=list(HealthCheck))
def test_no_generated_request_causes_a_server_error_on_postgresql(
    case: schemathesis.Case, on_postgresql: Target
) -> None:
    _call_and_validate(case, on_postgresql)
