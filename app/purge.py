"""Purging deleted models a chunk at a time, on a thread of its own (alembic 0012).

``DELETE /v1/models/{id}`` only marks the model deleted (``storage.repositories.models.delete_model``):
every process sees it gone at once, and the delete costs a few rows whatever the model's size. Its
rows are then deleted here, ``PURGE_CHUNK_ROWS`` scenes or token batches per transaction. Why not
in the delete's transaction: on SQLite a transaction that writes holds the database's one write lock,
every model's, and one that deleted a million-scene model held it 5.6 s, past the 5 s busy timeout of
every other write (docs/scaling.md). A chunk holds it for milliseconds, and the purger rests after
each chunk as long as the chunk took, so that it never has more than half of the lock's time.

Nothing is lost if the process stops mid-purge: each chunk is a transaction, the model stays marked,
and the next start of any process on the database purges what is left, as does any running process's
purger within ``RESCAN_SECONDS``. Two processes purging one
model at once each delete chunks of what is still there. A chunk that fails (the database is down,
busy, or full) is retried after ``RETRY_SECONDS``.
"""

from __future__ import annotations

import logging
import threading
import time

from sqlalchemy.orm import Session, sessionmaker

from storage.database import write_turn
from storage.repositories import models as model_repository
from storage.unit_of_work import unit_of_work

#: Scenes or token batches deleted per transaction: a median 22 ms of SQLite's write lock (5,000: 57 ms;
#: docs/scaling.md, "Deleting a model").
PURGE_CHUNK_ROWS = 2_000
#: The wait before a chunk that failed is tried again.
RETRY_SECONDS = 1.0
#: How often an idle purger looks for models marked deleted that nobody is purging.
RESCAN_SECONDS = 60.0

logger = logging.getLogger("contextweb")


class ModelPurger:
    """One thread that purges the deleted models it is given or finds, oldest first, a chunk per transaction."""

    def __init__(self, write_sessions: sessionmaker[Session]) -> None:
        self._write_sessions = write_sessions
        self._read_sessions: sessionmaker[Session] | None = None
        self._stopping = threading.Event()
        self._queued: list[str] = []
        """The models to purge, in order; the first stays listed while it is purged."""
        self._changed = threading.Condition()
        self._thread: threading.Thread | None = None

    def start(self, read_sessions: sessionmaker[Session]) -> None:
        """Start the thread, with the models a stopped process left marked (a start resumes their purge)."""
        self._read_sessions = read_sessions
        self._find_marked()
        self._thread = threading.Thread(target=self._run, name="contextweb-model-purge", daemon=True)
        self._thread.start()

    def purge(self, model_id: str) -> None:
        """Purge ``model_id``, which a committed delete marked, after the models given before it."""
        with self._changed:
            if model_id not in self._queued:
                self._queued.append(model_id)
                self._changed.notify_all()

    def stop(self, timeout_seconds: float = 5.0) -> None:
        """Stop after the chunk in progress; what is left is purged by the next start."""
        self._stopping.set()
        with self._changed:
            self._changed.notify_all()
        if self._thread is not None:
            self._thread.join(timeout_seconds)

    def wait_idle(self, timeout_seconds: float) -> bool:
        """Whether every model given or found so far was purged within ``timeout_seconds`` (tests)."""
        with self._changed:
            return self._changed.wait_for(lambda: not self._queued, timeout_seconds)

    def _find_marked(self) -> None:
        """Queue every model marked deleted: those a stopped process left, or whose deleting process
        stopped before it purged them (found within ``RESCAN_SECONDS`` by any process's purger)."""
        assert self._read_sessions is not None
        try:
            with self._read_sessions() as session:
                marked = model_repository.deleted_models(session)
        except Exception as error:  # noqa: BLE001 - the database is down: the next scan finds them
            logger.warning("looking for deleted models to purge failed (%s); trying again later", error)
            return
        for model_id in marked:
            self.purge(model_id)

    def _run(self) -> None:
        next_scan = time.monotonic() + RESCAN_SECONDS
        while True:
            with self._changed:
                self._changed.wait_for(
                    lambda: self._queued or self._stopping.is_set(), max(0.0, next_scan - time.monotonic())
                )
                if self._stopping.is_set():
                    return
                model_id = self._queued[0] if self._queued else None
            if model_id is None:  # idle until the scan was due
                self._find_marked()
                next_scan = time.monotonic() + RESCAN_SECONDS
                continue
            self._purge(model_id)
            with self._changed:
                self._queued.remove(model_id)
                self._changed.notify_all()

    def _purge(self, model_id: str) -> None:
        started, removed = time.monotonic(), 0
        while not self._stopping.is_set():
            chunk_started = time.monotonic()
            try:
                with write_turn(self._write_sessions), unit_of_work(self._write_sessions) as session:
                    deleted = model_repository.purge_chunk(session, model_id, PURGE_CHUNK_ROWS)
            except Exception as error:  # noqa: BLE001 - a blip: the model stays marked and is tried again
                logger.warning("model %s: purging its rows failed (%s); retrying", model_id, error)
                self._stopping.wait(RETRY_SECONDS)
                continue
            if deleted == 0:
                logger.info(
                    "model %s purged: %d scenes and token batches in %.1f s",
                    model_id,
                    removed,
                    time.monotonic() - started,
                )
                return
            removed += deleted
            self._stopping.wait(time.monotonic() - chunk_started)  # at most half of the write lock's time
