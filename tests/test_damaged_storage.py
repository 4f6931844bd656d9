"""Stored bytes damaged behind the server's back (bit rot, a bad restore, a half-written file).

Each test damages one model's rows from outside, with plain SQL on the real database, as an
operator would meet it, then checks the contract of issue 13: the server starts, the damaged
model is listed unavailable with its reason (or, where only one scene's answer is damaged,
answers that scene with a clear 500 ``stored_data_damaged``), the other models serve, no answer
is a bare 500, and ``contextweb models check`` names the damage (``repair`` mends what is derived).
Found by a drill by hand (docs/operations.md, "Damaged storage").
"""

from __future__ import annotations

import logging
import sqlite3
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine, text
from sqlalchemy.exc import DatabaseError
from starlette.applications import Starlette
from starlette.middleware import Middleware
from starlette.requests import Request
from starlette.routing import Route

from app.cli import main
from app.errors import is_storage_damage
from app.main import create_app
from app.middleware import UnexpectedErrors
from storage.database import create_database_engine
from storage.migrations import upgrade_to_head
from tests.conftest import FAST_HYPERPARAMETERS, concept_scenes, make_settings


def _execute(engine: Engine, statement: str, **parameters: Any) -> None:
    with engine.begin() as connection:
        connection.execute(text(statement), parameters)


def _scalar(engine: Engine, statement: str, **parameters: Any) -> Any:
    with engine.connect() as connection:
        return connection.execute(text(statement), parameters).scalar()


def _model_with_scenes(client: TestClient, name: str, count: int, *, keyed: bool = False) -> str:
    model_id = client.post(
        "/v1/models", json={"name": name, "seed": 3, "hyperparameters": FAST_HYPERPARAMETERS}
    ).json()["id"]
    for i, body in enumerate(concept_scenes(count, seed=8)):
        headers = {"Idempotency-Key": f"{name}-{i}"} if keyed else {}
        assert client.post(f"/v1/models/{model_id}/scenes", json=body, headers=headers).status_code == 201
    return model_id


def _check(model_id: str, capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    code = main(["models", "check", model_id])
    return code, capsys.readouterr().out


def test_a_damaged_answer_is_a_clear_500_for_that_scene_and_check_names_it(
    cli_database: str, engine: Engine, capsys: pytest.CaptureFixture[str]
) -> None:
    settings = make_settings(cli_database)
    with TestClient(create_app(settings)) as client:
        model_id = _model_with_scenes(client, "robot", 6, keyed=True)
    _execute(
        engine,
        "UPDATE scene SET answer_zlib = :damaged WHERE model_id = :m AND id = 3",
        damaged=b"\x02" + bytes(40),
        m=model_id,
    )
    url = f"/v1/models/{model_id}/scenes"
    with TestClient(create_app(settings)) as client:
        damaged = client.get(f"{url}/3")
        assert damaged.status_code == 500 and damaged.json()["error"] == "stored_data_damaged", damaged.text
        assert "scene 3" in damaged.json()["detail"] and "models check" in damaged.json()["detail"]
        assert client.get(f"{url}/2").status_code == 200, "the other scenes answer"
        replay = client.post(url, json=concept_scenes(6, seed=8)[3], headers={"Idempotency-Key": "robot-3"})
        assert replay.status_code == 500 and replay.json()["error"] == "stored_data_damaged"
        assert "stored and learned under this Idempotency-Key" in replay.json()["detail"]
        reused = client.post(url, json=concept_scenes(6, seed=8)[4], headers={"Idempotency-Key": "robot-3"})
        assert reused.status_code == 422 and reused.json()["error"] == "idempotency_key_reused"
        assert client.post(url, json=concept_scenes(1, seed=2)[0]).status_code == 201, "the model learns on"
        assert client.get(f"/v1/models/{model_id}").json()["status"] == "available"
    code, out = _check(model_id, capsys)
    assert code == 1 and "1 stored answer cannot be read, first scene 3" in out and "not repairable" in out, out


@pytest.mark.parametrize(
    ("column", "wrong", "named"),
    [
        ("hyperparameters", '{"priors": {"alpha": "lots"}, "sampler": 7}', "alpha"),
        ("vocabulary", '{"nouns": 42, "adjective_pairs": [], "verbs": []}', "model.vocabulary"),
    ],
)
def test_a_model_row_of_the_wrong_shape_leaves_the_listing_and_the_other_models_serving(
    cli_database: str, engine: Engine, capsys: pytest.CaptureFixture[str], column: str, wrong: str, named: str
) -> None:
    settings = make_settings(cli_database)
    with TestClient(create_app(settings)) as client:
        damaged = _model_with_scenes(client, "damaged", 3)
        healthy = _model_with_scenes(client, "healthy", 3)
    cast = "CAST(:value AS JSONB)" if engine.dialect.name == "postgresql" else ":value"
    _execute(engine, f"UPDATE model SET {column} = {cast} WHERE id = :m", value=wrong, m=damaged)
    with TestClient(create_app(settings)) as client:
        listing = client.get("/v1/models")
        assert listing.status_code == 200, listing.text
        listed = {model["id"]: model for model in listing.json()}
        assert listed[damaged]["status"] == "unavailable" and listed[damaged][column] is None, "never made up"
        assert named in listed[damaged]["unavailable_reason"]
        assert listed[damaged]["scene_count"] == 3, "listed with its stored scenes, not the stand-in's empty memory"
        assert listed[healthy]["status"] == "available" and listed[healthy][column] is not None
        answer = client.get(f"/v1/models/{damaged}/contexts")
        assert answer.status_code == 503 and answer.json()["error"] == "model_unavailable"
        assert client.post(f"/v1/models/{healthy}/scenes", json=concept_scenes(1, seed=1)[0]).status_code == 201
    code, out = _check(damaged, capsys)
    assert code == 1 and "a server cannot load it" in out and named in out, out
    assert main(["models", "repair", damaged]) == 1
    assert "not repaired, nothing changed" in capsys.readouterr().out


def test_undecodable_json_in_a_model_row_does_not_stop_the_server_from_starting(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """SQLite stores JSON as text, so a damaged byte can leave a row that no JSON decoder reads
    (PostgreSQL's jsonb refuses such a value)."""
    url = f"sqlite:///{tmp_path / 'damaged.sqlite3'}"
    engine = create_database_engine(url)
    upgrade_to_head(engine)
    settings = make_settings(url)
    with TestClient(create_app(settings)) as client:
        damaged = _model_with_scenes(client, "damaged", 3)
        healthy = _model_with_scenes(client, "healthy", 3)
    for column in ("vocabulary", "hyperparameters"):
        original = _scalar(engine, f"SELECT {column} FROM model WHERE id = :m", m=damaged)
        _execute(engine, f"UPDATE model SET {column} = :value WHERE id = :m", value='{"nouns": [', m=damaged)
        with TestClient(create_app(settings)) as client:
            assert client.get("/readyz").status_code == 200, "the server starts"
            listed = {model["id"]: model for model in client.get("/v1/models").json()}
            assert listed[damaged]["status"] == "unavailable"
            assert "its stored row cannot be read" in listed[damaged]["unavailable_reason"]
            response = client.post(f"/v1/models/{damaged}/scenes", json=concept_scenes(1, seed=1)[0])
            assert response.status_code == 503 and response.json()["error"] == "model_unavailable"
            assert client.post(f"/v1/models/{healthy}/scenes", json=concept_scenes(1, seed=1)[0]).status_code == 201
        monkeypatch.setenv("CONTEXTWEB_DATABASE_URL", url)
        code = main(["models", "check"])
        out = capsys.readouterr().out
        assert code == 1 and f"model.{column} cannot be read" in out and f"{healthy} healthy: ok" in out, out
        _execute(engine, f"UPDATE model SET {column} = :value WHERE id = :m", value=original, m=damaged)
    engine.dispose()


def test_token_batches_above_the_models_version_make_it_unavailable_until_repaired(
    cli_database: str, engine: Engine, capsys: pytest.CaptureFixture[str]
) -> None:
    """The state row restored behind its batches: before, the model loaded and every write to it
    collided with a stored batch (a 503 that said to retry, forever)."""
    settings = make_settings(cli_database)
    with TestClient(create_app(settings)) as client:
        model_id = _model_with_scenes(client, "robot", 8)
    _execute(engine, "UPDATE incremental_lda_state SET version = version - 3 WHERE model_id = :m", m=model_id)
    with TestClient(create_app(settings)) as client:
        (listed,) = client.get("/v1/models").json()
        assert listed["status"] == "unavailable" and "above the model's version" in listed["unavailable_reason"]
        refused = client.post(f"/v1/models/{model_id}/scenes", json=concept_scenes(1, seed=1)[0])
        assert refused.status_code == 503 and "above the model's version" in refused.json()["detail"]
    code, out = _check(model_id, capsys)
    assert code == 1 and "repairable" in out, out
    assert main(["models", "repair", model_id]) == 0
    capsys.readouterr()
    with TestClient(create_app(settings)) as client:
        response = client.post(f"/v1/models/{model_id}/scenes", json=concept_scenes(1, seed=1)[0])
        assert response.status_code == 201 and response.json()["scene_id"] == 8, response.text


def test_a_damaged_batch_the_checkpoint_covers_is_named_and_repair_drops_the_covered_batches(
    cli_database: str, engine: Engine, capsys: pytest.CaptureFixture[str]
) -> None:
    settings = make_settings(cli_database, checkpoint_interval=5)
    with TestClient(create_app(settings)) as client:
        model_id = _model_with_scenes(client, "robot", 12)  # checkpoints at scenes 5 and 10: batches 6-10 kept
    covered = _scalar(
        engine,
        "SELECT min(version) FROM token_batch WHERE model_id = :m AND version <= "
        "(SELECT version FROM incremental_lda_checkpoint WHERE model_id = :m)",
        m=model_id,
    )
    assert covered is not None, "the checkpoint keeps the batches it covers for catching up"
    _execute(
        engine, "UPDATE token_batch SET packed = :damaged WHERE model_id = :m AND version = :v",
        damaged=bytes(30), m=model_id, v=covered,
    )  # fmt: skip
    code, out = _check(model_id, capsys)
    assert code == 1 and f"token_batch at version {covered} cannot be read" in out and "all repairable" in out, out
    assert main(["models", "repair", model_id]) == 0
    out = capsys.readouterr().out
    assert "the checkpoint" in out and "deleted" in out, out
    assert _check(model_id, capsys)[0] == 0
    with TestClient(create_app(settings)) as client:
        assert client.post(f"/v1/models/{model_id}/scenes", json=concept_scenes(1, seed=1)[0]).status_code == 201


def test_a_database_page_damaged_under_sqlite_is_recognised_as_damage(tmp_path: Path) -> None:
    """SQLite's own "database disk image is malformed", from a page overwritten with zeros."""
    path = tmp_path / "pages.sqlite3"
    with sqlite3.connect(path) as connection:
        connection.execute("CREATE TABLE item (id INTEGER PRIMARY KEY, payload BLOB)")
        connection.executemany("INSERT INTO item VALUES (?, ?)", [(i, bytes(500)) for i in range(2_000)])
    page_size = 4096
    with path.open("r+b") as database:
        database.seek(page_size * 40)
        database.write(bytes(page_size))
    engine = create_database_engine(f"sqlite:///{path}")
    with pytest.raises(DatabaseError) as raised, engine.connect() as connection:
        connection.execute(text("SELECT sum(length(payload)) FROM item")).scalar()
    engine.dispose()
    assert is_storage_damage(raised.value), raised.value


def test_an_error_no_route_expected_is_a_json_500_and_is_logged(caplog: pytest.LogCaptureFixture) -> None:
    def broken(_request: Request) -> None:
        raise RuntimeError("a bug")

    app = Starlette(routes=[Route("/broken", broken)], middleware=[Middleware(UnexpectedErrors)])
    with caplog.at_level(logging.ERROR, logger="contextweb"), TestClient(app, raise_server_exceptions=False) as client:
        response = client.get("/broken")
    assert response.status_code == 500 and response.headers["content-type"] == "application/json"
    assert response.json() == {
        "error": "internal_error",
        "detail": "an unexpected error (RuntimeError); it is logged with its traceback, and retrying may meet it again",
        "field": None,
    }
    assert any(record.exc_info and "a bug" in str(record.exc_info[1]) for record in caplog.records)
