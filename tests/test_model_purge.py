"""Deleting a model marks it and answers at once; its rows are then purged a chunk per transaction
(app/purge.py, alembic 0012), and a purge cut short by a stop is finished by the next start."""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator

import pytest
import sqlalchemy as sa
from fastapi.testclient import TestClient
from sqlalchemy import Engine, event

from app import purge
from app.main import create_app
from app.state import AppState
from storage.models import Base
from storage.repositories import models as model_repository
from storage.unit_of_work import unit_of_work
from tests.conftest import FAST_HYPERPARAMETERS, concept_scenes, make_settings
from tests.faults import database_name, fresh_postgres_database, postgres_outage

CHUNK_ROWS = 4
SCENES = 14


@pytest.fixture(autouse=True)
def small_chunks(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(purge, "PURGE_CHUNK_ROWS", CHUNK_ROWS)


def _rows_of(engine: Engine, model_id: str) -> dict[str, int]:
    """How many rows of every table belong to ``model_id`` (the ``model`` row included)."""
    counts = {}
    with engine.connect() as connection:
        for table in Base.metadata.sorted_tables:
            column = table.c.get("model_id") if table.name != "model" else table.c.id
            if column is not None:
                counts[table.name] = connection.execute(
                    sa.select(sa.func.count()).select_from(table).where(column == model_id)
                ).scalar_one()
    return counts


def _model_with_scenes(client: TestClient, name: str, key: str | None = None) -> str:
    headers = {} if key is None else {"Idempotency-Key": key}
    created = client.post("/v1/models", json={"name": name, "hyperparameters": FAST_HYPERPARAMETERS}, headers=headers)
    assert created.status_code == 201, created.text
    model_id = created.json()["id"]
    for body in concept_scenes(SCENES, seed=3):
        assert client.post(f"/v1/models/{model_id}/scenes", json=body).status_code == 201
    return model_id


@pytest.fixture
def client_and_state(database_url: str) -> Iterator[tuple[TestClient, AppState]]:
    with TestClient(create_app(make_settings(database_url))) as client:
        yield client, client.app_state["contextweb"]


def test_a_deleted_model_is_gone_at_once_and_purged_a_chunk_per_transaction(
    client_and_state: tuple[TestClient, AppState],
) -> None:
    client, state = client_and_state
    doomed, kept = _model_with_scenes(client, "doomed", key="create-doomed"), _model_with_scenes(client, "kept")
    kept_rows = _rows_of(state.engine, kept)
    assert _rows_of(state.engine, doomed)["scene"] == SCENES
    chunks: list[tuple[str, int]] = []

    def record(_conn: object, _cursor: object, statement: str, _params: object, _context: object, _many: bool) -> None:
        words = statement.split()
        if words[:2] == ["DELETE", "FROM"] and words[2] in ("scene", "token_batch"):
            chunks.append((words[2], _cursor.rowcount))  # type: ignore[attr-defined]

    event.listen(state.engine, "after_cursor_execute", record)
    try:
        assert client.delete(f"/v1/models/{doomed}").status_code == 204
        assert client.get(f"/v1/models/{doomed}").status_code == 404
        assert client.post(f"/v1/models/{doomed}/scenes", json=concept_scenes(1, seed=4)[0]).status_code == 404
        assert [model["id"] for model in client.get("/v1/models").json()] == [kept]
        assert state.purger.wait_idle(60)
    finally:
        event.remove(state.engine, "after_cursor_execute", record)

    assert set(_rows_of(state.engine, doomed).values()) == {0}
    scene_chunks = [rows for table, rows in chunks if table == "scene"]
    assert sum(scene_chunks) == SCENES and max(scene_chunks) <= CHUNK_ROWS and len(scene_chunks) >= SCENES // CHUNK_ROWS
    assert max(rows for table, rows in chunks if table == "token_batch") <= CHUNK_ROWS
    assert _rows_of(state.engine, kept) == kept_rows
    assert client.get(f"/v1/models/{kept}/scenes").status_code == 200
    # The deleted model's Idempotency-Key is free: a creation under it makes a new model.
    again = client.post("/v1/models", json={"name": "again"}, headers={"Idempotency-Key": "create-doomed"})
    assert again.status_code == 201 and again.json()["id"] != doomed


def test_a_purge_cut_short_is_finished_by_the_next_start(database_url: str) -> None:
    """The database as a process leaves it that stopped after its delete's commit and one chunk."""
    with TestClient(create_app(make_settings(database_url))) as client:
        state: AppState = client.app_state["contextweb"]
        doomed, kept = _model_with_scenes(client, "doomed"), _model_with_scenes(client, "kept")
        state.purger.stop()  # this process purges nothing more
        with unit_of_work(state.write_sessions) as session:
            model_repository.delete_model(session, doomed)
        with unit_of_work(state.write_sessions) as session:
            assert model_repository.purge_chunk(session, doomed, CHUNK_ROWS) == CHUNK_ROWS
        engine = state.engine
        left = _rows_of(engine, doomed)
        assert left["model"] == 1 and left["scene"] == SCENES - CHUNK_ROWS

    with TestClient(create_app(make_settings(database_url))) as client:
        state = client.app_state["contextweb"]
        assert [model["id"] for model in client.get("/v1/models").json()] == [kept]
        assert client.get(f"/v1/models/{doomed}").status_code == 404
        assert state.purger.wait_idle(60)
        assert set(_rows_of(state.engine, doomed).values()) == {0}
        assert _rows_of(state.engine, kept)["scene"] == SCENES


def test_a_purge_never_touches_a_live_model(engine: Engine, client: TestClient) -> None:
    live = _model_with_scenes(client, "live")
    with unit_of_work(client.app_state["contextweb"].write_sessions) as session:
        assert model_repository.purge_chunk(session, live, CHUNK_ROWS) == 0
    assert _rows_of(engine, live)["scene"] == SCENES


def test_a_running_purger_finds_a_model_whose_deleting_process_stopped(
    database_url: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Marked by a process that stopped before purging it (here: marked from outside the app), the
    model is found by the running app's purger at its next scan."""
    monkeypatch.setattr(purge, "RESCAN_SECONDS", 0.2)
    with TestClient(create_app(make_settings(database_url))) as client:
        state: AppState = client.app_state["contextweb"]
        doomed = _model_with_scenes(client, "doomed")
        with unit_of_work(state.write_sessions) as session:
            model_repository.delete_model(session, doomed)
        deadline = time.monotonic() + 60
        while _rows_of(state.engine, doomed)["model"] and time.monotonic() < deadline:
            time.sleep(0.1)
        assert set(_rows_of(state.engine, doomed).values()) == {0}
        assert client.get(f"/v1/models/{doomed}").status_code == 404


@pytest.mark.postgres
def test_a_purge_outlives_a_postgresql_outage(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """The database refuses connections (and ends every open one) while a purge is due: its chunks
    fail and are retried, and once the database is back the purge ends with every row gone and the
    other model whole."""
    monkeypatch.setattr(purge, "RETRY_SECONDS", 0.2)
    with fresh_postgres_database() as url, TestClient(create_app(make_settings(url))) as client:
        state: AppState = client.app_state["contextweb"]
        doomed, kept = _model_with_scenes(client, "doomed"), _model_with_scenes(client, "kept")
        kept_rows = _rows_of(state.engine, kept)
        with unit_of_work(state.write_sessions) as session:  # marked by a process that stopped there
            model_repository.delete_model(session, doomed)
        with caplog.at_level(logging.WARNING, logger="contextweb"), postgres_outage(database_name(url)):
            state.purger.purge(doomed)
            time.sleep(1.5)
            assert not state.purger.wait_idle(0)
        assert state.purger.wait_idle(60)
        assert any("purging its rows failed" in record.getMessage() for record in caplog.records)
        assert set(_rows_of(state.engine, doomed).values()) == {0}
        assert _rows_of(state.engine, kept) == kept_rows
        assert client.get(f"/v1/models/{kept}").json()["scene_count"] == SCENES
