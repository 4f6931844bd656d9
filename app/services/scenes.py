"""Scenes: learn one online (Algorithm 2's loop body), or only analyse it; the scene history.

Learning a scene:

1. :func:`read_scene`, before any lock: the body's hash and its objects checked
   and made core's (for raw payloads the feature extraction, seconds for the
   largest bodies, in GIL-free kernels, on a write thread: so one raw scene never
   holds the scene thread of this process's other models); then, on the scene
   thread (app/admission.py ``Admission.run_scene``: one per process on SQLite,
   docs/scaling.md) and before the model's write lock (app/deps.py ``model_write``),
   :func:`prepare_scene`: the objects' concept webs (app/services/perception.py) —
   no database work, nothing of the model changed. Both run against the model's perception read once: a
   fit (or a catch-up or reload) replaces the perception whole, and
   :func:`learn_scene` redoes the analysis under the lock if it was replaced
   meanwhile (rare, and cheap next to the fit that caused it); and, if the
   model's lock is free, the context fed back into the webs (step 3) against the
   model in memory, used by step 3 if memory has not changed by then;

Then under the model's write lock, :func:`learn_scene`:

2. the Idempotency-Key: a key seen with the same body returns the stored answer
   and changes nothing; with another body it is a 422;
3. the context fed back into the webs (Eq. 6), against the model as it stood;
4. Incremental-LDA learns the scene's active concepts (in memory);
5. everything the update changed is written in this transaction: scene row with
   its answer, tokens, reassigned tokens, n_kw entries, new words, random state;
   every ``checkpoint_interval``-th scene also takes a copy of the corpus, its checkpoint;
6. after the commit: the summary is published (by the model's writer, which also undoes
   step 4 if the write fails: app/registry.py ``ModelWriter``). The stream learns of the scene from
   the database, on every process (app/feed.py). A checkpoint is packed and stored by
   :func:`store_checkpoint`, outside the locks, on a write thread, before the answer is sent.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from functools import partial
from typing import NamedTuple

import numpy as np
from sqlalchemy.orm import Session, sessionmaker

from app.errors import (
    ContextwebError,
    InvalidInput,
    SceneNotFound,
    StoredDataDamaged,
    is_storage_failure,
    storage_failure_reason,
)
from app.metrics import ModelEvents
from app.registry import ModelRuntime, jsonable
from app.schemas.common import Page
from app.schemas.scenes import ObjectAnalysis, SceneCreate, SceneRead, SceneSummary
from app.services.idempotency import check_retry, request_digest
from app.services.limits import check_token_room, check_vocabulary_growth
from app.services.perception import (
    ObjectResult,
    Perception,
    SceneAnalysis,
    analyse_objects,
    in_context,
    perceive_objects,
    reported,
    scene_objects,
)
from core.context.incremental import SceneUpdate
from core.errors import InvalidInputError
from core.scene import SceneObject as CoreObject
from storage.compression import DamagedAnswerError, narrowest
from storage.database import combined, pipelined, write_turn
from storage.repositories import contexts as context_repository
from storage.repositories import feed as feed_repository
from storage.repositories import incremental_lda as lda_repository
from storage.repositories import scenes as scene_repository
from storage.repositories.incremental_lda import LockedModel, SceneChanges, StoredCheckpoint
from storage.unit_of_work import after_commit, unit_of_work

logger = logging.getLogger("contextweb")


class LearnedScene(NamedTuple):
    """What :func:`learn_scene` did: the answer (``SceneRead`` JSON), whether it was a stored one
    (an idempotent replay), and the checkpoint the scene took, for :func:`store_checkpoint`."""

    answer: str
    replayed: bool
    checkpoint: StoredCheckpoint | None = None


@dataclass(frozen=True)
class ReadScene:
    """A scene's body checked and made core's (:func:`read_scene`), waiting for :func:`prepare_scene`."""

    body: SceneCreate
    request_hash: bytes | None
    """SHA-256 digest of the body, for a keyed scene only (stored, for its retries to match)."""
    perception: Perception
    """The perception the objects were checked against."""
    objects: list[CoreObject] | None
    refusal: ContextwebError | InvalidInputError | None
    """The body's refusal (a 4xx), kept for :func:`learn_scene` to raise after the replay check."""


@dataclass(frozen=True)
class PreparedScene:
    """A scene analysed outside the model's lock (:func:`prepare_scene`), waiting for :func:`learn_scene`."""

    body: SceneCreate
    request_hash: bytes | None
    """SHA-256 digest of the body, for a keyed scene only (stored, for its retries to match)."""
    perception: Perception
    """The perception the analysis used (compared by identity: a fit replaces it whole)."""
    analysis: SceneAnalysis | None
    refusal: ContextwebError | InvalidInputError | None
    """The analysis's refusal of the body (a 4xx), raised by :func:`learn_scene` after the replay check."""
    contextual: SceneAnalysis | None = None
    """``analysis`` with Eq. 6's feedback, against the model in memory at ``contextual_of``, or None."""
    contextual_of: tuple[object, int] | None = None
    """The Incremental-LDA object and the version of the memory ``contextual`` was computed on."""

    def analysis_for(self, model: ModelRuntime) -> SceneAnalysis:
        """The analysis against the model's perception now (redone if a fit replaced it)."""
        if self.perception is not model.perception:
            return analyse_objects(model.perception, self.body.objects, model.id)
        if self.refusal is not None:
            raise self.refusal
        assert self.analysis is not None
        return self.analysis

    def in_context_for(self, model: ModelRuntime, analysis: SceneAnalysis) -> SceneAnalysis:
        """``analysis`` with Eq. 6's feedback against the model as it stands (under its lock): the
        one computed by :func:`prepare_scene` if memory has not changed since, else computed now."""
        if analysis is self.analysis and self.contextual_of == (model.incremental_lda, model.writer.version):
            assert self.contextual is not None
            return self.contextual
        return in_context(model.perception, model.incremental_lda, analysis, sigma=model.sigma, seed=model.seed)


def read_scene(model: ModelRuntime, body: SceneCreate, idempotency_key: str | None) -> ReadScene:
    """``body``'s hash if it is keyed, and its objects checked against the model's perception and made
    core's (a raw object's features extracted), without any lock. A refusal is kept, not raised:
    a retried scene's stored answer (Idempotency-Key) wins over it, as when the analysis ran under the lock."""
    perception = model.perception
    request_hash = request_digest(idempotency_key, body)
    try:
        objects = scene_objects(perception, body.objects, model.id)
    except (ContextwebError, InvalidInputError) as refusal:
        return ReadScene(body, request_hash, perception, None, refusal)
    return ReadScene(body, request_hash, perception, objects, None)


def prepare_scene(model: ModelRuntime, read: ReadScene) -> PreparedScene:
    """Perception and concept webs of the scene :func:`read_scene` read, without the model's lock: changes
    nothing, so that one heavy scene never holds the lock that the model's other requests wait for.
    A refusal is kept, not raised (:func:`read_scene`).

    Then, if the model's lock is free, Eq. 6's feedback against memory as it stands, before the
    database's write lock: on SQLite that lock is the whole database's (other processes' writes
    wait for it; on SQLite this process's other scenes wait for its scene thread anyway), and the feedback was two
    fifths of a scene's GIL time under the locks (py-spy, PostgreSQL; docs/benchmarks.md). :meth:`PreparedScene.in_context_for`
    uses it only if memory is still at the same version when the write holds both locks (no write
    of this process, catch-up or reload came between), so the answer is the one computed under
    the lock; when the lock is taken, a write of the model is under way and the feedback waits."""
    body, request_hash, perception = read.body, read.request_hash, read.perception
    if read.refusal is not None:
        return PreparedScene(body, request_hash, perception, None, read.refusal)
    assert read.objects is not None
    try:
        analysis = perceive_objects(perception, read.objects)
    except (ContextwebError, InvalidInputError) as refusal:
        return PreparedScene(body, request_hash, perception, None, refusal)
    if not model.lock.acquire(blocking=False):  # a write of the model is under way: it will change memory
        return PreparedScene(body, request_hash, perception, analysis, None)
    try:
        if model.perception is not perception:
            return PreparedScene(body, request_hash, perception, analysis, None)
        contextual = in_context(perception, model.incremental_lda, analysis, sigma=model.sigma, seed=model.seed)
        contextual_of = (model.incremental_lda, model.writer.version)
    finally:
        model.lock.release()
    return PreparedScene(body, request_hash, perception, analysis, None, contextual, contextual_of)


def learn_scene(
    session: Session,
    model: ModelRuntime,
    version: int,
    prepared: PreparedScene,
    idempotency_key: str | None,
    locked: LockedModel,
    metrics: ModelEvents | None = None,
) -> LearnedScene:
    """Learn the prepared scene online as the model's write ``version``; returns the answer (the
    ``SceneRead`` JSON, stored byte for byte), whether it is a stored one (idempotent replay), and
    the checkpoint to store after the commit (:func:`store_checkpoint`) if the scene is one.
    ``locked``: what the write read with the model's lock (``ModelWrite.locked``): the labels of
    its contexts, and the scene stored under ``idempotency_key`` if the lock's read looked that key up.
    A learned scene stores ``version`` in its state row, sends the change notification and
    commits in one round trip with its rows (the caller must run nothing after it in the
    session); ``metrics`` count the online update once it is committed."""
    body, request_hash = prepared.body, prepared.request_hash
    if idempotency_key is not None:
        if locked.idempotency_key == idempotency_key:
            stored = locked.stored_under_key
        else:  # a write of several keyed scenes (bench_restart): looked up here, a round trip of its own
            stored = scene_repository.find_by_idempotency_key(session, model.id, idempotency_key)
        if stored is not None:
            check_retry(idempotency_key, stored.request_hash, request_hash)
            try:
                return LearnedScene(stored.answer, True)
            except DamagedAnswerError as error:
                raise _damaged_answer(model, stored.scene_id, error, keyed=True) from error
    analysis = prepared.analysis_for(model)
    words = _scene_words(analysis)
    check_vocabulary_growth(model, words)
    check_token_room(model, words)
    analysis = prepared.in_context_for(model, analysis)
    first_token = model.incremental_lda.lda_state.n_tokens
    started = time.perf_counter()
    update = model.writer.learn_scene(words, partial(_kind, model, body))  # memory holds it until the commit
    update_seconds = time.perf_counter() - started
    assert locked.labels is not None  # ModelWriter.transaction gives every write the labels at its version
    answer = _answer(model, update, analysis, datetime.now(UTC), locked.labels)
    answer_json = answer.model_dump_json()
    checkpoint = _save(session, model, update, first_token, version, answer, answer_json, idempotency_key, request_hash)
    if metrics is not None:
        after_commit(session, partial(metrics.scene_learned, model.id, update_seconds, update.growth_checked))
    return LearnedScene(answer_json, False, checkpoint)


def infer_scene(model: ModelRuntime, body: SceneCreate, session: Session | None = None) -> SceneRead:
    """The same analysis as :func:`learn_scene`, changing nothing (fold-in against the current counts);
    with a ``session``, the map context's label too."""
    analysis = analyse_objects(model.perception, body.objects, model.id)
    words = _scene_words(analysis)
    with model.lock:
        analysis = in_context(model.perception, model.incremental_lda, analysis, sigma=model.sigma, seed=model.seed)
        posterior = model.incremental_lda.infer_scene(words, seed=model.seed)
    context_count = int(posterior.shape[0])
    map_context = int(np.argmax(posterior))
    return SceneRead(
        model_id=model.id,
        scene_id=None,
        learned=False,
        context_count=context_count,
        previous_context_count=context_count,
        context_posterior=reported(posterior),
        map_context=map_context,
        map_context_label=None if session is None else context_repository.context_label(session, model.id, map_context),
        objects=[_object_analysis(result) for result in analysis.objects],
    )


def get_scene(session: Session, model: ModelRuntime, scene_id: int) -> str:
    """The ``SceneRead`` JSON the scene was acknowledged with."""
    try:
        row = scene_repository.get_scene(session, model.id, scene_id)
        if row is None:
            raise SceneNotFound(model.id, scene_id)
        return row.answer
    except DamagedAnswerError as error:
        raise _damaged_answer(model, scene_id, error) from error


def _damaged_answer(
    model: ModelRuntime, scene_id: int, error: DamagedAnswerError, *, keyed: bool = False
) -> StoredDataDamaged:
    """The 500 of a stored answer that cannot be read back (logged: an operator must know)."""
    stored = " (the scene was stored and learned under this Idempotency-Key)" if keyed else ""
    logger.error("model %s: scene %d's stored answer is damaged: %s", model.id, scene_id, error)
    return StoredDataDamaged(
        f"scene {scene_id} of model {model.id!r}: its stored answer cannot be read ({error}){stored}; "
        f"`contextweb models check {model.id}` reports the damaged answers"
    )


def scene_history(session: Session, model: ModelRuntime, *, offset: int, limit: int) -> Page[SceneSummary]:
    rows, total = scene_repository.page_scenes(session, model.id, offset=offset, limit=limit)
    return Page[SceneSummary](
        items=[SceneSummary.model_validate(row) for row in rows], total=total, offset=offset, limit=limit
    )


def _scene_words(analysis: SceneAnalysis) -> list[str]:
    words = analysis.words
    if not words:
        raise InvalidInput("objects", "no object of the scene has an active concept: the scene would be empty")
    return words


def _kind(model: ModelRuntime, body: SceneCreate, name: str) -> str | None:
    """The kind of a new word: the vocabulary's, else the one the scene gave in ``kinds``."""
    known = model.kind_of(name)
    if known is not None:
        return known
    return next((obj.kinds[name] for obj in body.objects if name in obj.kinds), None)


def _object_analysis(result: ObjectResult) -> ObjectAnalysis:
    return ObjectAnalysis(
        level=result.level,
        active_concepts=result.active_concepts,
        perception=result.perception,
        web=result.web,
        in_context=result.in_context,
    )


def _checkpoint(model: ModelRuntime, version: int) -> StoredCheckpoint:
    """The model's corpus as it stands after the write ``version`` (its checkpoint): copies, in
    their narrowest types (0.1 s at a million scenes), that the model's later scenes cannot change
    while :func:`store_checkpoint` packs and stores them outside the locks."""
    state = model.incremental_lda.lda_state
    return StoredCheckpoint(
        version=version,
        context_count=state.n_contexts,
        word_count=state.vocab_size,
        words=narrowest(state.words),
        contexts=narrowest(state.assignments),
        doc_offsets=state.doc_offsets.copy(),
    )


def store_checkpoint(write_sessions: sessionmaker[Session], model_id: str, checkpoint: StoredCheckpoint) -> None:
    """Store a checkpoint taken by a learned scene (:class:`LearnedScene`), after that scene's
    commit and outside the model's lock: packing it takes seconds at a million scenes, which held
    the model's writes (on SQLite every model's) when it ran in the scene's transaction. The
    transaction takes the database's write lock only for the row's statements.

    The scene is stored and acknowledged whatever happens here: a checkpoint that cannot be
    stored is logged and left to the next interval (a start then replays the batches since the
    previous checkpoint, which compaction keeps until a newer checkpoint is stored)."""
    started = time.perf_counter()
    try:
        packed = lda_repository.pack_checkpoint(checkpoint)
        with write_turn(write_sessions), unit_of_work(write_sessions) as session:
            lda_repository.save_checkpoint(session, model_id, packed, compact=True)
    except Exception as error:  # noqa: BLE001 - the acknowledged scene stands; the next checkpoint retries
        logger.warning(
            "model %s: the checkpoint at version %d was not stored (%s); a start replays the batches since the "
            "previous one until the next checkpoint",
            model_id,
            checkpoint.version,
            storage_failure_reason(error) if is_storage_failure(error) else f"{type(error).__name__}: {error}",
        )
        return
    logger.info(
        "model %s: checkpoint at version %d stored (%d scenes, %.1f MB) in %.2f s",
        model_id,
        checkpoint.version,
        checkpoint.scene_count,
        len(packed.arrays) / 1e6,
        time.perf_counter() - started,
    )


def _answer(
    model: ModelRuntime,
    update: SceneUpdate,
    analysis: SceneAnalysis,
    created_at: datetime,
    labels: Mapping[int, str],
) -> SceneRead:
    """The scene's answer, built without validation: every value is already of its field's
    type (Python ints, floats and strs; what validating them cost: docs/benchmarks.md).
    ``labels``: the model's contexts' labels."""
    posterior = update.context_posterior
    map_context = int(np.argmax(posterior))
    return SceneRead.model_construct(
        model_id=model.id,
        scene_id=int(update.scene_index),
        learned=True,
        context_count=int(update.contexts_after),
        previous_context_count=int(update.contexts_before),
        context_posterior=reported(posterior),
        map_context=map_context,
        map_context_label=labels.get(map_context),
        objects=[
            ObjectAnalysis.model_construct(
                level=result.level,
                active_concepts=result.active_concepts,
                perception=result.perception,
                web=result.web,
                in_context=result.in_context,
            )
            for result in analysis.objects
        ],
        created_at=created_at,
    )


def _save(
    session: Session,
    model: ModelRuntime,
    update: SceneUpdate,
    first_token: int,
    version: int,
    answer: SceneRead,
    answer_json: str,
    idempotency_key: str | None,
    request_hash: bytes | None,
) -> StoredCheckpoint | None:
    """The scene's rows, in one round trip with its commit; every ``checkpoint_interval``-th scene
    also returns the model's checkpoint at ``version``, which :func:`store_checkpoint` stores after
    the commit."""
    first_word = len(model.word_kinds) - len(update.vocabulary_additions)
    # PostgreSQL: the scene's statements in one round trip, with its notification and the commit;
    # its rows and the notification as one statement (they touch different rows: ``combined``).
    with pipelined(session, commit=True), combined(session):
        _save_rows(
            session,
            model,
            update,
            first_token,
            first_word,
            version,
            answer,
            answer_json,
            idempotency_key,
            request_hash,
        )
        feed_repository.notify_change(session, model.id)
    if (update.scene_index + 1) % model.checkpoint_interval == 0:
        return _checkpoint(model, version)
    return None


def _save_rows(
    session: Session,
    model: ModelRuntime,
    update: SceneUpdate,
    first_token: int,
    first_word: int,
    version: int,
    answer: SceneRead,
    answer_json: str,
    idempotency_key: str | None,
    request_hash: bytes | None,
) -> None:
    lda_repository.save_scene(
        session,
        model.id,
        SceneChanges(
            scene_id=update.scene_index,
            first_token=first_token,
            token_words=update.word_ids,
            token_contexts=update.assignments,
            moved_tokens=update.reassigned_tokens,
            moved_contexts=update.reassigned_contexts,
            counts=[tuple(row) for row in update.changed_counts.tolist()],
            new_words=[
                (first_word + i, name, model.word_kinds[first_word + i])
                for i, name in enumerate(update.vocabulary_additions)
            ],
            context_count=update.contexts_after,
            state={"rng_state": jsonable(update.rng_state)},
            version=version,
        ),
    )
    scene_repository.add_scene(
        session,
        model.id,
        update.scene_index,
        idempotency_key=idempotency_key,
        request_hash=request_hash,
        context_count=answer.context_count,
        map_context=answer.map_context,
        context_posterior=answer.context_posterior,
        answer=answer_json,
        created_at=answer.created_at,
    )
