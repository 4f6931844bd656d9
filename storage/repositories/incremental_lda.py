"""The Incremental-LDA state of a model, written scene by scene and read back on start.

:func:`save_scene` writes everything one learned scene changed — one
``token_batch`` row (its tokens and the tokens its sweeps reassigned, packed),
the n_kw entries that moved, new words and the scalar state — in the caller's
transaction (the scene's own), straight through the driver (see the statements
below). :func:`save_checkpoint` replaces the model's checkpoint (every token's
word and context at one version, packed) and deletes the batches at or below the
previous checkpoint's version; :func:`load_start` reads what a start needs: the
checkpoint and only the batches written since it, so a start costs the same at
any corpus size; :func:`load_changes` what a process behind needs to catch up
(docs/scaling.md, "Checkpoints" and "Token batches"). :func:`replay_batches`
applies batches to a known token count, checking that they continue it.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from sqlalchemy import func, insert, select
from sqlalchemy.exc import DBAPIError
from sqlalchemy.orm import Session

from storage.compression import pack_arrays, pack_small_arrays, unpack_arrays, unpack_small_arrays
from storage.database import LOCK_NOT_AVAILABLE, DriverStatements, QueuedRows, pipelined
from storage.models import ContextWordCount, IncrementalLdaCheckpoint, IncrementalLdaState, TokenBatch, Word, utc_now
from storage.repositories.contexts import submit_context_labels
from storage.repositories.scenes import StoredAnswer, stored_answer, submit_find_by_idempotency_key


@dataclass(frozen=True)
class StoredChanges:
    """What the writes after one version changed in a model's stored corpus (a catch-up)."""

    version: int
    scene_count: int
    context_count: int
    state: dict[str, Any]
    new_words: list[tuple[str, str | None]]
    """Words with ids >= the caller's vocabulary size, in id order: (name, kind)."""
    tokens: ReplayedTokens
    """The tokens added since and the earlier ones reassigned since (their final contexts)."""
    count_entries: np.ndarray
    """(context, word, count) rows of the n_kw entries changed since (int64)."""


@dataclass(frozen=True)
class StoredCheckpoint:
    """Every token's word and context at one version of the model (a checkpoint)."""

    version: int
    context_count: int
    word_count: int
    words: np.ndarray
    """Concept id of every token, scenes in order (integers: int32, or as :func:`load_checkpoint`
    read them, the narrowest unsigned type that holds them)."""
    contexts: np.ndarray
    """Context of every token at :attr:`version` (integers, as :attr:`words`)."""
    doc_offsets: np.ndarray
    """Scene d owns tokens doc_offsets[d]:doc_offsets[d + 1] (int32)."""

    @property
    def scene_count(self) -> int:
        return int(self.doc_offsets.shape[0]) - 1

    @property
    def token_count(self) -> int:
        return int(self.words.shape[0])


@dataclass(frozen=True)
class StoredStart:
    """What a start loads: the words, the latest checkpoint and the token batches written since it."""

    word_names: list[str]
    word_kinds: list[str | None]
    checkpoint: StoredCheckpoint | None
    """None before the first checkpoint: then :attr:`tail` holds every token."""
    tail: ReplayedTokens
    """The batches written after the checkpoint, applied to its tokens (to none without one)."""
    count_entries: np.ndarray
    """Every stored n_kw entry, (context, word, count) rows (int64): the whole of n_kw is checked on load."""
    scene_count: int
    context_count: int
    state: dict[str, Any]
    version: int


@dataclass(frozen=True)
class SceneChanges:
    """What one learned scene changed in the stored corpus (all indices are the model's own)."""

    scene_id: int
    first_token: int
    token_words: np.ndarray
    token_contexts: np.ndarray
    moved_tokens: np.ndarray
    """Earlier tokens whose context changed, ascending (int64)."""
    moved_contexts: np.ndarray
    """Their new contexts."""
    counts: Sequence[tuple[int, int, int]]
    new_words: Sequence[tuple[int, str, str | None]]
    context_count: int
    state: dict[str, Any]
    version: int
    """The model's version after this write: the batch's key and the version of every row it writes."""


@dataclass(frozen=True)
class StoredBatch:
    """One ``token_batch`` row, unpacked: the tokens a write added and the ones it reassigned."""

    version: int
    scene_id: int | None
    first_token: int
    words: np.ndarray
    contexts: np.ndarray
    moved: np.ndarray
    """Ids of the earlier tokens the write reassigned, ascending (int64)."""
    moved_contexts: np.ndarray


@dataclass(frozen=True)
class ReplayedTokens:
    """Batches applied in version order to a corpus of ``known`` tokens (:func:`replay_batches`)."""

    known: int
    moved: np.ndarray
    """(id, context) rows of tokens below ``known`` whose context the batches set, the last one (int64)."""
    added: np.ndarray
    """(scene, word, context) rows of the tokens ``known``, ``known`` + 1, ... the batches added (int64)."""

    @classmethod
    def none(cls, known: int) -> ReplayedTokens:
        return cls(known, np.zeros((0, 2), dtype=np.int64), np.zeros((0, 3), dtype=np.int64))


class DamagedCheckpointError(ValueError):
    """The stored checkpoint cannot be decoded, or its arrays contradict its own header."""


class DamagedBatchError(ValueError):
    """A ``token_batch`` cannot be decoded, or the batches do not continue the tokens before them."""


class BehindCompactionError(LookupError):
    """The batches after a version were deleted by a checkpoint (compaction), or replaying them would
    cost more than reloading from the newer checkpoint (:func:`reload_is_cheaper`): reload the model instead."""


#: What a catch-up and a reload cost, measured on PostgreSQL in-process (2026-12-05; paper-world models
#: of 10,000 and 30,000 scenes, 79 tokens a scene): replaying a version's batch 38.6 µs (385.7 ms for
#: 10,000); a reload 34.5-36.0 ms at 790,000 tokens, 60.0-63.1 ms at 2,370,000. Rounded up for the
#: reload, so that a catch-up is kept where the two are close.
REPLAY_SECONDS_PER_VERSION = 40e-6
RELOAD_SECONDS = 25e-3
RELOAD_SECONDS_PER_TOKEN = 20e-9


def reload_is_cheaper(spared_versions: int, checkpoint_tokens: int) -> bool:
    """Whether reloading from a checkpoint that is ``spared_versions`` ahead of memory costs less than
    replaying those versions' batches (the batches after the checkpoint are replayed either way).
    For a model of 790,000 tokens (10,000 scenes of the paper world) it picks a reload from about
    1,000 versions behind; past about 19 million tokens never, as the batches kept span one
    checkpoint interval (10,000 by default)."""
    replay = spared_versions * REPLAY_SECONDS_PER_VERSION
    return replay > RELOAD_SECONDS + checkpoint_tokens * RELOAD_SECONDS_PER_TOKEN


def pack_batch(words: np.ndarray, contexts: np.ndarray, moved: np.ndarray, moved_contexts: np.ndarray) -> bytes:
    """A batch's ``packed`` blob; the moved ids (ascending) are stored as differences, mostly small."""
    return pack_small_arrays([words, contexts, np.diff(moved, prepend=0), moved_contexts])


def unpack_batch(version: int, scene_id: int | None, first_token: int, token_count: int, blob: bytes) -> StoredBatch:
    """The batch of one row; :class:`DamagedBatchError` when its blob cannot be read or disagrees with the row."""
    try:
        words, contexts, moved_steps, moved_contexts = unpack_small_arrays(blob)
    except ValueError as error:
        raise DamagedBatchError(f"token_batch at version {version} cannot be read: {error}") from error
    if words.shape != contexts.shape or words.shape[0] != token_count or moved_steps.shape != moved_contexts.shape:
        raise DamagedBatchError(
            f"token_batch at version {version} holds {words.shape[0]} words, {contexts.shape[0]} contexts, "
            f"{moved_steps.shape[0]} moved tokens and {moved_contexts.shape[0]} of their contexts; "
            f"its row says {token_count} tokens"
        )
    if token_count and scene_id is None:
        raise DamagedBatchError(f"token_batch at version {version} adds {token_count} tokens without a scene")
    return StoredBatch(
        version=version,
        scene_id=scene_id,
        first_token=first_token,
        words=words,
        contexts=contexts,
        moved=np.cumsum(moved_steps, dtype=np.int64),
        moved_contexts=moved_contexts,
    )


def replay_batches(batches: Sequence[StoredBatch], known: int) -> ReplayedTokens:
    """The batches (in version order) applied to a corpus of ``known`` tokens.

    Each batch's new tokens must continue the tokens before them (``first_token`` = the count so
    far: no gap, no overlap) and its moved tokens must already exist; otherwise
    :class:`DamagedBatchError` names the batch and the numbers. A token moved several times keeps
    its last context; a token added and then moved, the context it was moved to.
    """
    count = known
    added_scenes, added_words, added_contexts, moved_ids, moved_contexts = [], [], [], [], []
    for batch in batches:
        if batch.moved.size and batch.moved[-1] >= count:
            raise DamagedBatchError(
                f"token_batch at version {batch.version} reassigns token {int(batch.moved[-1])}, "
                f"but only {count} tokens exist before it"
            )
        moved_ids.append(batch.moved)
        moved_contexts.append(batch.moved_contexts)
        if batch.words.size:
            if batch.first_token != count:
                raise DamagedBatchError(
                    f"token ids have a gap: token_batch at version {batch.version} starts at token "
                    f"{batch.first_token}, but {count} tokens come before it"
                )
            added_scenes.append(np.full(batch.words.shape[0], batch.scene_id, dtype=np.int64))
            added_words.append(batch.words)
            added_contexts.append(batch.contexts)
            count += batch.words.shape[0]
    added = np.zeros((count - known, 3), dtype=np.int64)
    if added_words:
        added[:, 0] = np.concatenate(added_scenes)
        added[:, 1] = np.concatenate(added_words)
        added[:, 2] = np.concatenate(added_contexts)
    ids = np.concatenate(moved_ids) if moved_ids else np.zeros(0, dtype=np.int64)
    contexts = np.concatenate(moved_contexts).astype(np.int64) if moved_contexts else np.zeros(0, dtype=np.int64)
    last, where = np.unique(ids[::-1], return_index=True)  # the last write of each token wins
    final = contexts[::-1][where]
    inside = last >= known
    added[last[inside] - known, 2] = final[inside]
    return ReplayedTokens(known, np.stack([last[~inside], final[~inside]], axis=1).astype(np.int64), added)


def create_state(
    session: Session,
    model_id: str,
    *,
    context_count: int,
    state: dict[str, Any],
    words: Iterable[tuple[int, str, str | None]],
) -> None:
    session.add(IncrementalLdaState(model_id=model_id, scene_count=0, context_count=context_count, state=state))
    _insert_words(session, model_id, list(words))
    session.flush()


def save_scene(session: Session, model_id: str, changes: SceneChanges) -> None:
    """Persist one scene's changes; the scene row itself is written by the scenes repository."""
    _insert_words(session, model_id, changes.new_words)
    driver = DriverStatements(session)
    version = changes.version
    blob = pack_batch(changes.token_words, changes.token_contexts, changes.moved_tokens, changes.moved_contexts)
    driver.execute(
        _INSERT_BATCH,
        (model_id, version, changes.scene_id, changes.first_token, len(changes.token_words), blob),
    )
    if driver.dialect.name == "postgresql":
        if changes.counts:
            contexts, words, counts = zip(*changes.counts, strict=True)
            driver.execute(
                _UPSERT_COUNTS,
                (model_id, version, _integer_array(contexts), _integer_array(words), _integer_array(counts)),
            )
    else:
        driver.executemany(_UPSERT_COUNT, [(model_id, k, w, n, version) for k, w, n in changes.counts])
    driver.execute(
        _UPDATE_STATE,
        (
            changes.scene_id + 1,
            changes.context_count,
            driver.bind(_STATE_TABLE.c.state)(changes.state),
            version,
            driver.bind(_STATE_TABLE.c.updated_at)(utc_now()),
            model_id,
        ),
    )


# The statements of every scene, in the SQL that SQLite and PostgreSQL share, sent
# straight to the driver (storage.database.DriverStatements): built by SQLAlchemy
# they cost more (parameter processing, per-statement set-up) than the database
# takes to store them. ``?`` stands for the driver's placeholder; JSON and time
# values get SQLAlchemy's own conversion for the column, and the state row its
# ``updated_at`` (the ORM's ``onupdate``), so the rows read back as before.
# A scene's tokens are one ``token_batch`` row (alembic 0007; before, ~80 ``token`` rows and
# the upserts of the reassigned ones).
_INSERT_BATCH = (
    "INSERT INTO token_batch (model_id, version, scene_id, first_token, token_count, packed) VALUES (?, ?, ?, ?, ?, ?)"
)
_UPSERT_COUNT = (
    "INSERT INTO context_word_count (model_id, context, word_id, count, version) VALUES (?, ?, ?, ?, ?) "
    "ON CONFLICT (model_id, context, word_id) DO UPDATE SET count = excluded.count, version = excluded.version"
)
# PostgreSQL: the n_kw entries in one statement with the rows as arrays (``unnest``): psycopg's
# executemany, even pipelined, costs Python time per row (docs/benchmarks.md). Each array holds
# distinct keys, as ON CONFLICT ... DO UPDATE requires.
_UPSERT_COUNTS = (
    "INSERT INTO context_word_count (model_id, context, word_id, count, version) "
    "SELECT ?, c.context, c.word_id, c.count, ? FROM unnest(?::integer[], ?::integer[], ?::integer[]) "
    "AS c(context, word_id, count) "
    "ON CONFLICT (model_id, context, word_id) DO UPDATE SET count = excluded.count, version = excluded.version"
)


def _integer_array(values: Iterable[int]) -> str:
    """PostgreSQL's text form of an integer array (``{1,2,3}``), which the statement casts. psycopg
    dumps a Python list element by element in Python: a scene's three ~40-entry lists took ≈ 68 µs
    that way and ≈ 15 µs as text (docs/benchmarks.md)."""
    return "{" + ",".join(map(str, values)) + "}"


_STATE_TABLE = IncrementalLdaState.__table__
_UPDATE_STATE = (
    "UPDATE incremental_lda_state SET scene_count = ?, context_count = ?, state = ?, version = ?, updated_at = ? "
    "WHERE model_id = ?"
)


def _insert_words(session: Session, model_id: str, words: Sequence[tuple[int, str, str | None]]) -> None:
    if words:
        session.execute(
            insert(Word.__table__),
            [{"model_id": model_id, "id": i, "name": name, "kind": kind} for i, name, kind in words],
        )


def load_batches(session: Session, model_id: str, *, since_version: int) -> list[StoredBatch]:
    """The model's batches above ``since_version``, in version order (a range of the primary key)."""
    rows = DriverStatements(session).fetchall(_SELECT_BATCHES_SINCE, (model_id, since_version))
    return [unpack_batch(int(v), s, int(first), int(n), bytes(blob)) for v, s, first, n, blob in rows]


_SELECT_BATCHES_SINCE = (
    "SELECT version, scene_id, first_token, token_count, packed FROM token_batch "
    "WHERE model_id = ? AND version > ? ORDER BY version"
)


def load_start(session: Session, model_id: str) -> StoredStart:
    """The model's latest checkpoint and the batches written since it, with every word and n_kw
    entry (read it in one snapshot). Raises LookupError for a model without state,
    :class:`DamagedCheckpointError` for a checkpoint that cannot be read and
    :class:`DamagedBatchError` for batches that cannot be read or do not continue it."""
    state = session.get(IncrementalLdaState, model_id)
    if state is None:
        raise LookupError(f"model {model_id!r} has no Incremental-LDA state")
    above = session.scalar(
        select(func.min(TokenBatch.version)).where(TokenBatch.model_id == model_id, TokenBatch.version > state.version)
    )
    if above is not None:  # every write stores its batch and its version together: one of them was damaged
        raise DamagedBatchError(
            f"token_batch holds rows above the model's version ({state.version}), the first at version {above}: "
            "a writer ignored the model's lock, or the state row was restored behind them"
        )
    words = session.execute(select(Word.name, Word.kind).where(Word.model_id == model_id).order_by(Word.id)).all()
    checkpoint = load_checkpoint(session, model_id)
    since, known = (0, 0) if checkpoint is None else (checkpoint.version, checkpoint.token_count)
    return StoredStart(
        word_names=[name for name, _ in words],
        word_kinds=[kind for _, kind in words],
        checkpoint=checkpoint,
        tail=replay_batches(load_batches(session, model_id, since_version=since), known),
        count_entries=_int_rows(DriverStatements(session), _SELECT_COUNTS, (model_id,), 3),
        scene_count=state.scene_count,
        context_count=state.context_count,
        state=dict(state.state),
        version=state.version,
    )


@dataclass(frozen=True)
class StoredAssignments:
    """Every token of a model as its checkpoint and batches give them (the truth of its corpus)."""

    words: np.ndarray
    contexts: np.ndarray
    scenes: np.ndarray
    """The scene of every token. The three are int32 (:func:`load_assignments`; int64 if a stored
    value does not fit, which only damage gives) or int64 (the batches' own replay)."""


_INT32 = np.iinfo(np.int32)


def load_assignments(session: Session, model_id: str) -> StoredAssignments:
    """Every token's word, context and scene: the checkpoint with the batches since applied (read it in
    one snapshot). Raises :class:`DamagedCheckpointError` / :class:`DamagedBatchError` as :func:`load_start`.

    Each array is written once, in place, as int32 where every stored value fits (a model's ids
    do: the model's own arrays are int32). Three int64 arrays and their concatenations peaked at
    461 MB for a 100,000-scene model (6.35 million tokens), which ``models check`` reads whole."""
    checkpoint = load_checkpoint(session, model_id)
    known, since = (0, 0) if checkpoint is None else (checkpoint.token_count, checkpoint.version)
    tail = replay_batches(load_batches(session, model_id, since_version=since), known)
    stored = [tail.added, tail.moved] + ([] if checkpoint is None else [checkpoint.words, checkpoint.contexts])
    fits = all(part.size == 0 or (int(part.min()) >= _INT32.min and int(part.max()) <= _INT32.max) for part in stored)
    dtype = np.int32 if fits else np.int64
    total = known + tail.added.shape[0]
    words, contexts, scenes = (np.empty(total, dtype=dtype) for _ in range(3))
    if checkpoint is not None:
        words[:known] = checkpoint.words
        contexts[:known] = checkpoint.contexts
        scenes[:known] = np.repeat(np.arange(checkpoint.scene_count, dtype=dtype), np.diff(checkpoint.doc_offsets))
    contexts[tail.moved[:, 0]] = tail.moved[:, 1]  # earlier tokens reassigned since (all below ``known``)
    words[known:], contexts[known:], scenes[known:] = tail.added[:, 1], tail.added[:, 2], tail.added[:, 0]
    return StoredAssignments(words=words, contexts=contexts, scenes=scenes)


@dataclass(frozen=True)
class PackedCheckpoint:
    """A :class:`StoredCheckpoint` as the checkpoint row stores it: its counts and its arrays' blob."""

    version: int
    scene_count: int
    token_count: int
    context_count: int
    word_count: int
    arrays: bytes


def pack_checkpoint(checkpoint: StoredCheckpoint) -> PackedCheckpoint:
    """The checkpoint's arrays packed (storage/compression.py ``pack_arrays``): no database work,
    and seconds at a million scenes, so a scene's checkpoint is packed outside every lock."""
    lengths = np.diff(checkpoint.doc_offsets)
    return PackedCheckpoint(
        version=checkpoint.version,
        scene_count=checkpoint.scene_count,
        token_count=checkpoint.token_count,
        context_count=checkpoint.context_count,
        word_count=checkpoint.word_count,
        arrays=pack_arrays({"words": checkpoint.words, "contexts": checkpoint.contexts, "scene_lengths": lengths}),
    )


def save_checkpoint(
    session: Session, model_id: str, checkpoint: StoredCheckpoint | PackedCheckpoint, *, compact: bool = False
) -> None:
    """Replace the model's checkpoint (in the caller's transaction: a scene's own, after its
    commit, or a repair's).

    ``compact`` (a scheduled checkpoint) also deletes the model's batches at or below the replaced
    checkpoint's version and records that version as ``compacted_version``: a process up to one
    checkpoint interval behind still catches up from the batches kept, one further behind
    reloads (:class:`BehindCompactionError`). A compacting checkpoint replaces only an older one
    (one written late, after a newer one, changes nothing: neither the row nor the batches).
    Otherwise (a repair) no batch is deleted and the mark is kept. Statements only, no read.
    """
    packed = checkpoint if isinstance(checkpoint, PackedCheckpoint) else pack_checkpoint(checkpoint)
    driver = DriverStatements(session)
    if compact:
        driver.execute(_DELETE_COMPACTED_BATCHES, (model_id, model_id, packed.version))
    driver.execute(
        _UPSERT_CHECKPOINT_COMPACTING if compact else _UPSERT_CHECKPOINT,
        (
            model_id,
            packed.version,
            packed.scene_count,
            packed.token_count,
            packed.context_count,
            packed.word_count,
            packed.arrays,
            driver.bind(_CHECKPOINT_TABLE.c.created_at)(utc_now()),
        ),
    )


_CHECKPOINT_TABLE = IncrementalLdaCheckpoint.__table__
_DELETE_COMPACTED_BATCHES = (
    "DELETE FROM token_batch WHERE model_id = ? "
    "AND version <= (SELECT version FROM incremental_lda_checkpoint WHERE model_id = ? AND version < ?)"
)
# ``compacted_version = incremental_lda_checkpoint.version``: the replaced row's version (SET reads the
# row as it was), the one the batches were just deleted up to.
_UPSERT_CHECKPOINT = (
    "INSERT INTO incremental_lda_checkpoint (model_id, version, scene_count, token_count, context_count, "
    "word_count, arrays, compacted_version, created_at) VALUES (?, ?, ?, ?, ?, ?, ?, 0, ?) "
    "ON CONFLICT (model_id) DO UPDATE SET version = excluded.version, scene_count = excluded.scene_count, "
    "token_count = excluded.token_count, context_count = excluded.context_count, "
    "word_count = excluded.word_count, arrays = excluded.arrays, created_at = excluded.created_at"
)
_UPSERT_CHECKPOINT_COMPACTING = (
    _UPSERT_CHECKPOINT
    + ", compacted_version = incremental_lda_checkpoint.version WHERE incremental_lda_checkpoint.version < excluded.version"
)


def compacted_version(session: Session, model_id: str) -> int:
    """The version at or below which the model's batches were deleted (0: none was)."""
    value = session.scalar(
        select(IncrementalLdaCheckpoint.compacted_version).where(IncrementalLdaCheckpoint.model_id == model_id)
    )
    return 0 if value is None else int(value)


def load_checkpoint(session: Session, model_id: str) -> StoredCheckpoint | None:
    """The model's checkpoint (None when it has none); :class:`DamagedCheckpointError` when its blob
    cannot be decoded or disagrees with the row's own counts."""
    row = session.execute(
        select(
            IncrementalLdaCheckpoint.version,
            IncrementalLdaCheckpoint.scene_count,
            IncrementalLdaCheckpoint.token_count,
            IncrementalLdaCheckpoint.context_count,
            IncrementalLdaCheckpoint.word_count,
            IncrementalLdaCheckpoint.arrays,
        ).where(IncrementalLdaCheckpoint.model_id == model_id)
    ).first()
    if row is None:
        return None
    try:
        arrays = unpack_arrays(bytes(row.arrays))
        words, contexts, lengths = arrays["words"], arrays["contexts"], arrays["scene_lengths"]
    except (ValueError, KeyError) as error:
        raise DamagedCheckpointError(f"incremental_lda_checkpoint.arrays cannot be read: {error}") from error
    if not (words.shape == contexts.shape == (row.token_count,) and lengths.shape == (row.scene_count,)):
        raise DamagedCheckpointError(
            f"incremental_lda_checkpoint holds {words.shape[0]} words, {contexts.shape[0]} contexts and "
            f"{lengths.shape[0]} scenes, its row says {row.token_count} tokens and {row.scene_count} scenes"
        )
    if int(lengths.sum(dtype=np.int64)) != row.token_count or (lengths.size and lengths.min() < 1):
        raise DamagedCheckpointError("incremental_lda_checkpoint's scene lengths do not add up to its tokens")
    return StoredCheckpoint(
        version=int(row.version),
        context_count=int(row.context_count),
        word_count=int(row.word_count),
        # As stored (uint8 for a vocabulary and K below 256): the model widens them as it copies them
        # into its own arrays, one fresh 312 MB write an array at a million 78-token scenes, not two.
        words=words,
        contexts=contexts,
        doc_offsets=np.concatenate([[0], np.cumsum(lengths, dtype=np.int64)]).astype(np.int32),
    )


def assignment_counts(session: Session, model_id: str) -> dict[tuple[int, int], int]:
    """n_kw recomputed from the stored token assignments (checkpoint and batches: the invariant's
    right-hand side)."""
    return token_counts(load_assignments(session, model_id))


#: Largest count table :func:`token_counts` fills in one pass (contexts × words); tokens naming a
#: context or word beyond it are damaged ones, counted by sorting instead.
COUNT_TABLE_LIMIT = 1 << 26


def token_counts(tokens: StoredAssignments) -> dict[tuple[int, int], int]:
    """n_kw of ``tokens``: {(context, word): count} of the nonzero entries.

    One pass (``np.bincount`` of context × |W| + word) where the contexts and words are ids a
    count table can hold; sorting the (context, word) pairs (``np.unique``) took 7.3 of the 11.2 s
    of ``models check`` on a 100,000-scene model. Negative or huge ids (damaged tokens, which the
    check reports by other rules) are counted by that sort, which any values survive."""
    contexts, words = tokens.contexts, tokens.words
    if words.size == 0:
        return {}
    width, height = int(words.max()) + 1, int(contexts.max()) + 1
    if min(int(words.min()), int(contexts.min())) < 0 or width * height > COUNT_TABLE_LIMIT:
        keys, counts = np.unique(np.stack([contexts, words], axis=1), axis=0, return_counts=True)
        return {(int(k), int(w)): int(n) for (k, w), n in zip(keys, counts, strict=True)}
    table = np.bincount(contexts.astype(np.int64) * width + words, minlength=width * height)
    entries = np.flatnonzero(table)
    rows, columns = np.divmod(entries, width)
    return dict(zip(zip(rows.tolist(), columns.tolist(), strict=True), table[entries].tolist(), strict=True))


def stored_counts(session: Session, model_id: str) -> dict[tuple[int, int], int]:
    """The stored n_kw entries that are not zero."""
    rows = session.execute(
        select(ContextWordCount.context, ContextWordCount.word_id, ContextWordCount.count).where(
            ContextWordCount.model_id == model_id, ContextWordCount.count != 0
        )
    ).all()
    return {(k, w): n for k, w, n in rows}


# Versions: every committed write to a model bumps its version (docs/scaling.md).


class LockHeldElsewhere(Exception):
    """``lock_model(..., wait=False)``: another transaction holds the model's lock (its state row)."""


@dataclass(frozen=True)
class LockedModel:
    """A model locked for this transaction's writes (:func:`lock_model`)."""

    version: int
    """Its stored version."""
    labels: dict[int, str] | None
    """Its contexts' labels (context index → label), which a learned scene's answer names; None
    when the lock was taken without them (``lock_model(labels=False)``)."""
    idempotency_key: str | None = None
    """The key looked up with the lock (the key of the scene this write learns), if any."""
    stored_under_key: StoredAnswer | None = None
    """The scene already stored under :attr:`idempotency_key` (the write is a retry), or None."""


def lock_model(
    session: Session,
    model_id: str,
    *,
    wait: bool = True,
    idempotency_key: str | None = None,
    labels: bool = True,
) -> LockedModel | None:
    """The model locked for this transaction's writes, with its stored version and its contexts'
    labels (None: no such model), and with ``idempotency_key`` the scene stored under that key.
    PostgreSQL locks the state row (``FOR UPDATE``, which waits for the lock and then reads the
    row's newest version), and the transaction's ``BEGIN``, the lock and the reads (run after the
    lock is held, so they see every write committed before it) go in one round trip
    (``pipelined(begin=True)``); SQLite's write transactions already hold the database's write
    lock (``BEGIN IMMEDIATE``).

    ``wait=False``: on PostgreSQL, raises :class:`LockHeldElsewhere` at once (``NOWAIT``; the
    transaction is then aborted) instead of waiting for a lock that another transaction holds;
    on SQLite, the same as ``wait=True``. ``labels=False``: the labels are not read (the caller
    knows them as of the version it will find: app/registry.py ``ModelWriter.transaction``)."""
    queued: dict[str, QueuedRows] = {}
    try:
        with pipelined(session, begin=True):
            driver = DriverStatements(session)
            lock = "" if driver.dialect.name != "postgresql" else " FOR UPDATE" if wait else " FOR UPDATE NOWAIT"
            queued["version"] = driver.submit(_SELECT_VERSION + lock, (model_id,))
            if labels:
                queued["labels"] = submit_context_labels(driver, model_id)
            if idempotency_key is not None:
                queued["keyed"] = submit_find_by_idempotency_key(driver, model_id, idempotency_key)
    except DBAPIError as error:
        for rows in queued.values():
            rows.close()
        if not wait and getattr(error.orig, "sqlstate", None) == LOCK_NOT_AVAILABLE:
            raise LockHeldElsewhere(model_id) from error
        raise
    read = {name: rows.all() for name, rows in queued.items()}  # every cursor read, and so closed
    if not read["version"]:
        return None
    return LockedModel(
        int(read["version"][0][0]),
        dict(read["labels"]) if "labels" in read else None,
        idempotency_key,
        stored_answer(read["keyed"]) if "keyed" in read else None,
    )


def stored_version(session: Session, model_id: str) -> int | None:
    """The model's stored version (one primary-key read), None when the model does not exist."""
    row = DriverStatements(session).fetchone(_SELECT_VERSION, (model_id,))
    return None if row is None else int(row[0])


def stored_summary(session: Session, model_id: str) -> tuple[int, int, int] | None:
    """(contexts, scenes, words) as the model's state and word rows say: what lists a model that
    cannot load. None when it has no state row."""
    row = session.execute(
        select(IncrementalLdaState.context_count, IncrementalLdaState.scene_count).where(
            IncrementalLdaState.model_id == model_id
        )
    ).first()
    if row is None:
        return None
    words = session.scalar(select(func.count()).select_from(Word).where(Word.model_id == model_id)) or 0
    return int(row.context_count), int(row.scene_count), int(words)


def stored_versions(session: Session) -> dict[str, int]:
    """Every stored model's version, by id."""
    rows = session.execute(select(IncrementalLdaState.model_id, IncrementalLdaState.version)).all()
    return {model_id: int(version) for model_id, version in rows}


def set_version(session: Session, model_id: str, version: int) -> None:
    """Record a write that changed no corpus row (training objects, a fit, a repair)."""
    DriverStatements(session).execute(_SET_VERSION, (version, model_id))


_SELECT_VERSION = "SELECT version FROM incremental_lda_state WHERE model_id = ?"
_SET_VERSION = "UPDATE incremental_lda_state SET version = ? WHERE model_id = ?"


def load_changes(
    session: Session, model_id: str, *, since_version: int, word_count: int, token_count: int
) -> StoredChanges | None:
    """What the writes after ``since_version`` changed, for a model in memory with ``word_count`` words
    and ``token_count`` tokens (None when the model is gone); read it in one snapshot
    (:func:`storage.database.snapshot`) or under the model's write lock. Raises
    :class:`BehindCompactionError` when batches after ``since_version`` were deleted by a checkpoint,
    or when a newer checkpoint makes a reload cheaper (:func:`reload_is_cheaper`; the caller reloads
    the model), and :class:`DamagedBatchError` when the batches do not continue
    ``token_count``."""
    state = session.execute(
        select(
            IncrementalLdaState.version,
            IncrementalLdaState.scene_count,
            IncrementalLdaState.context_count,
            IncrementalLdaState.state,
        ).where(IncrementalLdaState.model_id == model_id)
    ).one_or_none()
    if state is None:
        return None
    checkpoint = session.execute(
        select(
            IncrementalLdaCheckpoint.compacted_version,
            IncrementalLdaCheckpoint.version,
            IncrementalLdaCheckpoint.token_count,
        ).where(IncrementalLdaCheckpoint.model_id == model_id)
    ).first()
    if checkpoint is not None and since_version < checkpoint.compacted_version:
        raise BehindCompactionError(
            f"model {model_id!r} is at version {since_version}; its token batches up to version "
            f"{checkpoint.compacted_version} were folded into its checkpoint"
        )
    if checkpoint is not None and reload_is_cheaper(checkpoint.version - since_version, checkpoint.token_count):
        raise BehindCompactionError(
            f"model {model_id!r} is at version {since_version}, {checkpoint.version - since_version} versions behind "
            f"its checkpoint of {checkpoint.token_count} tokens: reloading from it is cheaper than replaying them"
        )
    words = session.execute(
        select(Word.name, Word.kind).where(Word.model_id == model_id, Word.id >= word_count).order_by(Word.id)
    ).all()
    tokens = replay_batches(load_batches(session, model_id, since_version=since_version), token_count)
    counts = _int_rows(DriverStatements(session), _SELECT_COUNTS_SINCE, (model_id, since_version), 3)
    return StoredChanges(
        version=int(state.version),
        scene_count=int(state.scene_count),
        context_count=int(state.context_count),
        state=dict(state.state),
        new_words=[(name, kind) for name, kind in words],
        tokens=tokens,
        count_entries=counts,
    )


# Bulk reads straight through the driver: numpy converts the driver's tuples much faster than
# SQLAlchemy's Row objects (the measurement: docs/benchmarks.md).
_SELECT_COUNTS = "SELECT context, word_id, count FROM context_word_count WHERE model_id = ?"
_SELECT_COUNTS_SINCE = "SELECT context, word_id, count FROM context_word_count WHERE model_id = ? AND version > ?"


def _int_rows(driver: DriverStatements, statement: str, parameters: tuple[Any, ...], columns: int) -> np.ndarray:
    return np.array(driver.fetchall(statement, parameters), dtype=np.int64).reshape(-1, columns)
