"""Probes and metrics: liveness, readiness (database and models), Prometheus."""

from __future__ import annotations

from fastapi.testclient import TestClient
from sqlalchemy import create_engine

from app.state import AppState


def test_liveness_readiness_and_metrics(client: TestClient, model_id: str) -> None:
    assert client.get("/healthz").json() == {"status": "ok"}
    assert client.get("/readyz").json() == {"status": "ready", "models_loaded": 1}
    client.post(f"/v1/models/{model_id}/scenes", json={"objects": [{"concepts": ["cup"]}]})
    metrics = client.get("/metrics")
    assert metrics.status_code == 200
    assert 'handler="/v1/models/{model_id}/scenes"' in metrics.text


def test_not_ready_without_a_database_or_before_models_are_loaded(client: TestClient) -> None:
    state: AppState = client.app_state["contextweb"]
    state.models_loaded = False
    response = client.get("/readyz")
    assert response.status_code == 503 and response.json()["detail"] == "models are still loading"
    state.models_loaded = True
    unreachable = create_engine("postgresql+psycopg://nobody@127.0.0.1:1/none", connect_args={"connect_timeout": 1})
    state.read_sessions.configure(bind=unreachable)
    response = client.get("/readyz")
    assert response.status_code == 503 and response.json()["error"] == "not_ready"
    assert "database unreachable" in response.json()["detail"]
