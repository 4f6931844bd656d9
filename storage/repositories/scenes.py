"""Queries on the ``scene`` table: the acknowledged answers, history and idempotency keys."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from sqlalchemy import Row, func, insert, select
from sqlalchemy.orm import Session

from storage.models import Scene


def add_scene(session: Session, model_id: str, scene_id: int, **values: Any) -> None:
    """Insert one scene row: idempotency_key, request_hash, context_count, map_context, context_posterior, answer."""
    session.connection().execute(_INSERT_SCENE, {"model_id": model_id, "id": scene_id, **values})


#: Built once: SQLAlchemy reuses its compiled form (and still converts the JSON and time columns).
_INSERT_SCENE = insert(Scene.__table__)


def get_scene(session: Session, model_id: str, scene_id: int) -> Scene | None:
    return session.get(Scene, (model_id, scene_id))


def find_by_idempotency_key(session: Session, model_id: str, key: str) -> Scene | None:
    return session.scalars(select(Scene).where(Scene.model_id == model_id, Scene.idempotency_key == key)).first()


def page_scenes(session: Session, model_id: str, *, offset: int, limit: int) -> tuple[Sequence[Row[Any]], int]:
    """Scenes ``offset`` to ``offset + limit`` in learning order (without their answers), and the total."""
    total = session.scalar(select(func.count()).select_from(Scene).where(Scene.model_id == model_id)) or 0
    columns = (Scene.id, Scene.context_count, Scene.map_context, Scene.context_posterior, Scene.created_at)
    rows = session.execute(
        select(*columns).where(Scene.model_id == model_id).order_by(Scene.id).offset(offset).limit(limit)
    ).all()
    return rows, int(total)
