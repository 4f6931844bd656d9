"""One transaction per request: commit on success, roll back on error, then the after-commit work.

Callbacks registered with :func:`after_commit` (stream events, in-memory
snapshots) run only once the transaction is durable, so nothing is announced
that could still be rolled back.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager

from sqlalchemy.exc import DBAPIError
from sqlalchemy.orm import Session, sessionmaker

_AFTER_COMMIT = "contextweb_after_commit"
_COMMIT_SENT = "contextweb_commit_sent"
_OUTCOME_UNKNOWN = "contextweb_commit_outcome_unknown"
_DEADLINE_PASSED = "contextweb_deadline_passed"


def after_commit(session: Session, callback: Callable[[], None]) -> None:
    """Run ``callback`` once ``session``'s transaction has committed (never if it rolls back)."""
    session.info.setdefault(_AFTER_COMMIT, []).append(callback)


def commit_sent(session: Session) -> None:
    """Mark ``session``'s ``COMMIT`` as on its way to the database: from here a lost connection
    leaves the transaction's outcome to the database, which may have committed it."""
    session.info[_COMMIT_SENT] = True


def commit_outcome_unknown(error: BaseException) -> bool:
    """Whether ``error`` lost its connection after the transaction's ``COMMIT`` was sent (marked by
    :func:`unit_of_work`): the database may have committed. Any other failure of a unit of work (one
    before the commit, an error the database answered, SQLite's full disk or I/O error, after which
    SQLite rolls back) left nothing stored."""
    return bool(getattr(error, _OUTCOME_UNKNOWN, False))


def deadline_passed(session: Session, deadline: str) -> None:
    """Mark ``session``'s connection as cut by its ``deadline`` ("the write deadline of 15 s";
    storage/deadlines.py)."""
    session.info[_DEADLINE_PASSED] = deadline


def deadline_that_passed(error: BaseException) -> str | None:
    """The deadline whose cut of the connection made ``error`` (marked by :func:`mark_failure`),
    or None: the database stopped answering."""
    return getattr(error, _DEADLINE_PASSED, None)


def mark_failure(session: Session, error: BaseException) -> None:
    """Mark on ``error``, when it lost ``session``'s connection, what :func:`commit_outcome_unknown`
    and :func:`deadline_that_passed` read: whether its ``COMMIT`` had been sent, and the deadline
    that cut it."""
    if isinstance(error, DBAPIError) and error.connection_invalidated:
        if session.info.get(_COMMIT_SENT):
            setattr(error, _OUTCOME_UNKNOWN, True)
        if _DEADLINE_PASSED in session.info:
            setattr(error, _DEADLINE_PASSED, session.info[_DEADLINE_PASSED])


@contextmanager
def unit_of_work(sessions: sessionmaker[Session]) -> Iterator[Session]:
    """A session committed when the block ends normally and rolled back when it raises."""
    with sessions() as session:
        try:
            yield session
            commit_sent(session)
            session.commit()
        except BaseException as error:
            mark_failure(session, error)
            session.rollback()
            raise
        for callback in session.info.pop(_AFTER_COMMIT, []):
            callback()
