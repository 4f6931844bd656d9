"""Migration 0005 converts the answers of a database written before it: every scene's answer reads back
byte for byte, on SQLite and PostgreSQL, the token rows are kept (SQLite's table rebuilt without
rowid), and the downgrade gives the old rows back."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest
from sqlalchemy import Engine, create_engine, text

from storage.database import create_database_engine, create_session_makers
from storage.repositories import scenes as scene_repository
from tests.conftest import BACKENDS, POSTGRES_SERVER_URL, migrate

#: Old-format answers: JSON with floats at full precision, non-ASCII text, and one large enough
#: to be stored in several database pages (more than 1,000 objects' worth of keys).
ANSWERS = [
    json.dumps({"scene_id": 0, "context_posterior": [0.1234567890123456, 0.8765432109876544], "label": "Küche ☕"}),
    '{"scene_id":1,"objects":[' + ",".join(f'{{"web":{{"cup":{i / 7!r}}}}}' for i in range(1500)) + "]}",
    "{}",
]


#: (id, scene, word, context, version) token rows of the old database.
TOKENS = [(0, 0, 3, 1, 1), (1, 0, 7, 0, 2), (2, 1, 3, 1, 2)]


def _tokens(engine: Engine) -> list[tuple[int, ...]]:
    with engine.connect() as connection:
        rows = connection.execute(text("SELECT id, scene_id, word_id, context, version FROM token ORDER BY id")).all()
    return [tuple(row) for row in rows]


def _token_table_sql(engine: Engine) -> str:
    with engine.connect() as connection:
        return connection.execute(text("SELECT sql FROM sqlite_master WHERE name = 'token'")).scalar_one()


@pytest.fixture(params=BACKENDS)
def empty_database(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[str]:
    """A database with no schema at all (PostgreSQL: one of its own, dropped afterwards)."""
    if request.param == "sqlite":
        yield f"sqlite:///{tmp_path / 'old.sqlite3'}"
        return
    request.getfixturevalue("postgres_url")  # skips when no server answers
    name = f"contextweb_migration_{abs(hash(tmp_path)) % 10**8}"
    admin = create_engine(f"{POSTGRES_SERVER_URL}/postgres", isolation_level="AUTOCOMMIT")
    with admin.connect() as connection:
        connection.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
        connection.execute(text(f'CREATE DATABASE "{name}"'))
    try:
        yield f"{POSTGRES_SERVER_URL}/{name}"
    finally:
        with admin.connect() as connection:
            connection.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
        admin.dispose()


def test_upgrading_converts_old_answers_byte_for_byte_and_downgrading_restores_them(empty_database: str) -> None:
    engine = create_database_engine(empty_database)
    try:
        migrate(engine, "upgrade", "0004")
        with engine.begin() as connection:
            connection.execute(
                text(
                    "INSERT INTO model (id, name, seed, sigma, hyperparameters, vocabulary, created_at, updated_at) "
                    "VALUES ('m', 'old', 0, 0.5, '{}', '{}', '2026-12-01 00:00:00', '2026-12-01 00:00:00')"
                )
            )
            for scene_id, answer in enumerate(ANSWERS):
                connection.execute(
                    text(
                        "INSERT INTO scene (model_id, id, idempotency_key, request_hash, context_count, map_context, "
                        "context_posterior, answer, created_at) "
                        "VALUES ('m', :id, :key, :hash, 2, 0, '[0.5, 0.5]', :answer, '2026-12-01 00:00:00')"
                    ),
                    {"id": scene_id, "key": f"key-{scene_id}", "hash": f"{scene_id:064x}", "answer": answer},
                )
            for token in TOKENS:
                connection.execute(
                    text(
                        "INSERT INTO token (model_id, id, scene_id, word_id, context, version) "
                        "VALUES ('m', :id, :scene, :word, :context, :version)"
                    ),
                    dict(zip(("id", "scene", "word", "context", "version"), token, strict=True)),
                )
        migrate(engine, "upgrade", "0006")  # 0007 replaces the token table (tests/test_migration_0007.py)
        assert _tokens(engine) == TOKENS
        if engine.dialect.name == "sqlite":
            assert "WITHOUT ROWID" in _token_table_sql(engine)
        migrate(engine, "upgrade", "head")  # the repository reads the latest scene table (alembic 0008)
        read, _ = create_session_makers(engine)
        with read() as session:
            scenes = [scene_repository.get_scene(session, "m", i) for i in range(len(ANSWERS))]
            assert [scene.answer if scene else None for scene in scenes] == ANSWERS
            replayed = scene_repository.find_by_idempotency_key(session, "m", "key-1")
            assert replayed is not None and replayed.answer == ANSWERS[1]
        with engine.connect() as connection:
            stored = connection.execute(text("SELECT answer_zlib FROM scene WHERE id = 1")).scalar_one()
        assert len(bytes(stored)) < len(ANSWERS[1]) / 4, "the answers are stored compressed"

        migrate(engine, "downgrade", "0004")
        with engine.connect() as connection:
            rows = connection.execute(text("SELECT answer FROM scene ORDER BY id")).scalars().all()
        assert rows == ANSWERS
        # Back through 0007, whose checkpoint keeps assignments but not each row's write version.
        assert [token[:4] for token in _tokens(engine)] == [token[:4] for token in TOKENS]
        if engine.dialect.name == "sqlite":
            assert "WITHOUT ROWID" not in _token_table_sql(engine)
    finally:
        engine.dispose()
