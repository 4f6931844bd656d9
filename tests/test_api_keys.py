"""Stored API keys: a role and a model scope per robot or dashboard, hashed, revoked at once, on every process."""

from __future__ import annotations

import hashlib
from collections.abc import Iterator

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine, select

from app.cli import main
from app.main import create_app
from storage.models import ApiKey
from tests.conftest import make_settings

ADMIN = {"X-API-Key": "bootstrap-admin"}
READ_ALL = {"X-API-Key": "bootstrap-read"}
SCENE = {"objects": [{"concepts": ["cup", "hard"]}]}


def _secured_app(database_url: str) -> TestClient:
    return TestClient(create_app(make_settings(database_url, write_key="bootstrap-admin", read_key="bootstrap-read")))


@pytest.fixture
def secured(database_url: str) -> Iterator[TestClient]:
    with _secured_app(database_url) as client:
        yield client


def _new_key(client: TestClient, name: str, role: str, models: list[str] | None = None) -> dict[str, str]:
    response = client.post("/v1/keys", json={"name": name, "role": role, "models": models}, headers=ADMIN)
    assert response.status_code == 201, response.text
    return {"X-API-Key": response.json()["key"]}


def _new_model(client: TestClient, name: str, headers: dict[str, str] = ADMIN) -> str:
    response = client.post("/v1/models", json={"name": name}, headers=headers)
    assert response.status_code == 201, response.text
    return response.json()["id"]


def test_a_scoped_key_uses_only_its_models_and_sees_no_other(secured: TestClient) -> None:
    mine, other = _new_model(secured, "mine"), _new_model(secured, "other")
    robot = _new_key(secured, "robot-7", "write", [mine])
    dashboard = _new_key(secured, "dashboard-7", "read", [mine])

    assert secured.post(f"/v1/models/{mine}/scenes", json=SCENE, headers=robot).status_code == 201
    assert secured.get(f"/v1/models/{mine}/contexts", headers=dashboard).status_code == 200
    assert [m["id"] for m in secured.get("/v1/models", headers=robot).json()] == [mine]
    assert [m["id"] for m in secured.get("/v1/models", headers=dashboard).json()] == [mine]
    assert {m["id"] for m in secured.get("/v1/models", headers=READ_ALL).json()} == {mine, other}

    # Another model answers exactly as a model that does not exist: its existence does not leak.
    missing = "0123456789abcdef0123456789abcdef"
    assert secured.get(f"/v1/models/{missing}", headers=ADMIN).json() == _not_found(missing)
    for headers in (robot, dashboard):
        for method, path in [
            ("GET", f"/v1/models/{other}"),
            ("GET", f"/v1/models/{other}/contexts"),
            ("POST", f"/v1/models/{other}/scenes"),
            ("POST", f"/v1/models/{other}/infer"),
            ("DELETE", f"/v1/models/{other}"),
        ]:
            response = secured.request(method, path, json=SCENE if method == "POST" else None, headers=headers)
            assert response.status_code == 404, (method, path)
            assert response.json() == _not_found(other)

    refused = secured.post(f"/v1/models/{mine}/scenes", json=SCENE, headers=dashboard)
    assert refused.status_code == 403 and refused.json()["error"] == "forbidden"
    creating = secured.post("/v1/models", json={"name": "new"}, headers=robot)
    assert creating.status_code == 403 and "scoped" in creating.json()["detail"]
    assert secured.get("/v1/keys", headers=robot).status_code == 403
    assert secured.delete(f"/v1/models/{mine}", headers=dashboard).status_code == 403
    assert secured.delete(f"/v1/models/{mine}", headers=robot).status_code == 204
    assert secured.get(f"/v1/models/{other}", headers=ADMIN).status_code == 200


def _not_found(model_id: str) -> dict[str, str]:
    return {"error": "model_not_found", "detail": f"no model {model_id!r}", "field": "path.model_id"}


def test_roles_read_write_admin(secured: TestClient) -> None:
    model = _new_model(secured, "m")
    reader, writer, admin = (_new_key(secured, role, role) for role in ("read", "write", "admin"))
    assert secured.post(f"/v1/models/{model}/scenes", json=SCENE, headers=reader).status_code == 403
    created = _new_model(secured, "by-the-writer", headers=writer)  # a write key of every model creates models
    assert secured.post(f"/v1/models/{created}/scenes", json=SCENE, headers=writer).status_code == 201
    for headers in (reader, writer, READ_ALL):
        response = secured.post("/v1/keys", json={"name": "x", "role": "read"}, headers=headers)
        assert response.status_code == 403 and response.json()["field"] == "header.X-API-Key"
    assert secured.post("/v1/keys", json={"name": "x", "role": "read"}).status_code == 401
    assert secured.post("/v1/keys", json={"name": "by-admin", "role": "write"}, headers=admin).status_code == 201
    assert secured.delete(f"/v1/models/{created}", headers=admin).status_code == 204


def test_a_key_names_existing_models_and_an_admin_key_no_model(secured: TestClient) -> None:
    model = _new_model(secured, "m")
    cases = [
        ({"name": "k", "role": "read", "models": [model, "nosuchmodel"]}, "models[1]"),
        ({"name": "k", "role": "admin", "models": [model]}, "models"),
        ({"name": "k", "role": "read", "models": []}, "models"),
        ({"name": "k", "role": "owner"}, "role"),
        ({"name": "", "role": "read"}, "name"),
        ({"name": "k", "role": "read", "secret": "mine"}, "secret"),
    ]
    for body, field in cases:
        response = secured.post("/v1/keys", json=body, headers=ADMIN)
        assert response.status_code == 422 and response.json()["field"] == field, (body, response.text)
    assert secured.get("/v1/keys", headers=ADMIN).json() == []


def test_only_the_hash_is_stored_and_the_secret_is_shown_once(secured: TestClient, engine: Engine) -> None:
    model = _new_model(secured, "m")
    created = secured.post("/v1/keys", json={"name": "robot", "role": "write", "models": [model]}, headers=ADMIN)
    body = created.json()
    key = body["key"]
    assert key.startswith(f"cw_{body['id']}_") and len(key) == 3 + 16 + 1 + 43
    assert key.startswith(body["prefix"]) and len(body["prefix"]) == 24
    with engine.connect() as connection:
        row = connection.execute(select(ApiKey)).one()
    assert row.secret_hash == hashlib.sha256(key.encode()).hexdigest()
    secret = key.removeprefix(f"cw_{body['id']}_")  # base64url: the secret itself may hold "_"
    assert all(secret not in str(value) for value in row)
    listed = secured.get("/v1/keys", headers=ADMIN)
    assert secret not in listed.text and "key" not in listed.json()[0] and "secret_hash" not in listed.json()[0]
    assert listed.json()[0] == {k: v for k, v in body.items() if k != "key"}
    assert listed.json()[0]["models"] == [model] and listed.json()[0]["revoked_at"] is None


def test_a_wrong_or_forged_key_is_a_401(secured: TestClient) -> None:
    key = _new_key(secured, "robot", "write")["X-API-Key"]
    key_id, secret = key[3:19], key[20:]
    forged = [
        f"cw_{key_id}_{secret[:-1]}{'A' if secret[-1] != 'A' else 'B'}",  # the right id, another secret
        f"cw_{'0' * 16}_{secret}",  # the right secret, another id
        key + "x",
        key.upper(),
        key[:-1] + "é",
    ]
    for value in forged:
        response = secured.get("/v1/models", headers={"X-API-Key": value.encode()})
        assert response.status_code == 401 and response.json()["error"] == "unauthorized", value
    assert secured.get("/v1/models", headers={"X-API-Key": key}).status_code == 200


def test_a_revoked_key_is_refused_on_its_next_request_on_every_process(database_url: str) -> None:
    """Two apps on one database stand for two server processes."""
    with _secured_app(database_url) as first, _secured_app(database_url) as second:
        model = _new_model(first, "m")
        robot = _new_key(first, "robot", "write", [model])
        key_id = robot["X-API-Key"][3:19]
        assert second.post(f"/v1/models/{model}/scenes", json=SCENE, headers=robot).status_code == 201
        assert first.get(f"/v1/models/{model}", headers=robot).status_code == 200

        assert first.delete(f"/v1/keys/{key_id}", headers=ADMIN).status_code == 204
        refused = second.post(f"/v1/models/{model}/scenes", json=SCENE, headers=robot)
        assert refused.status_code == 401 and refused.json()["error"] == "unauthorized"
        assert first.get(f"/v1/models/{model}", headers=robot).status_code == 401

        revoked_at = second.get("/v1/keys", headers=ADMIN).json()[0]["revoked_at"]
        assert revoked_at is not None
        assert second.delete(f"/v1/keys/{key_id}", headers=ADMIN).status_code == 204  # idempotent
        assert first.get("/v1/keys", headers=ADMIN).json()[0]["revoked_at"] == revoked_at
        unknown = first.delete("/v1/keys/0000000000000000", headers=ADMIN)
        assert unknown.status_code == 404 and unknown.json() == {
            "error": "key_not_found",
            "detail": "no API key '0000000000000000'",
            "field": "path.key_id",
        }


def test_the_cli_creates_lists_and_revokes_keys(
    cli_database: str, secured: TestClient, capsys: pytest.CaptureFixture[str]
) -> None:
    model = _new_model(secured, "m")
    assert main(["keys", "list"]) == 0
    assert capsys.readouterr().out == "no keys stored\n"

    assert main(["keys", "create", "--name", "robot-7", "--role", "write", "--model", model]) == 0
    printed = capsys.readouterr()
    key = printed.out.strip()
    assert key.startswith("cw_") and "\n" not in key and "robot-7" in printed.err
    robot = {"X-API-Key": key}
    assert secured.post(f"/v1/models/{model}/scenes", json=SCENE, headers=robot).status_code == 201

    assert main(["keys", "list"]) == 0
    (line,) = capsys.readouterr().out.splitlines()
    key_id = key[3:19]
    assert line.startswith(f"{key_id}  {key[:24]}…  write  active") and line.endswith(f"robot-7  ({model})")
    assert key[24:] not in line

    assert main(["keys", "revoke", key_id]) == 0
    assert "revoked" in capsys.readouterr().out
    assert secured.get(f"/v1/models/{model}", headers=robot).status_code == 401
    assert main(["keys", "revoke", "0000000000000000"]) == 2
    assert main(["keys", "create", "--name", "x", "--role", "read", "--model", "nosuchmodel"]) == 1
    assert "no model 'nosuchmodel'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["keys", "create", "--name", "x", "--role", "owner"])


def test_a_keyed_key_creation_retried_makes_no_second_key_and_names_the_first(secured: TestClient) -> None:
    """Before, the Idempotency-Key was ignored and a retry made a second key whose secret nobody held.
    The secret is stored only as a hash, so a retry cannot get it again: a 409 names the key to revoke."""
    body = {"name": "robot-7", "role": "write", "models": None}
    headers = {**ADMIN, "Idempotency-Key": "key-creation-1"}
    first = secured.post("/v1/keys", json=body, headers=headers)
    assert first.status_code == 201
    created = first.json()
    retried = secured.post("/v1/keys", json=body, headers=headers)
    assert retried.status_code == 409
    error = retried.json()
    assert error["error"] == "key_already_created" and error["field"] == "header.Idempotency-Key"
    assert f"created key {created['id']!r}" in error["detail"] and f"DELETE /v1/keys/{created['id']}" in error["detail"]
    assert "cw_" not in retried.text  # never the secret
    assert [key["id"] for key in secured.get("/v1/keys", headers=ADMIN).json() if key["name"] == "robot-7"] == [
        created["id"]
    ]
    assert secured.get("/v1/models", headers={"X-API-Key": created["key"]}).status_code == 200

    other_body = secured.post("/v1/keys", json={**body, "role": "read"}, headers=headers)
    assert other_body.status_code == 422 and other_body.json()["error"] == "idempotency_key_reused"

    assert secured.delete(f"/v1/keys/{created['id']}", headers=ADMIN).status_code == 204
    again = secured.post("/v1/keys", json=body, headers={**ADMIN, "Idempotency-Key": "key-creation-2"})
    assert again.status_code == 201 and again.json()["id"] != created["id"]
    assert secured.get("/v1/models", headers={"X-API-Key": again.json()["key"]}).status_code == 200


def test_keyless_key_creations_each_make_a_key(secured: TestClient) -> None:
    body = {"name": "dashboard", "role": "read", "models": None}
    ids = {secured.post("/v1/keys", json=body, headers=ADMIN).json()["id"] for _ in range(2)}
    assert len(ids) == 2


def test_two_creations_racing_on_one_idempotency_key_make_one_key(
    secured: TestClient, engine: Engine, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The later creation's lookup ran before the earlier one committed (its look-up is made to find
    nothing, as it would then): its insert meets the key's unique index in the database, is undone,
    and is answered 409 naming the earlier key."""
    from sqlalchemy.orm import Session

    from app.errors import KeyAlreadyCreated
    from app.schemas.keys import ApiKeyCreate
    from app.services import keys as key_service
    from storage.repositories import api_keys as api_key_repository

    body = {"name": "racer", "role": "write", "models": None}
    earlier = secured.post("/v1/keys", json=body, headers={**ADMIN, "Idempotency-Key": "raced"}).json()
    find = api_key_repository.find_by_idempotency_key
    calls: list[str] = []

    def not_yet_committed(session: Session, idempotency_key: str) -> ApiKey | None:
        calls.append(idempotency_key)
        return None if len(calls) == 1 else find(session, idempotency_key)

    monkeypatch.setattr(api_key_repository, "find_by_idempotency_key", not_yet_committed)
    with Session(engine) as session, pytest.raises(KeyAlreadyCreated) as refused:
        key_service.create_key(session, ApiKeyCreate.model_validate(body), "raced")
    assert refused.value.status_code == 409 and earlier["id"] in refused.value.message and len(calls) == 2
    with Session(engine) as session:
        assert session.scalars(select(ApiKey.id).where(ApiKey.name == "racer")).all() == [earlier["id"]]
