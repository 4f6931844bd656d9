"""Queries on the ``scene`` table: the acknowledged answers, history and idempotency keys."""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime
from typing import Any, NamedTuple

from sqlalchemy import Row, func, select
from sqlalchemy.orm import Session

from storage.compression import decompress_answer
from storage.database import DriverStatements, QueuedRows
from storage.models import Scene, utc_now


def add_scene(
    session: Session,
    model_id: str,
    scene_id: int,
    *,
    idempotency_key: str | None,
    request_hash: bytes | None,
    context_count: int,
    map_context: int,
    context_posterior: list[float],
    answer: str,
    created_at: datetime | None = None,
) -> None:
    """Insert one scene row (straight through the driver, like the scene's other rows:
    ``storage.repositories.incremental_lda``); ``created_at`` defaults to now."""
    driver = DriverStatements(session)
    driver.execute(
        _INSERT_SCENE,
        (
            model_id,
            scene_id,
            idempotency_key,
            request_hash,
            context_count,
            map_context,
            driver.bind(_SCENE.c.context_posterior)(context_posterior),
            driver.bind(_SCENE.c.answer_zlib)(answer),
            driver.bind(_SCENE.c.created_at)(created_at or utc_now()),
        ),
    )


_SCENE = Scene.__table__
_INSERT_SCENE = (
    "INSERT INTO scene (model_id, id, idempotency_key, request_hash, context_count, map_context, "
    "context_posterior, answer_zlib, created_at) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)"
)


def get_scene(session: Session, model_id: str, scene_id: int) -> Scene | None:
    return session.get(Scene, (model_id, scene_id))


class StoredAnswer(NamedTuple):
    """What a retried scene needs of the scene stored under its idempotency key."""

    scene_id: int
    request_hash: bytes
    stored: bytes
    """The answer as stored (``storage.compression``)."""

    @property
    def answer(self) -> str:
        """The answer as acknowledged (:class:`storage.compression.DamagedAnswerError` if its bytes are damaged)."""
        return decompress_answer(self.stored)


def find_by_idempotency_key(session: Session, model_id: str, key: str) -> StoredAnswer | None:
    """The scene stored under ``key``, straight through the driver: the look-up runs before every
    keyed scene (a robot's bridge keys them all), and the ORM's cost on PostgreSQL (docs/benchmarks.md)
    was not worth it."""
    return stored_answer(submit_find_by_idempotency_key(DriverStatements(session), model_id, key).all())


def submit_find_by_idempotency_key(driver: DriverStatements, model_id: str, key: str) -> QueuedRows:
    """The look-up of :func:`find_by_idempotency_key`, queued (``DriverStatements.submit``): in a
    pipeline it goes with the model's lock (``lock_model``); its rows go to :func:`stored_answer`."""
    return driver.submit(_FIND_BY_KEY, (model_id, key))


def stored_answer(rows: Sequence[tuple[Any, ...]]) -> StoredAnswer | None:
    """The rows of the key's look-up as the scene stored under it, or None."""
    if not rows:
        return None
    scene_id, request_hash, answer_zlib = rows[0]
    return StoredAnswer(scene_id, bytes(request_hash), bytes(answer_zlib))


_FIND_BY_KEY = "SELECT id, request_hash, answer_zlib FROM scene WHERE model_id = ? AND idempotency_key = ?"


def page_scenes(session: Session, model_id: str, *, offset: int, limit: int) -> tuple[Sequence[Row[Any]], int]:
    """Scenes ``offset`` to ``offset + limit`` in learning order (without their answers), and the total."""
    total = session.scalar(select(func.count()).select_from(Scene).where(Scene.model_id == model_id)) or 0
    columns = (Scene.id, Scene.context_count, Scene.map_context, Scene.context_posterior, Scene.created_at)
    rows = session.execute(
        select(*columns).where(Scene.model_id == model_id).order_by(Scene.id).offset(offset).limit(limit)
    ).all()
    return rows, int(total)
