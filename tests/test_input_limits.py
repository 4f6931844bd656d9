"""Bounded resources and the error contract for every body (issue 14, "Bounded resources").

The vocabulary limits are checked on both databases (a refused scene must leave the
stored model as it was); the body checks happen before any route, so they run on one
SQLite app shared by the module.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.main import create_app
from app.middleware import MAX_JSON_DEPTH, MAX_NUMBER_LENGTH, json_body_problem
from core.context import lda
from tests.conftest import CONTEXT_CONCEPTS, FAST_HYPERPARAMETERS, make_settings, migrated_database

SMALL_BODY_LIMIT = 16_384
JSON = {"Content-Type": "application/json"}


def _names(count: int, prefix: str = "thing") -> list[str]:
    return [f"{prefix}{i}" for i in range(count)]


def _new_model(client: TestClient, **fields: object) -> str:
    response = client.post(
        "/v1/models", json={"name": "limits", "seed": 5, "hyperparameters": FAST_HYPERPARAMETERS, **fields}
    )
    assert response.status_code == 201, response.text
    return response.json()["id"]


def _counts(client: TestClient, model_id: str) -> tuple[int, int]:
    model = client.get(f"/v1/models/{model_id}").json()
    return model["scene_count"], model["vocabulary_size"]


# The vocabulary limits.


def test_a_scene_with_too_many_new_names_is_refused_and_nothing_is_learned(database_url: str) -> None:
    settings = make_settings(database_url, max_new_concepts_per_scene=4)
    with TestClient(create_app(settings)) as client:
        model_id = _new_model(client)
        assert (
            client.post(f"/v1/models/{model_id}/scenes", json={"objects": [{"concepts": ["cup"]}]}).status_code == 201
        )
        before = _counts(client, model_id)
        response = client.post(
            f"/v1/models/{model_id}/scenes", json={"objects": [{"concepts": ["cup", *_names(5)]}, {"concepts": ["x0"]}]}
        )
        assert response.status_code == 422, response.text
        assert response.json() == {
            "error": "invalid_input",
            "detail": "the scene would add 6 new concepts; the limit per request is 4 "
            "(CONTEXTWEB_MAX_NEW_CONCEPTS_PER_SCENE)",
            "field": "objects",
        }
        assert _counts(client, model_id) == before
        assert client.get(f"/v1/models/{model_id}/scenes").json()["total"] == 1
        # A name repeated counts once; exactly the limit is learned.
        at_limit = {"objects": [{"concepts": _names(4)}, {"concepts": _names(4)}]}
        assert client.post(f"/v1/models/{model_id}/scenes", json=at_limit).status_code == 201
        assert _counts(client, model_id) == (before[0] + 1, before[1] + 4)


def test_the_vocabulary_of_a_model_stops_at_its_limit_and_known_names_still_learn(database_url: str) -> None:
    with TestClient(create_app(make_settings(database_url, max_vocabulary=31))) as client:
        model_id = _new_model(client)  # the paper's 29 concepts
        assert (
            client.post(f"/v1/models/{model_id}/scenes", json={"objects": [{"concepts": _names(2)}]}).status_code == 201
        )
        assert _counts(client, model_id) == (1, 31)
        response = client.post(f"/v1/models/{model_id}/scenes", json={"objects": [{"concepts": ["cup", "new"]}]})
        assert response.status_code == 422 and response.json()["field"] == "objects"
        assert response.json()["detail"] == (
            "the scene would add 1 new concepts to a vocabulary of 31; the limit per model is 31 concepts "
            "(CONTEXTWEB_MAX_VOCABULARY)"
        )
        assert _counts(client, model_id) == (1, 31)
        known = {"objects": [{"concepts": ["cup", "thing0", "thing1"]}]}
        assert client.post(f"/v1/models/{model_id}/scenes", json=known).status_code == 201
        assert _counts(client, model_id) == (2, 31)


def test_the_default_limit_refuses_65_new_names_and_models_loaded_from_storage_get_the_limits(
    database_url: str,
) -> None:
    with TestClient(create_app(make_settings(database_url))) as client:
        model_id = _new_model(client)
        response = client.post(f"/v1/models/{model_id}/scenes", json={"objects": [{"concepts": _names(65)}]})
        assert response.status_code == 422 and "limit per request is 64" in response.json()["detail"]
        assert (
            client.post(f"/v1/models/{model_id}/scenes", json={"objects": [{"concepts": _names(64)}]}).status_code
            == 201
        )
    # Another app on the same database loads the model at start with its own, smaller limit.
    with TestClient(create_app(make_settings(database_url, max_new_concepts_per_scene=1))) as client:
        response = client.post(f"/v1/models/{model_id}/scenes", json={"objects": [{"concepts": _names(2, "new")}]})
        assert response.status_code == 422 and "limit per request is 1" in response.json()["detail"]
        assert _counts(client, model_id) == (1, 29 + 64)


def test_a_scene_past_the_most_tokens_a_model_holds_is_refused_and_nothing_is_learned(
    database_url: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The bound (int32 token indices: 2,147,483,647 tokens, about two years of a scene every 2 s)
    is lowered to one token more than the model holds, so that a test reaches it; the check is the same."""

    def tokens(answer: dict) -> int:
        return sum(len(obj["active_concepts"]) for obj in answer["objects"])

    with TestClient(create_app(make_settings(database_url))) as client:
        model_id = _new_model(client)
        scenes = f"/v1/models/{model_id}/scenes"
        first = client.post(scenes, json={"objects": [{"concepts": ["cup", "hard", "grasp"]}]})
        assert first.status_code == 201
        held = tokens(first.json())
        monkeypatch.setattr(lda, "MAX_TOKENS", held + 1)
        before = _counts(client, model_id)
        response = client.post(scenes, json={"objects": [{"concepts": ["cup"]}, {"concepts": ["brand_new"]}]})
        assert response.status_code == 422, response.text
        assert response.json() == {
            "error": "invalid_input",
            "detail": f"the model holds {held} tokens and a scene of 2 would take it past {held + 1}, the most one "
            "model holds (int32 token indices): learn into a new model",
            "field": "objects",
        }
        assert _counts(client, model_id) == before  # no scene, and the new name did not join the vocabulary
        assert tokens(client.post(scenes, json={"objects": [{"concepts": ["cup"]}]}).json()) == 1  # exactly fits
        assert client.post(scenes, json={"objects": [{"concepts": ["cup"]}]}).status_code == 422
        assert _counts(client, model_id) == (before[0] + 1, before[1])


# Hyperparameters within their documented ranges.


@pytest.fixture(scope="module")
def shared_client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    """One SQLite app with a small body limit, for the checks that no route or database takes part in."""
    url = migrated_database("sqlite", None, Path(tmp_path_factory.mktemp("limits")))  # type: ignore[arg-type]
    with TestClient(create_app(make_settings(url, max_body_bytes=SMALL_BODY_LIMIT))) as client:
        yield client


@pytest.fixture(scope="module")
def shared_model(shared_client: TestClient) -> str:
    return _new_model(shared_client)


@pytest.mark.parametrize(
    "value", ["1e308", "1e3000", "1000.5", "0", "0.0", "1e-7", "-1", "NaN", "Infinity", "-Infinity"]
)
@pytest.mark.parametrize("name", ["priors.alpha", "priors.xi", "k_rule.scene_prior_strength"])
def test_dirichlet_priors_outside_their_range_are_refused(shared_client: TestClient, name: str, value: str) -> None:
    response = shared_client.post("/v1/models", content=_body_setting(name, value), headers=JSON)
    assert response.status_code == 422, response.text
    assert response.json()["error"] == "invalid_input" and response.json()["field"] == f"hyperparameters.{name}"


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("k_rule[paper].tau", "0"),
        ("k_rule[paper].tau", "1"),
        ("k_rule[paper].delta", "1.5"),
        ("k_rule.delta", "-0.1"),
        ("k_rule.online_birth_margin", "1e5"),
        ("k_rule.birth_margin", "-1"),
        ("k_rule.birth_margin", "NaN"),
        ("sampler.sweeps", "0"),
        ("sampler.sweeps", "10001"),
        ("k_rule.max_contexts", "101"),
        ("sampler.rejuvenation_tokens", "1e400"),
        ("sampler.inference_sweeps", "NaN"),
    ],
)
def test_other_hyperparameters_outside_their_range_are_refused(
    shared_client: TestClient, name: str, value: str
) -> None:
    response = shared_client.post("/v1/models", content=_body_setting(name, value), headers=JSON)
    assert response.status_code == 422, response.text
    assert response.json()["field"] == "hyperparameters." + name.replace("[paper]", "")


def _body_setting(name: str, value: str) -> str:
    """A model body setting ``group.setting`` (``k_rule[paper].setting``: under the paper rule) to
    ``value``, written as JSON text so that NaN and out-of-range literals reach the service."""
    group, setting = name.split(".")
    rule = '"name": "paper", ' if group == "k_rule[paper]" else ""
    return (
        '{"name": "bad", "hyperparameters": {"'
        + group.split("[")[0]
        + '": {'
        + rule
        + '"'
        + setting
        + '": '
        + value
        + "}}}"
    )


@pytest.mark.parametrize("value", ["NaN", "-Infinity", "1.5", "-0.5"])
def test_sigma_outside_zero_one_is_refused(shared_client: TestClient, value: str) -> None:
    response = shared_client.post("/v1/models", content='{"name": "bad", "sigma": ' + value + "}", headers=JSON)
    assert response.status_code == 422 and response.json()["field"] == "sigma"


@pytest.mark.parametrize("prior", [1e-6, 1e3])
def test_at_either_end_of_the_prior_range_every_posterior_is_a_distribution(
    shared_client: TestClient, prior: float
) -> None:
    model_id = _new_model(
        shared_client, hyperparameters={**FAST_HYPERPARAMETERS, "priors": {"alpha": prior, "xi": prior}}
    )
    for concepts in [*CONTEXT_CONCEPTS.values()] * 2:
        response = shared_client.post(f"/v1/models/{model_id}/scenes", json={"objects": [{"concepts": concepts}]})
        assert response.status_code == 201, response.text
        posterior = np.array(response.json()["context_posterior"])
        assert np.isfinite(posterior).all() and posterior.sum() == pytest.approx(1.0)
    inferred = shared_client.post(f"/v1/models/{model_id}/infer", json={"objects": [{"concepts": ["cup"]}]})
    assert np.array(inferred.json()["context_posterior"]).sum() == pytest.approx(1.0)


# Bodies: every malformed one answers in the documented shape, on the body.


def _nested(depth: int) -> str:
    """A scene whose first concept sits inside ``depth`` levels of arrays and objects in all."""
    return '{"objects": [{"concepts": ' + "[" * (depth - 3) + '"cup"' + "]" * (depth - 3) + "}]}"


def _chunks(data: bytes) -> Iterator[bytes]:
    for start in range(0, len(data), 1000):
        yield data[start : start + 1000]


SCENE = json.dumps({"objects": [{"concepts": ["cup", "hard"]}]})
MODEL = json.dumps({"name": "fine", "hyperparameters": FAST_HYPERPARAMETERS})
OVER_LIMIT = ("[" + "0," * SMALL_BODY_LIMIT + "0]").encode()

# (body, extra headers, status, error, detail fragment)
MALFORMED = {
    "invalid JSON": (b'{"objects": [', {}, 422, "invalid_input", "not valid JSON"),
    "nested 33 deep": (_nested(MAX_JSON_DEPTH + 1).encode(), {}, 422, "invalid_input", "nested 33 levels deep"),
    "nested 5,000 deep": (b"[" * 5000 + b"]" * 5000, {}, 422, "invalid_input", "nested 5000 levels deep"),
    "5,000-digit integer": (b'{"seed": ' + b"7" * 5000 + b"}", {}, 422, "invalid_input", "longer than 100 characters"),
    "101-character float": (b'{"sigma": 0.' + b"5" * 99 + b"}", {}, 422, "invalid_input", "longer than 100"),
    "UTF-16-LE": (SCENE.encode("utf-16-le"), {}, 422, "invalid_input", "this body is UTF-16-LE"),
    "UTF-16 with BOM": (SCENE.encode("utf-16"), {}, 422, "invalid_input", "this body is UTF-16"),
    "UTF-32-BE": (SCENE.encode("utf-32-be"), {}, 422, "invalid_input", "this body is UTF-32-BE"),
    "declared UTF-16": (
        SCENE.encode("utf-16"),
        {"Content-Type": "application/json; charset=utf-16"},
        422,
        "invalid_input",
        "charset=utf-16",
    ),
    "declared Latin-1": (
        SCENE.encode(),
        {"Content-Type": "application/json; charset=ISO-8859-1"},
        422,
        "invalid_input",
        "charset=ISO-8859-1",
    ),
    "not UTF-8 bytes": ('{"name": "caf\xe9"}'.encode("latin-1"), {}, 422, "invalid_input", "is not UTF-8"),
    "wrong content type": (SCENE.encode(), {"Content-Type": "text/plain"}, 422, "invalid_input", "Content-Type"),
    "Content-Length over the limit": (OVER_LIMIT, {}, 413, "payload_too_large", "exceeds 16384 bytes"),
}


@pytest.mark.parametrize("path", ["/v1/models/{model_id}/scenes", "/v1/models"])
@pytest.mark.parametrize("case", list(MALFORMED))
def test_each_malformed_body_is_answered_on_the_body(
    shared_client: TestClient, shared_model: str, path: str, case: str
) -> None:
    body, headers, status, error, fragment = MALFORMED[case]
    response = shared_client.post(path.format(model_id=shared_model), content=body, headers={**JSON, **headers})
    assert response.status_code == status, response.text
    assert response.json()["error"] == error and response.json()["field"] == "body"
    assert fragment in response.json()["detail"]


@pytest.mark.parametrize("path", ["/v1/models/{model_id}/scenes", "/v1/models"])
def test_a_chunked_body_over_the_limit_is_a_413_on_the_body_and_closes(
    shared_client: TestClient, shared_model: str, path: str
) -> None:
    response = shared_client.post(path.format(model_id=shared_model), content=_chunks(OVER_LIMIT), headers=JSON)
    assert response.status_code == 413
    assert response.json() == {
        "error": "payload_too_large",
        "detail": f"the request body exceeds {SMALL_BODY_LIMIT} bytes (CONTEXTWEB_MAX_BODY_BYTES)",
        "field": "body",
    }
    assert response.headers["connection"] == "close"


def test_nan_literals_are_refused_on_their_field(shared_client: TestClient, shared_model: str) -> None:
    scene = shared_client.post(
        f"/v1/models/{shared_model}/scenes", content='{"objects": [{"concepts": {"cup": NaN}}]}', headers=JSON
    )
    assert scene.status_code == 422 and scene.json()["field"] == "objects[0].concepts.cup"
    model = shared_client.post(
        "/v1/models", content='{"name": "nan", "hyperparameters": {"priors": {"xi": NaN}}}', headers=JSON
    )
    assert model.status_code == 422 and model.json()["field"] == "hyperparameters.priors.xi"


def test_bodies_within_the_limits_are_served(shared_client: TestClient, shared_model: str) -> None:
    """At the depth limit the parser runs (the schema then names the field); UTF-8 with a BOM and an
    explicit ``charset=utf-8`` are UTF-8; long digit runs inside strings are not numbers."""
    deep = shared_client.post(f"/v1/models/{shared_model}/scenes", content=_nested(MAX_JSON_DEPTH), headers=JSON)
    assert deep.status_code == 422 and deep.json()["field"].startswith("objects[0].concepts")
    for body, content_type in [
        (SCENE.encode("utf-8-sig"), "application/json"),
        (SCENE.encode(), "application/json; charset=UTF-8"),
    ]:
        response = shared_client.post(
            f"/v1/models/{shared_model}/scenes", content=body, headers={"Content-Type": content_type}
        )
        assert response.status_code == 201, response.text
    digits = json.dumps({"name": "9" * 120, "seed": int("9" * 18)})
    response = shared_client.post("/v1/models", content=digits, headers=JSON)
    assert response.status_code == 201 and response.json()["name"] == "9" * 120


@pytest.mark.parametrize(
    ("body", "problem"),
    [
        (b'{"a": "[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[["}', None),
        (b'{"a": "\\"[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[\\\\"}', None),
        (b'["\\\\", ' + b"[" * 33 + b"]" * 33 + b"]", "nested 34 levels deep"),
        (b'["\\"", "' + b"1" * 200 + b'"]', None),
        (b"[" + b"1" * MAX_NUMBER_LENGTH + b"]", None),
        (b"[-" + b"1" * MAX_NUMBER_LENGTH + b"]", "longer than"),
        (b"[1e" + b"0" * 200 + b"]", "longer than"),
        (b"[" * 100_000 + b"]" * 100_000, "nested 100000 levels deep"),
        (b"{}", None),
        (b"", None),
    ],
)
def test_the_json_checks_see_only_what_is_outside_strings(body: bytes, problem: str | None) -> None:
    found = json_body_problem(body)
    assert found == problem if problem is None else problem in (found or "")
