"""API keys: a write key for robots, a read key for dashboards; no key means loopback only."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient
from pydantic import ValidationError
from starlette.websockets import WebSocketDisconnect

from app.main import create_app
from app.settings import Settings
from app.stream import CLOSE_UNAUTHORIZED
from tests.conftest import make_settings

WRITE, READ = {"X-API-Key": "robot-secret"}, {"X-API-Key": "dashboard-secret"}
SCENE = {"objects": [{"concepts": ["cup", "hard"]}]}


@pytest.fixture
def secured(database_url: str):
    settings = make_settings(database_url, write_key="robot-secret", read_key="dashboard-secret")
    with TestClient(create_app(settings)) as client:
        yield client


def test_missing_or_wrong_keys_are_401_and_the_read_key_cannot_write(secured: TestClient) -> None:
    assert secured.get("/v1/models").status_code == 401
    assert secured.get("/v1/models", headers={"X-API-Key": "guess"}).status_code == 401
    refused = secured.post("/v1/models", json={"name": "m"})
    assert refused.status_code == 401 and refused.headers["WWW-Authenticate"] == "ApiKey"
    assert refused.json()["field"] == "header.X-API-Key"

    forbidden = secured.post("/v1/models", json={"name": "m"}, headers=READ)
    assert forbidden.status_code == 403 and forbidden.json()["error"] == "forbidden"
    model_id = secured.post("/v1/models", json={"name": "m"}, headers=WRITE).json()["id"]
    assert secured.post(f"/v1/models/{model_id}/scenes", json=SCENE, headers=READ).status_code == 403
    assert secured.post(f"/v1/models/{model_id}/scenes", json=SCENE, headers=WRITE).status_code == 201
    assert secured.delete(f"/v1/models/{model_id}", headers=READ).status_code == 403

    assert secured.get(f"/v1/models/{model_id}/contexts", headers=READ).status_code == 200
    assert secured.post(f"/v1/models/{model_id}/infer", json=SCENE, headers=READ).status_code == 200
    assert secured.get(f"/v1/models/{model_id}/scenes", headers=WRITE).status_code == 200
    assert secured.get("/healthz").status_code == 200 and secured.get("/readyz").status_code == 200


def test_the_stream_needs_a_key_too(secured: TestClient) -> None:
    model_id = secured.post("/v1/models", json={"name": "m"}, headers=WRITE).json()["id"]
    with pytest.raises(WebSocketDisconnect) as closed, secured.websocket_connect(f"/v1/models/{model_id}/stream") as ws:
        ws.receive_json()
    assert closed.value.code == CLOSE_UNAUTHORIZED
    with secured.websocket_connect(f"/v1/models/{model_id}/stream?api_key=dashboard-secret") as ws:
        assert ws.receive_json()["type"] == "hello"


def test_without_keys_the_server_binds_loopback_only() -> None:
    assert Settings(host="0.0.0.0", write_key=None, read_key=None).bind_host() == "127.0.0.1"
    assert Settings(host="0.0.0.0", write_key="w", read_key=None).bind_host() == "0.0.0.0"
    with pytest.raises(ValidationError, match="without CONTEXTWEB_WRITE_KEY"):
        Settings(write_key=None, read_key="r")
    with pytest.raises(ValidationError, match="production needs CONTEXTWEB_WRITE_KEY"):
        Settings(environment="production", write_key=None, read_key=None)


def test_any_header_value_is_a_401_never_a_500(secured: TestClient) -> None:
    """Keys are compared as bytes: a non-ASCII key (seen as a 500 with a traceback) is only a wrong key."""
    for key in ("é", "robot-secreté", "\u2603" * 40):
        response = secured.get("/v1/models", headers={"X-API-Key": key.encode()})
        assert response.status_code == 401 and response.json()["error"] == "unauthorized", key
    model_id = secured.post("/v1/models", json={"name": "m"}, headers=WRITE).json()["id"]
    stream = f"/v1/models/{model_id}/stream?api_key=%C3%A9"
    with pytest.raises(WebSocketDisconnect) as closed, secured.websocket_connect(stream) as ws:
        ws.receive_json()
    assert closed.value.code == CLOSE_UNAUTHORIZED


def test_an_empty_key_is_unset_and_never_matches(database_url: str) -> None:
    """An operator who exports an empty read key gets no read key, and an empty presented key opens nothing."""
    settings = make_settings(database_url, write_key="robot-secret", read_key="")
    assert settings.read_key is None
    with TestClient(create_app(settings)) as client:
        model_id = client.post("/v1/models", json={"name": "m"}, headers=WRITE).json()["id"]
        assert client.get("/v1/models", headers={"X-API-Key": ""}).status_code == 401
        stream = f"/v1/models/{model_id}/stream?api_key="
        with pytest.raises(WebSocketDisconnect) as closed, client.websocket_connect(stream) as ws:
            ws.receive_json()
        assert closed.value.code == CLOSE_UNAUTHORIZED
    assert make_settings(database_url, write_key="", read_key="").write_key is None
