"""An even spread of keep-alive connections over ``contextweb serve --workers N`` (docs/scaling.md).

Each worker listens on its own socket, bound to the server's port with ``SO_REUSEPORT``
(:class:`WorkerListener`): the kernel gives a new connection to one of the workers' sockets by a hash
of the connection's addresses, so which worker gets it does not depend on which one is awake. (With
uvicorn's one shared socket, the worker that reached ``accept`` first took it: under CPU contention
the worker awake after the request just before, so a client bounced off a busy worker could land on
it again and again: a fresh clone's ``make test`` failed ``test_worker_connections`` so, a close in
each of 40 rounds.)

A fleet's robots keep their connections open for hours, so a chance spread of 2/6 or 1/7 lasts, and
the busier worker's one scene thread then bounds the fleet while the other idles (bench_scaling, 8
clients on 8 models, ``--workers 2``, PostgreSQL, one scene thread: 4/4 384.6, 392.2 and 380.7
scenes/s, 3/5 317.5 and 323.4; with 4 scene threads 1/7 247.3).

So each worker also counts its open connections in a small file that every worker of one server maps
(:class:`ConnectionCounts`, one slot per worker, named after the supervising process). A worker
that accepts a connection while it holds more than its share (⌈open connections / workers⌉) answers
that connection's first request with ``Connection: close``: the client opens a new connection (every
HTTP client does so by itself, as it does after a keep-alive time-out), which lands on a worker drawn
by its new source port's hash. Each such round moves the spread towards even; a connection within
its worker's share is never closed. Nothing is shared but counts, and a stale or torn count costs at
most one extra reconnection or one missed one: the slots are plain memory, written by their worker
only, read by the others.

With one worker, uvicorn's own socket runs unchanged (``serve`` uses these only with N > 1).

Every worker's protocol, one worker's included, also puts a deadline on a request's line and headers
(:class:`HeaderDeadlineProtocol`): uvicorn times out neither a connection that sends nothing nor one
whose headers stall (a "slowloris" client), so each would hold a connection, a file descriptor and
its buffers for good (seen: 31 such connections still open after 65 s).
"""

from __future__ import annotations

import asyncio
import fcntl
import math
import mmap
import os
import select
import socket
import struct
import sys
import tempfile
from http import HTTPStatus
from pathlib import Path
from typing import Any, ClassVar, TypeVar

import httptools
from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

from app.errors import BadHttpRequest, ContextwebError, ErrorRead, HeadersTimeout

SocketT = TypeVar("SocketT", bound=socket.socket)

_SLOT = struct.Struct("=qq")
"""A worker's slot: its process id (0: free) and its open connections."""


def counts_path(supervisor_pid: int) -> Path:
    """The counts file of the server whose supervising process is ``supervisor_pid``."""
    folder = Path("/dev/shm") if Path("/dev/shm").is_dir() else Path(tempfile.gettempdir())
    return folder / f"contextweb-connections-{supervisor_pid}"


def create_counts(supervisor_pid: int, workers: int) -> Path:
    """The empty counts file of a server of ``workers`` workers (the supervisor makes it before they start)."""
    path = counts_path(supervisor_pid)
    path.write_bytes(bytes(_SLOT.size * workers))
    return path


class ConnectionCounts:
    """This worker's view of every worker's open connections, in the file :func:`create_counts` made."""

    def __init__(self, path: Path) -> None:
        with path.open("r+b") as handle:
            fcntl.flock(handle, fcntl.LOCK_EX)  # two workers starting at once claim two slots
            try:
                self._memory = mmap.mmap(handle.fileno(), 0)
                self._workers = len(self._memory) // _SLOT.size
                self._slot = self._claim(os.getpid())
            finally:
                fcntl.flock(handle, fcntl.LOCK_UN)
        self.open = 0

    def _claim(self, pid: int) -> int:
        """A free slot, or that of a worker that has exited (uvicorn replaces a dead worker)."""
        for slot in range(self._workers):
            owner, _ = _SLOT.unpack_from(self._memory, slot * _SLOT.size)
            if owner == 0 or not _alive(owner):
                _SLOT.pack_into(self._memory, slot * _SLOT.size, pid, 0)
                return slot
        raise RuntimeError(f"no free slot among {self._workers} workers' connection counts")

    def opened(self) -> bool:
        """Count a new connection; True if this worker now holds more than its share of them."""
        self.open += 1
        self._write()
        total = 0
        for slot in range(self._workers):
            owner, count = _SLOT.unpack_from(self._memory, slot * _SLOT.size)
            if owner != 0:
                total += max(0, count)
        # The share is over every worker of the server, not those that have claimed a slot: a worker
        # claims its slot on its first connection, so one that never got any would not count, and
        # the others would keep a 1/7 spread as even (a fresh clone's make test, 2026-12-06).
        return self.open > math.ceil(total / self._workers)

    def closed(self) -> None:
        self.open -= 1
        self._write()

    def _write(self) -> None:
        _SLOT.pack_into(self._memory, self._slot * _SLOT.size, os.getpid(), self.open)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, another user's
        pass
    return True


_counts: ConnectionCounts | None = None
"""This worker's counts, opened on its first connection (None until then, or without a counts file)."""


def _worker_counts() -> ConnectionCounts | None:
    global _counts  # one per worker process, shared by its connections
    if _counts is None:
        path = counts_path(os.getppid())
        if path.exists():
            _counts = ConnectionCounts(path)
    return _counts


class HeaderDeadlineProtocol(HttpToolsProtocol):
    """uvicorn's httptools protocol with a deadline on each request's line and headers.

    The clock starts when the connection opens and when a request's first byte arrives (on a
    keep-alive connection; between requests uvicorn's own keep-alive time-out closes an idle one)
    and stops when the headers are complete: the body has its own deadline (app/middleware.py).
    Past it the client gets a 408 ``request_timeout`` in the documented error shape and the
    connection is closed, as nginx's ``client_header_timeout`` would.

    Bytes that the parser refuses get a 400 ``bad_request`` in the same shape, quoting the parser,
    instead of uvicorn's plain-text "Invalid HTTP request received." (the connection is closed, as
    uvicorn does)."""

    read_timeout_seconds: ClassVar[float] = 10.0
    """``CONTEXTWEB_HEADER_READ_TIMEOUT_SECONDS``, set in each serving process (:func:`set_header_read_timeout`)."""

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._header_deadline: asyncio.TimerHandle | None = None
        self._arm_header_deadline()

    def connection_lost(self, exc: Exception | None) -> None:
        self._disarm_header_deadline()
        super().connection_lost(exc)

    def on_message_begin(self) -> None:
        super().on_message_begin()
        if self._header_deadline is None:
            self._arm_header_deadline()

    def on_headers_complete(self) -> None:
        self._disarm_header_deadline()
        super().on_headers_complete()

    def timeout_keep_alive_handler(self) -> None:
        """uvicorn's (close an idle kept-alive connection), unless the next request is already in
        its socket: after a stall of this process (stopped, its machine paused) the keep-alive timer
        and that request are due together, and the event loop runs the timer first, which reset a
        request the client had sent. ``data_received`` comes next and unsets the keep-alive."""
        if not self._readable():
            super().timeout_keep_alive_handler()

    def _readable(self) -> bool:
        """Whether the connection's socket holds bytes to read (or the peer's end), without reading them."""
        sock = self.transport.get_extra_info("socket")
        if sock is None:
            return False
        poller = select.poll()  # not select.select: no limit on the descriptor's number
        try:
            poller.register(sock.fileno(), select.POLLIN)
            return bool(poller.poll(0))
        except (OSError, ValueError):  # closed meanwhile
            return False

    def _arm_header_deadline(self) -> None:
        self._header_deadline = self.loop.call_later(self.read_timeout_seconds, self._header_deadline_passed)

    def _disarm_header_deadline(self) -> None:
        if self._header_deadline is not None:
            self._header_deadline.cancel()
            self._header_deadline = None

    def _header_deadline_passed(self) -> None:
        self._header_deadline = None
        if self.transport.is_closing():
            return
        self._answer_and_close(HeadersTimeout(self.read_timeout_seconds))

    def send_400_response(self, msg: str) -> None:
        # uvicorn calls this while it handles httptools' HttpParserError, whose message says what was wrong.
        refused = sys.exc_info()[1]
        self._answer_and_close(BadHttpRequest(str(refused) if isinstance(refused, httptools.HttpParserError) else msg))

    def _answer_and_close(self, error: ContextwebError) -> None:
        """``error`` in the documented shape, before any route ran; the connection is closed after it."""
        body = ErrorRead(error=error.error, detail=error.message, field=error.field).model_dump_json().encode()
        head = [b"HTTP/1.1 %d %s\r\n" % (error.status_code, HTTPStatus(error.status_code).phrase.encode())]
        head += [name + b": " + value + b"\r\n" for name, value in self.server_state.default_headers]
        head.append(b"content-type: application/json\r\nconnection: close\r\ncontent-length: %d\r\n\r\n" % len(body))
        self.transport.write(b"".join(head) + body)
        self.transport.close()


def set_header_read_timeout(seconds: float) -> None:
    """The header deadline of this process's connections (:class:`HeaderDeadlineProtocol`); the
    serving app sets it from its settings before the process accepts a connection."""
    HeaderDeadlineProtocol.read_timeout_seconds = seconds


class BalancedHttpToolsProtocol(HeaderDeadlineProtocol):
    """uvicorn's httptools protocol, counting this worker's connections (:class:`ConnectionCounts`)
    and closing one accepted beyond the worker's share after its first response."""

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        counts = _worker_counts()
        self._counted = counts is not None
        self._over_share = counts.opened() if counts is not None else False

    def connection_lost(self, exc: Exception | None) -> None:
        self._uncount()
        super().connection_lost(exc)

    def on_headers_complete(self) -> None:
        super().on_headers_complete()
        if self._over_share and self.cycle is not None:
            self._over_share = False
            self.cycle.keep_alive = False  # the response says "connection: close", then the transport closes
            self._uncount()  # no longer this worker's: the client's next connection is counted instead

    def _uncount(self) -> None:
        if self._counted and _counts is not None:
            _counts.closed()
            self._counted = False


class WorkerListener(socket.socket):
    """The server's listening address, bound with ``SO_REUSEPORT``, that becomes a socket of its own
    in each worker it is passed to.

    uvicorn's supervisor passes its sockets to every worker it spawns, by pickling. This one pickles as
    its address, and unpickles, in the worker, as a new socket bound to that address with
    ``SO_REUSEPORT``: so each worker, first or restarted, listens on its own socket of the port's group,
    and the kernel spreads new connections over them by their addresses' hash. The supervisor's socket
    holds the port (bound, never listening, so the kernel gives it no connection) and makes a port in
    use fail at start-up, before any worker starts.

    What this trades (docs/scaling.md): connections waiting in a worker's own queue when that worker
    dies are reset, where a shared queue would have kept them for the other workers; and a new
    connection hashed to a busy worker waits for it, where the idle worker would have taken it.
    """

    @classmethod
    def bind_to(cls, host: str, port: int) -> WorkerListener:
        """Bound to ``host:port`` (port 0: one the kernel picks, which every worker then shares).

        A plain socket is bound there first and closed: ``SO_REUSEPORT`` would let a second server
        (of the same user) join this one's port and take half its connections, where a plain bind
        fails while any socket holds the port (``OSError``, ``EADDRINUSE``)."""
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        with socket.socket(family, socket.SOCK_STREAM, socket.IPPROTO_TCP) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            probe.bind((host, port))
            address = probe.getsockname()
        return _bound(cls, family, address)

    def __reduce__(self) -> tuple[Any, tuple[Any, ...]]:
        return _bound, (socket.socket, self.family, self.getsockname())


def _bound(kind: type[SocketT], family: int, address: tuple[Any, ...]) -> SocketT:
    """A TCP socket of ``kind`` bound to ``address`` in its port's ``SO_REUSEPORT`` group."""
    bound = kind(family, socket.SOCK_STREAM, socket.IPPROTO_TCP)
    try:
        bound.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        bound.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
        bound.bind(address)
    except OSError:
        bound.close()
        raise
    return bound
