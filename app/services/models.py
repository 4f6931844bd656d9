"""Creating, describing and deleting models."""

from __future__ import annotations

import logging
import uuid
from typing import NamedTuple

from pydantic import ValidationError
from sqlalchemy.orm import Session

from app.errors import InvalidInput
from app.purge import ModelPurger
from app.registry import FittedPerception, ModelRegistry, ModelRuntime, ModelWriter, jsonable
from app.schemas.models import Hyperparameters as HyperparametersSchema
from app.schemas.models import ModelCreate, ModelRead, VocabularySchema
from app.services.idempotency import check_retry, create_once, request_digest
from app.services.perception import Perception
from app.stream import CLOSE_NORMAL, StreamHub
from core.context import Hyperparameters, IncrementalLDA
from core.errors import InvalidInputError
from core.vocabulary import Vocabulary, paper_vocabulary
from storage.models import Model
from storage.repositories import incremental_lda as lda_repository
from storage.repositories import models as model_repository
from storage.unit_of_work import after_commit

logger = logging.getLogger("contextweb")


class CreatedModel(NamedTuple):
    model: ModelRuntime
    replayed: bool
    """True when an Idempotency-Key's earlier creation is answered again (nothing new was made)."""


def create_model(
    session: Session, registry: ModelRegistry, body: ModelCreate, idempotency_key: str | None = None
) -> CreatedModel:
    """A new model with K = 1 and the vocabulary's concepts as its first words; registered on commit.

    ``idempotency_key``: a retry of a creation that may have been stored (a 503 that says so, a
    lost answer) with the same key and body answers the model that creation made, as it is now;
    with another body, 422 ``idempotency_key_reused``. Two creations with one key racing on two
    processes meet at the key's unique index: the later one's insert is undone (a savepoint) and
    it answers the earlier one's model."""
    request_hash = request_digest(idempotency_key, body)

    def earlier(key: str) -> CreatedModel | None:
        stored = model_repository.find_by_idempotency_key(session, key)
        return None if stored is None else _replayed(registry, key, request_hash, stored)

    return create_once(
        session, idempotency_key, lambda: _create(session, registry, body, idempotency_key, request_hash), earlier
    )


def _create(
    session: Session,
    registry: ModelRegistry,
    body: ModelCreate,
    idempotency_key: str | None,
    request_hash: bytes | None,
) -> CreatedModel:
    vocabulary = _vocabulary(body.vocabulary)
    try:
        settings = Hyperparameters.from_dict(body.hyperparameters.model_dump())
    except InvalidInputError as error:
        raise InvalidInput(f"hyperparameters.{error.field}", error.problem) from None
    incremental_lda = IncrementalLDA(vocabulary.concepts, seed=body.seed, hyperparameters=settings)
    row = _add_model(session, body, vocabulary, settings, incremental_lda, idempotency_key, request_hash)
    writer = ModelWriter(row.id, FittedPerception(Perception(vocabulary)), incremental_lda, list(vocabulary.kinds), 0)
    model = ModelRuntime.from_row(row, writer)
    after_commit(session, lambda: registry.add(model))
    return CreatedModel(model, replayed=False)


def _add_model(
    session: Session,
    body: ModelCreate,
    vocabulary: Vocabulary,
    settings: Hyperparameters,
    incremental_lda: IncrementalLDA,
    idempotency_key: str | None,
    request_hash: bytes | None,
) -> Model:
    row = model_repository.add_model(
        session,
        model_id=uuid.uuid4().hex,
        name=body.name,
        seed=body.seed,
        sigma=body.sigma,
        hyperparameters=settings.to_dict(),
        vocabulary=vocabulary.to_dict(),
        idempotency_key=idempotency_key,
        request_hash=request_hash,
    )
    lda_repository.create_state(
        session,
        row.id,
        context_count=incremental_lda.n_contexts,
        state={"rng_state": jsonable(incremental_lda.to_state().rng_state)},
        words=[(i, name, vocabulary.kind(name)) for i, name in enumerate(vocabulary.concepts)],
    )
    return row


def _replayed(
    registry: ModelRegistry, idempotency_key: str, request_hash: bytes | None, stored: tuple[str, bytes | None]
) -> CreatedModel:
    model_id, stored_hash = stored
    check_retry(idempotency_key, stored_hash, request_hash)
    return CreatedModel(registry.resolve(model_id), replayed=True)


def _vocabulary(body: VocabularySchema | None) -> Vocabulary:
    if body is None:
        return paper_vocabulary()
    try:
        return Vocabulary.from_dict(body.model_dump())
    except InvalidInputError as error:
        raise InvalidInput(
            error.field if error.field.startswith("vocabulary") else f"vocabulary.{error.field}", error.problem
        ) from None


def delete_model(
    session: Session, registry: ModelRegistry, hub: StreamHub, purger: ModelPurger, model: ModelRuntime
) -> None:
    """Delete the model and everything it learned: on commit it is gone for every process, its
    dashboards are disconnected, and its rows are handed to the purger (app/purge.py)."""
    model_repository.delete_model(session, model.id)

    def forget() -> None:
        registry.forget(model.writer)
        hub.close_model(model.id, CLOSE_NORMAL, "model deleted")
        purger.purge(model.id)
        logger.info(
            "model %s (%r, %d scenes) deleted; its streams were closed", model.id, model.name, model.summary.scene_count
        )

    after_commit(session, forget)


def model_read(model: ModelRuntime) -> ModelRead:
    summary = model.summary
    perception = model.perception
    return ModelRead(
        id=model.id,
        name=model.name,
        seed=model.seed,
        sigma=model.sigma,
        hyperparameters=_listed_hyperparameters(model),
        vocabulary=VocabularySchema.model_validate(model.vocabulary.to_dict()) if model.vocabulary_known else None,
        context_count=summary.context_count,
        vocabulary_size=summary.vocabulary_size,
        scene_count=summary.scene_count,
        training_object_count=model.training_object_count,
        status="unavailable" if model.unavailable is not None else "available",
        unavailable_reason=model.unavailable,
        prototypes_fitted=perception.prototypes is not None,
        concept_web_fitted=perception.concept_web is not None,
        created_at=model.created_at,
    )


def _listed_hyperparameters(model: ModelRuntime) -> HyperparametersSchema | None:
    """The model's hyperparameters as listed; None for an unavailable model whose stored ones are
    missing or do not validate (its reason says why it cannot load), so that one damaged row does
    not fail the listing of every model."""
    if model.hyperparameters is None and model.unavailable is not None:
        return None
    try:
        return HyperparametersSchema.model_validate(model.hyperparameters)
    except ValidationError:
        if model.unavailable is None:
            raise
        return None
