"""A restarted server continues exactly where it stopped (§IV-C online learning, persisted scene by scene).

Two models with the same seed see the same scenes: one in a single server run,
the other across a restart after half of them. The answers after the restart,
the next posterior, K, the assignments and the counts are identical.
"""

from __future__ import annotations

from fastapi.testclient import TestClient

from app.main import create_app
from tests.conftest import FAST_HYPERPARAMETERS, assert_same_state, concept_scenes, make_settings, memory_state


def _post(client: TestClient, model_id: str, scenes: list[dict]) -> list[dict]:
    answers = []
    for body in scenes:
        response = client.post(f"/v1/models/{model_id}/scenes", json=body)
        assert response.status_code == 201, response.text
        answers.append({k: v for k, v in response.json().items() if k not in ("model_id", "created_at")})
    return answers


def _create(client: TestClient) -> str:
    body = {"name": "robot", "seed": 42, "hyperparameters": FAST_HYPERPARAMETERS}
    return client.post("/v1/models", json=body).json()["id"]


def test_restart_continues_exactly_like_an_uninterrupted_run(database_url: str) -> None:
    scenes = concept_scenes(24, seed=3)
    settings = make_settings(database_url)
    with TestClient(create_app(settings)) as client:
        uninterrupted = _create(client)
        expected = _post(client, uninterrupted, scenes)
        expected_state = memory_state(client, uninterrupted)
        restarted = _create(client)
        before = _post(client, restarted, scenes[:13])
    with TestClient(create_app(settings)) as client:
        after = _post(client, restarted, scenes[13:])
        state = memory_state(client, restarted)
        assert memory_state(client, uninterrupted).rng_state == expected_state.rng_state

    assert before + after == expected
    assert max(answer["context_count"] for answer in expected) > 1, "the scenes should make K grow"
    assert_same_state(state, expected_state)
