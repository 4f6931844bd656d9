"""Deadlines on PostgreSQL transactions: a database that stops answering ends the request.

A PostgreSQL server that freezes but keeps its connections (its processes stopped, a stalled VM
or storage) leaves every write already sent waiting as long as the freeze: the kernel still
acknowledges the packets, so neither ``tcp_user_timeout`` nor the keepalives fire, and a server
side time-out (``statement_timeout``) cannot run in a frozen server. libpq has no client-side
time-out for an answer on an open connection, and psycopg's synchronous calls cannot be
interrupted from another thread (``cancel()`` asks the frozen server itself).

So one watchdog thread per process cuts the connection of a transaction that has run past its
deadline (a write's, ``CONTEXTWEB_WRITE_DEADLINE_SECONDS``; a request's version check, 5 s):
``shutdown(2)`` of its socket. The thread blocked in libpq then fails at once with
"server closed the connection unexpectedly", which is a lost connection like any other
(storage/unit_of_work.py): the pool drops the connection, and the write is a 503 that says whether
its ``COMMIT`` had been sent. The server, once it runs again, reads the end of the stream and rolls
back what it had not committed. A ``COMMIT`` that it had already received may still commit: the
503 says so, and a keyed retry gets the stored answer.

A deadline measures the database, not this process: when the process itself does not run for a
while (stopped, its machine paused), the watchdog wakes late by as much, and every armed deadline
moves by that stall (``_postpone``) instead of cutting, at once, writes whose answer may be waiting
in their sockets.

The socket is ``dup``-ed when the deadline is armed, so the watchdog cuts that connection's socket
even if the connection is closed meanwhile and its descriptor number reused; the copy is closed
when the transaction ends. Written here because no maintained library offers a deadline on a
blocking libpq call (psycopg's own time-outs are the connection's, or the server's).
"""

from __future__ import annotations

import logging
import os
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, replace

logger = logging.getLogger("contextweb")


#: While a deadline is armed the watchdog looks at least this often (seconds), so that it notices a
#: stall of its process within a tick of its end.
TICK_SECONDS = 0.25
#: A wake-up later than this (seconds) is a stall of the process, not the scheduler's jitter (a thread
#: waits for the GIL a switch interval, 5 ms, at a time), and is not counted against any deadline.
STALL_SECONDS = 1.0


@dataclass(frozen=True)
class _Armed:
    deadline: float
    socket_copy: int
    on_expiry: Callable[[], None]


class SocketDeadlines:
    """Deadlines on sockets: each one armed and not disarmed in time is shut down, after its
    ``on_expiry`` has run (on the watchdog thread, which starts with the first deadline)."""

    def __init__(self) -> None:
        self._condition = threading.Condition()
        self._armed: dict[int, _Armed] = {}
        self._next_token = 0
        self._wakes_at = float("inf")  # when the watchdog looks next, unless notified
        self._thread: threading.Thread | None = None

    def arm(self, fileno: int, seconds: float, on_expiry: Callable[[], None]) -> int:
        """Shut down the socket ``fileno`` in ``seconds`` unless :meth:`disarm` comes first; a token for that."""
        armed = _Armed(time.monotonic() + seconds, os.dup(fileno), on_expiry)
        with self._condition:
            token = self._next_token
            self._next_token += 1
            self._armed[token] = armed
            if self._thread is None or not self._thread.is_alive():
                self._thread = threading.Thread(target=self._watch, name="contextweb-deadlines", daemon=True)
                self._thread.start()
            elif armed.deadline < self._wakes_at:  # the common case, a later deadline, wakes nobody
                self._condition.notify()
        return token

    def disarm(self, token: int) -> None:
        """The socket's work is done in time (or has failed): forget its deadline. Once this returns,
        the socket is never cut for it (a cut in progress ends first: both hold the lock)."""
        with self._condition:
            armed = self._armed.pop(token, None)
        if armed is not None:
            os.close(armed.socket_copy)

    def _watch(self) -> None:
        with self._condition:
            while True:
                now = time.monotonic()
                stalled = now - self._wakes_at
                if stalled > STALL_SECONDS and self._armed:
                    self._postpone(stalled)
                for token in [token for token, armed in self._armed.items() if armed.deadline <= now]:
                    # Under the lock, so that a connection whose transaction has just ended (and which
                    # may be handed to the next one) is not cut: shutdown(2) does not block.
                    self._cut(self._armed.pop(token))
                next_deadline = min((armed.deadline for armed in self._armed.values()), default=float("inf"))
                self._wakes_at = min(next_deadline, now + TICK_SECONDS) if self._armed else float("inf")
                self._condition.wait(None if self._wakes_at == float("inf") else self._wakes_at - now)

    def _postpone(self, stalled: float) -> None:
        """The watchdog woke ``stalled`` seconds late: this process did not run (stopped, its machine
        paused). Every armed deadline moves by that much, so that a deadline counts the time the
        database had to answer while this process could hear it, not a stall of its own: cut at once,
        a write the database had answered (or that this process had not even sent) came back 503
        "the database did not answer within the write deadline" (a drill: a replica stopped for 15 s,
        2026-12-07)."""
        logger.warning(
            "this process did not run for %.1f s (stopped, or its machine paused): %d database deadline(s) "
            "moved by that much",
            stalled,
            len(self._armed),
        )
        self._armed = {token: replace(armed, deadline=armed.deadline + stalled) for token, armed in self._armed.items()}

    @staticmethod
    def _cut(armed: _Armed) -> None:
        try:
            armed.on_expiry()
        except Exception:  # the cut must happen whatever the callback does
            logger.exception("a deadline's callback failed")
        cut = socket.socket(fileno=armed.socket_copy)
        try:
            cut.shutdown(socket.SHUT_RDWR)
        except OSError as error:  # already closed by the peer: the write fails, or has, on its own
            logger.debug("cutting a connection past its deadline: %s", error)
        finally:
            cut.close()


#: The process's watchdog (one thread for every engine's deadlines).
DEADLINES = SocketDeadlines()
