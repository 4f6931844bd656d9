"""Models: create, list, get and delete through the API, each independent of the others."""

from __future__ import annotations

from fastapi.testclient import TestClient

from tests.conftest import FAST_HYPERPARAMETERS


def test_create_get_list_and_delete(client: TestClient) -> None:
    created = client.post("/v1/models", json={"name": "kitchen robot", "seed": 3, "hyperparameters": {"alpha": 0.5}})
    assert created.status_code == 201
    model = created.json()
    assert model["hyperparameters"]["alpha"] == 0.5 and model["hyperparameters"]["xi"] == 0.1
    assert (model["context_count"], model["vocabulary_size"], model["scene_count"]) == (1, 29, 0)
    assert model["vocabulary"]["nouns"] == ["box", "ball", "cylinder", "cup", "plate", "tool"]
    other = client.post("/v1/models", json={"name": "workshop robot"}).json()
    assert [m["id"] for m in client.get("/v1/models").json()] == [model["id"], other["id"]]
    assert client.get(f"/v1/models/{model['id']}").json() == model

    assert client.delete(f"/v1/models/{model['id']}").status_code == 204
    missing = client.get(f"/v1/models/{model['id']}")
    assert missing.status_code == 404
    assert missing.json() == {
        "error": "model_not_found",
        "detail": f"no model {model['id']!r}",
        "field": "path.model_id",
    }
    assert [m["id"] for m in client.get("/v1/models").json()] == [other["id"]]


def test_models_learn_independently(client: TestClient) -> None:
    first, second = (
        client.post("/v1/models", json={"name": name, "hyperparameters": FAST_HYPERPARAMETERS}).json()["id"]
        for name in ("a", "b")
    )
    client.post(f"/v1/models/{first}/scenes", json={"objects": [{"concepts": ["cup", "spoon"]}]})
    assert client.get(f"/v1/models/{first}").json()["scene_count"] == 1
    assert client.get(f"/v1/models/{first}").json()["vocabulary_size"] == 30
    assert client.get(f"/v1/models/{second}").json()["scene_count"] == 0
    assert client.get(f"/v1/models/{second}").json()["vocabulary_size"] == 29


def test_a_custom_vocabulary_and_bad_hyperparameters(client: TestClient) -> None:
    vocabulary = {"nouns": ["mug", "pan"], "adjective_pairs": [["hot", "cold"]], "verbs": ["stir"]}
    model = client.post("/v1/models", json={"name": "cook", "vocabulary": vocabulary}).json()
    assert model["vocabulary"] == vocabulary and model["vocabulary_size"] == 5

    duplicate = client.post("/v1/models", json={"name": "x", "vocabulary": {**vocabulary, "verbs": ["mug"]}})
    assert duplicate.status_code == 422 and duplicate.json()["field"] == "vocabulary"
    burn_in = client.post(
        "/v1/models", json={"name": "x", "hyperparameters": {"inference_sweeps": 5, "inference_burn_in": 5}}
    )
    assert burn_in.status_code == 422 and burn_in.json()["field"] == "hyperparameters.inference_burn_in"
    negative = client.post("/v1/models", json={"name": "x", "hyperparameters": {"alpha": -1}})
    assert negative.status_code == 422 and negative.json()["field"] == "hyperparameters.alpha"
    unknown = client.post("/v1/models", json={"name": "x", "hyperparameters": {"gamma": 1}})
    assert unknown.status_code == 422 and unknown.json()["field"] == "hyperparameters.gamma"
