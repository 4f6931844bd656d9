"""The models in memory: one :class:`ModelRuntime` per stored model, kept equal to the database.

A runtime holds the model's Incremental-LDA, its fitted perception (prototypes,
concept web, learned behaviour effects), the version of the stored state it
equals and the lock that makes it this process's single writer of the model.
The database is the truth, and memory follows it (docs/scaling.md):

- :func:`load_runtime` rebuilds a runtime exactly (counts, assignments, random
  state) from one consistent snapshot: how the server starts, and how a model
  whose write failed is reloaded;
- :func:`catch_up` brings a runtime that is behind (another process wrote) to
  the stored version, reading only the rows written since its own version;
- a model whose stored state cannot be loaded, or whose memory could not be
  proven equal to the database after a failed write, is *unavailable* (503
  ``model_unavailable``) until a reload succeeds; the other models serve on.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Iterator
from contextlib import AbstractContextManager, contextmanager
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any

import numpy as np
from sqlalchemy import func, select
from sqlalchemy.orm import Session, sessionmaker

from app.errors import ModelNotFound, ModelUnavailable, is_storage_failure, storage_error, storage_failure_reason
from app.services.limits import VocabularyLimits
from app.services.perception import Perception
from core.concept_web import ConceptWeb
from core.context.incremental import ContextModelState, IncrementalLDA
from core.planning import BehaviourEffects, Workspace, learn_effects
from core.prototypes.prototypes import PrototypeSet
from core.vocabulary import Vocabulary
from storage.database import snapshot
from storage.models import Model, TrainingObject
from storage.repositories import incremental_lda as lda_repository
from storage.repositories import models as model_repository

logger = logging.getLogger("contextweb")

#: Seconds between two reload attempts of an unavailable model while the database fails.
RELOAD_BACKOFF_SECONDS = 1.0


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
    version: int = 0
    """The stored version this memory equals (docs/scaling.md)."""
    fitted_at: datetime | None = None
    lock: threading.Lock = field(default_factory=threading.Lock, repr=False)
    changing: bool = False
    """True while the in-memory state holds changes not yet committed."""
    deleted: bool = False
    unavailable: str | None = None
    """Why the model does not serve (its memory is not proven equal to the database), or None."""
    reload_after: float = 0.0
    """``time.monotonic()`` before which no reload is tried (a database that fails is not hammered)."""
    failed_version: int | None = None
    """The stored version whose state failed its check: reloaded again only once that version moves."""
    vocabulary_limits: VocabularyLimits = field(default_factory=VocabularyLimits.defaults)
    """How far scenes may grow the vocabulary: the registry's, set when the model enters it."""

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
            fitted_at=row.fitted_at,
        )
        runtime.publish_summary()
        return runtime

    @classmethod
    def unloadable(cls, row: Model, reason: str) -> ModelRuntime:
        """The stand-in of a stored model whose state failed its load: listed, answering 503 with ``reason``."""
        try:
            vocabulary = Vocabulary.from_dict(row.vocabulary)
        except Exception:  # noqa: BLE001 - a corrupt vocabulary is one more reason the model cannot load
            vocabulary = Vocabulary(nouns=("unknown",), adjective_pairs=(), verbs=())
        runtime = cls.from_row(
            row,
            incremental_lda=IncrementalLDA(),
            word_kinds=[],
            perception=Perception(vocabulary),
            effects=None,
            training_object_count=0,
        )
        runtime.unavailable = reason
        return runtime

    def replace_with(self, fresh: ModelRuntime) -> None:
        """Take ``fresh``'s state (a reload), keeping this object, its lock and its subscribers' references."""
        self.vocabulary = fresh.vocabulary
        self.incremental_lda = fresh.incremental_lda
        self.word_kinds = fresh.word_kinds
        self.perception = fresh.perception
        self.effects = fresh.effects
        self.training_object_count = fresh.training_object_count
        self.fitted_at = fresh.fitted_at
        self.version = fresh.version
        self.unavailable = None
        self.failed_version = None
        self.publish_summary()

    def mark_unavailable(self, reason: str, *, failed_version: int | None = None) -> None:
        self.unavailable = reason
        self.failed_version = failed_version
        self.reload_after = time.monotonic() + RELOAD_BACKOFF_SECONDS

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
    runtime = ModelRuntime.from_row(
        row,
        incremental_lda=incremental_lda,
        word_kinds=stored.word_kinds,
        perception=fitted_perception(Vocabulary.from_dict(row.vocabulary), row.prototypes, row.concept_web),
        effects=behaviour_effects(vectors, behaviours) if row.fitted_at is not None else None,
        training_object_count=training_count,
    )
    runtime.version = stored.version
    return runtime


def catch_up(session: Session, model: ModelRuntime) -> bool:
    """Bring ``model`` to the stored version from the rows written since its own (in one snapshot, or
    under the model's write lock); False when the model is gone. Raises what the load would: an
    error here leaves memory unproven, and the caller marks the model unavailable."""
    changes = lda_repository.load_changes(
        session, model.id, since_version=model.version, word_count=len(model.incremental_lda.vocabulary)
    )
    if changes is None:
        return False
    if changes.version == model.version:
        return True
    fitted_at, training_count = session.execute(
        select(
            Model.fitted_at, select(func.count()).where(TrainingObject.model_id == model.id).scalar_subquery()
        ).where(Model.id == model.id)
    ).one()
    if fitted_at != model.fitted_at:
        row = model_repository.get_model(session, model.id)
        assert row is not None
        vectors, behaviours, _ = training_effects(session, model.id)
        model.perception = fitted_perception(model.vocabulary, row.prototypes, row.concept_web)
        model.effects = behaviour_effects(vectors, behaviours) if row.fitted_at is not None else None
        model.fitted_at = row.fitted_at
    model.incremental_lda.catch_up(
        new_words=[name for name, _ in changes.new_words],
        n_contexts=changes.context_count,
        tokens=changes.tokens,
        count_entries=changes.count_entries,
        scene_count=changes.scene_count,
        rng_state=changes.state["rng_state"],
    )
    model.word_kinds.extend(kind for _, kind in changes.new_words)
    model.training_object_count = int(training_count)
    model.version = changes.version
    model.publish_summary()
    return True


class ModelRegistry:
    """Every model of the deployment, by id, kept equal to the database (docs/scaling.md).

    Models created or deleted by another process are found on the next request
    that names them (:meth:`resolve`) or lists them (:meth:`synchronise`).
    """

    def __init__(self, read_sessions: sessionmaker[Session], vocabulary_limits: VocabularyLimits | None = None) -> None:
        self.vocabulary_limits = vocabulary_limits or VocabularyLimits.defaults()
        self._models: dict[str, ModelRuntime] = {}
        self._lock = threading.Lock()
        self._read_sessions = read_sessions

    def __len__(self) -> int:
        return len(self._models)

    def get(self, model_id: str) -> ModelRuntime | None:
        return self._models.get(model_id)

    def all(self) -> list[ModelRuntime]:
        return sorted(self._models.values(), key=lambda model: (model.created_at, model.id))

    def add(self, model: ModelRuntime) -> None:
        model.vocabulary_limits = self.vocabulary_limits
        with self._lock:
            self._models[model.id] = model

    def remove(self, model_id: str) -> None:
        with self._lock:
            self._models.pop(model_id, None)

    def forget(self, model: ModelRuntime) -> None:
        """The model was deleted (here or by another process)."""
        model.deleted = True
        self.remove(model.id)

    def load_all(self, session: Session) -> None:
        """Every stored model; one whose state fails its load is registered unavailable, never fatal."""
        for row in model_repository.list_models(session):
            self.add(_loaded_or_unavailable(session, row))

    # Keeping memory equal to the database.

    def _snapshot(self) -> AbstractContextManager[Session]:
        return snapshot(self._read_sessions)

    def resolve(self, model_id: str) -> ModelRuntime:
        """The model ``model_id`` as stored now: loaded if another process created it, caught up if
        another process wrote to it; 404 if it does not exist, 503 if it cannot serve. Costs one
        primary-key read when memory is current (read-your-writes across processes)."""
        with _storage_errors(), self._snapshot() as session:
            version = lda_repository.stored_version(session, model_id)
        model = self._models.get(model_id)
        if version is None:
            if model is not None:
                self.forget(model)
            raise ModelNotFound(model_id)
        if model is None:
            return self._load_new(model_id)
        if model.version != version or model.unavailable is not None:
            with model.lock:
                self.refresh(model)
        return model

    def _load_new(self, model_id: str) -> ModelRuntime:
        with self._lock:  # one loader per new model: concurrent first requests wait for it
            model = self._models.get(model_id)
            if model is None:
                with self._snapshot() as session:
                    row = model_repository.get_model(session, model_id)
                    if row is None:
                        raise ModelNotFound(model_id)
                    model = _loaded_or_unavailable(session, row)
                model.vocabulary_limits = self.vocabulary_limits
                self._models[model_id] = model
        if model.unavailable is not None:
            raise ModelUnavailable(model.id, model.unavailable)
        return model

    def refresh(self, model: ModelRuntime) -> None:
        """Under ``model.lock``: catch ``model`` up, or reload it if it is unavailable. Raises 404 when
        it was deleted, 503 while it cannot be proven equal to the database."""
        if model.deleted:
            raise ModelNotFound(model.id)
        if model.unavailable is None:
            try:
                with self._snapshot() as session:
                    found = catch_up(session, model)
            except Exception as error:
                _mark_failed(model, error, "catching up with the database failed")
                raise _unavailable(model, error) from error
            if not found:
                self.forget(model)
                raise ModelNotFound(model.id)
            return
        self.reload(model)

    def reload(self, model: ModelRuntime) -> None:
        """Under ``model.lock``: replace ``model``'s memory by the stored state, read in one snapshot."""
        if time.monotonic() < model.reload_after:
            raise ModelUnavailable(model.id, model.unavailable or "reloading", retry_after=1)
        try:
            with self._snapshot() as session:
                version = lda_repository.stored_version(session, model.id)
                row = None if version is None else model_repository.get_model(session, model.id)
                if row is None:
                    self.forget(model)
                    raise ModelNotFound(model.id)
                if model.failed_version is not None and version == model.failed_version:
                    raise ModelUnavailable(model.id, model.unavailable or "stored state inconsistent")
                try:
                    fresh = load_runtime(session, row)
                except Exception as error:
                    if is_storage_failure(error):
                        raise
                    model.mark_unavailable(_inconsistency(model.id, error), failed_version=version)
                    raise ModelUnavailable(model.id, model.unavailable or "") from error
        except (ModelUnavailable, ModelNotFound):
            raise
        except Exception as error:
            _mark_failed(model, error, "reloading from the database failed")
            raise _unavailable(model, error) from error
        model.replace_with(fresh)
        logger.info("model %s reloaded from the database at version %d", model.id, model.version)

    def synchronise(self) -> list[ModelRuntime]:
        """Every stored model, as stored now (a listing): new ones loaded, deleted ones forgotten, the
        others caught up; one query when nothing changed. Models that cannot serve stay listed."""
        with _storage_errors(), self._snapshot() as session:
            versions = lda_repository.stored_versions(session)
        for model_id in set(self._models) - set(versions):
            self.forget(self._models[model_id])
        for model_id, version in versions.items():
            model = self._models.get(model_id)
            try:
                if model is None:
                    self._load_new(model_id)
                elif model.version != version or model.unavailable is not None:
                    with model.lock:
                        self.refresh(model)
            except (ModelUnavailable, ModelNotFound):
                continue  # listed as unavailable, or gone meanwhile
        return self.all()


@contextmanager
def _storage_errors() -> Iterator[None]:
    """A storage failure in the block is a 503 (no model is left unproven by it)."""
    try:
        yield
    except Exception as error:
        if is_storage_failure(error):
            raise storage_error(error) from error
        raise


def _loaded_or_unavailable(session: Session, row: Model) -> ModelRuntime:
    try:
        return load_runtime(session, row)
    except Exception as error:
        if is_storage_failure(error):
            raise
        reason = _inconsistency(row.id, error)
        logger.error("%s", reason)
        runtime = ModelRuntime.unloadable(row, reason)
        runtime.failed_version = lda_repository.stored_version(session, row.id)
        return runtime


def _inconsistency(model_id: str, error: BaseException) -> str:
    detail = getattr(error, "problem", None) or str(error) or type(error).__name__
    field_name = getattr(error, "field", None)
    where = f" ({field_name})" if field_name else ""
    return (
        f"its stored state failed its check{where}: {detail}; "
        f"`contextweb models check {model_id}` reports it, `contextweb models repair {model_id}` rebuilds it"
    )


def _mark_failed(model: ModelRuntime, error: BaseException, what: str) -> None:
    if is_storage_failure(error):
        model.mark_unavailable(f"{what} ({storage_failure_reason(error)}); it is reloaded once the database answers")
    else:
        model.mark_unavailable(f"{what}: {_inconsistency(model.id, error)}")


def _unavailable(model: ModelRuntime, error: BaseException) -> Exception:
    if is_storage_failure(error):
        return storage_error(error)
    return ModelUnavailable(model.id, model.unavailable or "unavailable")
