"""What the websocket feed reads (app/feed.py): change notifications, new scenes' answers, model marks.

Every process streams every model from the database: a write to a model calls
:func:`notify_change` in its transaction (on PostgreSQL a ``NOTIFY`` that is
delivered at commit, in commit order; nothing on SQLite, where the feed polls),
and each process's feed then reads the scenes after its cursor with
:func:`scenes_after` and the models' marks with :func:`model_marks`.
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime
from typing import NamedTuple

from sqlalchemy import LargeBinary, func, select, type_coerce
from sqlalchemy.orm import Session

from storage.database import DriverStatements
from storage.models import IncrementalLdaState, Model, Scene, TrainingObject

#: The PostgreSQL channel every model write notifies; the payload is the model id.
CHANNEL = "contextweb_models"
_NOTIFY = f"SELECT pg_notify('{CHANNEL}', ?)"


def notify_change(session: Session, model_id: str) -> None:
    """Tell every process's feed that ``model_id`` changed, once the caller's transaction commits.

    PostgreSQL only (``pg_notify`` in the transaction: nothing is sent if it rolls back, and
    notifications arrive in commit order); a no-op on SQLite, whose feeds poll.
    """
    if session.get_bind().dialect.name == "postgresql":
        DriverStatements(session).execute(_NOTIFY, (model_id,))


def scenes_after(session: Session, model_id: str, after_scene_id: int, limit: int) -> list[tuple[int, bytes]]:
    """(scene id, stored answer) of the model's scenes with id > ``after_scene_id``, in id order; the
    answers as stored (``storage.compression.decompress_answer`` reads one), so that one damaged
    answer is the caller's to skip, not an error of the whole page."""
    statement = (
        select(Scene.id, type_coerce(Scene.answer, LargeBinary))
        .where(Scene.model_id == model_id, Scene.id > after_scene_id)
        .order_by(Scene.id)
        .limit(limit)
    )
    return [(int(scene_id), bytes(stored)) for scene_id, stored in session.execute(statement)]


class ModelMark(NamedTuple):
    """Where a stored model stands: what the feed compares between two reads."""

    scene_count: int
    context_count: int
    """K after the model's last scene (``incremental_lda_state``, written with each scene)."""
    fitted_at: datetime | None
    training_object_count: int


def model_marks(session: Session, model_ids: Sequence[str]) -> dict[str, ModelMark]:
    """The marks of the given models that exist (a model missing from the answer was deleted)."""
    if not model_ids:
        return {}
    training_objects = (
        select(func.count()).select_from(TrainingObject).where(TrainingObject.model_id == Model.id).scalar_subquery()
    )
    statement = (
        select(
            Model.id,
            IncrementalLdaState.scene_count,
            IncrementalLdaState.context_count,
            Model.fitted_at,
            training_objects,
        )
        .join(IncrementalLdaState, IncrementalLdaState.model_id == Model.id)
        .where(Model.id.in_(list(model_ids)))
    )
    return {
        model_id: ModelMark(int(scenes), int(contexts), fitted_at, int(objects))
        for model_id, scenes, contexts, fitted_at, objects in session.execute(statement)
    }
