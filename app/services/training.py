"""Training: store labelled objects, fit prototypes, the concept web and the behaviours' effects.

A fit uses every training object stored for the model (Appendix):
``fit_prototypes`` learns the 29 prototypes and the perception temperatures,
``ConceptWeb.fit`` the co-occurrences of each object's noun, adjectives and the
verbs of its interactions (§III-B), and ``learn_effects`` the planner's
transition model from the effect vectors (§V-E).
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import NamedTuple

import numpy as np
from sqlalchemy.orm import Session

from app.errors import InvalidInput, ModelNotFitted
from app.registry import FittedPerception, ModelRuntime, behaviour_effects, jsonable
from app.schemas.training import (
    FitCreate,
    FitRead,
    PrototypeRead,
    PrototypeTableRead,
    TrainingBatchCreate,
    TrainingBatchRead,
    TrainingObjectCreate,
)
from app.services.idempotency import check_retry, request_digest
from app.services.perception import Perception, check_behaviours, feature_vectors, raw_feature_vectors
from core.concept_web import ConceptWeb
from core.errors import InvalidInputError
from core.features.layout import EFFECT_SIZE
from core.prototypes.prototypes import RELEVANCE_SYMBOLS, fit_prototypes, format_prototype_table
from core.vocabulary import Vocabulary
from storage.repositories import models as model_repository


class AddedBatch(NamedTuple):
    answer: TrainingBatchRead
    replayed: bool
    """True when a keyed batch's earlier answer is given again (nothing was added)."""


class PreparedBatch(NamedTuple):
    """A training batch's rows computed outside the model's write (:func:`prepare_training_objects`),
    or why the batch is refused."""

    rows: list[dict[str, object]]
    refusal: InvalidInput | None


def prepare_training_objects(model: ModelRuntime, body: TrainingBatchCreate) -> PreparedBatch:
    """The batch's rows (each object's labels checked, its features extracted from raw payloads:
    about a second an object) or its refusal, computed from the body and the model's vocabulary
    alone: a route runs it before the model's write, which on SQLite holds every model's writes."""
    try:
        return PreparedBatch(
            [_training_row(model.vocabulary, obj, f"objects[{i}]") for i, obj in enumerate(body.objects)], None
        )
    except InvalidInput as refusal:
        return PreparedBatch([], refusal)


def add_training_objects(
    session: Session,
    model: ModelRuntime,
    body: TrainingBatchCreate,
    idempotency_key: str | None = None,
    prepared: PreparedBatch | None = None,
) -> AddedBatch:
    """Add the batch's objects (``prepared``: its rows computed before the write, else computed
    now), under the model's write lock. ``idempotency_key``: a retry with the same key and body is
    answered as the batch first was, and adds nothing; another body is 422
    ``idempotency_key_reused``, before any refusal of the body itself. The lookup is under the
    model's lock, so two processes cannot both add a batch of one key."""
    request_hash = request_digest(idempotency_key, body)
    if idempotency_key is not None:
        stored = model_repository.find_training_batch(session, model.id, idempotency_key)
        if stored is not None:
            check_retry(idempotency_key, bytes(stored.request_hash), request_hash)
            answer = TrainingBatchRead(added=stored.added, training_object_count=stored.training_object_count)
            return AddedBatch(answer, replayed=True)
    rows, refusal = prepared if prepared is not None else prepare_training_objects(model, body)
    if refusal is not None:
        raise refusal
    model_repository.add_training_objects(session, model.id, rows)
    total = model.training_object_count + len(rows)
    if idempotency_key is not None and request_hash is not None:
        model_repository.add_training_batch(session, model.id, idempotency_key, request_hash, len(rows), total)
    model.writer.count_training_objects(total)
    return AddedBatch(TrainingBatchRead(added=len(rows), training_object_count=total), replayed=False)


def _training_row(vocabulary: Vocabulary, obj: TrainingObjectCreate, field: str) -> dict[str, object]:
    if obj.noun not in vocabulary.nouns:
        raise InvalidInput(
            f"{field}.noun", f"{obj.noun!r} is not a noun of the model; nouns are {list(vocabulary.nouns)}"
        )
    _check_adjectives(vocabulary, obj.adjectives, f"{field}.adjectives")
    if obj.features is not None:
        check_behaviours(vocabulary, obj.features.effects, f"{field}.features")
        entity, effects = feature_vectors(obj.features)
    else:
        assert obj.raw is not None
        check_behaviours(vocabulary, [i.behaviour for i in obj.raw.interactions], f"{field}.raw")
        entity, effects = raw_feature_vectors(obj.raw, f"{field}.raw")
    for behaviour, verb in obj.verbs.items():
        if behaviour not in effects:
            raise InvalidInput(f"{field}.verbs.{behaviour}", f"the object has no interaction {behaviour!r} to label")
        if verb not in vocabulary.verbs:
            raise InvalidInput(f"{field}.verbs.{behaviour}", f"{verb!r} is not a verb of the model")
    return {
        "noun": obj.noun,
        "adjectives": list(obj.adjectives),
        "entity": entity.tolist(),
        "effects": {behaviour: vector.tolist() for behaviour, vector in effects.items()},
        "verbs": {behaviour: obj.verbs.get(behaviour, behaviour) for behaviour in effects},
    }


def _check_adjectives(vocabulary: Vocabulary, adjectives: list[str], field: str) -> None:
    """Exactly one adjective of every dichotomic pair, as the Appendix labels its objects."""
    for adjective in adjectives:
        if adjective not in vocabulary.adjectives:
            raise InvalidInput(field, f"{adjective!r} is not an adjective of the model")
    for first, second in vocabulary.adjective_pairs:
        given = [a for a in adjectives if a in (first, second)]
        if len(given) != 1:
            raise InvalidInput(field, f"needs exactly one of {first!r} / {second!r}, got {given}")


class PreparedFit(NamedTuple):
    """A fit computed from the training objects up to ``last_object_id`` (:func:`prepare_fit`)."""

    object_count: int
    last_object_id: int
    fitted_at: datetime
    fitted: FittedPerception
    answer: FitRead
    prototypes_state: dict[str, object]
    concept_web_state: dict[str, object]


def prepare_fit(session: Session, model: ModelRuntime, body: FitCreate) -> PreparedFit:
    """Fit the model's perception from all its stored training objects, read in ``session``.

    Pure computation on one read of the objects: a route runs it outside the model's write, so
    that the seconds a fit takes do not hold the database's lock (on SQLite the one write lock of
    every model); :func:`fit` then stores it if the objects are still the same."""
    objects = model_repository.list_training_objects(session, model.id)
    if not objects:
        raise ModelNotFitted(model.id, "training objects")
    vocabulary = model.vocabulary
    effect_rows = [
        (vector, behaviour, obj.verbs[behaviour]) for obj in objects for behaviour, vector in obj.effects.items()
    ]
    try:
        prototypes = fit_prototypes(
            vocabulary,
            np.array([obj.entity for obj in objects], dtype=np.float64),
            [[obj.noun, *obj.adjectives] for obj in objects],
            np.array([vector for vector, _, _ in effect_rows], dtype=np.float64).reshape(-1, EFFECT_SIZE),
            [verb for _, _, verb in effect_rows],
            method=body.method,
            seed=model.seed if body.seed is None else body.seed,
        )
        concept_web = ConceptWeb.fit(
            vocabulary, [[obj.noun, *obj.adjectives, *dict.fromkeys(obj.verbs.values())] for obj in objects]
        )
    except InvalidInputError as error:
        raise InvalidInput(f"training.{error.field}", error.problem) from None
    effects = behaviour_effects(
        [vector for vector, _, _ in effect_rows], [behaviour for _, behaviour, _ in effect_rows]
    )
    fitted_at = datetime.now(UTC)
    return PreparedFit(
        object_count=len(objects),
        last_object_id=objects[-1].id,
        fitted_at=fitted_at,
        fitted=FittedPerception(Perception(vocabulary, prototypes, concept_web), effects, fitted_at),
        answer=FitRead(
            model_id=model.id,
            method=prototypes.method,
            training_object_count=len(objects),
            concept_web_edges=len(concept_web.edges),
            behaviours=[] if effects is None else list(effects.behaviours),
        ),
        prototypes_state=jsonable(prototypes.to_state()),
        concept_web_state=jsonable(concept_web.to_state()),
    )


def fit(session: Session, model: ModelRuntime, body: FitCreate, prepared: PreparedFit | None = None) -> FitRead:
    """Store a fit of the model's perception from all its training objects, in the model's write;
    it replaces the old one on commit (the stream's ``model_fitted`` event comes from the database:
    app/feed.py). ``prepared`` (computed before the write) is stored if the model's training
    objects are still those it was computed from (training objects are only ever added, so their
    count and last id say so); otherwise, or without one, the fit is computed now, in the write."""
    if prepared is None or model_repository.training_objects_extent(session, model.id) != (
        prepared.object_count,
        prepared.last_object_id,
    ):
        prepared = prepare_fit(session, model, body)
    model_repository.save_fit(
        session,
        model.id,
        prototypes=prepared.prototypes_state,
        concept_web=prepared.concept_web_state,
        fitted_at=prepared.fitted_at,
    )
    model.writer.install_fit(prepared.fitted)
    return prepared.answer


def prototype_table(model: ModelRuntime) -> PrototypeTableRead:
    prototypes = model.perception.prototypes
    if prototypes is None:
        raise ModelNotFitted(model.id, "prototypes")
    vocabulary = model.vocabulary
    symbols = np.array(RELEVANCE_SYMBOLS)
    rows = list(zip(prototypes.entity_concepts, prototypes.entity_relevance, strict=True))
    rows += list(zip(vocabulary.verbs, prototypes.verb_relevance, strict=True))
    return PrototypeTableRead(
        method=prototypes.method,
        concepts=[
            PrototypeRead(name=name, kind=vocabulary.kind(name), relevance="".join(symbols[codes]))
            for name, codes in rows
        ],
        table=format_prototype_table(prototypes),
    )
