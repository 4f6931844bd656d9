"""The Incremental-LDA state of a model, written scene by scene and read back on start.

:func:`save_scene` writes everything one learned scene changed — its tokens,
the tokens its sweeps reassigned, the n_kw entries that moved, new words and
the scalar state — in the caller's transaction (the scene's own), straight
through the driver (see the statements below). :func:`save_checkpoint` replaces
the model's checkpoint (every token's word and context at one version, packed);
:func:`load_start` reads what a start needs: the checkpoint and only the token
rows written since it, so a start costs the same at any corpus size
(docs/scaling.md, "Checkpoints").
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from sqlalchemy import delete, func, insert, select
from sqlalchemy.orm import Session

from storage.compression import pack_arrays, unpack_arrays
from storage.database import DriverStatements
from storage.models import ContextWordCount, IncrementalLdaCheckpoint, IncrementalLdaState, Token, Word, utc_now


@dataclass(frozen=True)
class StoredCorpus:
    """A model's LDA corpus as stored: words, token arrays, n_kw entries and the scalar state."""

    word_names: list[str]
    word_kinds: list[str | None]
    token_words: np.ndarray
    token_contexts: np.ndarray
    doc_offsets: np.ndarray
    count_entries: np.ndarray
    scene_count: int
    context_count: int
    state: dict[str, Any]
    version: int


@dataclass(frozen=True)
class StoredChanges:
    """What the writes after one version changed in a model's stored corpus (a catch-up)."""

    version: int
    scene_count: int
    context_count: int
    state: dict[str, Any]
    new_words: list[tuple[str, str | None]]
    """Words with ids >= the caller's vocabulary size, in id order: (name, kind)."""
    tokens: np.ndarray
    """(id, scene, word, context) rows of the tokens inserted or reassigned since, by id (int64)."""
    count_entries: np.ndarray
    """(context, word, count) rows of the n_kw entries changed since (int64)."""


@dataclass(frozen=True)
class StoredCheckpoint:
    """Every token's word and context at one version of the model (a checkpoint)."""

    version: int
    context_count: int
    word_count: int
    words: np.ndarray
    """Concept id of every token, scenes in order (int32)."""
    contexts: np.ndarray
    """Context of every token at :attr:`version` (int32)."""
    doc_offsets: np.ndarray
    """Scene d owns tokens doc_offsets[d]:doc_offsets[d + 1] (int32)."""

    @property
    def scene_count(self) -> int:
        return int(self.doc_offsets.shape[0]) - 1

    @property
    def token_count(self) -> int:
        return int(self.words.shape[0])


class DamagedCheckpointError(ValueError):
    """The stored checkpoint cannot be decoded, or its arrays contradict its own header."""


@dataclass(frozen=True)
class StoredStart:
    """What a start loads: the words, the latest checkpoint and the rows written since it."""

    word_names: list[str]
    word_kinds: list[str | None]
    checkpoint: StoredCheckpoint | None
    """None before the first checkpoint: then :attr:`tail` holds every token."""
    tail: np.ndarray
    """(id, scene, word, context) rows of the tokens written after the checkpoint, by id (int64)."""
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
    token_words: Sequence[int]
    token_contexts: Sequence[int]
    reassigned: Sequence[tuple[int, int, int, int]]
    """Earlier tokens whose context changed, as whole rows: (token, scene, word, new context)."""
    counts: Sequence[tuple[int, int, int]]
    new_words: Sequence[tuple[int, str, str | None]]
    context_count: int
    state: dict[str, Any]
    version: int
    """The model's version after this write: stamped on every row the scene writes."""


def reassigned_rows(update: Any) -> list[tuple[int, int, int, int]]:
    """The ``SceneChanges.reassigned`` rows of an Incremental-LDA scene update (duck-typed:
    storage does not import the core)."""
    return list(
        zip(
            update.reassigned_tokens.tolist(),
            update.reassigned_scenes.tolist(),
            update.reassigned_words.tolist(),
            update.reassigned_contexts.tolist(),
            strict=True,
        )
    )


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
    if driver.dialect.name == "postgresql":
        _save_rows_as_arrays(driver, model_id, changes)
    else:
        first, scene, version = changes.first_token, changes.scene_id, changes.version
        tokens = zip(changes.token_words, changes.token_contexts, strict=True)
        driver.executemany(
            _INSERT_TOKEN, [(model_id, first + i, scene, w, k, version) for i, (w, k) in enumerate(tokens)]
        )
        driver.executemany(_UPSERT_TOKEN, [(model_id, *row, version) for row in changes.reassigned])
        driver.executemany(_UPSERT_COUNT, [(model_id, k, w, n, version) for k, w, n in changes.counts])
    driver.execute(
        _UPDATE_STATE,
        (
            changes.scene_id + 1,
            changes.context_count,
            driver.bind(_STATE_TABLE.c.state)(changes.state),
            changes.version,
            driver.bind(_STATE_TABLE.c.updated_at)(utc_now()),
            model_id,
        ),
    )


# The statements of every scene, in the SQL that SQLite and PostgreSQL share, sent
# straight to the driver (storage.database.DriverStatements): built by SQLAlchemy
# they cost more (parameter processing for ~100 rows a scene, per-statement set-up)
# than the database takes to store them. ``?`` stands for the driver's placeholder;
# JSON and time values get SQLAlchemy's own conversion for the column, and the
# state row its ``updated_at`` (the ORM's ``onupdate``), so the rows read back as before.
_INSERT_TOKEN = "INSERT INTO token (model_id, id, scene_id, word_id, context, version) VALUES (?, ?, ?, ?, ?, ?)"
# A reassigned token is written as its whole row, upserted on its primary key: on PostgreSQL an
# UPDATE ... FROM unnest(...) is planned from the table's statistics, and with statistics older
# than the model's growth it hash-joined every token of the model (a cost growing with the
# corpus: docs/benchmarks.md); the arbiter index of ON CONFLICT is probed row by row whatever the
# statistics say. The row's other values are the stored ones (the in-memory state's).
_UPSERT_TOKEN = (
    "INSERT INTO token (model_id, id, scene_id, word_id, context, version) VALUES (?, ?, ?, ?, ?, ?) "
    "ON CONFLICT (model_id, id) DO UPDATE SET context = excluded.context, version = excluded.version"
)
_UPSERT_COUNT = (
    "INSERT INTO context_word_count (model_id, context, word_id, count, version) VALUES (?, ?, ?, ?, ?) "
    "ON CONFLICT (model_id, context, word_id) DO UPDATE SET count = excluded.count, version = excluded.version"
)
# PostgreSQL: one statement per table with the rows as arrays (``unnest``). psycopg's
# executemany, even pipelined, costs Python time per row (docs/benchmarks.md), and a scene has ~100-250
# rows (its tokens, the tokens its sweeps reassigned, the n_kw entries that moved).
# Each array holds distinct keys, as ON CONFLICT ... DO UPDATE requires.
_INSERT_TOKENS = (
    "INSERT INTO token (model_id, id, scene_id, word_id, context, version) "
    "SELECT ?, t.id, ?, t.word_id, t.context, ? FROM unnest(?::integer[], ?::integer[], ?::integer[]) "
    "AS t(id, word_id, context)"
)
_UPSERT_TOKENS = (
    "INSERT INTO token (model_id, id, scene_id, word_id, context, version) "
    "SELECT ?, t.id, t.scene_id, t.word_id, t.context, ? "
    "FROM unnest(?::integer[], ?::integer[], ?::integer[], ?::integer[]) AS t(id, scene_id, word_id, context) "
    "ON CONFLICT (model_id, id) DO UPDATE SET context = excluded.context, version = excluded.version"
)
_UPSERT_COUNTS = (
    "INSERT INTO context_word_count (model_id, context, word_id, count, version) "
    "SELECT ?, c.context, c.word_id, c.count, ? FROM unnest(?::integer[], ?::integer[], ?::integer[]) "
    "AS c(context, word_id, count) "
    "ON CONFLICT (model_id, context, word_id) DO UPDATE SET count = excluded.count, version = excluded.version"
)


def _save_rows_as_arrays(driver: DriverStatements, model_id: str, changes: SceneChanges) -> None:
    first, scene, version = changes.first_token, changes.scene_id, changes.version
    token_ids = list(range(first, first + len(changes.token_words)))
    driver.execute(
        _INSERT_TOKENS,
        (model_id, scene, version, token_ids, list(changes.token_words), list(changes.token_contexts)),
    )
    if changes.reassigned:
        tokens, scenes, words, contexts = zip(*changes.reassigned, strict=True)
        driver.execute(_UPSERT_TOKENS, (model_id, version, list(tokens), list(scenes), list(words), list(contexts)))
    if changes.counts:
        contexts, words, counts = zip(*changes.counts, strict=True)
        driver.execute(_UPSERT_COUNTS, (model_id, version, list(contexts), list(words), list(counts)))


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


def load_corpus(session: Session, model_id: str) -> StoredCorpus:
    state = session.get(IncrementalLdaState, model_id)
    if state is None:
        raise LookupError(f"model {model_id!r} has no Incremental-LDA state")
    words = session.execute(select(Word.name, Word.kind).where(Word.model_id == model_id).order_by(Word.id)).all()
    driver = DriverStatements(session)
    tokens = _int_rows(driver, _SELECT_TOKENS, (model_id,), 3)
    counts = _int_rows(driver, _SELECT_COUNTS, (model_id,), 3)
    scene_lengths = np.bincount(tokens[:, 0], minlength=state.scene_count)
    return StoredCorpus(
        word_names=[name for name, _ in words],
        word_kinds=[kind for _, kind in words],
        token_words=tokens[:, 1].astype(np.int32),
        token_contexts=tokens[:, 2].astype(np.int32),
        doc_offsets=np.concatenate([[0], np.cumsum(scene_lengths)]).astype(np.int32),
        count_entries=counts,
        scene_count=state.scene_count,
        context_count=state.context_count,
        state=dict(state.state),
        version=state.version,
    )


def load_start(session: Session, model_id: str) -> StoredStart:
    """The model's latest checkpoint and the token rows written since it, with every word and n_kw
    entry (read it in one snapshot). Raises LookupError for a model without state and
    :class:`DamagedCheckpointError` for a checkpoint that cannot be read."""
    state = session.get(IncrementalLdaState, model_id)
    if state is None:
        raise LookupError(f"model {model_id!r} has no Incremental-LDA state")
    words = session.execute(select(Word.name, Word.kind).where(Word.model_id == model_id).order_by(Word.id)).all()
    checkpoint = load_checkpoint(session, model_id)
    driver = DriverStatements(session)
    since = -1 if checkpoint is None else checkpoint.version  # rows from before migration 0002 carry version 0
    return StoredStart(
        word_names=[name for name, _ in words],
        word_kinds=[kind for _, kind in words],
        checkpoint=checkpoint,
        tail=_int_rows(driver, _SELECT_TOKENS_SINCE, (model_id, since), 4),
        count_entries=_int_rows(driver, _SELECT_COUNTS, (model_id,), 3),
        scene_count=state.scene_count,
        context_count=state.context_count,
        state=dict(state.state),
        version=state.version,
    )


def save_checkpoint(session: Session, model_id: str, checkpoint: StoredCheckpoint) -> None:
    """Replace the model's checkpoint (in the caller's transaction: the scene's, or a repair's)."""
    lengths = np.diff(checkpoint.doc_offsets)
    blob = pack_arrays({"words": checkpoint.words, "contexts": checkpoint.contexts, "scene_lengths": lengths})
    session.execute(delete(IncrementalLdaCheckpoint).where(IncrementalLdaCheckpoint.model_id == model_id))
    session.execute(
        insert(IncrementalLdaCheckpoint).values(
            model_id=model_id,
            version=checkpoint.version,
            scene_count=checkpoint.scene_count,
            token_count=checkpoint.token_count,
            context_count=checkpoint.context_count,
            word_count=checkpoint.word_count,
            arrays=blob,
            created_at=utc_now(),
        )
    )


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
        words=words.astype(np.int32),
        contexts=contexts.astype(np.int32),
        doc_offsets=np.concatenate([[0], np.cumsum(lengths, dtype=np.int64)]).astype(np.int32),
    )


def assignment_counts(session: Session, model_id: str) -> dict[tuple[int, int], int]:
    """n_kw recomputed from the stored token assignments (the invariant's right-hand side)."""
    rows = session.execute(
        select(Token.context, Token.word_id, func.count())
        .where(Token.model_id == model_id)
        .group_by(Token.context, Token.word_id)
    ).all()
    return {(k, w): n for k, w, n in rows}


def stored_counts(session: Session, model_id: str) -> dict[tuple[int, int], int]:
    """The stored n_kw entries that are not zero."""
    rows = session.execute(
        select(ContextWordCount.context, ContextWordCount.word_id, ContextWordCount.count).where(
            ContextWordCount.model_id == model_id, ContextWordCount.count != 0
        )
    ).all()
    return {(k, w): n for k, w, n in rows}


# Versions: every committed write to a model bumps its version (docs/scaling.md).


def lock_version(session: Session, model_id: str) -> int | None:
    """The model's stored version, with the model locked for this transaction's writes (None: no
    such model). PostgreSQL locks the state row (``FOR UPDATE``, which waits for the lock and then
    reads the row's newest version); SQLite's write transactions already hold the database's write
    lock (``BEGIN IMMEDIATE``)."""
    driver = DriverStatements(session)
    statement = _SELECT_VERSION + (" FOR UPDATE" if driver.dialect.name == "postgresql" else "")
    row = driver.fetchone(statement, (model_id,))
    return None if row is None else int(row[0])


def stored_version(session: Session, model_id: str) -> int | None:
    """The model's stored version (one primary-key read), None when the model does not exist."""
    row = DriverStatements(session).fetchone(_SELECT_VERSION, (model_id,))
    return None if row is None else int(row[0])


def stored_versions(session: Session) -> dict[str, int]:
    """Every stored model's version, by id."""
    rows = session.execute(select(IncrementalLdaState.model_id, IncrementalLdaState.version)).all()
    return {model_id: int(version) for model_id, version in rows}


def set_version(session: Session, model_id: str, version: int) -> None:
    """Record a write that changed no corpus row (training objects, a fit, a repair)."""
    DriverStatements(session).execute(_SET_VERSION, (version, model_id))


_SELECT_VERSION = "SELECT version FROM incremental_lda_state WHERE model_id = ?"
_SET_VERSION = "UPDATE incremental_lda_state SET version = ? WHERE model_id = ?"


def load_changes(session: Session, model_id: str, *, since_version: int, word_count: int) -> StoredChanges | None:
    """The rows written after ``since_version`` (None when the model is gone); read them in one
    snapshot (:func:`storage.database.snapshot`) or under the model's write lock."""
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
    words = session.execute(
        select(Word.name, Word.kind).where(Word.model_id == model_id, Word.id >= word_count).order_by(Word.id)
    ).all()
    driver = DriverStatements(session)
    tokens = _int_rows(driver, _SELECT_TOKENS_SINCE, (model_id, since_version), 4)
    counts = _int_rows(driver, _SELECT_COUNTS_SINCE, (model_id, since_version), 3)
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
_SELECT_TOKENS = "SELECT scene_id, word_id, context FROM token WHERE model_id = ? ORDER BY id"
_SELECT_COUNTS = "SELECT context, word_id, count FROM context_word_count WHERE model_id = ?"
_SELECT_TOKENS_SINCE = "SELECT id, scene_id, word_id, context FROM token WHERE model_id = ? AND version > ? ORDER BY id"
_SELECT_COUNTS_SINCE = "SELECT context, word_id, count FROM context_word_count WHERE model_id = ? AND version > ?"


def _int_rows(driver: DriverStatements, statement: str, parameters: tuple[Any, ...], columns: int) -> np.ndarray:
    return np.array(driver.fetchall(statement, parameters), dtype=np.int64).reshape(-1, columns)
