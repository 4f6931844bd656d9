"""Check a model's stored Incremental-LDA state against its invariants, and rebuild what is derived.

The truth of a model is its ``scene`` rows, its ``token`` rows (word and context
assignment of every word occurrence), its ``word`` rows and the random state in
``incremental_lda_state.state``. What is derived from them can be rebuilt:
``context_word_count`` (n_kw, the token counts grouped by context and word),
``incremental_lda_state.scene_count`` and ``context_count``, and the model's
checkpoint (``incremental_lda_checkpoint``: every token's word and context at
one version, which must equal the token rows not written since that version).
:func:`check_model`
names every broken invariant; :func:`repair_model` rebuilds the derived rows
and bumps the model's version, so that serving processes reload it. A problem in
the truth itself (a gap in the token ids, a scene without tokens, a missing
state row, a bad random state …) cannot be repaired from the rows: then
:func:`repair_model` changes nothing and raises :class:`UnrepairableModelError`.

The checks are aggregate queries, except the checkpoint's: its arrays are
compared with the token rows' numbers, read once through the driver.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from sqlalchemy import (
    ColumnElement,
    CursorResult,
    Integer,
    Result,
    Row,
    delete,
    func,
    literal_column,
    select,
    text,
    union_all,
    update,
)
from sqlalchemy.orm import Session

from storage.database import DriverStatements
from storage.models import (
    ContextWordCount,
    IncrementalLdaCheckpoint,
    IncrementalLdaState,
    Model,
    Scene,
    Token,
    Word,
    utc_now,
)
from storage.repositories.incremental_lda import (
    DamagedCheckpointError,
    StoredCheckpoint,
    load_checkpoint,
    save_checkpoint,
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


def stored_models(session: Session) -> list[tuple[str, str]]:
    """(id, name) of every stored model, in creation order."""
    rows = session.execute(select(Model.id, Model.name).order_by(Model.created_at, Model.id)).all()
    return [(model_id, name) for model_id, name in rows]


def check_model(session: Session, model_id: str) -> list[str]:
    """Every problem of the stored model, one sentence each; empty when the model is sound."""
    return [problem.message for problem in find_problems(session, model_id)]


def find_problems(session: Session, model_id: str) -> list[Problem]:
    """Every problem of the stored model, each marked repairable or not."""
    model = session.execute(select(Model.hyperparameters).where(Model.id == model_id)).first()
    if model is None:
        return [Problem(f"model {model_id!r} is not stored", repairable=False)]
    state = _state_row(session, model_id)
    words = _id_range(session, Word.id, Word.model_id, model_id)
    scenes = _id_range(session, Scene.id, Scene.model_id, model_id)
    tokens = _id_range(session, Token.id, Token.model_id, model_id)
    problems = [
        *_dense_id_problems("word", "words", words),
        *_dense_id_problems("scene", "scenes", scenes),
        *_dense_id_problems("token", "tokens", tokens),
        *_token_problems(session, model_id, words.count),
        *_scene_problems(session, model_id),
        *_count_problems(session, model_id),
    ]
    if state is None:
        problems.append(Problem("incremental_lda_state has no row for the model", repairable=False))
    else:
        k_rule = model.hyperparameters.get("k_rule") if isinstance(model.hyperparameters, dict) else None
        max_contexts = k_rule.get("max_contexts") if isinstance(k_rule, dict) else None
        problems += _state_problems(session, model_id, state, scenes.count, words.count, max_contexts)
        problems += _checkpoint_problems(session, model_id, state.version)
    return problems


def repair_model(session: Session, model_id: str) -> list[str]:
    """Rebuild the model's derived rows from its scenes and token assignments, in the caller's transaction.

    Sets ``scene_count`` to the number of scene rows and ``context_count`` to at
    least the largest token context + 1, rewrites ``context_word_count`` from the
    token rows (a GROUP BY; entries no token backs any more stay as 0, rows naming
    a context or word that does not exist are deleted) and bumps the model's
    version by one: every count row carries the new version, so a process that
    catches up on the rows written since its version reads all of n_kw again.
    Returns what changed, one sentence each; an empty list when the model was
    sound (then nothing is written). Raises :class:`LookupError` for an unknown
    model and :class:`UnrepairableModelError`, before writing anything, when the
    truth itself is damaged.
    """
    if session.execute(select(Model.id).where(Model.id == model_id)).first() is None:
        raise LookupError(f"model {model_id!r} is not stored")
    state = _state_row(session, model_id, lock=True)  # the model's writers lock it too (PostgreSQL)
    problems = find_problems(session, model_id)
    unrepairable = [problem.message for problem in problems if not problem.repairable]
    if unrepairable:
        raise UnrepairableModelError(model_id, unrepairable)
    if not problems:
        return []
    assert state is not None  # a missing state row is unrepairable
    changes = []
    new_version = state.version + 1
    scene_count = _id_range(session, Scene.id, Scene.model_id, model_id).count
    largest_context = session.scalar(select(func.max(Token.context)).where(Token.model_id == model_id))
    context_count = max(state.context_count, 1 if largest_context is None else largest_context + 1, 1)
    word_count = _id_range(session, Word.id, Word.model_id, model_id).count
    changes += _rewrite_counts(session, model_id, new_version, context_count, word_count)
    moved_tokens = _rowcount(
        session.execute(
            update(Token).where(Token.model_id == model_id, Token.version > state.version).values(version=new_version)
        )
    )
    if moved_tokens:
        changes.append(f"token: {moved_tokens} rows carried a version above {state.version}, set to {new_version}")
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
            session, model_id, _checkpoint_of_tokens(session, model_id, new_version, context_count, word_count)
        )
        changes.append(f"incremental_lda_checkpoint: rebuilt from the token rows at version {new_version}")
    changes.append(f"incremental_lda_state.version: {state.version} -> {new_version}")
    return changes


def _rowcount(result: Result[*tuple[Any, ...]]) -> int:
    """The rows an UPDATE, DELETE or INSERT matched: ``Session.execute`` types every result as a Result."""
    assert isinstance(result, CursorResult)
    return result.rowcount


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
    session: Session, model_id: str, state: AnyRow, scene_count: int, word_count: int, max_contexts: Any
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
    problems += _context_range_problems(session, model_id, state.context_count, max_contexts)
    problems += _count_range_problems(session, model_id, state.context_count, word_count)
    problems += _version_problems(session, model_id, state.version)
    return problems


def _rng_state_problem(state: Any) -> str | None:
    if not isinstance(state, dict) or "rng_state" not in state:
        return "has no rng_state"
    try:
        np.random.PCG64().state = state["rng_state"]
    except (TypeError, ValueError, KeyError, OverflowError) as error:
        return f"rng_state is not a PCG64 generator state ({type(error).__name__}: {error})"
    return None


# The checkpoint.


def _checkpoint_problems(session: Session, model_id: str, version: int) -> list[Problem]:
    """The checkpoint against the token rows: every token it covers has its word, and its context
    unless the token row was written after the checkpoint's version (then it moved since)."""
    try:
        checkpoint = load_checkpoint(session, model_id)
    except DamagedCheckpointError as error:
        return [Problem(str(error), repairable=True)]
    if checkpoint is None:
        return []
    if checkpoint.version > version:
        return [
            Problem(
                f"incremental_lda_checkpoint is at version {checkpoint.version}, above the model's "
                f"(incremental_lda_state.version {version})",
                repairable=True,
            )
        ]
    rows = _token_columns(session, model_id, checkpoint.token_count)
    if rows.shape[0] != checkpoint.token_count or not np.array_equal(rows[:, 0], np.arange(rows.shape[0])):
        return [
            Problem(
                f"incremental_lda_checkpoint covers {checkpoint.token_count} tokens, but token ids "
                f"0..{checkpoint.token_count - 1} are not all stored",
                repairable=True,
            )
        ]
    scenes = np.repeat(np.arange(checkpoint.scene_count), np.diff(checkpoint.doc_offsets))
    problems = []
    for what, differs, stored, saved in (
        ("scene", rows[:, 1] != scenes, rows[:, 1], scenes),
        ("word", rows[:, 2] != checkpoint.words, rows[:, 2], checkpoint.words),
        (
            "context",
            (rows[:, 3] != checkpoint.contexts) & (rows[:, 4] <= checkpoint.version),
            rows[:, 3],
            checkpoint.contexts,
        ),
    ):
        if differs.any():
            first = int(np.flatnonzero(differs)[0])
            problems.append(
                Problem(
                    f"incremental_lda_checkpoint (version {checkpoint.version}) differs from the token rows in the "
                    f"{what} of {_count(int(differs.sum()), 'token')}, first token {first} "
                    f"(checkpoint {int(saved[first])}, token row {int(stored[first])})",
                    repairable=True,
                )
            )
    return problems


def _token_columns(session: Session, model_id: str, count: int) -> np.ndarray:
    """(id, scene, word, context, version) of the model's tokens with id < ``count``, by id (int64)."""
    rows = DriverStatements(session).fetchall(_SELECT_TOKEN_COLUMNS, (model_id, count))
    return np.array(rows, dtype=np.int64).reshape(-1, 5)


_SELECT_TOKEN_COLUMNS = (
    "SELECT id, scene_id, word_id, context, version FROM token WHERE model_id = ? AND id < ? ORDER BY id"
)


def _has_checkpoint(session: Session, model_id: str) -> bool:
    return (
        session.execute(
            select(IncrementalLdaCheckpoint.model_id).where(IncrementalLdaCheckpoint.model_id == model_id)
        ).first()
        is not None
    )


def _checkpoint_of_tokens(
    session: Session, model_id: str, version: int, context_count: int, word_count: int
) -> StoredCheckpoint:
    """The checkpoint of the model's token rows as they stand (the truth), at ``version``."""
    rows = _token_columns(session, model_id, np.iinfo(np.int32).max)
    scene_count = _id_range(session, Scene.id, Scene.model_id, model_id).count
    lengths = np.bincount(rows[:, 1], minlength=scene_count)
    return StoredCheckpoint(
        version=version,
        context_count=context_count,
        word_count=word_count,
        words=rows[:, 2].astype(np.int32),
        contexts=rows[:, 3].astype(np.int32),
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


# Tokens and scenes.


def _first_and_total(
    session: Session, columns: Sequence[Any], *conditions: Any, order_by: Sequence[Any]
) -> AnyRow | None:
    """The first row meeting ``conditions`` (in ``order_by``) with the number of such rows as its ``total``."""
    statement = select(*columns, func.count().over().label("total")).where(*conditions).order_by(*order_by).limit(1)
    return session.execute(statement).first()


def _token_problems(session: Session, model_id: str, word_count: int) -> list[Problem]:
    problems = []
    mine = Token.model_id == model_id
    columns = (Token.id, Token.scene_id, Token.word_id, Token.context)
    unknown_word = (Token.word_id < 0) | (Token.word_id >= word_count)
    bad_word = _first_and_total(session, columns, mine, unknown_word, order_by=(Token.id,))
    if bad_word:
        problems.append(
            Problem(
                f"{_tokens(bad_word.total)} a word id outside the {word_count} stored words, "
                f"first token {bad_word.id} (word {bad_word.word_id})",
                repairable=False,
            )
        )
    negative = _first_and_total(session, columns, mine, Token.context < 0, order_by=(Token.id,))
    if negative:
        problems.append(
            Problem(
                f"{_tokens(negative.total)} a negative context, first token {negative.id} (context {negative.context})",
                repairable=False,
            )
        )
    orphan = _orphan_token(session, model_id)
    if orphan:
        problems.append(
            Problem(
                f"{_tokens(orphan.total)} a scene id with no scene row, "
                f"first token {orphan.id} (scene {orphan.scene_id})",
                repairable=False,
            )
        )
    ordered = (
        select(Token.id, Token.scene_id, func.lag(Token.scene_id).over(order_by=(Token.id,)).label("previous_scene"))
        .where(mine)
        .subquery()
    )
    backwards = _first_and_total(
        session,
        (ordered.c.id, ordered.c.scene_id, ordered.c.previous_scene),
        ordered.c.previous_scene > ordered.c.scene_id,
        order_by=(ordered.c.id,),
    )
    if backwards:
        problems.append(
            Problem(
                f"token scene ids decrease at {_count(backwards.total, 'token')}, first token {backwards.id} "
                f"(scene {backwards.scene_id} after scene {backwards.previous_scene})",
                repairable=False,
            )
        )
    return problems


def _orphan_token(session: Session, model_id: str) -> AnyRow | None:
    statement = (
        select(Token.id, Token.scene_id, func.count().over().label("total"))
        .outerjoin(Scene, (Scene.model_id == Token.model_id) & (Scene.id == Token.scene_id))
        .where(Token.model_id == model_id, Scene.id.is_(None))
        .order_by(Token.id)
        .limit(1)
    )
    return session.execute(statement).first()


def _scene_problems(session: Session, model_id: str) -> list[Problem]:
    token_scenes = select(Token.scene_id).where(Token.model_id == model_id).distinct().subquery()
    statement = (
        select(Scene.id, func.count().over().label("total"))
        .outerjoin(token_scenes, token_scenes.c.scene_id == Scene.id)
        .where(Scene.model_id == model_id, token_scenes.c.scene_id.is_(None))
        .order_by(Scene.id)
        .limit(1)
    )
    empty = session.execute(statement).first()
    if empty is None:
        return []
    return [Problem(f"{_count(empty.total, 'scene')} without token rows, first scene {empty.id}", repairable=False)]


def _context_range_problems(session: Session, model_id: str, context_count: int, max_contexts: Any) -> list[Problem]:
    beyond = _first_and_total(
        session,
        (Token.id, Token.context),
        Token.model_id == model_id,
        Token.context >= context_count,
        order_by=(Token.id,),
    )
    if beyond is None:
        return []
    largest = session.scalar(select(func.max(Token.context)).where(Token.model_id == model_id))
    assert largest is not None  # ``beyond`` is a token of the model
    fits = not isinstance(max_contexts, int) or largest < max_contexts
    limit = "" if fits else f"; the largest, {largest}, is beyond the model's max_contexts {max_contexts}"
    return [
        Problem(
            f"{_tokens(beyond.total)} a context at or above incremental_lda_state.context_count {context_count}, "
            f"first token {beyond.id} (context {beyond.context}){limit}",
            repairable=fits,
        )
    ]


def _tokens(total: int) -> str:
    return "1 token has" if total == 1 else f"{total} tokens have"


def _count(total: int, noun: str) -> str:
    """``1 entry``, ``2 entries``, ``3 tokens``."""
    if total == 1:
        return f"1 {noun}"
    return f"{total} {noun[:-1]}ies" if noun.endswith("y") else f"{total} {noun}s"


# The n_kw entries.


def _count_problems(session: Session, model_id: str) -> list[Problem]:
    entry = _first_count_difference(session, model_id)
    if entry is None:
        return []
    return [
        Problem(
            f"context_word_count differs from the token assignments at {_count(entry.total, 'entry')}, "
            f"first (context {entry.context}, word {entry.word_id}): stored {int(entry.stored)}, "
            f"tokens {int(entry.assigned)}",
            repairable=True,
        )
    ]


def _first_count_difference(session: Session, model_id: str) -> AnyRow | None:
    """The first (context, word) whose stored count differs from its token count, with the number of such."""
    stored = select(
        ContextWordCount.context,
        ContextWordCount.word_id,
        ContextWordCount.count.label("stored"),
        literal_column("0", Integer).label("assigned"),
    ).where(ContextWordCount.model_id == model_id)
    assigned = (
        select(
            Token.context, Token.word_id, literal_column("0", Integer).label("stored"), func.count().label("assigned")
        )
        .where(Token.model_id == model_id)
        .group_by(Token.context, Token.word_id)
    )
    both = union_all(stored, assigned).subquery()
    differences = (
        select(
            both.c.context,
            both.c.word_id,
            func.sum(both.c.stored).label("stored"),
            func.sum(both.c.assigned).label("assigned"),
        )
        .group_by(both.c.context, both.c.word_id)
        .having(func.sum(both.c.stored) != func.sum(both.c.assigned))
        .subquery()
    )
    return session.execute(
        select(differences, func.count().over().label("total"))
        .order_by(differences.c.context, differences.c.word_id)
        .limit(1)
    ).first()


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
        ("token", (Token.id,), Token.model_id, Token.version),
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


def _rewrite_counts(session: Session, model_id: str, version: int, context_count: int, word_count: int) -> list[str]:
    """Set the model's n_kw entries to the token counts, every row stamped ``version``; what changed."""
    changes = []
    difference = _first_count_difference(session, model_id)
    outside = _count_row_outside(context_count, word_count)
    deleted = _rowcount(session.execute(delete(ContextWordCount).where(ContextWordCount.model_id == model_id, outside)))
    if deleted:
        changes.append(
            f"context_word_count: deleted {_count(deleted, 'row')} naming a context or word that does not exist "
            f"({context_count} contexts, {word_count} words)"
        )
    session.execute(
        update(ContextWordCount).where(ContextWordCount.model_id == model_id).values(count=0, version=version)
    )
    written = _rowcount(session.execute(_UPSERT_COUNTS_FROM_TOKENS, {"model_id": model_id, "version": version}))
    rewritten = f"context_word_count: rewrote {_count(written, 'entry')} from the token rows"
    if difference is not None:
        changes.append(
            f"{rewritten}; {_count(difference.total, 'entry')} differed, first (context {difference.context}, "
            f"word {difference.word_id}): stored {int(difference.stored)}, tokens {int(difference.assigned)}"
        )
    else:
        changes.append(rewritten)
    return changes


# Every (context, word) of the tokens with its count; entries without tokens were set to 0 before.
# The same SQL on SQLite and PostgreSQL (SQLite needs the WHERE before ON CONFLICT, which it has).
_UPSERT_COUNTS_FROM_TOKENS = text(
    "INSERT INTO context_word_count (model_id, context, word_id, count, version) "
    "SELECT model_id, context, word_id, count(*), :version FROM token WHERE model_id = :model_id "
    "GROUP BY model_id, context, word_id "
    "ON CONFLICT (model_id, context, word_id) DO UPDATE SET count = excluded.count, version = excluded.version"
)
