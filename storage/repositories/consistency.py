"""Check a model's stored Incremental-LDA state against its invariants, and rebuild what is derived.

The truth of a model is its ``scene`` rows, its tokens (word and context
assignment of every word occurrence), its ``word`` rows and the random state in
``incremental_lda_state.state``. The tokens are stored as the model's checkpoint
(``incremental_lda_checkpoint``) with the ``token_batch`` rows above its version
applied in order; while no batch was deleted by a checkpoint
(``compacted_version`` 0) the batches alone hold every token, and the checkpoint
is derived from them (it must equal their replay up to its version). What is
derived can be rebuilt: ``context_word_count`` (n_kw, the token counts grouped
by context and word), ``incremental_lda_state.scene_count`` and
``context_count``, and, while every batch is kept, the checkpoint.
:func:`check_model` names every broken invariant; :func:`repair_model` rebuilds
the derived rows and bumps the model's version, so that serving processes
reload it. A problem in the truth itself (a gap in the token ids, a scene
without tokens, a missing state row, a bad random state, a damaged checkpoint
whose batches were deleted …) cannot be repaired from the rows: then
:func:`repair_model` changes nothing and raises :class:`UnrepairableModelError`.

The tokens are read once (checkpoint and batches) and checked as arrays; the
other checks are aggregate queries.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from sqlalchemy import (
    ColumnElement,
    Row,
    delete,
    func,
    select,
    text,
    update,
)
from sqlalchemy.orm import Session

from storage.compression import DamagedAnswerError, decompress_answer
from storage.database import DriverStatements
from storage.models import (
    ContextWordCount,
    IncrementalLdaCheckpoint,
    IncrementalLdaState,
    Model,
    Scene,
    TokenBatch,
    Word,
    utc_now,
)
from storage.repositories import models as model_repository
from storage.repositories import rowcount
from storage.repositories.feed import scenes_after
from storage.repositories.incremental_lda import (
    DamagedBatchError,
    DamagedCheckpointError,
    StoredAssignments,
    StoredCheckpoint,
    compacted_version,
    load_assignments,
    load_batches,
    load_checkpoint,
    replay_batches,
    save_checkpoint,
    token_counts,
    unpack_batch,
)

#: A row of any width, read by column name (``row.total``).
AnyRow = Row[*tuple[Any, ...]]


@dataclass(frozen=True)
class Problem:
    """One broken invariant: a short sentence naming the table and the numbers."""

    message: str
    repairable: bool
    """True when :func:`repair_model` fixes it (it concerns only the derived rows)."""


class UnrepairableModelError(Exception):
    """The model's scenes, tokens, words or random state are damaged: nothing was changed."""

    def __init__(self, model_id: str, problems: Sequence[str]) -> None:
        super().__init__(f"model {model_id!r} cannot be repaired from its rows: " + "; ".join(problems))
        self.model_id = model_id
        self.problems = list(problems)


def check_model(session: Session, model_id: str) -> list[str]:
    """Every problem of the stored model, one sentence each; empty when the model is sound."""
    return [problem.message for problem in find_problems(session, model_id)]


def find_problems(session: Session, model_id: str) -> list[Problem]:
    """Every problem of the stored model, each marked repairable or not."""
    return _find_problems(session, model_id).problems


class _Found(NamedTuple):
    """What :func:`_find_problems` read: every problem, those of the kept batches
    (:func:`_kept_batch_problems`), and the tokens (None when they cannot be read), so that
    :func:`repair_model` reads neither again."""

    problems: list[Problem]
    kept_batch_problems: list[Problem]
    tokens: StoredAssignments | None


def _find_problems(session: Session, model_id: str) -> _Found:
    if not model_repository.is_live(session, model_id):
        return _Found([Problem(f"model {model_id!r} is not stored", repairable=False)], [], None)
    hyperparameters, problems = _model_json(session, model_id)
    state = _state_row(session, model_id)
    words = _id_range(session, Word.id, Word.model_id, model_id)
    scenes = _id_range(session, Scene.id, Scene.model_id, model_id)
    tokens, token_problems = _read_tokens(session, model_id)
    kept_batch_problems = _kept_batch_problems(session, model_id)
    problems = [
        *problems,
        *_dense_id_problems("word", "words", words),
        *_dense_id_problems("scene", "scenes", scenes),
        *token_problems,
        *kept_batch_problems,
        *_answer_problems(session, model_id),
    ]
    if tokens is not None:
        problems += _token_problems(session, model_id, tokens, words.count)
        problems += _count_problems(session, model_id, tokens)
    if state is None:
        problems.append(Problem("incremental_lda_state has no row for the model", repairable=False))
    else:
        k_rule = hyperparameters.get("k_rule") if isinstance(hyperparameters, dict) else None
        max_contexts = k_rule.get("max_contexts") if isinstance(k_rule, dict) else None
        problems += _state_problems(session, model_id, state, scenes.count, words.count, max_contexts, tokens)
    return _Found(problems, kept_batch_problems, tokens)


def _model_json(session: Session, model_id: str) -> tuple[Any, list[Problem]]:
    """The model row's hyperparameters, and a problem for each of its JSON columns that cannot be
    decoded (a damaged row: SQLite stores JSON as text). Not repairable: they are what was asked."""
    problems, hyperparameters = [], None
    for column in (Model.hyperparameters, Model.vocabulary):
        try:
            value = session.execute(select(column).where(Model.id == model_id)).scalar_one()
        except ValueError as error:  # json.JSONDecodeError, or a type's own refusal
            problems.append(Problem(f"model.{column.key} cannot be read: {error}", repairable=False))
            continue
        if not isinstance(value, dict):
            problems.append(Problem(f"model.{column.key} is not a JSON object", repairable=False))
        elif column is Model.hyperparameters:
            hyperparameters = value
    return hyperparameters, problems


#: Stored answers decoded at a time by :func:`_answer_problems`.
ANSWERS_PER_READ = 2_000


def _answer_problems(session: Session, model_id: str) -> list[Problem]:
    """Every stored answer must decompress (``storage.compression.decompress_answer``): they are what
    the scenes were acknowledged with, so a damaged one is not repairable (a replay of its key, a
    ``GET`` of the scene and its stream event cannot be answered). Read in pages of
    :data:`ANSWERS_PER_READ` by scene id, so that a model of a million scenes is never in memory."""
    damaged: list[int] = []
    first_error = ""
    after = -1
    while True:
        rows = scenes_after(session, model_id, after, ANSWERS_PER_READ)
        for scene_id, stored in rows:
            try:
                decompress_answer(stored)
            except DamagedAnswerError as error:
                damaged.append(scene_id)
                first_error = first_error or str(error)
        if len(rows) < ANSWERS_PER_READ:
            break
        after = rows[-1][0]
    if not damaged:
        return []
    return [
        Problem(
            f"scene: {_count(len(damaged), 'stored answer')} cannot be read, first scene {damaged[0]} ({first_error}); "
            "they are what the scenes were acknowledged with",
            repairable=False,
        )
    ]


def _kept_batch_problems(session: Session, model_id: str) -> list[Problem]:
    """The batches a compacting checkpoint kept at or below its version (for a process up to one
    interval behind to catch up from) must be readable and continue one another. They are not the
    truth (the checkpoint holds their tokens), so repairing deletes them (:func:`_drop_kept_batches`)
    and a process that far behind reloads instead."""
    compacted = compacted_version(session, model_id)
    if compacted == 0:
        return []
    try:
        checkpoint = load_checkpoint(session, model_id)
    except DamagedCheckpointError:
        return []  # named by _read_tokens
    if checkpoint is None:
        return []
    rows = DriverStatements(session).fetchall(_SELECT_KEPT_BATCHES, (model_id, compacted, checkpoint.version))
    next_token: int | None = None
    for version, scene_id, first_token, token_count, blob in rows:
        try:
            unpack_batch(int(version), scene_id, int(first_token), int(token_count), bytes(blob))
        except DamagedBatchError as error:
            return [Problem(f"{error} (a batch the checkpoint covers, kept for catching up)", repairable=True)]
        if int(token_count) == 0:
            continue
        if next_token is not None and int(first_token) != next_token:
            return [
                Problem(
                    f"token ids have a gap among the batches the checkpoint covers: token_batch at version "
                    f"{int(version)} starts at token {int(first_token)}, the batch before it ends at {next_token}",
                    repairable=True,
                )
            ]
        next_token = int(first_token) + int(token_count)
    if next_token is not None and next_token != checkpoint.token_count:
        return [
            Problem(
                f"the batches the checkpoint covers end at token {next_token}, the checkpoint (version "
                f"{checkpoint.version}) at {checkpoint.token_count}",
                repairable=True,
            )
        ]
    return []


_SELECT_KEPT_BATCHES = (
    "SELECT version, scene_id, first_token, token_count, packed FROM token_batch "
    "WHERE model_id = ? AND version > ? AND version <= ? ORDER BY version"
)


def _drop_kept_batches(session: Session, model_id: str) -> list[str]:
    """Delete the batches the checkpoint covers and mark them compacted (a process behind them reloads)."""
    checkpoint_version = session.scalar(
        select(IncrementalLdaCheckpoint.version).where(IncrementalLdaCheckpoint.model_id == model_id)
    )
    assert checkpoint_version is not None  # kept batches exist only beside a compacting checkpoint
    deleted = rowcount(
        session.execute(
            delete(TokenBatch).where(TokenBatch.model_id == model_id, TokenBatch.version <= checkpoint_version)
        )
    )
    session.execute(
        update(IncrementalLdaCheckpoint)
        .where(IncrementalLdaCheckpoint.model_id == model_id)
        .values(compacted_version=checkpoint_version)
    )
    return [f"token_batch: deleted the {_count(deleted, 'batch')} the checkpoint (version {checkpoint_version}) covers"]


def repair_model(session: Session, model_id: str) -> list[str]:
    """Rebuild the model's derived rows from its scenes and tokens, in the caller's transaction.

    Sets ``scene_count`` to the number of scene rows and ``context_count`` to at
    least the largest token context + 1, rewrites ``context_word_count`` from the
    tokens (entries no token backs any more stay as 0, rows naming a context or
    word that does not exist are deleted), rebuilds the checkpoint from the tokens
    (when the model has one) and bumps the model's version above every stored row's:
    every count row carries the new version, so a process that catches up on the
    rows written since its version reads all of n_kw again. Returns what changed,
    one sentence each; an empty list when the model was sound (then nothing is
    written). Raises :class:`LookupError` for an unknown model and
    :class:`UnrepairableModelError`, before writing anything, when the truth itself
    is damaged.
    """
    if not model_repository.is_live(session, model_id):
        raise LookupError(f"model {model_id!r} is not stored")
    state = _state_row(session, model_id, lock=True)  # the model's writers lock it too (PostgreSQL)
    problems, kept_batch_problems, tokens = _find_problems(session, model_id)
    unrepairable = [problem.message for problem in problems if not problem.repairable]
    if unrepairable:
        raise UnrepairableModelError(model_id, unrepairable)
    if not problems:
        return []
    assert state is not None  # a missing state row is unrepairable
    assert tokens is not None  # unreadable tokens are unrepairable (dropping covered batches leaves them as read)
    changes = _drop_kept_batches(session, model_id) if kept_batch_problems else []
    largest_batch = session.scalar(select(func.max(TokenBatch.version)).where(TokenBatch.model_id == model_id))
    new_version = max(state.version, largest_batch or 0) + 1
    scene_count = _id_range(session, Scene.id, Scene.model_id, model_id).count
    largest_context = int(tokens.contexts.max()) if tokens.contexts.size else 0
    context_count = max(state.context_count, largest_context + 1, 1)
    word_count = _id_range(session, Word.id, Word.model_id, model_id).count
    changes += _rewrite_counts(session, model_id, tokens, new_version, context_count, word_count)
    session.execute(
        update(IncrementalLdaState)
        .where(IncrementalLdaState.model_id == model_id)
        .values(scene_count=scene_count, context_count=context_count, version=new_version, updated_at=utc_now())
    )
    if scene_count != state.scene_count:
        changes.append(f"incremental_lda_state.scene_count: {state.scene_count} -> {scene_count}")
    if context_count != state.context_count:
        changes.append(f"incremental_lda_state.context_count: {state.context_count} -> {context_count}")
    if _has_checkpoint(session, model_id):
        save_checkpoint(
            session, model_id, _checkpoint_of_tokens(tokens, new_version, scene_count, context_count, word_count)
        )
        changes.append(f"incremental_lda_checkpoint: rebuilt from the tokens at version {new_version}")
    changes.append(f"incremental_lda_state.version: {state.version} -> {new_version}")
    return changes


# The state row.


def _state_row(session: Session, model_id: str, *, lock: bool = False) -> AnyRow | None:
    statement = select(
        IncrementalLdaState.scene_count,
        IncrementalLdaState.context_count,
        IncrementalLdaState.state,
        IncrementalLdaState.version,
    ).where(IncrementalLdaState.model_id == model_id)
    return session.execute(statement.with_for_update() if lock else statement).first()


def _state_problems(
    session: Session,
    model_id: str,
    state: AnyRow,
    scene_count: int,
    word_count: int,
    max_contexts: Any,
    tokens: StoredAssignments | None,
) -> list[Problem]:
    problems = []
    rng_problem = _rng_state_problem(state.state)
    if rng_problem:
        problems.append(Problem(f"incremental_lda_state.state: {rng_problem}", repairable=False))
    if state.scene_count != scene_count:
        problems.append(
            Problem(
                f"incremental_lda_state.scene_count is {state.scene_count} but {scene_count} scene rows are stored",
                repairable=True,
            )
        )
    if state.context_count < 1:
        problems.append(
            Problem(f"incremental_lda_state.context_count is {state.context_count}, not at least 1", repairable=True)
        )
    if isinstance(max_contexts, int) and state.context_count > max_contexts:
        problems.append(
            Problem(
                f"incremental_lda_state.context_count is {state.context_count}, above the model's "
                f"max_contexts {max_contexts}",
                repairable=False,
            )
        )
    if tokens is not None:
        problems += _context_range_problems(tokens, state.context_count, max_contexts)
    problems += _count_range_problems(session, model_id, state.context_count, word_count)
    problems += _version_problems(session, model_id, state.version)
    problems += _checkpoint_problems(session, model_id, state.version)
    return problems


def _rng_state_problem(state: Any) -> str | None:
    if not isinstance(state, dict) or "rng_state" not in state:
        return "has no rng_state"
    try:
        np.random.PCG64().state = state["rng_state"]
    except (TypeError, ValueError, KeyError, OverflowError) as error:
        return f"rng_state is not a PCG64 generator state ({type(error).__name__}: {error})"
    return None


# The tokens: the checkpoint and the batches.


def _read_tokens(session: Session, model_id: str) -> tuple[StoredAssignments | None, list[Problem]]:
    """The model's tokens (None when they cannot be read) and the problems of reading them.

    While no batch was compacted the batches alone are the truth (the checkpoint is derived
    from them and checked against them by :func:`_checkpoint_problems`); afterwards the truth
    is the checkpoint with the batches above its version."""
    try:
        if compacted_version(session, model_id) == 0:
            return _tokens_of_batches(session, model_id), []
        return load_assignments(session, model_id), []
    except DamagedCheckpointError as error:
        return None, [
            Problem(
                f"{error}; the token batches up to version {compacted_version(session, model_id)} were folded "
                "into it, so the tokens cannot be rebuilt",
                repairable=False,
            )
        ]
    except DamagedBatchError as error:
        return None, [Problem(str(error), repairable=False)]


def _tokens_of_batches(session: Session, model_id: str, *, up_to: int | None = None) -> StoredAssignments:
    """Every token from the model's batches alone (all of them, or those at or below ``up_to``)."""
    batches = load_batches(session, model_id, since_version=0)
    if up_to is not None:
        batches = [batch for batch in batches if batch.version <= up_to]
    added = replay_batches(batches, 0).added
    return StoredAssignments(words=added[:, 1], contexts=added[:, 2], scenes=added[:, 0])


def _checkpoint_problems(session: Session, model_id: str, version: int) -> list[Problem]:
    """While every batch is kept, the checkpoint must equal their replay up to its version."""
    compacted = compacted_version(session, model_id)
    try:
        checkpoint = load_checkpoint(session, model_id)
    except DamagedCheckpointError as error:
        return [Problem(str(error), repairable=True)] if compacted == 0 else []  # else named by _read_tokens
    if checkpoint is None:
        return []
    if checkpoint.version > version:
        return [
            Problem(
                f"incremental_lda_checkpoint is at version {checkpoint.version}, above the model's "
                f"(incremental_lda_state.version {version})",
                repairable=compacted == 0,
            )
        ]
    if compacted != 0:
        return []
    try:
        truth = _tokens_of_batches(session, model_id, up_to=checkpoint.version)
    except DamagedBatchError:
        return []  # named by _read_tokens
    if truth.words.shape[0] != checkpoint.token_count:
        return [
            Problem(
                f"incremental_lda_checkpoint (version {checkpoint.version}) covers {checkpoint.token_count} tokens, "
                f"but the token batches up to its version add {truth.words.shape[0]}",
                repairable=True,
            )
        ]
    scenes = np.repeat(np.arange(checkpoint.scene_count), np.diff(checkpoint.doc_offsets))
    problems = []
    for what, stored, saved in (
        ("scene", truth.scenes, scenes),
        ("word", truth.words, checkpoint.words),
        ("context", truth.contexts, checkpoint.contexts),
    ):
        differs = stored != saved
        if differs.any():
            first = int(np.flatnonzero(differs)[0])
            problems.append(
                Problem(
                    f"incremental_lda_checkpoint (version {checkpoint.version}) differs from the token batches in "
                    f"the {what} of {_count(int(differs.sum()), 'token')}, first token {first} "
                    f"(checkpoint {int(saved[first])}, token batches {int(stored[first])})",
                    repairable=True,
                )
            )
    return problems


def _has_checkpoint(session: Session, model_id: str) -> bool:
    return (
        session.execute(
            select(IncrementalLdaCheckpoint.model_id).where(IncrementalLdaCheckpoint.model_id == model_id)
        ).first()
        is not None
    )


def _checkpoint_of_tokens(
    tokens: StoredAssignments, version: int, scene_count: int, context_count: int, word_count: int
) -> StoredCheckpoint:
    """The checkpoint of the model's tokens as they stand (the truth), at ``version``."""
    lengths = np.bincount(tokens.scenes, minlength=scene_count)
    return StoredCheckpoint(
        version=version,
        context_count=context_count,
        word_count=word_count,
        words=tokens.words.astype(np.int32),
        contexts=tokens.contexts.astype(np.int32),
        doc_offsets=np.concatenate([[0], np.cumsum(lengths)]).astype(np.int32),
    )


# Dense ids.


@dataclass(frozen=True)
class _IdRange:
    count: int
    first: int | None
    last: int | None


def _id_range(session: Session, id_column: Any, model_column: Any, model_id: str) -> _IdRange:
    count, first, last = session.execute(
        select(func.count(), func.min(id_column), func.max(id_column)).where(model_column == model_id)
    ).one()
    return _IdRange(int(count), first, last)


def _dense_id_problems(table: str, plural: str, ids: _IdRange) -> list[Problem]:
    if ids.count == 0 or (ids.first == 0 and ids.last == ids.count - 1):
        return []
    stored = f"{ids.count} {plural} stored, ids {ids.first}..{ids.last}"
    if ids.first != 0:
        return [Problem(f"{table} ids do not start at 0: {stored}", repairable=False)]
    return [Problem(f"{table} ids have gaps: {stored}", repairable=False)]


def _first_and_total(
    session: Session, columns: Sequence[Any], *conditions: Any, order_by: Sequence[Any]
) -> AnyRow | None:
    """The first row meeting ``conditions`` (in ``order_by``) with the number of such rows as its ``total``."""
    statement = select(*columns, func.count().over().label("total")).where(*conditions).order_by(*order_by).limit(1)
    return session.execute(statement).first()


# Tokens and scenes.


def _first_of(flags: np.ndarray) -> tuple[int, int] | None:
    """(first index, how many) of the set flags, None when none is set."""
    where = np.flatnonzero(flags)
    return None if where.size == 0 else (int(where[0]), int(where.size))


def _token_problems(session: Session, model_id: str, tokens: StoredAssignments, word_count: int) -> list[Problem]:
    problems = []
    bad_word = _first_of(tokens.words >= word_count)
    if bad_word:
        first, total = bad_word
        problems.append(
            Problem(
                f"{_tokens(total)} a word id outside the {word_count} stored words, "
                f"first token {first} (word {int(tokens.words[first])})",
                repairable=False,
            )
        )
    scene_ids = np.array(session.execute(select(Scene.id).where(Scene.model_id == model_id)).scalars().all())
    orphan = _first_of(~np.isin(tokens.scenes, scene_ids))
    if orphan:
        first, total = orphan
        problems.append(
            Problem(
                f"{_tokens(total)} a scene id with no scene row, first token {first} "
                f"(scene {int(tokens.scenes[first])})",
                repairable=False,
            )
        )
    backwards = _first_of(np.diff(tokens.scenes) < 0)
    if backwards:
        first, total = backwards
        problems.append(
            Problem(
                f"token scene ids decrease at {_count(total, 'token')}, first token {first + 1} "
                f"(scene {int(tokens.scenes[first + 1])} after scene {int(tokens.scenes[first])})",
                repairable=False,
            )
        )
    empty = np.setdiff1d(scene_ids, tokens.scenes)
    if empty.size:
        problems.append(
            Problem(
                f"{_count(int(empty.size), 'scene')} without tokens, first scene {int(empty.min())}", repairable=False
            )
        )
    return problems


def _context_range_problems(tokens: StoredAssignments, context_count: int, max_contexts: Any) -> list[Problem]:
    beyond = _first_of(tokens.contexts >= context_count)
    if beyond is None:
        return []
    first, total = beyond
    largest = int(tokens.contexts.max())
    fits = not isinstance(max_contexts, int) or largest < max_contexts
    limit = "" if fits else f"; the largest, {largest}, is beyond the model's max_contexts {max_contexts}"
    return [
        Problem(
            f"{_tokens(total)} a context at or above incremental_lda_state.context_count {context_count}, "
            f"first token {first} (context {int(tokens.contexts[first])}){limit}",
            repairable=fits,
        )
    ]


def _tokens(total: int) -> str:
    return "1 token has" if total == 1 else f"{total} tokens have"


def _count(total: int, noun: str) -> str:
    """``1 entry``, ``2 entries``, ``3 tokens``."""
    if total == 1:
        return f"1 {noun}"
    if noun.endswith("y"):
        return f"{total} {noun[:-1]}ies"
    return f"{total} {noun}es" if noun.endswith(("ch", "s")) else f"{total} {noun}s"


# The n_kw entries.


def _count_differences(session: Session, model_id: str, tokens: StoredAssignments) -> list[tuple[int, int, int, int]]:
    """(context, word, stored, tokens) of every entry whose stored count differs from the tokens', in order."""
    stored = {
        (int(k), int(w)): int(n)
        for k, w, n in session.execute(
            select(ContextWordCount.context, ContextWordCount.word_id, ContextWordCount.count).where(
                ContextWordCount.model_id == model_id
            )
        ).all()
    }
    counted = token_counts(tokens)
    return [
        (k, w, stored.get((k, w), 0), counted.get((k, w), 0))
        for k, w in sorted(set(stored) | set(counted))
        if stored.get((k, w), 0) != counted.get((k, w), 0)
    ]


def _count_problems(session: Session, model_id: str, tokens: StoredAssignments) -> list[Problem]:
    differences = _count_differences(session, model_id, tokens)
    if not differences:
        return []
    context, word, stored, counted = differences[0]
    return [
        Problem(
            f"context_word_count differs from the token assignments at {_count(len(differences), 'entry')}, "
            f"first (context {context}, word {word}): stored {stored}, tokens {counted}",
            repairable=True,
        )
    ]


def _count_row_outside(context_count: int, word_count: int) -> ColumnElement[bool]:
    """An n_kw row naming a context or word the model does not have."""
    return (
        (ContextWordCount.context < 0)
        | (ContextWordCount.context >= context_count)
        | (ContextWordCount.word_id < 0)
        | (ContextWordCount.word_id >= word_count)
    )


def _count_range_problems(session: Session, model_id: str, context_count: int, word_count: int) -> list[Problem]:
    row = _first_and_total(
        session,
        (ContextWordCount.context, ContextWordCount.word_id),
        ContextWordCount.model_id == model_id,
        _count_row_outside(context_count, word_count),
        order_by=(ContextWordCount.context, ContextWordCount.word_id),
    )
    if row is None:
        return []
    rows = "1 context_word_count row names" if row.total == 1 else f"{row.total} context_word_count rows name"
    return [
        Problem(
            f"{rows} a context or word that does not exist ({context_count} contexts, {word_count} words), "
            f"first (context {row.context}, word {row.word_id})",
            repairable=True,
        )
    ]


def _version_problems(session: Session, model_id: str, version: int) -> list[Problem]:
    problems = []
    for table, key, model_column, version_column in (
        ("token_batch", (TokenBatch.version,), TokenBatch.model_id, TokenBatch.version),
        (
            "context_word_count",
            (ContextWordCount.context, ContextWordCount.word_id),
            ContextWordCount.model_id,
            ContextWordCount.version,
        ),
    ):
        row = _first_and_total(
            session, (*key, version_column), model_column == model_id, version_column > version, order_by=key
        )
        if row is not None:
            problems.append(
                Problem(
                    f"{_count(row.total, f'{table} row')} written at a version above the model's "
                    f"(incremental_lda_state.version {version}), first at version {row.version}",
                    repairable=True,
                )
            )
    return problems


# The repair.


def _rewrite_counts(
    session: Session, model_id: str, tokens: StoredAssignments, version: int, context_count: int, word_count: int
) -> list[str]:
    """Set the model's n_kw entries to the token counts, every row stamped ``version``; what changed."""
    changes = []
    differences = _count_differences(session, model_id, tokens)
    outside = _count_row_outside(context_count, word_count)
    deleted = rowcount(session.execute(delete(ContextWordCount).where(ContextWordCount.model_id == model_id, outside)))
    if deleted:
        changes.append(
            f"context_word_count: deleted {_count(deleted, 'row')} naming a context or word that does not exist "
            f"({context_count} contexts, {word_count} words)"
        )
    session.execute(
        update(ContextWordCount).where(ContextWordCount.model_id == model_id).values(count=0, version=version)
    )
    counted = token_counts(tokens)
    if counted:
        session.execute(
            _UPSERT_COUNT,
            [
                {"model_id": model_id, "context": k, "word_id": w, "count": n, "version": version}
                for (k, w), n in counted.items()
            ],
        )
    rewritten = f"context_word_count: rewrote {_count(len(counted), 'entry')} from the tokens (at the new version)"
    if not differences:
        rewritten += ", none of them changed"
    if differences:
        context, word, stored, assigned = differences[0]
        changes.append(
            f"{rewritten}; {_count(len(differences), 'entry')} differed, first (context {context}, "
            f"word {word}): stored {stored}, tokens {assigned}"
        )
    else:
        changes.append(rewritten)
    return changes


# Entries without tokens were set to 0 before. The same SQL on SQLite and PostgreSQL.
_UPSERT_COUNT = text(
    "INSERT INTO context_word_count (model_id, context, word_id, count, version) "
    "VALUES (:model_id, :context, :word_id, :count, :version) "
    "ON CONFLICT (model_id, context, word_id) DO UPDATE SET count = excluded.count, version = excluded.version"
)
