"""Migration 0008 compacts the scene rows of a database written before it, on SQLite and PostgreSQL:
request digests become 32 bytes (null without a key), only keyed scenes are indexed by key, and the
downgrade gives the hex digests and the unique constraint back."""

from __future__ import annotations

import hashlib
from datetime import UTC, datetime

import pytest
import sqlalchemy as sa
from sqlalchemy import Engine
from sqlalchemy.exc import IntegrityError

from storage.compression import compress_answer
from storage.database import create_session_makers
from storage.repositories import scenes as scene_repository
from tests.conftest import migrate

NOW = datetime(2026, 12, 1, tzinfo=UTC)
#: (scene id, idempotency key) of the old rows: keyed and keyless scenes of one model.
KEYS = [(0, "key-0"), (1, None), (2, "key-2"), (3, None)]
DIGESTS = {scene_id: hashlib.sha256(f"body {scene_id}".encode()).digest() for scene_id, _ in KEYS}

SCENE = sa.table(
    "scene",
    sa.column("model_id", sa.String(32)),
    sa.column("id", sa.Integer()),
    sa.column("idempotency_key", sa.String(200)),
    sa.column("request_hash"),
    sa.column("context_count", sa.Integer()),
    sa.column("map_context", sa.Integer()),
    sa.column("context_posterior", sa.JSON()),
    sa.column("answer_zlib", sa.LargeBinary()),
    sa.column("created_at", sa.DateTime(timezone=True)),
)


def _scene(scene_id: int, key: str | None, request_hash: object) -> dict[str, object]:
    return {
        "model_id": "m", "id": scene_id, "idempotency_key": key, "request_hash": request_hash, "context_count": 1,
        "map_context": 0, "context_posterior": [1.0], "answer_zlib": compress_answer(f'{{"scene_id":{scene_id}}}'),
        "created_at": NOW,
    }  # fmt: skip


def _hashes(engine: Engine) -> dict[int, object]:
    with engine.connect() as connection:
        rows = connection.execute(sa.select(SCENE.c.id, SCENE.c.request_hash).order_by(SCENE.c.id)).all()
    return {
        scene_id: None if value is None else (value if isinstance(value, str) else bytes(value))
        for scene_id, value in rows
    }


def _insert(engine: Engine, *rows: dict[str, object]) -> None:
    with engine.begin() as connection:
        connection.execute(SCENE.insert(), list(rows))


def test_upgrading_compacts_the_scene_rows_and_downgrading_restores_them(engine: Engine) -> None:
    migrate(engine, "downgrade", "0008-1")
    with engine.begin() as connection:
        connection.execute(
            sa.text(
                "INSERT INTO model (id, name, seed, sigma, hyperparameters, vocabulary, created_at, updated_at) "
                "VALUES ('m', 'old', 0, 0.5, '{}', '{}', :now, :now)"
            ),
            {"now": NOW},
        )
    _insert(engine, *(_scene(scene_id, key, DIGESTS[scene_id].hex()) for scene_id, key in KEYS))

    migrate(engine, "upgrade", "head")
    assert _hashes(engine) == {0: DIGESTS[0], 1: None, 2: DIGESTS[2], 3: None}
    read, _ = create_session_makers(engine)
    with read() as session:
        stored = scene_repository.find_by_idempotency_key(session, "m", "key-2")
    assert stored is not None and (stored.scene_id, stored.request_hash) == (2, DIGESTS[2])
    assert stored.answer == '{"scene_id":2}'
    _insert(engine, _scene(4, None, None), _scene(5, None, None))  # keyless scenes: not indexed, never collide
    with pytest.raises(IntegrityError):
        _insert(engine, _scene(6, "key-0", DIGESTS[0]))

    migrate(engine, "downgrade", "0008-1")
    restored = {0: DIGESTS[0].hex(), 1: "", 2: DIGESTS[2].hex(), 3: "", 4: "", 5: ""}
    assert _hashes(engine) == restored
    with pytest.raises(IntegrityError):
        _insert(engine, _scene(6, "key-0", DIGESTS[0].hex()))
    inspector = sa.inspect(engine)
    assert {c["name"] for c in inspector.get_unique_constraints("scene")} == {"uq_scene_model_id_idempotency_key"}
    assert not any(column["nullable"] for column in inspector.get_columns("scene") if column["name"] == "request_hash")
    migrate(engine, "upgrade", "head")
    assert _hashes(engine) == {0: DIGESTS[0], 1: None, 2: DIGESTS[2], 3: None, 4: None, 5: None}
