"""Turns at SQLite's one write lock, for the threads of a process and for the processes on a database.

SQLite has one write lock per database, and a writer that finds it taken waits in SQLite's busy
handler, which sleeps between tries (1, 2, 5, ... up to 100 ms): the lock then sits free while its
waiters sleep. Between the threads of a process a mutex hands the turn on at once. Between
processes an exclusive ``flock`` on a file beside the database (``<database>-turn``) does the same:
the kernel wakes the next waiter when the lock is released. Measured with 8 clients on 8 models
and two processes on one database (docs/benchmarks.md): tails of 0.65-0.76 s and no gain over one
process with the busy handler alone.

A ``flock`` cannot be waited for with a deadline, so a contended wait is handed to one waiter
thread per turn that blocks in ``flock`` while the writer waits on an event with the busy timeout;
a writer that gives up leaves the lock to be released by the waiter as soon as it gets it. (The
maintained file-lock packages, filelock and portalocker, wait by polling every 50 ms or so: the
sleeping this replaces.) Where the file cannot be opened (a read-only folder), or its ``flock``
fails (a filesystem without locks answers ENOLCK), the turn is the mutex alone and processes meet
at SQLite's lock, as before: a warning is logged once, and the write goes on rather than failing.
"""

from __future__ import annotations

import fcntl
import logging
import os
import queue
import sqlite3
import threading
import time
import weakref
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field

from sqlalchemy.exc import DBAPIError, StatementError

#: A waiter thread with no request for this long ends (a new one starts on the next contended wait).
WAITER_IDLE_SECONDS = 2.0

logger = logging.getLogger("contextweb")


class WriteTurn:
    """This process's turn to write one SQLite database: its mutex, then the database's turn file."""

    def __init__(self, database: str | None, timeout_seconds: float) -> None:
        self.timeout_seconds = timeout_seconds
        self.path = None if not database or database == ":memory:" else f"{database}-turn"
        self._mutex = threading.Lock()
        self._file: _TurnFile | None = None

    @contextmanager
    def held(self) -> Iterator[None]:
        """Hold the turn for a write transaction; past the busy timeout, SQLite's own busy error
        (a 503 ``storage_busy``), as a ``BEGIN IMMEDIATE`` that waited that long would raise."""
        deadline = time.monotonic() + self.timeout_seconds
        if not self._mutex.acquire(timeout=self.timeout_seconds):
            raise _busy("this process's other writes held it")
        try:
            turn_file = self._turn_file()
            if turn_file is not None:
                try:
                    if not turn_file.lock(deadline):
                        raise _busy("another process's writes held it")
                except OSError as error:
                    self._stop_using_file(error)
                    turn_file = None
            try:
                yield
            finally:
                if turn_file is not None:
                    try:
                        turn_file.unlock()
                    except OSError as error:  # the write is done: it must not fail for the turn's sake
                        self._stop_using_file(error)
        finally:
            self._mutex.release()

    def _stop_using_file(self, error: OSError) -> None:
        """From now on the turn is the mutex alone (under the mutex): the turn file's ``flock`` failed."""
        logger.warning(
            "SQLite write turns: flock on %s failed (%s); processes on this database now meet at SQLite's lock instead",
            self.path,
            error,
        )
        self.path, self._file = None, None

    def _turn_file(self) -> _TurnFile | None:
        """The open turn file (under the mutex), or None where it cannot be opened (tried again next time)."""
        if self._file is None and self.path is not None:
            try:
                descriptor = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            except OSError:
                return None
            self._file = _TurnFile(descriptor)
        return self._file


@dataclass
class _Request:
    """One contended wait, handed to the waiter thread."""

    granted: threading.Event = field(default_factory=threading.Event)
    abandoned: bool = False
    error: OSError | None = None
    """Why the waiter's ``flock`` failed, if it did (``granted`` is set then too)."""
    decided: threading.Lock = field(default_factory=threading.Lock)


class _TurnFile:
    """The exclusive ``flock`` on one open turn file, waited for with a deadline.

    Only the holder of the process's mutex calls :meth:`lock` and :meth:`unlock`. ``flock`` locks
    belong to the open file, not to a thread, so the waiter thread takes the lock for the writer.
    While a request is outstanding the writer never tries the lock itself: the waiter may be about
    to release it for an abandoned request, and a second ``flock`` on the same open file would
    succeed without waiting. The descriptor is closed when neither the turn nor a waiter needs it.
    """

    def __init__(self, descriptor: int) -> None:
        self.descriptor = descriptor
        self._requests: queue.SimpleQueue[_Request] = queue.SimpleQueue()
        self._state = threading.Lock()
        self._outstanding = 0
        self._waiter_running = False
        weakref.finalize(self, os.close, descriptor)

    def lock(self, deadline: float) -> bool:
        """True once this process holds the lock, False past ``deadline``; the ``flock``'s
        ``OSError`` if it failed otherwise than by being taken."""
        with self._state:
            if self._outstanding == 0:
                try:
                    fcntl.flock(self.descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
                    return True
                except BlockingIOError:
                    pass
            request = _Request()
            self._outstanding += 1
            self._requests.put(request)
            if not self._waiter_running:
                self._waiter_running = True
                threading.Thread(target=self._wait_for_turns, name="sqlite-write-turn", daemon=True).start()
        if not request.granted.wait(max(0.0, deadline - time.monotonic())):
            with request.decided:
                if not request.granted.is_set():
                    request.abandoned = True
                    return False
        if request.error is not None:
            raise request.error
        return True

    def unlock(self) -> None:
        fcntl.flock(self.descriptor, fcntl.LOCK_UN)

    def _wait_for_turns(self) -> None:
        """The waiter thread: takes the lock for each request in turn (blocking in the kernel, which
        wakes it when the holder releases); gives it back at once for a writer that gave up."""
        while True:
            try:
                request = self._requests.get(timeout=WAITER_IDLE_SECONDS)
            except queue.Empty:
                with self._state:
                    if self._outstanding == 0:
                        self._waiter_running = False
                        return
                continue
            try:
                fcntl.flock(self.descriptor, fcntl.LOCK_EX)
            except OSError as error:  # the writer raises it (WriteTurn then stops using the file)
                request.error = error
            with request.decided:
                if request.abandoned and request.error is None:
                    with suppress(OSError):  # not held, then: nothing to give back
                        fcntl.flock(self.descriptor, fcntl.LOCK_UN)
                else:
                    request.granted.set()
            with self._state:
                self._outstanding -= 1


def _busy(why: str) -> StatementError:
    busy = sqlite3.OperationalError(f"database is locked ({why})")
    busy.sqlite_errorcode = sqlite3.SQLITE_BUSY
    return DBAPIError.instance("BEGIN IMMEDIATE", (), busy, sqlite3.Error)
