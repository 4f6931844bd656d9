"""Whether the database can take a write now: what the readiness probe reports (docs/operations.md).

Two sources, because neither is enough alone. The writes of the requests say it
first: a storage failure marks the database failing until a later write
succeeds. A probe write (one row per process in ``storage_probe``) says it when
no request writes: ``/readyz`` runs one at most every :data:`PROBE_INTERVAL_SECONDS`,
and on every call while the database is failing, so readiness returns as soon
as the database does. A full disk can accept the probe's small write (SQLite
reuses the pages of its WAL file) and still refuse a scene's: so the probe's
success does not clear a failure that a request's write reported; only a
request's successful write does, or a probe after :data:`FAILURE_MEMORY_SECONDS`.
"""

from __future__ import annotations

import logging
import os
import socket
import threading
import time
from dataclasses import dataclass, field

logger = logging.getLogger("contextweb")

#: Seconds a successful probe answers for.
PROBE_INTERVAL_SECONDS = 2.0
#: Seconds a request's storage failure keeps the service not ready unless a write succeeds.
FAILURE_MEMORY_SECONDS = 5.0
#: Seconds after a write found the database unresponsive (a deadline or a connection time-out ran
#: out) during which writes answer 503 at once instead of each waiting out a time-out of its own.
UNRESPONSIVE_BACKOFF_SECONDS = 1.0


@dataclass(eq=False)
class StorageHealth:
    """The last known outcome of a write to the database, shared by the threads of one process."""

    process_id: str = field(default_factory=lambda: f"{socket.gethostname()}:{os.getpid()}"[:64])
    failure: str | None = None
    failed_at: float = 0.0
    probed_at: float = float("-inf")
    unresponsive_until: float = float("-inf")
    failing_since: float = 0.0
    """``time.monotonic()`` when the current failure began (for the log line of its end)."""
    failures: int = 0
    """Requests and probes that failed since then."""
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def record_success(self) -> None:
        if self.failure is not None:
            with self._lock:
                self._recovered()
                self.unresponsive_until = float("-inf")

    def record_failure(self, reason: str, *, unresponsive: bool = False) -> None:
        """A request's storage failure; ``unresponsive``: the database did not answer in time at all
        (its writes then fail fast for :data:`UNRESPONSIVE_BACKOFF_SECONDS`: :meth:`unresponsive`)."""
        with self._lock:
            self._failed(reason)
            if unresponsive:
                self.unresponsive_until = self.failed_at + UNRESPONSIVE_BACKOFF_SECONDS

    def _failed(self, reason: str) -> None:
        """Under the lock. The log says when the database starts failing and when it answers again,
        not every request's 503 (an outage under a fleet's load would be thousands of lines)."""
        now = time.monotonic()
        if self.failure is None:
            self.failing_since, self.failures = now, 0
            logger.warning("the database fails requests (%s): they answer 503 until it answers again", reason)
        self.failure, self.failed_at = reason, now
        self.failures += 1

    def _recovered(self) -> None:
        """Under the lock: the failure is over."""
        if self.failure is not None:
            logger.warning(
                "the database answers again after %.1f s; %d requests and probes failed meanwhile, the last with: %s",
                time.monotonic() - self.failing_since,
                self.failures,
                self.failure,
            )
        self.failure = None

    def unresponsive(self) -> str | None:
        """The failure of a write that found the database unresponsive a moment ago, or None.

        The writes queued behind one that waited out its deadline (or its connection's time-out)
        would each wait as long again, one after the other, on a database that is not answering:
        for a moment they answer 503 at once instead."""
        failure = self.failure
        return failure if failure is not None and time.monotonic() < self.unresponsive_until else None

    def probe_due(self) -> bool:
        return self.failure is not None or time.monotonic() - self.probed_at >= PROBE_INTERVAL_SECONDS

    def record_probe(self, failure: str | None) -> None:
        """A probe's outcome; a success clears only a failure old enough (see the module's docstring)."""
        with self._lock:
            self.probed_at = time.monotonic()
            if failure is not None:
                self._failed(failure)
            elif self.failure is not None and self.probed_at - self.failed_at >= FAILURE_MEMORY_SECONDS:
                self._recovered()
