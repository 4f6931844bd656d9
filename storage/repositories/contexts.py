"""Queries on the ``context_label`` table: the names operators give contexts."""

from __future__ import annotations

from sqlalchemy import delete
from sqlalchemy.orm import Session

from storage.database import DriverStatements, QueuedRows
from storage.models import ContextLabel, utc_now


def context_labels(session: Session, model_id: str) -> dict[int, str]:
    """Every labelled context of ``model_id``: context index → label."""
    return dict(submit_context_labels(DriverStatements(session), model_id).all())


def submit_context_labels(driver: DriverStatements, model_id: str) -> QueuedRows:
    """:func:`context_labels`' query, its rows read later (``DriverStatements.submit``): a write
    that does not know the labels reads them in the round trip that locks the model (``lock_model``)."""
    return driver.submit(_SELECT_LABELS, (model_id,))


_SELECT_LABELS = "SELECT context, label FROM context_label WHERE model_id = ?"


def context_label(session: Session, model_id: str, context: int) -> str | None:
    """The label of one context, or None (one primary-key read, straight through the driver: it runs
    in every learned scene's transaction, where the ORM's statement machinery cost more than the read)."""
    row = DriverStatements(session).fetchone(_SELECT_LABEL, (model_id, context))
    return None if row is None else row[0]


_SELECT_LABEL = "SELECT label FROM context_label WHERE model_id = ? AND context = ?"


def set_context_label(session: Session, model_id: str, context: int, label: str | None) -> None:
    """Name context ``context`` (None removes its label)."""
    if label is None:
        session.execute(delete(ContextLabel).where(ContextLabel.model_id == model_id, ContextLabel.context == context))
        return
    # One statement, not a read then an insert (which two writers could both find empty).
    driver = DriverStatements(session)
    updated_at = driver.bind(ContextLabel.__table__.c.updated_at)(utc_now())
    driver.execute(_UPSERT_LABEL, (model_id, context, label, updated_at))


_UPSERT_LABEL = (
    "INSERT INTO context_label (model_id, context, label, updated_at) VALUES (?, ?, ?, ?) "
    "ON CONFLICT (model_id, context) DO UPDATE SET label = excluded.label, updated_at = excluded.updated_at"
)
