"""Bad input is a 4xx whose body names the field, never a 500."""

from __future__ import annotations

import base64
import json

import numpy as np
import pytest
from fastapi.routing import APIRoute
from fastapi.testclient import TestClient

from app.main import create_app
from app.routing import JsonBodyRoute
from tests.conftest import make_settings

ENTITY = [0.0] * 91
EFFECT = [0.0] * 66


def _scene(*objects: dict) -> dict:
    return {"objects": list(objects)}


@pytest.mark.parametrize(
    ("body", "field"),
    [
        (_scene({"features": {"entity": [0.0, 1.0, 2.0]}}), "objects[0].features.entity"),
        (
            _scene({"features": {"entity": ENTITY, "effects": {"push_left": [0.0] * 65}}}),
            "objects[0].features.effects.push_left",
        ),
        (_scene({"features": {"entity": ENTITY, "effects": {"fly": EFFECT}}}), "objects[0].features.effects.fly"),
        (_scene({"concepts": ["cup"], "kinds": {"spoon": "utensil"}}), "objects[0].kinds.spoon"),
        (_scene({"concepts": {"cup": 1.5}}), "objects[0].concepts.cup"),
        (_scene({"concepts": []}), "objects[0].concepts"),
        (_scene({"concepts": ["cup"], "features": {"entity": ENTITY}}), "objects[0]"),
        (_scene({}), "objects[0]"),
        (_scene(), "objects"),
        ({"objects": [{"concepts": ["cup"]}], "extra": 1}, "extra"),
        (_scene({"raw": {"look": {"points": "not base64!"}}}), "objects[0].raw.look.points"),
        (_scene({"raw": {"look": {"points": [[0.0, 1.0]]}}}), "objects[0].raw.look.points[0]"),
        (
            _scene(
                {
                    "raw": {
                        "look": {"points": [[0.0, 0.0, 0.0]]},
                        "interactions": [
                            {"behaviour": "fly", "before": {"points": [[0, 0, 0]]}, "after": {"points": [[0, 0, 0]]}}
                        ],
                    }
                }
            ),
            "objects[0].raw.interactions[0].behaviour",
        ),
    ],
)
def test_a_bad_scene_is_a_422_naming_the_field(client: TestClient, model_id: str, body: dict, field: str) -> None:
    response = client.post(f"/v1/models/{model_id}/scenes", json=body)
    assert response.status_code == 422, response.text
    assert response.json()["field"] == field
    assert response.json()["error"] == "invalid_input" and response.json()["detail"]


@pytest.mark.parametrize(
    ("body", "field", "problem"),
    [
        (
            _scene({"concepts": "cup"}),
            "objects[0].concepts",
            "an array of names or an object of names to probabilities",
        ),
        (
            _scene({"raw": {"look": {"points": {"x": 1.0}}}}),
            "objects[0].raw.look.points",
            "a JSON array or a base64 string of little-endian float32 values",
        ),
    ],
)
def test_a_field_of_two_shapes_given_neither_says_which_it_takes(
    client: TestClient, model_id: str, body: dict, field: str, problem: str
) -> None:
    """Not pydantic's words for its union of two shapes (``Input tag 'as base64' found using _shape()``)."""
    response = client.post(f"/v1/models/{model_id}/scenes", json=body)
    assert response.status_code == 422, response.text
    assert response.json()["field"] == field
    detail = response.json()["detail"]
    assert problem in detail and "tag" not in detail and "_shape" not in detail, detail


@pytest.mark.parametrize(("text", "position"), [('{"objects": [{"concepts": ["cup"]', 33), ("{objects", 1)])
def test_a_body_that_is_not_json_is_a_422_on_the_body_saying_where(
    client: TestClient, model_id: str, text: str, position: int
) -> None:
    response = client.post(f"/v1/models/{model_id}/scenes", content=text, headers={"Content-Type": "application/json"})
    assert response.status_code == 422, response.text
    assert response.json()["field"] == "body"
    assert response.json()["detail"].startswith(f"body: not valid JSON at character {position} (")
    assert client.get(f"/v1/models/{model_id}").json()["scene_count"] == 0


@pytest.mark.parametrize(
    ("path", "text", "key"),
    [
        ("scenes", '{"objects": [{"concepts": {"cup": 0.2, "plate": 1, "cup": 0.9}}]}', '"cup"'),
        ("scenes", '{"objects": [{"concepts": ["cup"]}], "objects": [{"concepts": ["plate"]}]}', '"objects"'),
        ("models", '{"name": "a", "seed": 1, "name": "b"}', '"name"'),
    ],
)
def test_a_key_given_twice_in_one_object_is_a_422_on_the_body_naming_it(
    client: TestClient, model_id: str, path: str, text: str, key: str
) -> None:
    """Python's parser would keep the last value silently (app/routing.py)."""
    url = f"/v1/models/{model_id}/scenes" if path == "scenes" else "/v1/models"
    models_before = len(client.get("/v1/models").json())
    response = client.post(url, content=text, headers={"Content-Type": "application/json"})
    assert response.status_code == 422, response.text
    assert response.json()["field"] == "body"
    assert response.json()["detail"] == f"body: not valid JSON (the key {key} appears twice in one object)"
    assert client.get(f"/v1/models/{model_id}").json()["scene_count"] == 0
    assert len(client.get("/v1/models").json()) == models_before
    # The same key in two different objects is not a repeat.
    response = client.post(f"/v1/models/{model_id}/scenes", json=_scene({"concepts": ["cup"]}, {"concepts": ["cup"]}))
    assert response.status_code == 201, response.text


def _api_routes(routes: list) -> list[APIRoute]:
    """The API routes, also those of included routers (FastAPI keeps those nested)."""
    found: list[APIRoute] = []
    for route in routes:
        if isinstance(route, APIRoute):
            found.append(route)
        elif hasattr(route, "original_router"):
            found += _api_routes(route.original_router.routes)
    return found


def test_every_route_with_a_body_reads_it_refusing_repeated_keys(client: TestClient) -> None:
    with_body = [route for route in _api_routes(client.app.routes) if route.body_field is not None]
    assert len(with_body) >= 6 and all(isinstance(route, JsonBodyRoute) for route in with_body), [
        route.path for route in with_body if not isinstance(route, JsonBodyRoute)
    ]


def test_a_body_that_is_not_utf8_is_a_422_on_the_body(client: TestClient, model_id: str) -> None:
    body = '{"objects": [{"concepts": ["caf\xe9"]}]}'.encode("latin-1")
    response = client.post(f"/v1/models/{model_id}/scenes", content=body, headers={"Content-Type": "application/json"})
    assert response.status_code == 422, response.text
    assert response.json() == {
        "error": "invalid_input",
        "detail": "body: not valid JSON: byte 31 is not UTF-8 (JSON text is UTF-8)",
        "field": "body",
    }


def test_a_json_body_sent_as_text_is_a_422_saying_which_content_type(client: TestClient, model_id: str) -> None:
    body = json.dumps({"objects": [{"concepts": ["cup"]}]})
    response = client.post(f"/v1/models/{model_id}/scenes", content=body, headers={"Content-Type": "text/plain"})
    assert response.status_code == 422, response.text
    assert response.json()["field"] == "body" and "Content-Type: application/json" in response.json()["detail"]


@pytest.mark.parametrize(
    ("path", "body", "field"),
    [
        ("scenes", _scene({"concepts": {"cup": True}}), "objects[0].concepts.cup"),
        ("scenes", _scene({"concepts": {"cup": "0.5"}}), "objects[0].concepts.cup"),
        ("scenes", _scene({"concepts": [7]}), "objects[0].concepts[0]"),
        ("scenes", _scene({"features": {"entity": ["0.5", *ENTITY[1:]]}}), "objects[0].features.entity[0]"),
        ("models", {"name": "m", "seed": "3"}, "seed"),
        ("models", {"name": "m", "seed": 3.0}, "seed"),
        ("models", {"name": 12}, "name"),
        ("models", {"name": "m", "hyperparameters": {"sampler": {"sweeps": "12"}}}, "hyperparameters.sampler.sweeps"),
        ("models", {"name": "m", "hyperparameters": {"priors": {"alpha": False}}}, "hyperparameters.priors.alpha"),
    ],
)
def test_a_value_of_another_json_type_is_refused_not_converted(
    client: TestClient, model_id: str, path: str, body: dict, field: str
) -> None:
    """Strict types (``RequestSchema``): a boolean or a string where a number belongs is a client's
    bug that a lax conversion would hide (``true`` would have been learned as probability 1)."""
    url = f"/v1/models/{model_id}/scenes" if path == "scenes" else "/v1/models"
    response = client.post(url, json=body)
    assert response.status_code == 422, response.text
    assert response.json()["field"] == field and response.json()["error"] == "invalid_input"


def test_whole_numbers_are_numbers_and_arrays_are_pairs(client: TestClient, model_id: str) -> None:
    """What strict mode still takes: an integer probability, and a vocabulary's adjective pairs as
    JSON arrays (the schema's tuples)."""
    response = client.post(f"/v1/models/{model_id}/scenes", json=_scene({"concepts": {"cup": 1, "plate": 0}}))
    assert response.status_code == 201, response.text
    vocabulary = {"nouns": ["cup"], "adjective_pairs": [["hard", "soft"]], "verbs": ["grasp"]}
    response = client.post("/v1/models", json={"name": "m", "vocabulary": vocabulary})
    assert response.status_code == 201, response.text


def test_a_refused_pattern_is_said_in_words(client: TestClient, model_id: str) -> None:
    response = client.post(f"/v1/models/{model_id}/scenes", json=_scene({"concepts": ["cup\u0000x"]}))
    assert response.status_code == 422 and response.json()["detail"] == (
        "objects[0].concepts[0]: String should contain no control characters (U+0000 to U+001F, U+007F)"
    )
    response = client.post(
        f"/v1/models/{model_id}/scenes", json=_scene({"concepts": ["cup"]}), headers={"Idempotency-Key": "a b"}
    )
    assert response.status_code == 422 and response.json()["detail"] == (
        "header.Idempotency-Key: String should be printable ASCII without spaces (the characters ! to ~)"
    )
    assert client.get(f"/v1/models/{model_id}").json()["scene_count"] == 0


def test_nan_and_infinity_are_refused(client: TestClient, model_id: str) -> None:
    for literal in ("NaN", "Infinity", "-Infinity"):
        entity = ", ".join([literal] + ["0.0"] * 90)
        body = '{"objects": [{"features": {"entity": [' + entity + "]}}]}"
        response = client.post(
            f"/v1/models/{model_id}/scenes", content=body, headers={"Content-Type": "application/json"}
        )
        assert response.status_code == 422 and response.json()["field"] == "objects[0].features.entity[0]"
    nan32 = base64.b64encode(np.array([0.0, np.nan, 0.0], dtype="<f4").tobytes()).decode()
    response = client.post(f"/v1/models/{model_id}/scenes", json=_scene({"raw": {"look": {"points": nan32}}}))
    assert response.status_code == 422 and "NaN" in response.json()["detail"]


def test_levels_that_need_prototypes_say_so_and_nothing_is_learned(client: TestClient, model_id: str) -> None:
    response = client.post(f"/v1/models/{model_id}/scenes", json=_scene({"features": {"entity": ENTITY}}))
    assert response.status_code == 409 and response.json()["error"] == "model_not_fitted"
    assert client.get(f"/v1/models/{model_id}").json()["scene_count"] == 0


def test_unknown_model_malformed_json_and_unknown_route(client: TestClient) -> None:
    response = client.post("/v1/models/nope/scenes", json=_scene({"concepts": ["cup"]}))
    assert response.status_code == 404 and response.json()["error"] == "model_not_found"
    malformed = client.post("/v1/models", content=b"{not json", headers={"Content-Type": "application/json"})
    assert malformed.status_code == 422 and malformed.json()["error"] == "invalid_input"
    assert client.get("/v2/anything").json()["error"] == "not_found"


def test_a_body_over_the_limit_is_a_413(database_url: str) -> None:
    with TestClient(create_app(make_settings(database_url, max_body_bytes=4096))) as client:
        model_id = client.post("/v1/models", json={"name": "small"}).json()["id"]
        body = json.dumps(_scene(*[{"features": {"entity": ENTITY}}] * 20))
        response = client.post(
            f"/v1/models/{model_id}/scenes", content=body, headers={"Content-Type": "application/json"}
        )
        assert response.status_code == 413 and response.json()["error"] == "payload_too_large"

        def chunks():
            yield body.encode()

        streamed = client.post(
            f"/v1/models/{model_id}/scenes", content=chunks(), headers={"Content-Type": "application/json"}
        )
        assert streamed.status_code == 413 and streamed.json()["error"] == "payload_too_large"
