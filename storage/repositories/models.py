"""Queries on the ``model`` table and the training objects of a model."""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime
from typing import Any, NamedTuple

from sqlalchemy import delete, func, select, update
from sqlalchemy.orm import Session

from storage.models import Model, TrainingBatch, TrainingObject


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
    return session.get(Model, model_id)


def find_by_idempotency_key(session: Session, idempotency_key: str) -> tuple[str, bytes | None] | None:
    """(id, request digest) of the model created under ``idempotency_key``, or None."""
    row = session.execute(select(Model.id, Model.request_hash).where(Model.idempotency_key == idempotency_key)).first()
    return None if row is None else (row.id, None if row.request_hash is None else bytes(row.request_hash))


def stored_models(session: Session) -> list[tuple[str, str]]:
    """(id, name) of every stored model, in creation order: no JSON column is decoded, so one model
    whose stored JSON is damaged cannot stop the listing (a start, ``contextweb models check``)."""
    rows = session.execute(select(Model.id, Model.name).order_by(Model.created_at, Model.id)).all()
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
            Model.id == model_id
        )
    ).first()
    return None if row is None else ModelHeader(*row)


def delete_model(session: Session, model_id: str) -> None:
    """Delete a model; its scenes, tokens, counts and training objects go by ON DELETE CASCADE."""
    session.execute(delete(Model).where(Model.id == model_id))


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
