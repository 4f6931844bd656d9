"""The models in memory: one :class:`ModelRuntime` per stored model, kept equal to the database.

A runtime is what the model is (fixed), its :class:`FittedPerception` (prototypes,
concept web, behaviour effects: frozen, replaced whole by a fit) and its
:class:`ModelWriter`, which owns the model's lock and its learning state (the
Incremental-LDA, the version of the stored state memory equals, availability) and
is the only code that changes them; its ``transaction`` commits a write or, in
its ``undo``, the one place for it, undoes what memory holds of a failed one.
The database is the truth, and memory follows it (docs/scaling.md):

- :func:`load_runtime` rebuilds a runtime exactly (counts, assignments, random
  state) from one consistent snapshot: how the server starts, and how a model
  whose write failed is reloaded;
- :func:`catch_up` brings a runtime that is behind (another process wrote) to
  the stored version, reading only the rows written since its own version;
- a failed scene write is taken back out of memory exactly
  (:meth:`IncrementalLDA.undo_scene`), which leaves memory equal to the database
  at the version it held, so the model serves on without a reload;
- a model whose stored state cannot be loaded, or whose memory could not be
  proven equal to the database after any other failed write, is *unavailable* (503
  ``model_unavailable``) until a reload succeeds; the other models serve on.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import AbstractContextManager, contextmanager
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any

import numpy as np
from sqlalchemy import func, select
from sqlalchemy.exc import DBAPIError
from sqlalchemy.orm import Session, sessionmaker

from app.errors import (
    ModelNotFound,
    ModelUnavailable,
    is_storage_failure,
    is_write_conflict,
    storage_error,
    storage_failure_reason,
)
from app.services.limits import VocabularyLimits
from app.services.perception import Perception
from app.settings import DEFAULT_CHECKPOINT_INTERVAL
from core.concept_web import ConceptWeb
from core.context.hyperparameters import nest_flat_settings
from core.context.incremental import ContextModelState, IncrementalLDA, SceneUpdate
from core.context.k_selection import K_RULES
from core.errors import InvalidInputError
from core.planning import BehaviourEffects, Workspace, learn_effects
from core.prototypes.prototypes import PrototypeSet
from core.vocabulary import Vocabulary
from storage.database import autocommit_reads, snapshot, with_deadline, write_turn
from storage.models import HYPERPARAMETERS_VERSION, Model, TrainingObject
from storage.repositories import contexts as context_repository
from storage.repositories import feed as feed_repository
from storage.repositories import incremental_lda as lda_repository
from storage.repositories import models as model_repository
from storage.unit_of_work import unit_of_work

logger = logging.getLogger("contextweb")

#: Seconds between two reload attempts of an unavailable model while the database fails.
RELOAD_BACKOFF_SECONDS = 1.0
VERSION_CHECK_DEADLINE_SECONDS = 5.0
"""PostgreSQL: how long a request's check of a model's stored version (one primary-key read, which
waits for no lock) may take before its connection is cut and the request answered 503: a
database that stopped answering (storage/deadlines.py), not one that is slow."""
#: A model whose stored state failed its check is loaded again as soon as its stored version moves
#: (``contextweb models repair`` moves it), and otherwise after this many seconds, doubling after
#: each check that fails again up to :data:`FAILED_CHECK_RECHECK_MAX_SECONDS`: rows mended by hand,
#: which leave the version where it was, are then found without a restart, while a model that stays
#: broken costs one load per hour at most (a load of a million scenes takes seconds).
FAILED_CHECK_RECHECK_SECONDS = 30.0
FAILED_CHECK_RECHECK_MAX_SECONDS = 3600.0


@dataclass(frozen=True)
class ModelSummary:
    """The counters a listing shows, published after each commit (read without the lock)."""

    context_count: int
    scene_count: int
    vocabulary_size: int


@dataclass(frozen=True)
class FittedPerception:
    """What the model's last committed fit made of its training objects: core's perception
    (vocabulary, the prototypes of Eq. 1, the concept web of Eqs. 2-4, with the web's memo of
    settled named webs) and the behaviours' effects the planner uses (§V-E).

    Replaced whole when a fit commits or memory catches up past another process's fit, never
    changed in place: a request that read it without the lock (a scene's perception) keeps a
    consistent one, and notices a fit by identity.
    """

    perception: Perception
    effects: BehaviourEffects | None = None
    fitted_at: datetime | None = None

    @classmethod
    def from_row(
        cls, row: Model, vocabulary: Vocabulary, effect_vectors: list[list[float]], behaviours: list[str]
    ) -> FittedPerception:
        """The fit stored in ``row`` (unfitted parts None), with the effects of its training objects."""
        perception = fitted_perception(vocabulary, row.prototypes, row.concept_web)
        if row.fitted_at is None:
            return cls(perception)
        return cls(perception, behaviour_effects(effect_vectors, behaviours), row.fitted_at)


@dataclass(eq=False)
class ModelWrite:
    """One write to a model: its transaction and the version the model has once it commits."""

    session: Session
    version: int
    locked: lda_repository.LockedModel
    """What was read with the model's lock: its contexts' labels (a learned scene's answer names
    its context) and, for a keyed write, the scene already stored under its key."""
    version_saved: bool = False
    """Set by a service whose own statements stored :attr:`version` (a scene's state row)."""
    unchanged: bool = False
    """Set when the write changed nothing (an idempotent replay): no new version, no notification."""
    notified: bool = False
    """Set by a service whose own statements sent the change notification (a scene, in its pipeline)."""
    keeps_labels: bool = False
    """Set by a service whose write cannot change the contexts' labels (a learned scene): the labels
    known at the write's start stay true at its version (:meth:`ModelWriter.transaction`)."""


class ModelWriter:
    """The one writer of a model's memory in this process: it owns the model's lock and its
    learning state (Incremental-LDA, the words' kinds, the training object count, the version
    memory equals, the published summary, whether it serves) and the reference to its
    :class:`FittedPerception`, and it is the only code that changes them (docs/scaling.md).

    Every write runs in :meth:`transaction`: services ask the writer to apply a change to memory
    (:meth:`learn_scene`, :meth:`count_training_objects`, :meth:`install_fit`); what must wait
    for the commit is applied after it, and a change that memory already holds is undone by
    :meth:`undo` if the write fails: the one place where memory that may lead the database is
    taken back (a scene, exactly), or reloaded from the database, or else marked unavailable. Read the state through :class:`ModelRuntime`;
    readers that need several of its values consistent hold :attr:`lock` while they read.
    """

    def __init__(
        self,
        model_id: str,
        fitted: FittedPerception,
        incremental_lda: IncrementalLDA,
        word_kinds: list[str | None],
        training_object_count: int,
        *,
        version: int = 0,
        unavailable: str | None = None,
        failed_version: int | None = None,
    ) -> None:
        self.id = model_id
        self.lock = threading.Lock()
        self.fitted = fitted
        self.incremental_lda = incremental_lda
        self.word_kinds = word_kinds
        self.training_object_count = training_object_count
        self.version = version
        """The stored version this memory equals (docs/scaling.md)."""
        self.summary = ModelSummary(0, 0, 0)
        self.deleted = False
        self.unavailable = unavailable
        """Why the model does not serve (its memory is not proven equal to the database), or None."""
        self.reload_after = 0.0
        """``time.monotonic()`` before which no reload is tried (a database that fails is not hammered)."""
        self.failed_version: int | None = None
        """The stored version whose state failed its check: reloaded again once that version moves, or
        at the same version after :attr:`recheck_after`."""
        self.failed_checks = 0
        """How many checks in a row failed at :attr:`failed_version` (the recheck's backoff doubles)."""
        self.recheck_after = 0.0
        """``time.monotonic()`` before which a failed check is not repeated at :attr:`failed_version`."""
        if failed_version is not None:  # a model registered unloadable at start-up
            self._failed_check(failed_version)
        self._changed = False
        """True while memory holds changes the database may not (from the change to the commit)."""
        self._on_commit: list[Callable[[], None]] = []
        """What waits for the commit of the open write."""
        self._learned: tuple[SceneUpdate, int] | None = None
        """The open write's scene, if memory holds nothing else of it, and how many words had a
        kind before it: what :meth:`undo` takes back exactly."""
        self._writing = False
        self._known_labels: tuple[int, dict[int, str]] | None = None
        """The contexts' labels as stored at a database version (the version, the labels): what a
        write under the lock at that version reads without asking (:meth:`transaction`)."""
        self._labels_with_lock = True
        """Whether the next write reads the labels with the lock: none are known, or the last write
        found the known ones stale (another process wrote in between: two processes writing in turn)."""
        self.publish_summary()

    # The unit of work.

    @contextmanager
    def transaction(
        self,
        write_sessions: sessionmaker[Session],
        registry: ModelRegistry,
        *,
        wait: bool = True,
        idempotency_key: str | None = None,
    ) -> Iterator[ModelWrite]:
        """One write to the model, committed or undone (app/deps.py ``model_write`` documents the order).
        ``wait=False``: on PostgreSQL, raises ``LockHeldElsewhere`` at once, before anything else, if
        another transaction holds the model's lock (``lda_repository.lock_model``).
        ``idempotency_key``: the key of the scene the write learns, looked up with the lock
        (``ModelWrite.locked``), in the lock's round trip.

        Under the database's lock (the model's state row, or SQLite's write lock, which this
        process's writers take turns to wait for: ``storage.database.write_turn``), taken first,
        then this process's lock: the stored version is read; memory that is behind catches up
        from the rows written since; the block runs; the version is bumped and the other processes
        notified; the commit; then the changes that waited for it. If anything fails once memory
        may hold the write, :meth:`undo` runs under the lock.
        """
        if self.deleted:
            raise ModelNotFound(self.id)
        if self.unavailable is not None:
            # What the reload under the locks would answer, answered before waiting for them: the
            # writes queued behind one that failed (a database that stopped answering: each would
            # wait out its own deadline) fail fast until the reload's back-off has passed.
            self.refuse_while_backing_off()
        holding = False
        try:
            with write_turn(write_sessions), unit_of_work(write_sessions) as session:
                # Read before this process's lock: only a hint of whether to read the labels with the lock.
                locked = lda_repository.lock_model(
                    session, self.id, wait=wait, idempotency_key=idempotency_key, labels=self._labels_with_lock
                )
                self.lock.acquire()
                holding = True
                if self.deleted:
                    raise ModelNotFound(self.id)
                if self.unavailable is not None:
                    registry.reload(self)
                if locked is None:
                    registry.forget(self)
                    raise ModelNotFound(self.id)
                if locked.version != self.version:
                    self._catch_up_for_write(session, registry)
                locked = self._with_labels(session, locked)
                write = ModelWrite(session, locked.version + 1, locked)
                self._writing = True
                yield write
                if not write.unchanged:
                    if not write.version_saved:
                        lda_repository.set_version(session, self.id, write.version)
                    if not write.notified:
                        feed_repository.notify_change(session, self.id)
            self._committed(write)
        except BaseException as error:
            self._known_labels, self._labels_with_lock = None, True
            if self._changed:
                self.undo(error, registry)  # under the lock: memory changed only once it was held
            raise
        finally:
            self._changed = self._writing = False
            self._on_commit.clear()
            self._learned = None
            if holding:
                self.lock.release()

    def _with_labels(self, session: Session, locked: lda_repository.LockedModel) -> lda_repository.LockedModel:
        """``locked`` with the contexts' labels at its version: as read with the lock, else as known
        at that version, else read now (a round trip: another process or another kind of write
        changed the model since). Labels change only by a write, which bumps the version, so labels
        known at the version the lock found are the stored ones."""
        known = self._known_labels
        known_now = known[1] if known is not None and known[0] == locked.version else None
        labels = locked.labels
        if labels is None:
            labels = known_now if known_now is not None else context_repository.context_labels(session, self.id)
        self._labels_with_lock = known is not None and known_now is None
        self._known_labels = (locked.version, labels)
        return dataclasses.replace(locked, labels=labels)

    def _committed(self, write: ModelWrite) -> None:
        self._learned = None  # committed: from here only a reload follows the database
        if not write.unchanged:
            self.version = write.version
            # A write that may have changed the labels leaves them unknown at its version (the next
            # write reads them with the lock).
            labels = write.locked.labels
            if write.keeps_labels and labels is not None:
                self._known_labels = (write.version, labels)
            else:
                self._known_labels, self._labels_with_lock = None, True
        for change in self._on_commit:
            change()

    def _catch_up_for_write(self, session: Session, registry: ModelRegistry) -> None:
        """Catch up under the write lock; changes that do not fit memory make the model unavailable
        (a consistency problem of the stored state, never the client's invalid input)."""
        self._changed = True  # until the catch-up completes, memory is unproven
        try:
            catch_up(session, self)
        except Exception as error:
            if is_storage_failure(error):
                raise
            self.undo(error, registry)
            raise ModelUnavailable(self.id, self.unavailable or "its stored changes do not fit memory") from error
        self._changed = False

    def undo(self, error: BaseException, registry: ModelRegistry, *, reload_now: bool = True) -> None:
        """Memory may hold what the database does not (a write or a catch-up failed): the one undo.

        The model is marked unavailable (503 ``model_unavailable``), then reloaded from one
        snapshot: at once after a failed write (the database answered its statements), or by a
        later request after a failed catch-up of a read (a backoff: its database just failed).
        A reload that fails leaves the model unavailable until one succeeds. Under :attr:`lock`.

        A write whose only change to memory is one learned scene, failed before its commit
        returned, is undone exactly instead (:meth:`IncrementalLDA.undo_scene`): memory is then
        what it was at :attr:`version`, which the database held before the write and holds still
        unless its commit landed unseen (then the next request catches up from the stored rows, as
        after another process's write). The model serves on: a database that fails writes for a
        while (a full disk) costs no reload per write, which takes seconds at a million scenes. Not
        so a write that conflicts with a stored row: the database holds what memory does not, so
        the reload's check is what names it.
        """
        self._changed = False
        self._on_commit.clear()
        if self.deleted:
            return
        # A conflict with a stored row says the database holds what memory does not: reload, and its check names it.
        if self._learned is not None and not is_write_conflict(error) and self._undo_scene(error):
            return
        if not reload_now:
            _mark_failed(self, error, "catching up with the database failed")
            return
        self.mark_unavailable(f"a write failed ({type(error).__name__}) and its model is being reloaded")
        self.reload_after = 0.0
        try:
            registry.reload(self)
        except Exception:  # noqa: BLE001 - the model stays unavailable; a later request reloads it
            logger.warning("model %s stays unavailable until the database answers: %s", self.id, self.unavailable)

    # The changes a write asks for, inside :meth:`transaction`.

    def learn_scene(self, words: list[str], kind_of: Callable[[str], str | None]) -> SceneUpdate:
        """Incremental-LDA learns ``words`` (Algorithm 2's loop body), new words get ``kind_of(word)``;
        memory holds the scene from here (undone if the write fails), the summary follows the commit."""
        self._check_writing()
        first_write = not self._changed
        self._changed = True
        update = self.incremental_lda.learn_scene(words)
        self._learned = (update, len(self.word_kinds)) if first_write else None
        self.word_kinds.extend(kind_of(name) for name in update.vocabulary_additions)
        self._on_commit.append(self.publish_summary)
        return update

    def _undo_scene(self, error: BaseException) -> bool:
        """Take the failed write's one scene back out of memory (:meth:`undo`); False when it cannot
        be (memory is then unproven and the caller reloads)."""
        update, kinds = self._learned  # type: ignore[misc]
        self._learned = None
        try:
            self.incremental_lda.undo_scene(update)
        except Exception:
            logger.exception("model %s: a failed write's scene could not be taken back; reloading", self.id)
            return False
        del self.word_kinds[kinds:]
        logger.warning(
            "model %s: a write failed (%s); its scene was taken back out of memory, which equals the "
            "database at version %d, and the model serves on",
            self.id,
            storage_failure_reason(error),
            self.version,
        )
        return True

    def count_training_objects(self, total: int) -> None:
        """The model has ``total`` training objects once the write commits."""
        self._check_writing()
        self._on_commit.append(lambda: setattr(self, "training_object_count", total))

    def install_fit(self, fitted: FittedPerception) -> None:
        """``fitted`` replaces the model's perception once the write commits."""
        self._check_writing()
        self._on_commit.append(lambda: setattr(self, "fitted", fitted))

    def _check_writing(self) -> None:
        if not self._writing:
            raise RuntimeError(f"model {self.id}: a change outside a write (ModelWriter.transaction)")

    # Following the database (the registry reads it; the writer applies what it read).

    def apply_changes(
        self, changes: lda_repository.StoredChanges, fitted: FittedPerception | None, training_object_count: int
    ) -> None:
        """Another process's writes, read from the rows since :attr:`version` (``fitted`` when it fitted)."""
        self._changed = True
        if fitted is not None:
            self.fitted = fitted
        apply_stored_changes(self.incremental_lda, changes)
        self.word_kinds.extend(kind for _, kind in changes.new_words)
        self.training_object_count = training_object_count
        self.version = changes.version
        self.publish_summary()
        self._changed = False

    def replace(self, fresh: ModelWriter) -> None:
        """Take ``fresh``'s state (a reload), keeping this writer, its lock and its readers' references."""
        self.fitted = fresh.fitted
        self.incremental_lda = fresh.incremental_lda
        self.word_kinds = fresh.word_kinds
        self.training_object_count = fresh.training_object_count
        self.version = fresh.version
        self._known_labels, self._labels_with_lock = None, True
        self.unavailable = None
        self.failed_version = None
        self.failed_checks = 0
        self.publish_summary()

    def refuse_while_backing_off(self) -> None:
        """503 ``model_unavailable`` while a failed reload's back-off runs (:data:`RELOAD_BACKOFF_SECONDS`)."""
        if time.monotonic() < self.reload_after:
            raise ModelUnavailable(self.id, self.unavailable or "reloading", retry_after=1)

    def mark_unavailable(self, reason: str, *, failed_version: int | None = None) -> None:
        self.unavailable = reason
        if failed_version is not None:
            self._failed_check(failed_version)
        self.failed_version = failed_version
        self.reload_after = time.monotonic() + RELOAD_BACKOFF_SECONDS

    def _failed_check(self, version: int) -> None:
        """The stored state at ``version`` failed its check: when to check it again at that version."""
        self.failed_checks = self.failed_checks + 1 if version == self.failed_version else 1
        self.failed_version = version
        backoff = FAILED_CHECK_RECHECK_SECONDS * 2.0 ** min(self.failed_checks - 1, 20)
        self.recheck_after = time.monotonic() + min(backoff, FAILED_CHECK_RECHECK_MAX_SECONDS)

    def check_due(self, version: int) -> bool:
        """Whether the stored state at ``version`` is to be loaded (and so checked) now."""
        return self.failed_version is None or version != self.failed_version or time.monotonic() >= self.recheck_after

    def forget(self) -> None:
        """The model was deleted (here or by another process)."""
        self.deleted = True

    def publish_summary(self) -> None:
        lda = self.incremental_lda
        self.summary = ModelSummary(lda.n_contexts, lda.n_scenes, len(lda.vocabulary))


@dataclass(eq=False)
class ModelRuntime:
    """One model in memory: what it is (fixed once registered), its :class:`ModelWriter`, and
    read-only views of the writer's state. Nothing else changes a model's memory."""

    id: str
    name: str
    seed: int
    sigma: float
    created_at: datetime
    hyperparameters: dict[str, Any] | None
    """Nested (:func:`stored_hyperparameters`); None for a stand-in whose stored ones cannot be read."""
    writer: ModelWriter = field(repr=False)
    vocabulary_limits: VocabularyLimits = field(default_factory=VocabularyLimits.defaults)
    """How far scenes may grow the vocabulary: the registry's, set when the model enters it."""
    checkpoint_interval: int = DEFAULT_CHECKPOINT_INTERVAL
    """Every this-many scenes the model's checkpoint is rewritten (the registry's, as above)."""
    vocabulary_known: bool = True
    """False for a stand-in whose stored vocabulary cannot be read (its perception holds a placeholder):
    the listing shows none."""

    @classmethod
    def from_row(cls, row: Model, writer: ModelWriter) -> ModelRuntime:
        """The runtime of the model stored as ``row``, its in-memory state held by ``writer``."""
        return cls._of(row, writer, stored_hyperparameters(row))

    @classmethod
    def _of(
        cls, row: Model | model_repository.ModelHeader, writer: ModelWriter, hyperparameters: dict[str, Any] | None
    ) -> ModelRuntime:
        return cls(
            id=row.id,
            name=row.name,
            seed=row.seed,
            sigma=row.sigma,
            created_at=row.created_at,
            hyperparameters=hyperparameters,
            writer=writer,
        )

    @classmethod
    def unloadable(
        cls,
        row: Model | model_repository.ModelHeader,
        reason: str,
        failed_version: int | None,
        counts: tuple[int, int, int] | None = None,
    ) -> ModelRuntime:
        """The stand-in of a stored model whose state failed its load (or whose row's JSON cannot
        be decoded: a header of its other columns): listed, answering 503 with ``reason``, with
        the stored (contexts, scenes, words) ``counts`` when they could be read."""
        vocabulary_known = True
        try:
            vocabulary = _stored_vocabulary(row)  # type: ignore[arg-type]
        except Exception:  # noqa: BLE001 - a corrupt vocabulary is one more reason the model cannot load
            vocabulary, vocabulary_known = Vocabulary(nouns=("unknown",), adjective_pairs=(), verbs=()), False
        hyperparameters: dict[str, Any] | None
        try:
            hyperparameters = stored_hyperparameters(row)  # type: ignore[arg-type]
        except Exception:  # noqa: BLE001 - as above: listed without them
            hyperparameters = None
        fitted = FittedPerception(Perception(vocabulary), fitted_at=row.fitted_at)
        writer = ModelWriter(row.id, fitted, IncrementalLDA(), [], 0, unavailable=reason, failed_version=failed_version)
        if counts is not None:  # listed with what is stored, not the stand-in's empty memory
            writer.summary = ModelSummary(*counts)
        return dataclasses.replace(cls._of(row, writer, hyperparameters), vocabulary_known=vocabulary_known)

    @property
    def lock(self) -> threading.Lock:
        """The model's lock in this process (its writer's): hold it to read several values consistently."""
        return self.writer.lock

    @property
    def fitted(self) -> FittedPerception:
        return self.writer.fitted

    @property
    def perception(self) -> Perception:
        return self.writer.fitted.perception

    @property
    def vocabulary(self) -> Vocabulary:
        return self.writer.fitted.perception.vocabulary

    @property
    def effects(self) -> BehaviourEffects | None:
        return self.writer.fitted.effects

    @property
    def fitted_at(self) -> datetime | None:
        return self.writer.fitted.fitted_at

    @property
    def incremental_lda(self) -> IncrementalLDA:
        return self.writer.incremental_lda

    @property
    def word_kinds(self) -> Sequence[str | None]:
        return self.writer.word_kinds

    @property
    def training_object_count(self) -> int:
        return self.writer.training_object_count

    @property
    def summary(self) -> ModelSummary:
        return self.writer.summary

    @property
    def version(self) -> int:
        return self.writer.version

    @property
    def unavailable(self) -> str | None:
        return self.writer.unavailable

    @property
    def deleted(self) -> bool:
        return self.writer.deleted

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


def apply_stored_changes(incremental_lda: IncrementalLDA, changes: lda_repository.StoredChanges) -> None:
    """Bring ``incremental_lda`` to the state the rows written since its version give (another
    process's writes: words, moved and added tokens, the changed n_kw entries, the random state)."""
    incremental_lda.catch_up(
        new_words=[name for name, _ in changes.new_words],
        n_contexts=changes.context_count,
        moved=changes.tokens.moved,
        added=changes.tokens.added,
        count_entries=changes.count_entries,
        scene_count=changes.scene_count,
        rng_state=changes.state["rng_state"],
    )


def stored_hyperparameters(row: Model) -> dict[str, Any]:
    """A model row's hyperparameters in the nested form (alembic 0006).

    A row whose ``hyperparameters_version`` is older was written flat by a process older than 0006,
    still running during a rolling upgrade (the column's server default marks it): it is read as
    the deprecated flat form is read from a request, and a retired K rule continues as ``scenes``,
    as the migration carries such rows over.
    """
    settings = dict(row.hyperparameters)
    if row.hyperparameters_version >= HYPERPARAMETERS_VERSION:
        return settings
    nested, _ = nest_flat_settings(settings)
    if nested["k_rule"]["name"] not in K_RULES:
        logger.warning(
            "model %s was stored flat with the K rule %r, which the service no longer offers: it continues with 'scenes'",
            row.id,
            nested["k_rule"]["name"],
        )
        nested, _ = nest_flat_settings({**settings, "k_selection": "scenes"})
    # Settings no version reads any more (the retired rule's) are dropped, as the migration drops them.
    return {group: nested[group] for group in ("priors", "sampler", "k_rule") if group in nested}


def load_runtime(session: Session, row: Model) -> ModelRuntime:
    """A model exactly as stored: LDA counts, assignments and random state included, from its latest
    checkpoint and the rows written since (docs/scaling.md, "Checkpoints")."""
    stored = lda_repository.load_start(session, row.id)
    incremental_lda = stored_incremental_lda(stored, stored_hyperparameters(row))
    vectors, behaviours, training_count = training_effects(session, row.id)
    fitted = FittedPerception.from_row(row, _stored_vocabulary(row), vectors, behaviours)
    writer = ModelWriter(row.id, fitted, incremental_lda, stored.word_kinds, training_count, version=stored.version)
    return ModelRuntime.from_row(row, writer)


def stored_incremental_lda(stored: lda_repository.StoredStart, hyperparameters: dict[str, Any]) -> IncrementalLDA:
    """The Incremental-LDA of a start: the checkpoint's arrays, then the batches since caught up on
    top (the same catch-up as another process's writes), then the whole of n_kw checked against the
    stored n_kw entries. Without a checkpoint the batches' tokens are read as the arrays."""
    base, tail = stored.checkpoint, stored.tail
    if base is None:
        added = tail.added
        scene_lengths = np.bincount(added[:, 0], minlength=stored.scene_count)
        base = lda_repository.StoredCheckpoint(
            version=stored.version,
            context_count=stored.context_count,
            word_count=len(stored.word_names),
            words=added[:, 1].astype(np.int32),
            contexts=added[:, 2].astype(np.int32),
            doc_offsets=np.concatenate([[0], np.cumsum(scene_lengths)]).astype(np.int32),
        )
        tail = lda_repository.ReplayedTokens.none(base.token_count)
    n_contexts, n_words = base.context_count, base.word_count
    incremental_lda = IncrementalLDA.from_state(
        ContextModelState(
            hyperparameters=hyperparameters,
            vocabulary=stored.word_names[:n_words],
            n_contexts=n_contexts,
            words=base.words,
            assignments=base.contexts,
            doc_offsets=base.doc_offsets,
            n_kw=None,  # checked below, once the tail is on, against the stored n_kw entries
            rng_state=stored.state["rng_state"],
        )
    )
    incremental_lda.catch_up(
        new_words=stored.word_names[n_words:],
        n_contexts=stored.context_count,
        moved=tail.moved,
        added=tail.added,
        count_entries=np.zeros((0, 3), dtype=np.int64),
        scene_count=stored.scene_count,
        rng_state=stored.state["rng_state"],
    )
    state = incremental_lda.lda_state
    n_kw = np.zeros((stored.context_count, len(stored.word_names)), dtype=np.int64)
    entries = stored.count_entries
    if entries.size:
        if entries[:, 0].max() >= n_kw.shape[0] or entries[:, 1].max() >= n_kw.shape[1]:
            raise InvalidInputError("state.n_kw", "an entry names a context or concept the model does not have")
        n_kw[entries[:, 0], entries[:, 1]] = entries[:, 2]
    if not np.array_equal(n_kw, state.n_kw):
        raise InvalidInputError("state.n_kw", "differs from the counts of the stored assignments")
    return incremental_lda


def catch_up(session: Session, writer: ModelWriter) -> bool:
    """Bring the model to the stored version from the rows written since its own (in one snapshot, or
    under the model's write lock); False when the model is gone. A model so far behind that the
    batches it needs were folded into a checkpoint, or that a newer checkpoint is cheaper to load than
    those batches are to replay (``lda_repository.reload_is_cheaper``), is reloaded from that snapshot instead. Raises
    what the load would: an error here leaves memory unproven, and the caller has the writer undo it."""
    try:
        changes = lda_repository.load_changes(
            session,
            writer.id,
            since_version=writer.version,
            word_count=len(writer.incremental_lda.vocabulary),
            token_count=writer.incremental_lda.lda_state.n_tokens,
        )
    except lda_repository.BehindCompactionError as behind:
        row = model_repository.get_model(session, writer.id)
        if row is None:
            return False
        logger.info("%s: reloading it from its checkpoint", behind)
        writer.replace(load_runtime(session, row).writer)
        return True
    if changes is None:
        return False
    if changes.version == writer.version:
        return True
    fitted_at, training_count = session.execute(
        select(
            Model.fitted_at, select(func.count()).where(TrainingObject.model_id == writer.id).scalar_subquery()
        ).where(Model.id == writer.id)
    ).one()
    fitted = None
    if fitted_at != writer.fitted.fitted_at:
        row = model_repository.get_model(session, writer.id)
        assert row is not None
        vectors, behaviours, _ = training_effects(session, writer.id)
        fitted = FittedPerception.from_row(row, writer.fitted.perception.vocabulary, vectors, behaviours)
    writer.apply_changes(changes, fitted, int(training_count))
    return True


class ModelRegistry:
    """Every model of the deployment, by id, kept equal to the database (docs/scaling.md).

    Models created or deleted by another process are found on the next request
    that names them (:meth:`resolve`) or lists them (:meth:`synchronise`).
    """

    def __init__(
        self,
        read_sessions: sessionmaker[Session],
        vocabulary_limits: VocabularyLimits | None = None,
        *,
        checkpoint_interval: int = DEFAULT_CHECKPOINT_INTERVAL,
        load_deadline_seconds: float | None = None,
    ) -> None:
        """``load_deadline_seconds``: PostgreSQL, how long a model's load, reload or catch-up may
        read before its connection is cut (``CONTEXTWEB_LOAD_DEADLINE_SECONDS``); None for no deadline."""
        self.vocabulary_limits = vocabulary_limits or VocabularyLimits.defaults()
        self.checkpoint_interval = checkpoint_interval
        self._models: dict[str, ModelRuntime] = {}
        self._lock = threading.Lock()
        self._load_sessions = (
            read_sessions
            if load_deadline_seconds is None
            else with_deadline(read_sessions, load_deadline_seconds, "the load deadline")
        )
        self._version_sessions = with_deadline(read_sessions, VERSION_CHECK_DEADLINE_SECONDS)

    def __len__(self) -> int:
        return len(self._models)

    def get(self, model_id: str) -> ModelRuntime | None:
        return self._models.get(model_id)

    def all(self) -> list[ModelRuntime]:
        return sorted(self._models.values(), key=lambda model: (model.created_at, model.id))

    def add(self, model: ModelRuntime) -> None:
        self._configure(model)
        with self._lock:
            self._models[model.id] = model

    def _configure(self, model: ModelRuntime) -> None:
        """The registry's settings, given to a model as it enters (the only change of its fixed part)."""
        model.vocabulary_limits = self.vocabulary_limits
        model.checkpoint_interval = self.checkpoint_interval

    def remove(self, model_id: str) -> None:
        with self._lock:
            self._models.pop(model_id, None)

    def forget(self, writer: ModelWriter) -> None:
        """The model was deleted (here or by another process)."""
        writer.forget()
        self.remove(writer.id)

    def load_all(self) -> None:
        """Every stored model, each read in one snapshot of its own (:meth:`_snapshot`, as every later
        load reads one); one whose state fails its load is registered unavailable, never fatal.

        One snapshot a model, not one session for all: on PostgreSQL a plain session reads each
        statement as of its own start, so a process starting while another writes read a model's
        state row before that write and its token batches after it, and took a sound model for a
        damaged one ("846 stored, 848 after catching up": a ``--workers 2`` worker restarted under
        load, 2026-12-07; tests/test_runtime_processes.py)."""
        with self._snapshot() as session:
            model_ids = [model_id for model_id, _ in model_repository.stored_models(session)]
        for model_id in model_ids:
            model = self._stored(model_id)
            if model is not None:  # else deleted since the list
                self.add(model)

    # Keeping memory equal to the database.

    def _stored(self, model_id: str) -> ModelRuntime | None:
        """The model as stored, read in one snapshot (unavailable if its state fails its check); None
        if there is no such model."""
        with self._snapshot() as session:
            try:
                row = model_repository.get_model(session, model_id)
            except Exception as error:  # its stored JSON cannot be decoded (a damaged row)
                if is_storage_failure(error):
                    raise
                return _unreadable(session, model_id, error)
            return None if row is None else _loaded_or_unavailable(session, row)

    def _snapshot(self) -> AbstractContextManager[Session]:
        """One snapshot for a model's load, reload or catch-up, cut at the load deadline: a database
        that stops answering mid-load must not hold the model's lock (or, for a first load, the
        registry's) for as long as it stays frozen."""
        return snapshot(self._load_sessions)

    def resolve(self, model_id: str) -> ModelRuntime:
        """The model ``model_id`` as stored now: loaded if another process created it, caught up if
        another process wrote to it; 404 if it does not exist, 503 if it cannot serve. Costs one
        primary-key read when memory is current (read-your-writes across processes)."""
        with _storage_errors(), autocommit_reads(self._version_sessions) as session:
            version = lda_repository.stored_version(session, model_id)
        model = self._models.get(model_id)
        if version is None:
            if model is not None:
                self.forget(model.writer)
            raise ModelNotFound(model_id)
        if model is None:
            return self._load_new(model_id)
        if model.version != version or model.unavailable is not None:
            with model.lock:
                self.refresh(model.writer)
        return model

    def _load_new(self, model_id: str) -> ModelRuntime:
        with self._lock:  # one loader per new model: concurrent first requests wait for it
            model = self._models.get(model_id)
            if model is None:
                model = self._stored(model_id)
                if model is None:
                    raise ModelNotFound(model_id)
                self._configure(model)
                self._models[model_id] = model
        if model.unavailable is not None:
            raise ModelUnavailable(model.id, model.unavailable)
        return model

    def refresh(self, writer: ModelWriter) -> None:
        """Under the model's lock: catch it up, or reload it if it is unavailable. Raises 404 when
        it was deleted, 503 while it cannot be proven equal to the database."""
        if writer.deleted:
            raise ModelNotFound(writer.id)
        if writer.unavailable is None:
            try:
                with self._snapshot() as session:
                    found = catch_up(session, writer)
            except Exception as error:
                writer.undo(error, self, reload_now=False)
                raise _unavailable(writer, error) from error
            if not found:
                self.forget(writer)
                raise ModelNotFound(writer.id)
            return
        self.reload(writer)

    def reload(self, model: ModelWriter) -> None:
        """Under the model's lock: replace its memory by the stored state, read in one snapshot."""
        model.refuse_while_backing_off()
        try:
            with self._snapshot() as session:
                version = lda_repository.stored_version(session, model.id)
                if version is None:
                    self.forget(model)
                    raise ModelNotFound(model.id)
                if not model.check_due(version):
                    raise ModelUnavailable(model.id, model.unavailable or "stored state inconsistent")
                what = "its stored row cannot be read"
                try:
                    row = model_repository.get_model(session, model.id)  # its JSON may not decode
                    what = "its stored state failed its check"
                    fresh = None if row is None else load_runtime(session, row)
                except Exception as error:
                    if is_storage_failure(error):
                        raise
                    model.mark_unavailable(_inconsistency(model.id, error, what), failed_version=version)
                    raise ModelUnavailable(model.id, model.unavailable or "") from error
                if fresh is None:
                    self.forget(model)
                    raise ModelNotFound(model.id)
        except (ModelUnavailable, ModelNotFound):
            raise
        except Exception as error:
            _mark_failed(model, error, "reloading from the database failed")
            raise _unavailable(model, error) from error
        model.replace(fresh.writer)
        logger.info("model %s reloaded from the database at version %d", model.id, model.version)

    def synchronise(self) -> list[ModelRuntime]:
        """Every stored model, as stored now (a listing): new ones loaded, deleted ones forgotten, the
        others caught up; one query when nothing changed. Models that cannot serve stay listed."""
        with _storage_errors(), autocommit_reads(self._version_sessions) as session:
            versions = lda_repository.stored_versions(session)
        for model_id in set(self._models) - set(versions):
            self.forget(self._models[model_id].writer)
        for model_id, version in versions.items():
            model = self._models.get(model_id)
            try:
                if model is None:
                    self._load_new(model_id)
                elif model.version != version or model.unavailable is not None:
                    with model.lock:
                        self.refresh(model.writer)
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
        logger.error("model %s: %s", row.id, reason)
        return ModelRuntime.unloadable(
            row, reason, lda_repository.stored_version(session, row.id), _stored_summary(session, row.id)
        )


def _stored_vocabulary(row: Model) -> Vocabulary:
    """The model row's vocabulary; InvalidInputError naming ``model.vocabulary`` when it is not one."""
    try:
        return Vocabulary.from_dict(row.vocabulary)
    except InvalidInputError as error:
        raise InvalidInputError(f"model.vocabulary.{error.field}", error.problem) from error
    except (TypeError, ValueError, KeyError, AttributeError) as error:
        raise InvalidInputError("model.vocabulary", f"not a vocabulary ({type(error).__name__}: {error})") from error


def _unreadable(session: Session, model_id: str, error: BaseException) -> ModelRuntime | None:
    """The stand-in of a model whose row cannot be read whole (its JSON is damaged), or None if it is gone."""
    header = model_repository.get_model_header(session, model_id)
    if header is None:
        return None
    reason = _inconsistency(model_id, error, what="its stored row cannot be read")
    logger.error("model %s: %s", model_id, reason)
    return ModelRuntime.unloadable(
        header, reason, lda_repository.stored_version(session, model_id), _stored_summary(session, model_id)
    )


def _stored_summary(session: Session, model_id: str) -> tuple[int, int, int] | None:
    try:
        return lda_repository.stored_summary(session, model_id)
    except Exception as error:  # the state row itself may be what is damaged: listed without them
        if is_storage_failure(error):
            raise
        return None


def _inconsistency(model_id: str, error: BaseException, what: str = "its stored state failed its check") -> str:
    """Why a model cannot load, for its 503s and the listing: the problem (the database's own first
    line for a database error, never its SQL), and the commands that tell what to do."""
    if isinstance(error, DBAPIError):
        detail = storage_failure_reason(error)
    else:
        detail = getattr(error, "problem", None) or str(error) or type(error).__name__
    field_name = getattr(error, "field", None)
    where = f" ({field_name})" if field_name else ""
    return (
        f"{what}{where}: {detail}; `contextweb models check {model_id}` names the problem and "
        f"whether `contextweb models repair {model_id}` can rebuild it"
    )


def _mark_failed(model: ModelWriter, error: BaseException, what: str) -> None:
    if is_storage_failure(error):
        model.mark_unavailable(f"{what} ({storage_failure_reason(error)}); it is reloaded once the database answers")
    else:
        model.mark_unavailable(f"{what}: {_inconsistency(model.id, error)}")


def _unavailable(model: ModelWriter, error: BaseException) -> Exception:
    if is_storage_failure(error):
        return storage_error(error)
    return ModelUnavailable(model.id, model.unavailable or "unavailable")
