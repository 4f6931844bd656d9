"""One bad model never takes the server down: it is listed unavailable and answers 503 with the reason.

A model whose stored counts were corrupted behind the server's back fails the
check that loading runs (n_kw must equal the counts of the stored assignments).
The server still starts, the other models serve, and once ``contextweb models
repair`` has rebuilt the counts from the stored assignments (which bumps the
model's version) the next request reloads the model and it serves again.
"""

from __future__ import annotations

from fastapi.testclient import TestClient
from sqlalchemy import text

from app.main import create_app
from core.features.layout import ENTITY_SIZE
from storage.database import create_database_engine, create_session_makers
from storage.repositories.consistency import check_model, repair_model
from storage.unit_of_work import unit_of_work
from tests.conftest import FAST_HYPERPARAMETERS, concept_scenes, make_settings


def _create_with_scenes(client: TestClient, count: int) -> str:
    body = {"name": "robot", "seed": 4, "hyperparameters": FAST_HYPERPARAMETERS}
    model_id = client.post("/v1/models", json=body).json()["id"]
    for scene in concept_scenes(count, seed=6):
        assert client.post(f"/v1/models/{model_id}/scenes", json=scene).status_code == 201
    return model_id


def test_a_model_with_corrupted_counts_is_unavailable_until_repaired(database_url: str) -> None:
    settings = make_settings(database_url)
    with TestClient(create_app(settings)) as client:
        broken = _create_with_scenes(client, 8)
        healthy = _create_with_scenes(client, 3)
    engine = create_database_engine(database_url)
    _, write_sessions = create_session_makers(engine)
    with engine.begin() as connection:
        connection.execute(
            text("UPDATE context_word_count SET count = count + 5 WHERE model_id = :id AND count > 0"), {"id": broken}
        )

    with TestClient(create_app(settings)) as client:
        assert client.get("/readyz").status_code == 200, "the server starts and is ready"
        response = client.get(f"/v1/models/{broken}/contexts")
        assert response.status_code == 503 and response.headers["Retry-After"]
        body = response.json()
        assert body["error"] == "model_unavailable" and "n_kw" in body["detail"] and "models repair" in body["detail"]
        post = client.post(f"/v1/models/{broken}/scenes", json=concept_scenes(1, seed=0)[0])
        assert post.status_code == 503 and post.json()["error"] == "model_unavailable"
        listed = {model["id"]: model for model in client.get("/v1/models").json()}
        assert listed[broken]["status"] == "unavailable" and "n_kw" in listed[broken]["unavailable_reason"]
        assert listed[healthy]["status"] == "available"
        assert client.post(f"/v1/models/{healthy}/scenes", json=concept_scenes(1, seed=0)[0]).status_code == 201

        with unit_of_work(write_sessions) as session:
            assert any("context_word_count" in problem for problem in check_model(session, broken))
            assert repair_model(session, broken)
        with write_sessions() as session:
            assert check_model(session, broken) == []
        response = client.post(f"/v1/models/{broken}/scenes", json=concept_scenes(1, seed=0)[0])
        assert response.status_code == 201, response.text
        assert response.json()["scene_id"] == 8
        assert client.get(f"/v1/models/{broken}").json()["status"] == "available"
    engine.dispose()


def test_a_refused_scene_changes_nothing_and_costs_no_reload(client: TestClient, model_id: str) -> None:
    state = client.app_state["contextweb"]
    model = state.registry.get(model_id)
    learned = model.incremental_lda
    unfitted = {"objects": [{"features": {"entity": [0.0] * ENTITY_SIZE}}]}  # refused inside the write
    response = client.post(f"/v1/models/{model_id}/scenes", json=unfitted)
    assert response.status_code == 409 and response.json()["error"] == "model_not_fitted"
    assert model.unavailable is None and model.incremental_lda is learned, "a 422 must not reload the model"
    assert client.post(f"/v1/models/{model_id}/scenes", json=concept_scenes(1, seed=3)[0]).status_code == 201


def test_stored_changes_that_do_not_fit_memory_are_a_503_never_a_422(database_url: str) -> None:
    """The other process's rows were corrupted after it wrote them: catching up finds n_kw off."""
    settings = make_settings(database_url)
    with TestClient(create_app(settings)) as first, TestClient(create_app(settings)) as second:
        model_id = _create_with_scenes(first, 2)
        assert second.get(f"/v1/models/{model_id}").json()["scene_count"] == 2  # in the second's memory
        for scene in concept_scenes(3, seed=12):
            assert first.post(f"/v1/models/{model_id}/scenes", json=scene).status_code == 201
        engine = create_database_engine(database_url)
        with engine.begin() as connection:
            connection.execute(
                text("UPDATE context_word_count SET count = count + 1 WHERE model_id = :id AND version > 2"),
                {"id": model_id},
            )
        engine.dispose()
        response = second.post(f"/v1/models/{model_id}/scenes", json=concept_scenes(1, seed=0)[0])
        assert response.status_code == 503, response.text
        assert response.json()["error"] == "model_unavailable" and response.headers["Retry-After"]
        listed = {model["id"]: model for model in second.get("/v1/models").json()}
        assert listed[model_id]["status"] == "unavailable" and "n_kw" in listed[model_id]["unavailable_reason"]
