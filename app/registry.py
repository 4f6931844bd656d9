"""The models in memory: one :class:`ModelRuntime` per stored model, rebuilt from the database on start.

A runtime holds the model's Incremental-LDA, its fitted perception (prototypes,
concept web, learned behaviour effects) and the lock that makes it the model's
single writer. The database is the truth: :func:`load_runtime` rebuilds a
runtime exactly (the LDA's counts, assignments and random state), which is how
the server continues where it stopped and how a failed write is undone.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any

import numpy as np
from sqlalchemy.orm import Session

from app.services.perception import Perception
from core.concept_web import ConceptWeb
from core.context.incremental import ContextModelState, IncrementalLDA
from core.planning import BehaviourEffects, Workspace, learn_effects
from core.prototypes.prototypes import PrototypeSet
from core.vocabulary import Vocabulary
from storage.models import Model
from storage.repositories import incremental_lda as lda_repository
from storage.repositories import models as model_repository


@dataclass(frozen=True)
class ModelSummary:
    """The counters a listing shows, published after each commit (read without the lock)."""

    context_count: int
    scene_count: int
    vocabulary_size: int


@dataclass(eq=False)
class ModelRuntime:
    """One model in memory. Mutate it only while holding :attr:`lock`."""

    id: str
    name: str
    seed: int
    sigma: float
    created_at: datetime
    hyperparameters: dict[str, Any]
    vocabulary: Vocabulary
    incremental_lda: IncrementalLDA
    word_kinds: list[str | None]
    perception: Perception
    effects: BehaviourEffects | None
    training_object_count: int
    summary: ModelSummary = ModelSummary(0, 0, 0)
    lock: threading.Lock = field(default_factory=threading.Lock, repr=False)
    changing: bool = False
    """True while the in-memory state holds changes not yet committed."""
    deleted: bool = False

    @classmethod
    def from_row(
        cls,
        row: Model,
        *,
        incremental_lda: IncrementalLDA,
        word_kinds: list[str | None],
        perception: Perception,
        effects: BehaviourEffects | None,
        training_object_count: int,
    ) -> ModelRuntime:
        """The runtime of the model stored as ``row`` with this in-memory state, its summary published."""
        runtime = cls(
            id=row.id,
            name=row.name,
            seed=row.seed,
            sigma=row.sigma,
            created_at=row.created_at,
            hyperparameters=dict(row.hyperparameters),
            vocabulary=perception.vocabulary,
            incremental_lda=incremental_lda,
            word_kinds=word_kinds,
            perception=perception,
            effects=effects,
            training_object_count=training_object_count,
        )
        runtime.publish_summary()
        return runtime

    def publish_summary(self) -> None:
        lda = self.incremental_lda
        self.summary = ModelSummary(lda.n_contexts, lda.n_scenes, len(lda.vocabulary))

    def kind_of(self, word: str) -> str | None:
        if word in self.vocabulary:
            return self.vocabulary.kind(word)
        return None


def jsonable(value: Any) -> Any:
    """Arrays and numpy scalars of a core state as JSON values."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, dict):
        return {str(key): jsonable(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(item) for item in value]
    return value


def fitted_perception(
    vocabulary: Vocabulary, prototypes: dict[str, Any] | None, concept_web: dict[str, Any] | None
) -> Perception:
    return Perception(
        vocabulary=vocabulary,
        prototypes=None if prototypes is None else PrototypeSet.from_state(prototypes),
        concept_web=None if concept_web is None else ConceptWeb.from_state(vocabulary, concept_web),
    )


def behaviour_effects(effect_vectors: list[list[float]], behaviours: list[str]) -> BehaviourEffects | None:
    """The planner's transition model from the training effects (None without any)."""
    if not effect_vectors:
        return None
    return learn_effects(np.asarray(effect_vectors, dtype=np.float64), behaviours, Workspace())


def training_effects(session: Session, model_id: str) -> tuple[list[list[float]], list[str], int]:
    """Every training effect vector with its behaviour, and the number of training objects."""
    objects = model_repository.list_training_objects(session, model_id)
    vectors = [vector for obj in objects for vector in obj.effects.values()]
    behaviours = [behaviour for obj in objects for behaviour in obj.effects]
    return vectors, behaviours, len(objects)


def load_runtime(session: Session, row: Model) -> ModelRuntime:
    """A model exactly as stored: LDA counts, assignments and random state included."""
    stored = lda_repository.load_corpus(session, row.id)
    hyperparameters = dict(row.hyperparameters)
    n_kw = np.zeros((stored.context_count, len(stored.word_names)), dtype=np.int32)
    if stored.count_entries.size:
        contexts, words, counts = stored.count_entries.T
        n_kw[contexts, words] = counts
    incremental_lda = IncrementalLDA.from_state(
        ContextModelState(
            hyperparameters=hyperparameters,
            vocabulary=stored.word_names,
            n_contexts=stored.context_count,
            words=stored.token_words,
            assignments=stored.token_contexts,
            doc_offsets=stored.doc_offsets,
            n_kw=n_kw,
            rng_state=stored.state["rng_state"],
        )
    )
    vectors, behaviours, training_count = training_effects(session, row.id)
    return ModelRuntime.from_row(
        row,
        incremental_lda=incremental_lda,
        word_kinds=stored.word_kinds,
        perception=fitted_perception(Vocabulary.from_dict(row.vocabulary), row.prototypes, row.concept_web),
        effects=behaviour_effects(vectors, behaviours) if row.fitted_at is not None else None,
        training_object_count=training_count,
    )


class ModelRegistry:
    """Every model of the deployment, by id."""

    def __init__(self) -> None:
        self._models: dict[str, ModelRuntime] = {}
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self._models)

    def get(self, model_id: str) -> ModelRuntime | None:
        return self._models.get(model_id)

    def all(self) -> list[ModelRuntime]:
        return sorted(self._models.values(), key=lambda model: (model.created_at, model.id))

    def add(self, model: ModelRuntime) -> None:
        with self._lock:
            self._models[model.id] = model

    def remove(self, model_id: str) -> None:
        with self._lock:
            self._models.pop(model_id, None)

    def load_all(self, session: Session) -> None:
        for row in model_repository.list_models(session):
            self.add(load_runtime(session, row))

    def reload(self, session: Session, model: ModelRuntime) -> None:
        """Replace ``model``'s in-memory state by the stored one (after a failed write)."""
        row = model_repository.get_model(session, model.id)
        if row is None:
            model.deleted = True
            self.remove(model.id)
            return
        fresh = load_runtime(session, row)
        model.incremental_lda = fresh.incremental_lda
        model.word_kinds = fresh.word_kinds
        model.perception = fresh.perception
        model.effects = fresh.effects
        model.training_object_count = fresh.training_object_count
        model.publish_summary()
