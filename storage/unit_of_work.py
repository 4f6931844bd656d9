"""One transaction per request: commit on success, roll back on error, then the after-commit work.

Callbacks registered with :func:`after_commit` (stream events, in-memory
snapshots) run only once the transaction is durable, so nothing is announced
that could still be rolled back.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager

from sqlalchemy.orm import Session, sessionmaker

_AFTER_COMMIT = "contextweb_after_commit"


def after_commit(session: Session, callback: Callable[[], None]) -> None:
    """Run ``callback`` once ``session``'s transaction has committed (never if it rolls back)."""
    session.info.setdefault(_AFTER_COMMIT, []).append(callback)


@contextmanager
def unit_of_work(sessions: sessionmaker[Session]) -> Iterator[Session]:
    """A session committed when the block ends normally and rolled back when it raises."""
    with sessions() as session:
        try:
            yield session
            session.commit()
        except BaseException:
            session.rollback()
            raise
        for callback in session.info.pop(_AFTER_COMMIT, []):
            callback()
