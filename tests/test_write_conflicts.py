"""A write that collides with a row the database already holds (a writer that ignored the model's
lock, or rows restored from elsewhere) is a 503 ``model_unavailable`` to retry, never a 500: nothing
of it is stored or acknowledged, memory follows the database, and once the stray row is gone the
model serves again. The collision is real: the row is inserted from outside, as such a writer would."""

from __future__ import annotations

from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine, text

from app import registry
from storage.database import create_session_makers
from storage.repositories.consistency import check_model
from tests.conftest import concept_scenes


def _one(engine: Engine, statement: str, **parameters: Any) -> Any:
    with engine.connect() as connection:
        return connection.execute(text(statement), parameters).one()


def _execute(engine: Engine, statement: str, **parameters: Any) -> None:
    with engine.begin() as connection:
        connection.execute(text(statement), parameters)


def _stored(engine: Engine, model_id: str) -> tuple[int, int, int]:
    """The state row's version, the scene rows and the token batches of the model."""
    row = _one(
        engine,
        "SELECT (SELECT version FROM incremental_lda_state WHERE model_id = :m) AS version, "
        "(SELECT count(*) FROM scene WHERE model_id = :m) AS scenes, "
        "(SELECT count(*) FROM token_batch WHERE model_id = :m) AS batches",
        m=model_id,
    )
    return int(row.version), int(row.scenes), int(row.batches)


def test_a_scene_colliding_with_a_stored_row_is_a_503_that_stores_nothing(
    client: TestClient, engine: Engine, model_id: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    # No backoff: every request below that meets the unavailable model tries to load it again.
    monkeypatch.setattr(registry, "RELOAD_BACKOFF_SECONDS", 0.0)
    monkeypatch.setattr(registry, "FAILED_CHECK_RECHECK_SECONDS", 0.0)
    url = f"/v1/models/{model_id}/scenes"
    scenes = concept_scenes(9, seed=6)
    for body in scenes[:6]:
        assert client.post(url, json=body).status_code == 201
    version, scene_rows, batches = _stored(engine, model_id)
    tokens = _one(engine, "SELECT sum(token_count) AS n FROM token_batch WHERE model_id = :m", m=model_id).n
    # The batch the next scene would write, already there: a copy of the last one at the next version.
    _execute(
        engine,
        "INSERT INTO token_batch (model_id, version, scene_id, first_token, token_count, packed) "
        "SELECT model_id, version + 1, scene_id + 1, first_token + token_count, token_count, packed "
        "FROM token_batch WHERE model_id = :m AND version = :v",
        m=model_id,
        v=version,
    )

    refused = client.post(url, json=scenes[6], headers={"Idempotency-Key": "collides"})
    assert refused.status_code == 503, refused.text
    assert refused.headers["Retry-After"] == "1"
    assert refused.json()["error"] == "model_unavailable"
    assert "conflicts with a stored row" in refused.json()["detail"]
    assert _stored(engine, model_id) == (version, scene_rows, batches + 1)  # nothing of the scene was stored
    # While the stray row stays, the model stays unavailable: its stored state fails the load's check.
    again = client.post(url, json=scenes[6], headers={"Idempotency-Key": "collides"})
    assert again.status_code == 503 and "failed its check" in again.json()["detail"], again.text

    read, _ = create_session_makers(engine)
    with read() as session:
        problems = check_model(session, model_id)
    assert any(
        problem.endswith(f"have a scene id with no scene row, first token {tokens} (scene {scene_rows})")
        for problem in problems
    ), problems
    # Mended by hand (the version stays where it was): the model is checked again and serves.
    _execute(engine, "DELETE FROM token_batch WHERE model_id = :m AND version = :v", m=model_id, v=version + 1)
    retried = client.post(url, json=scenes[6], headers={"Idempotency-Key": "collides"})
    assert retried.status_code == 201, retried.text
    assert retried.json()["scene_id"] == scene_rows
    assert client.post(url, json=scenes[7]).status_code == 201
    assert _stored(engine, model_id) == (version + 2, scene_rows + 2, batches + 2)
    with read() as session:
        assert check_model(session, model_id) == []
    assert client.get(f"/v1/models/{model_id}").json()["scene_count"] == scene_rows + 2
