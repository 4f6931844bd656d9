"""Queries on the ``model`` table and the training objects of a model."""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime
from typing import Any, NamedTuple

from sqlalchemy import ColumnElement, delete, func, select, update
from sqlalchemy.orm import Session

from storage.models import IncrementalLdaState, Model, Scene, TokenBatch, TrainingBatch, TrainingObject, utc_now
from storage.repositories import rowcount

#: The models that live: not deleted (a deleted model's row stays until it is purged, alembic 0012).
LIVE = Model.deleted_at.is_(None)
#: The models marked deleted whose rows are still being purged (app/purge.py).
MARKED = Model.deleted_at.is_not(None)
#: The tables a purge empties a chunk at a time (the rest of a model is small and goes with its row),
#: each with the column of its key after ``model_id``, which orders the chunks.
_PURGED_IN_CHUNKS = ((Scene, Scene.id), (TokenBatch, TokenBatch.version))


def add_model(
    session: Session,
    *,
    model_id: str,
    name: str,
    seed: int,
    sigma: float,
    hyperparameters: dict[str, Any],
    vocabulary: dict[str, Any],
    idempotency_key: str | None = None,
    request_hash: bytes | None = None,
) -> Model:
    model = Model(
        id=model_id,
        name=name,
        seed=seed,
        sigma=sigma,
        hyperparameters=hyperparameters,
        vocabulary=vocabulary,
        idempotency_key=idempotency_key,
        request_hash=request_hash,
    )
    session.add(model)
    session.flush()
    return model


def get_model(session: Session, model_id: str) -> Model | None:
    """The live model ``model_id``, or None (no such model, or a deleted one)."""
    return session.scalars(select(Model).where(Model.id == model_id, LIVE)).first()


def is_live(session: Session, model_id: str) -> bool:
    return _exists(session, model_id, LIVE)


def _exists(session: Session, model_id: str, condition: ColumnElement[bool]) -> bool:
    return session.execute(select(Model.id).where(Model.id == model_id, condition)).first() is not None


def find_by_idempotency_key(session: Session, idempotency_key: str) -> tuple[str, bytes | None] | None:
    """(id, request digest) of the model created under ``idempotency_key``, or None."""
    row = session.execute(select(Model.id, Model.request_hash).where(Model.idempotency_key == idempotency_key)).first()
    return None if row is None else (row.id, None if row.request_hash is None else bytes(row.request_hash))


def stored_models(session: Session) -> list[tuple[str, str]]:
    """(id, name) of every stored model, in creation order: no JSON column is decoded, so one model
    whose stored JSON is damaged cannot stop the listing (a start, ``contextweb models check``)."""
    rows = session.execute(select(Model.id, Model.name).where(LIVE).order_by(Model.created_at, Model.id)).all()
    return [(model_id, name) for model_id, name in rows]


class ModelHeader(NamedTuple):
    """A model row's columns without its JSON ones: what lists a model whose JSON cannot be decoded."""

    id: str
    name: str
    seed: int
    sigma: float
    created_at: datetime
    fitted_at: datetime | None


def get_model_header(session: Session, model_id: str) -> ModelHeader | None:
    row = session.execute(
        select(Model.id, Model.name, Model.seed, Model.sigma, Model.created_at, Model.fitted_at).where(
            Model.id == model_id, LIVE
        )
    ).first()
    return None if row is None else ModelHeader(*row)


def delete_model(session: Session, model_id: str) -> None:
    """Mark a model deleted: a few rows, whatever its size. Its version row goes, so every process
    finds it gone on its next request (app/registry.py), and its Idempotency-Key is freed for a new
    model; :func:`purge_chunk` deletes the rest later, a chunk per transaction (app/purge.py)."""
    session.execute(
        update(Model).where(Model.id == model_id).values(deleted_at=utc_now(), idempotency_key=None, request_hash=None)
    )
    session.execute(delete(IncrementalLdaState).where(IncrementalLdaState.model_id == model_id))


def deleted_models(session: Session) -> list[str]:
    """Ids of the deleted models whose rows are still being purged, oldest deletion first."""
    return list(session.scalars(select(Model.id).where(MARKED).order_by(Model.deleted_at)))


def purge_chunk(session: Session, model_id: str, max_rows: int) -> int:
    """Delete at most ``max_rows`` of a deleted model's scenes or token batches, in key order; once
    none is left, its row, and by ON DELETE CASCADE the rest of it (words, counts, training objects,
    labels, checkpoint: rows bounded by its vocabulary and training set, not its history). Returns
    how many rows of the chunked tables went (0 once the row itself is gone). A live model is never
    touched."""
    if not _exists(session, model_id, MARKED):
        return 0
    for table, key in _PURGED_IN_CHUNKS:
        first = select(key).where(table.model_id == model_id).order_by(key).limit(max_rows).subquery()
        last = session.execute(select(func.max(first.c[key.key]))).scalar()
        if last is not None:
            return rowcount(session.execute(delete(table).where(table.model_id == model_id, key <= last)))
    session.execute(delete(Model).where(Model.id == model_id))
    return 0


def save_fit(
    session: Session, model_id: str, *, prototypes: dict[str, Any], concept_web: dict[str, Any], fitted_at: datetime
) -> None:
    session.execute(
        update(Model)
        .where(Model.id == model_id)
        .values(prototypes=prototypes, concept_web=concept_web, fitted_at=fitted_at, updated_at=fitted_at)
    )


def add_training_objects(session: Session, model_id: str, objects: Sequence[dict[str, Any]]) -> None:
    """Insert labelled objects: dicts with noun, adjectives, entity, effects and verbs."""
    session.add_all(TrainingObject(model_id=model_id, **values) for values in objects)
    session.flush()


def list_training_objects(session: Session, model_id: str) -> Sequence[TrainingObject]:
    return session.scalars(
        select(TrainingObject).where(TrainingObject.model_id == model_id).order_by(TrainingObject.id)
    ).all()


def training_objects_extent(session: Session, model_id: str) -> tuple[int, int]:
    """How many training objects the model has and the id of the last (0 when none): objects are
    only ever added, so the two name the set a fit used (app/services/training.py)."""
    count, last = session.execute(
        select(func.count(), func.coalesce(func.max(TrainingObject.id), 0)).where(TrainingObject.model_id == model_id)
    ).one()
    return int(count), int(last)


def find_training_batch(session: Session, model_id: str, idempotency_key: str) -> TrainingBatch | None:
    """The keyed training batch ``idempotency_key`` of the model, or None."""
    return session.get(TrainingBatch, (model_id, idempotency_key))


def add_training_batch(
    session: Session, model_id: str, idempotency_key: str, request_hash: bytes, added: int, training_object_count: int
) -> None:
    """Remember a keyed batch and its answer (its objects are added by :func:`add_training_objects`)."""
    session.add(
        TrainingBatch(
            model_id=model_id,
            idempotency_key=idempotency_key,
            request_hash=request_hash,
            added=added,
            training_object_count=training_object_count,
        )
    )
