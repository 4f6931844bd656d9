"""The Incremental-LDA state of a model, written scene by scene and read back whole on start.

:func:`save_scene` writes everything one learned scene changed — its tokens,
the tokens its sweeps reassigned, the n_kw entries that moved, new words and
the scalar state — in the caller's transaction (the scene's own). The
per-row statements go to the driver's executemany (see ``_executemany``).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from sqlalchemy import Connection, bindparam, func, insert, select, update
from sqlalchemy.orm import Session

from storage.models import ContextWordCount, IncrementalLdaState, Token, Word


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


@dataclass(frozen=True)
class SceneChanges:
    """What one learned scene changed in the stored corpus (all indices are the model's own)."""

    scene_id: int
    first_token: int
    token_words: Sequence[int]
    token_contexts: Sequence[int]
    reassigned: Sequence[tuple[int, int]]
    counts: Sequence[tuple[int, int, int]]
    new_words: Sequence[tuple[int, str, str | None]]
    context_count: int
    state: dict[str, Any]


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
    connection = session.connection()
    first, scene = changes.first_token, changes.scene_id
    tokens = zip(changes.token_words, changes.token_contexts, strict=True)
    _executemany(connection, _INSERT_TOKEN, [(model_id, first + i, scene, w, k) for i, (w, k) in enumerate(tokens)])
    _executemany(connection, _UPDATE_TOKEN, [(k, model_id, token) for token, k in changes.reassigned])
    _executemany(connection, _UPSERT_COUNT, [(model_id, k, w, n) for k, w, n in changes.counts])
    connection.execute(
        _UPDATE_STATE,
        {
            "state_model_id": model_id,
            "new_scene_count": changes.scene_id + 1,
            "new_context_count": changes.context_count,
            "new_state": changes.state,
        },
    )


# The statements of every scene. The three per-row ones are in the SQL that SQLite and
# PostgreSQL share, run through the driver's executemany: built by SQLAlchemy they cost
# more per row (parameter processing for ~100 rows a scene) than the database takes to
# store them; ``?`` stands for the driver's placeholder. The state update is built once
# (SQLAlchemy then reuses its compiled form) and keeps SQLAlchemy's JSON and
# ``updated_at`` handling; all go through the one connection of the transaction.
_INSERT_TOKEN = "INSERT INTO token (model_id, id, scene_id, word_id, context) VALUES (?, ?, ?, ?, ?)"
_UPDATE_TOKEN = "UPDATE token SET context = ? WHERE model_id = ? AND id = ?"
_UPSERT_COUNT = (
    "INSERT INTO context_word_count (model_id, context, word_id, count) VALUES (?, ?, ?, ?) "
    "ON CONFLICT (model_id, context, word_id) DO UPDATE SET count = excluded.count"
)
_STATE_TABLE = IncrementalLdaState.__table__
_UPDATE_STATE = (
    update(_STATE_TABLE)
    .where(_STATE_TABLE.c.model_id == bindparam("state_model_id"))
    .values(
        scene_count=bindparam("new_scene_count"),
        context_count=bindparam("new_context_count"),
        state=bindparam("new_state"),
    )
)


def _executemany(connection: Connection, statement: str, rows: Sequence[tuple[object, ...]]) -> None:
    if not rows:
        return
    if connection.dialect.paramstyle != "qmark":
        statement = statement.replace("?", "%s")
    connection.exec_driver_sql(statement, list(rows))


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
    tokens = np.array(
        session.execute(
            select(Token.scene_id, Token.word_id, Token.context).where(Token.model_id == model_id).order_by(Token.id)
        ).all(),
        dtype=np.int64,
    ).reshape(-1, 3)
    counts = np.array(
        session.execute(
            select(ContextWordCount.context, ContextWordCount.word_id, ContextWordCount.count).where(
                ContextWordCount.model_id == model_id
            )
        ).all(),
        dtype=np.int64,
    ).reshape(-1, 3)
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
