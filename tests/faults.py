"""Real faults for the end-to-end tests, and the clients and checks that go with them.

The recipes are those of the shared notes ("Causing faults for real on these
machines"); each one is undone in a ``finally``, whatever the test does:

- :func:`postgres_outage`: one PostgreSQL database refuses connections and loses
  every open one (``ALTER DATABASE … ALLOW_CONNECTIONS false`` and
  ``pg_terminate_backend``), then is allowed again. The PostgreSQL server itself
  is never stopped: other tests share it. :func:`fresh_postgres_database` creates
  (and drops) a migrated database of the test's own.
- :func:`small_tmpfs`, :func:`fill_disk`, :func:`free_disk`: a full disk under a
  SQLite file; :func:`sqlite_checkpoint` empties the WAL first, so that the next
  write needs new space at once instead of reusing the WAL's old frames.
- :func:`immutable`: ``chattr +i`` on a SQLite file and its ``-wal`` (the ``-shm``
  only on request: see there): every write through the server's open descriptors
  fails with EPERM (an I/O error for SQLite). Only on file systems that check the
  flag on open files (ext4 does; tmpfs does not), which the helper verifies first.
- :class:`TcpProxy`: a partition between one server process and PostgreSQL.

:class:`KeyedClient` is a robot: it posts scenes with Idempotency-Keys and
retries 503s and transport errors with the same key and body until a deadline,
recording every status it saw. :func:`model_invariants` checks what must hold
after any fault.
"""

from __future__ import annotations

import errno
import itertools
import os
import select
import shutil
import signal
import socket
import sqlite3
import subprocess
import threading
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Self, TypeVar

import httpx
import pytest
from sqlalchemy import Engine, create_engine, func, text
from sqlalchemy import select as sql_select
from sqlalchemy.orm import Session

from storage.database import create_database_engine, create_session_makers
from storage.migrations import upgrade_to_head
from storage.models import Scene
from storage.repositories import incremental_lda as lda_repository
from tests.conftest import POSTGRES_SERVER_URL

T = TypeVar("T")

# --------------------------------------------------------------------------- PostgreSQL


def postgres_admin_engine() -> Engine:
    """An autocommit engine on the server's ``postgres`` database (for CREATE/ALTER/DROP DATABASE).
    Its pooled connections are pinged before use: the clean-up must still drop the database after
    a restart of the PostgreSQL server (tried by hand with ``pg_ctlcluster … restart``)."""
    return create_engine(
        f"{POSTGRES_SERVER_URL}/postgres",
        isolation_level="AUTOCOMMIT",
        pool_pre_ping=True,
        connect_args={"connect_timeout": 3},
    )


@contextmanager
def fresh_postgres_database(prefix: str = "contextweb_fault") -> Iterator[str]:
    """A new, migrated database ``<prefix>_<pid>_<random>`` for one test, dropped (FORCE) afterwards.

    Skips the test when no PostgreSQL answers on the configured server.
    """
    name = f"{prefix}_{os.getpid()}_{uuid.uuid4().hex[:6]}"
    admin = postgres_admin_engine()
    try:
        with admin.connect() as connection:
            connection.execute(text(f'CREATE DATABASE "{name}"'))
    except Exception as error:  # noqa: BLE001 - no server: skip
        admin.dispose()
        pytest.skip(f"PostgreSQL not reachable at {POSTGRES_SERVER_URL} ({type(error).__name__})")
    url = f"{POSTGRES_SERVER_URL}/{name}"
    try:
        engine = create_database_engine(url)
        upgrade_to_head(engine)
        engine.dispose()
        yield url
    finally:
        try:
            with admin.connect() as connection:
                connection.execute(text(f'ALTER DATABASE "{name}" ALLOW_CONNECTIONS true'))
                connection.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
        finally:
            admin.dispose()


def database_name(url: str) -> str:
    """The database part of a SQLAlchemy URL."""
    from sqlalchemy.engine import make_url

    name = make_url(url).database
    assert name, url
    return name


def terminate_connections(admin: Engine, name: str) -> int:
    """End every backend connected to database ``name`` (not our own); how many were ended."""
    with admin.connect() as connection:
        return len(
            connection.execute(
                text(
                    "SELECT pg_terminate_backend(pid) FROM pg_stat_activity "
                    "WHERE datname = :name AND pid <> pg_backend_pid()"
                ),
                {"name": name},
            ).all()
        )


@contextmanager
def connections_refused(name: str) -> Iterator[None]:
    """Database ``name`` refuses new connections inside the block; open ones are left alone.
    Allowed again in ``finally``, whatever happened."""
    admin = postgres_admin_engine()
    try:
        with admin.connect() as connection:
            connection.execute(text(f'ALTER DATABASE "{name}" ALLOW_CONNECTIONS false'))
        try:
            yield
        finally:
            with admin.connect() as connection:
                connection.execute(text(f'ALTER DATABASE "{name}" ALLOW_CONNECTIONS true'))
    finally:
        admin.dispose()


@contextmanager
def postgres_outage(name: str) -> Iterator[None]:
    """Database ``name`` is unreachable inside the block: no new connection, every open one ended.

    Connections are allowed again in ``finally``, whatever happened.
    """
    with connections_refused(name):
        admin = postgres_admin_engine()
        try:
            terminate_connections(admin, name)
            time.sleep(0.05)
            terminate_connections(admin, name)  # a connection that was being set up at the ALTER
        finally:
            admin.dispose()
        yield


def postgres_outage_for(name: str, seconds: float) -> None:
    """An outage of database ``name`` lasting ``seconds``."""
    with postgres_outage(name):
        time.sleep(seconds)


def libpq_url(url: str) -> str:
    """The SQLAlchemy URL ``url`` as psycopg's own ``connect`` takes it."""
    return url.replace("postgresql+psycopg://", "postgresql://")


_SLOW_COMMIT = """
CREATE OR REPLACE FUNCTION slow_commit() RETURNS trigger LANGUAGE plpgsql AS $$
BEGIN PERFORM pg_sleep({seconds}); RETURN NULL; END $$;
CREATE CONSTRAINT TRIGGER slow_commit AFTER INSERT ON {table} DEFERRABLE INITIALLY DEFERRED
FOR EACH ROW EXECUTE FUNCTION slow_commit();
"""


@contextmanager
def slow_commits(url: str, table: str, seconds: float) -> Iterator[None]:
    """Inside the block, every ``COMMIT`` that inserted into ``table`` of database ``url`` is held for
    ``seconds`` by a deferred constraint trigger (its backend waits with ``wait_event = 'PgSleep'``);
    the trigger is dropped in ``finally``."""
    import psycopg

    with psycopg.connect(libpq_url(url), autocommit=True) as admin:
        admin.execute(_SLOW_COMMIT.format(table=table, seconds=seconds))
    try:
        yield
    finally:
        with psycopg.connect(libpq_url(url), autocommit=True) as admin:
            admin.execute(f"DROP TRIGGER slow_commit ON {table}")


def backend_when(url: str, condition: str, seconds: float = 20.0) -> tuple[int, str]:
    """The pid and query of the backend of database ``url`` matching ``condition`` (SQL on
    ``pg_stat_activity``), once one does, polled every 20 ms for up to ``seconds``."""
    admin = postgres_admin_engine()
    deadline = time.monotonic() + seconds
    try:
        with admin.connect() as connection:
            while time.monotonic() < deadline:
                row = connection.execute(
                    text(f"SELECT pid, query FROM pg_stat_activity WHERE datname = :name AND {condition}"),
                    {"name": database_name(url)},
                ).first()
                if row is not None:
                    return int(row.pid), str(row.query)
                time.sleep(0.02)
    finally:
        admin.dispose()
    raise AssertionError(f"no backend of the test database came to: {condition}")


def database_backends(url: str) -> list[int]:
    """The pids of every backend connected to database ``url`` now."""
    admin = postgres_admin_engine()
    try:
        with admin.connect() as connection:
            rows = connection.execute(
                text("SELECT pid FROM pg_stat_activity WHERE datname = :name AND pid <> pg_backend_pid()"),
                {"name": database_name(url)},
            ).all()
    finally:
        admin.dispose()
    return [int(row.pid) for row in rows]


def end_backend(pid: int) -> None:
    """``pg_terminate_backend(pid)``: the backend's client finds its connection lost."""
    admin = postgres_admin_engine()
    try:
        with admin.connect() as connection:
            connection.execute(text("SELECT pg_terminate_backend(:pid)"), {"pid": pid})
    finally:
        admin.dispose()


@contextmanager
def frozen_backends(pids: Sequence[int]) -> Iterator[None]:
    """The PostgreSQL backends ``pids`` stopped (SIGSTOP) inside the block, as in a stalled VM: their
    connections stay open and the kernel still acknowledges what their clients send, but nothing is
    answered. Continued (SIGCONT) in ``finally``, whatever happened."""
    stopped: list[int] = []
    try:
        for pid in pids:
            os.kill(pid, signal.SIGSTOP)
            stopped.append(pid)
        yield
    finally:
        for pid in stopped:
            os.kill(pid, signal.SIGCONT)


def at_once(calls: Sequence[Callable[[], T]]) -> list[T]:
    """The calls on threads of their own, released together (a barrier); their results in order."""
    start = threading.Barrier(len(calls))

    def run(call: Callable[[], T]) -> T:
        start.wait()
        return call()

    with ThreadPoolExecutor(len(calls)) as pool:
        return list(pool.map(run, calls))


def model_with_keyed_posts(
    base_url: str, bodies: Sequence[dict[str, Any]], *, name: str, posted: int
) -> tuple[str, list[KeyedPost]]:
    """A new model (``FAST_HYPERPARAMETERS``) and one :class:`KeyedPost` per body, keys ``k0``, ``k1``
    …, of which the first ``posted`` are posted once each (each must be a 201)."""
    from tests.conftest import FAST_HYPERPARAMETERS

    model_id = create_model(base_url, FAST_HYPERPARAMETERS, name=name)
    posts = [KeyedPost(key=f"k{index}", body=body) for index, body in enumerate(bodies)]
    with httpx.Client(base_url=base_url, timeout=30) as client:
        for post in posts[:posted]:
            answer = post_keyed_once(client, model_id, post)
            assert answer.status_code == 201, answer.text
    return model_id, posts


@contextmanager
def holding_model_row(url: str, model_id: str) -> Iterator[Any]:
    """An outside transaction holding the model's state row (``FOR UPDATE``), which every write to
    the model waits for; the open psycopg connection (commit it to let them through)."""
    import psycopg

    with psycopg.connect(libpq_url(url)) as outside:
        outside.execute("SELECT 1 FROM incremental_lda_state WHERE model_id = %s FOR UPDATE", (model_id,))
        yield outside


@dataclass(frozen=True)
class Timing:
    """When a request started and when its answer came (``time.monotonic()``)."""

    started: float
    ended: float

    @property
    def seconds(self) -> float:
        return self.ended - self.started


def answer_while(
    base_url: str, request: Callable[[httpx.Client], httpx.Response], fault: Callable[[], T]
) -> tuple[httpx.Response, T, Timing]:
    """``request`` on a thread while ``fault()`` runs here: the answer, what ``fault`` returned,
    and when the request started and was answered."""
    answers: list[tuple[httpx.Response, Timing]] = []

    def run() -> None:
        with httpx.Client(base_url=base_url, timeout=60) as client:
            started = time.monotonic()
            answer = request(client)
            answers.append((answer, Timing(started, time.monotonic())))

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    returned = fault()
    thread.join(60)
    assert answers, "the request got no answer"
    return answers[0][0], returned, answers[0][1]


# --------------------------------------------------------------------------- disks


@contextmanager
def small_tmpfs(path: Path, size_mb: int) -> Iterator[Path]:
    """A tmpfs of ``size_mb`` MiB mounted on ``path`` (created), unmounted in ``finally``.

    Skips the test when mounting is not permitted (not root, no CAP_SYS_ADMIN, no ``mount``).
    Processes using files on it must be stopped before the block ends; if one still
    holds a file the mount is detached lazily (``umount -l``).
    """
    path.mkdir(parents=True, exist_ok=True)
    if shutil.which("mount") is None:
        pytest.skip("no mount command: cannot make a small file system for the full-disk test")
    mounted = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={size_mb}m,mode=0755", "tmpfs", str(path)],
        capture_output=True,
        text=True,
        check=False,
    )
    if mounted.returncode != 0:
        reason = mounted.stderr.strip() or f"exit {mounted.returncode}"
        pytest.skip(f"cannot mount a tmpfs here ({reason}): full-disk test skipped")
    try:
        yield path
    finally:
        if subprocess.run(["umount", str(path)], capture_output=True, check=False).returncode != 0:
            subprocess.run(["umount", "-l", str(path)], capture_output=True, check=False)


FILLER_NAME = "zz-filler"


def fill_disk(directory: Path) -> int:
    """Fill ``directory``'s file system to the last byte with a filler file; how many bytes it took."""
    filler = directory / FILLER_NAME
    written = 0
    with filler.open("ab", buffering=0) as handle:
        for chunk_size in (1 << 20, 1 << 16, 1 << 12, 512, 1):
            chunk = b"\0" * chunk_size
            while True:
                try:
                    written += handle.write(chunk) or 0
                except OSError as error:
                    if error.errno not in (errno.ENOSPC, errno.EDQUOT):
                        raise
                    break
    return written


def free_disk(directory: Path) -> None:
    """Delete the filler of :func:`fill_disk` (nothing if there is none)."""
    (directory / FILLER_NAME).unlink(missing_ok=True)


def sqlite_checkpoint(database: Path) -> tuple[int, int, int]:
    """``PRAGMA wal_checkpoint(TRUNCATE)`` from outside the server: the WAL emptied to 0 bytes.

    Done just before :func:`fill_disk`, so that the server's next commits need new
    space (a WAL keeps its size after a checkpoint and reuses it).
    """
    connection = sqlite3.connect(database, timeout=10)
    try:
        return tuple(connection.execute("PRAGMA wal_checkpoint(TRUNCATE)").fetchone())  # type: ignore[return-value]
    finally:
        connection.close()


def sqlite_files(database: Path) -> list[Path]:
    """The database file and its ``-wal`` and ``-shm`` files that exist."""
    return [p for p in (database, Path(f"{database}-wal"), Path(f"{database}-shm")) if p.exists()]


def _chattr(flag: str, paths: Sequence[Path]) -> None:
    subprocess.run(["chattr", flag, *map(str, paths)], check=True, capture_output=True)


def _immutable_flag_blocks_open_files(directory: Path) -> str | None:
    """None when ``chattr +i`` stops writes through an already open descriptor here, else why not."""
    probe = directory / f".immutable-probe-{uuid.uuid4().hex[:6]}"
    descriptor = os.open(probe, os.O_RDWR | os.O_CREAT, 0o600)
    try:
        os.write(descriptor, b"probe")
        try:
            _chattr("+i", [probe])
        except subprocess.CalledProcessError as error:
            return f"chattr +i failed: {error.stderr.decode(errors='replace').strip()}"
        try:
            os.pwrite(descriptor, b"x", 0)
            return "this file system lets an open descriptor write to an immutable file (tmpfs does)"
        except PermissionError:
            return None
        finally:
            _chattr("-i", [probe])
    finally:
        os.close(descriptor)
        probe.unlink(missing_ok=True)


@contextmanager
def immutable(database: Path, *, include_shm: bool = False) -> Iterator[list[Path]]:
    """``chattr +i`` on the SQLite file and its ``-wal`` inside the block, ``-i`` in ``finally``.

    Every ``write``/``ftruncate`` through the server's open descriptors then fails
    with EPERM (SQLITE_IOERR), and a connection opened meanwhile cannot open the
    files for writing. The ``-shm`` is left alone unless ``include_shm``: SQLite
    writes it through a shared ``mmap``, and once the kernel has write-protected a
    page for writeback, the next store to an immutable file's page is a SIGBUS that
    kills the server outright (seen here: exit -7 every time), which no process can
    handle and no disk error of the WAL or database file causes.

    Skips the test when ``chattr`` is missing or the file system does not enforce
    the flag on open files (the server's descriptors are open long before).
    """
    if shutil.which("chattr") is None:
        pytest.skip("no chattr here: the I/O-error test needs it")
    reason = _immutable_flag_blocks_open_files(database.parent)
    if reason is not None:
        pytest.skip(f"chattr +i cannot cause write errors here: {reason}")
    files = [path for path in sqlite_files(database) if include_shm or not str(path).endswith("-shm")]
    _chattr("+i", files)
    try:
        yield files
    finally:
        _chattr("-i", files)


# --------------------------------------------------------------------------- network


class TcpProxy:
    """A threaded TCP proxy on ``127.0.0.1:<free port>`` to ``target``; :meth:`cut` partitions it.

    A server process whose ``CONTEXTWEB_DATABASE_URL`` names the proxy's port reaches
    PostgreSQL only through it, so :meth:`cut` separates that one process from the
    database while every other process keeps its direct connections.

    :meth:`cut` closes every open connection (both sides: the server sees its
    PostgreSQL connections drop) and, for new ones, either *blackholes* them (the
    default: TCP connects to the proxy, then nothing ever answers, as when a
    network drops packets: only the client's own timeouts end the wait) or
    *refuses* them (accepted and closed at once). :meth:`restore` ends the
    blackholed connections and forwards again. :meth:`freeze` is a frozen server
    instead (a stalled VM): open connections stay open but nothing is relayed, what
    the server process sends waits in the buffers (the kernel acknowledges it), and
    new connections are blackholed; :meth:`restore` relays again, buffered bytes first.

    Written here with sockets and threads rather than with Toxiproxy: Toxiproxy is
    a Go server binary, which no registry this machine reaches packages (PyPI has
    only clients of it: ``toxiproxy-python``, ``chaostoolkit-toxiproxy``; Debian has
    no ``toxiproxy`` package), and no maintained pure-Python fault proxy is in the
    package lists. A network namespace cuts a real link (tests/netns.py), which shows
    what this proxy cannot (a backend whose last answer went unacknowledged: the
    proxy's kernel acknowledges everything); there this class is also the relay that
    stands in for PostgreSQL on the link (``listen_host``, ``like_postgres``).
    """

    def __init__(
        self,
        target_port: int = 5432,
        target_host: str = "127.0.0.1",
        *,
        listen_host: str = "127.0.0.1",
        listen_port: int = 0,
        like_postgres: bool = False,
    ) -> None:
        """``like_postgres``: the accepted connections get the keepalive and ``TCP_USER_TIMEOUT``
        settings the service asks of PostgreSQL's side of every connection
        (``storage.database.POSTGRES_SESSION_OPTIONS``), so that a relay standing in for PostgreSQL
        on a real link (tests/netns.py) notices a vanished client as PostgreSQL would, and ends its
        session by closing the upstream connection."""
        self.target = (target_host, target_port)
        self.listen_host = listen_host
        self._like_postgres = like_postgres
        self._listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._listener.bind((listen_host, listen_port))
        self._listener.listen(128)
        self._listener.settimeout(0.2)
        self.port = int(self._listener.getsockname()[1])
        self._lock = threading.Lock()
        self._pairs: set[tuple[socket.socket, socket.socket]] = set()
        self._held: set[socket.socket] = set()
        self._mode = "forward"  # forward | blackhole | refuse | freeze
        self._closed = threading.Event()
        self.accepted = 0
        self.forwarded = 0
        self._thread = threading.Thread(target=self._accept_loop, name=f"tcp-proxy-{self.port}", daemon=True)
        self._thread.start()

    # -- control
    @property
    def mode(self) -> str:
        return self._mode

    def cut(self, new: str = "blackhole") -> int:
        """Partition: close every open connection, then ``new`` (``"blackhole"`` or ``"refuse"``) new ones.

        Returns how many connections were closed."""
        assert new in ("blackhole", "refuse"), new
        with self._lock:
            self._mode = new
            pairs = list(self._pairs)
            self._pairs.clear()
        for client, upstream in pairs:
            _close(client)
            _close(upstream)
        return len(pairs)

    def freeze(self) -> None:
        """Relay nothing on the open connections (they stay open) and blackhole new ones."""
        with self._lock:
            self._mode = "freeze"

    def restore(self) -> None:
        """Forward again; the connections held by a blackhole are closed (their clients retry)."""
        with self._lock:
            self._mode = "forward"
            held = list(self._held)
            self._held.clear()
        for sock in held:
            _close(sock)

    def close(self) -> None:
        self._closed.set()
        self.cut("refuse")
        self.restore()
        self._thread.join(timeout=5)
        _close(self._listener)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def url_for(self, postgres_url: str) -> str:
        """``postgres_url`` with its host and port replaced by the proxy's."""
        from sqlalchemy.engine import make_url

        return make_url(postgres_url).set(host=self.listen_host, port=self.port).render_as_string(hide_password=False)

    # -- the threads
    def _accept_loop(self) -> None:
        while not self._closed.is_set():
            try:
                client, _ = self._listener.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            self.accepted += 1
            if self._like_postgres:
                _postgres_socket_options(client)
            mode = self._mode
            if mode == "refuse":
                _close(client)
            elif mode in ("blackhole", "freeze"):
                with self._lock:
                    self._held.add(client)
                threading.Thread(target=self._swallow, args=(client,), daemon=True).start()
            else:
                threading.Thread(target=self._connect, args=(client,), daemon=True).start()

    def _connect(self, client: socket.socket) -> None:
        try:
            upstream = socket.create_connection(self.target, timeout=5)
        except OSError:
            _close(client)
            return
        upstream.settimeout(None)
        pair = (client, upstream)
        with self._lock:
            if self._mode != "forward":  # cut while connecting
                _close(client)
                _close(upstream)
                return
            self._pairs.add(pair)
        self.forwarded += 1
        self._pump(pair)

    def _pump(self, pair: tuple[socket.socket, socket.socket]) -> None:
        """Both directions in one thread with select, until either side closes or the pair is cut."""
        client, upstream = pair
        peers = {client: upstream, upstream: client}
        try:
            while True:
                with self._lock:
                    if pair not in self._pairs:
                        return
                    frozen = self._mode == "freeze"
                if frozen:
                    time.sleep(0.05)
                    continue
                readable, _, _ = select.select([client, upstream], [], [], 0.2)
                for sock in readable:
                    data = sock.recv(65536)
                    if not data:
                        return
                    peers[sock].sendall(data)
        except (OSError, ValueError):
            return
        finally:
            with self._lock:
                self._pairs.discard(pair)
            _close(client)
            _close(upstream)

    def _swallow(self, client: socket.socket) -> None:
        """A blackholed connection: read and drop whatever comes, answer nothing, until restored."""
        try:
            while True:
                with self._lock:
                    if client not in self._held:
                        return
                readable, _, _ = select.select([client], [], [], 0.2)
                if readable and not client.recv(65536):
                    return
        except (OSError, ValueError):
            return
        finally:
            with self._lock:
                self._held.discard(client)
            _close(client)


def _postgres_socket_options(sock: socket.socket) -> None:
    """PostgreSQL's side of a connection as the service configures it (``tcp_keepalives_idle=5``,
    ``_interval=2``, ``_count=2``, ``tcp_user_timeout=5000``: storage/database.py)."""
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_KEEPIDLE, 5)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_KEEPINTVL, 2)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_KEEPCNT, 2)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_USER_TIMEOUT, 5_000)


def _close(sock: socket.socket) -> None:
    try:
        sock.shutdown(socket.SHUT_RDWR)
    except OSError:
        pass
    try:
        sock.close()
    except OSError:
        pass


# --------------------------------------------------------------------------- clients

#: The 503s of the contract (docs/api.md): the database cannot take a write, the model is being
#: reloaded, or a write waited out the database's lock timeout behind another (a frozen or slow peer
#: process): each with Retry-After, each retried by the clients.
RETRYABLE_ERRORS = frozenset({"storage_unavailable", "model_unavailable", "storage_busy"})


@dataclass
class KeyedPost:
    """One scene a client posted under one Idempotency-Key, with every attempt's outcome."""

    key: str
    body: dict[str, Any]
    statuses: list[int | str] = field(default_factory=list)
    """Each attempt: the HTTP status, or ``"transport:<error>"``."""
    durations: list[float] = field(default_factory=list)
    """Each attempt's duration in seconds (parallel to :attr:`statuses`)."""
    started: list[float] = field(default_factory=list)
    """Each attempt's ``time.monotonic()`` at its start."""
    final_status: int | None = None
    answer: dict[str, Any] | None = None
    answer_text: str | None = None
    replayed: bool = False
    server: str = ""

    @property
    def acknowledged(self) -> bool:
        return self.final_status == 201


def post_keyed_once(client: httpx.Client, model_id: str, post: KeyedPost) -> httpx.Response:
    """One attempt of ``post`` (no retry), its outcome recorded on it."""
    response = client.post(f"/v1/models/{model_id}/scenes", json=post.body, headers={"Idempotency-Key": post.key})
    post.statuses.append(response.status_code)
    post.final_status = response.status_code
    if response.status_code == 201:
        post.answer, post.answer_text = response.json(), response.text
        post.replayed = response.headers.get("idempotent-replayed") == "true"
    return response


#: The pace of the time-bounded fault tests' robots: 25 scenes a second each at the most, a few
#: hundred across a fault, where each robot took as many as the server answered (200-400 a second
#: for four: the suite's largest CPU use).
FAULT_PACE = 0.04


@dataclass
class KeyedClient:
    """A robot: posts ``bodies`` in order, each under its own Idempotency-Key, retrying until a deadline.

    503s and transport errors are retried with the same key and body (exponential
    backoff from ``backoff[0]`` to ``backoff[1]`` s, or ``Retry-After`` if shorter);
    any other status ends that scene. Every answer that breaks the contract is
    recorded in :attr:`problems` (a 503 that is not the JSON error with
    ``Retry-After``, a keep-alive connection dropped after a 503, a replay without
    ``Idempotent-Replayed: true``…). Run it with :meth:`start`/:meth:`join`.
    """

    base_url: str
    model_id: str
    bodies: Sequence[dict[str, Any]]
    key_prefix: str
    deadline: float
    """``time.monotonic()`` after which no new attempt starts (a scene still being retried is left
    unfinished: ``final_status`` None)."""
    request_timeout: float = 20.0
    backoff: tuple[float, float] = (0.05, 1.0)
    pace: float = 0.0
    """Seconds at least between the first attempts of two scenes (0: as fast as the server answers).
    A fault test needs traffic across its fault, not all the traffic the machine can make: the
    suite's time is CPU time on 2 cores (:data:`FAULT_PACE`)."""
    posts: list[KeyedPost] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)
    error: BaseException | None = None
    first_503_at: float | None = None
    _thread: threading.Thread | None = None
    _stop: threading.Event = field(default_factory=threading.Event)

    def stop_posting(self) -> None:
        """No new scene after the current one (which is still retried until it is answered or the deadline)."""
        self._stop.set()

    def start(self) -> KeyedClient:
        self._thread = threading.Thread(target=self._run_safely, name=f"client-{self.key_prefix}", daemon=True)
        self._thread.start()
        return self

    def join(self, timeout: float) -> None:
        assert self._thread is not None
        self._thread.join(timeout)
        if self._thread.is_alive():
            self.problems.append(f"client {self.key_prefix} still running {timeout:.0f} s after it was joined")

    @property
    def alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def _run_safely(self) -> None:
        try:
            self.run()
        except BaseException as error:  # noqa: BLE001 - reported by the test
            self.error = error
            self.problems.append(f"client {self.key_prefix} crashed: {error!r}")

    def run(self) -> None:
        next_start = time.monotonic()
        with httpx.Client(base_url=self.base_url, timeout=self.request_timeout) as client:
            for index, body in enumerate(self.bodies):
                self._stop.wait(max(0.0, next_start - time.monotonic()))
                if self._stop.is_set() or time.monotonic() >= self.deadline:
                    return
                next_start = time.monotonic() + self.pace
                post = KeyedPost(key=f"{self.key_prefix}-{index}", body=body, server=self.base_url)
                self.posts.append(post)
                self._post(client, post)

    def _post(self, client: httpx.Client, post: KeyedPost) -> None:
        delay = self.backoff[0]
        after_503_port: int | None = None
        path = f"/v1/models/{self.model_id}/scenes"
        while time.monotonic() < self.deadline:
            started = time.monotonic()
            post.started.append(started)
            try:
                response = client.post(path, json=post.body, headers={"Idempotency-Key": post.key})
            except httpx.TransportError as error:
                post.durations.append(time.monotonic() - started)
                post.statuses.append(f"transport:{type(error).__name__}")
                after_503_port = None
                time.sleep(delay)
                delay = min(delay * 2, self.backoff[1])
                continue
            post.durations.append(time.monotonic() - started)
            post.statuses.append(response.status_code)
            port = _local_port(response)
            if after_503_port is not None and port is not None and port != after_503_port:
                self.problems.append(
                    f"{post.key}: the keep-alive connection was not reused after a 503 "
                    f"(local port {after_503_port} then {port})"
                )
            after_503_port = None
            if response.status_code == 503:
                if self.first_503_at is None:
                    self.first_503_at = time.monotonic()
                retry_after = self._check_503(post.key, response)
                if response.headers.get("connection", "").lower() == "close":
                    self.problems.append(f"{post.key}: a 503 closed the keep-alive connection (Connection: close)")
                else:
                    after_503_port = port
                time.sleep(min(delay, retry_after) if retry_after is not None else delay)
                delay = min(delay * 2, self.backoff[1])
                continue
            post.final_status = response.status_code
            if response.status_code == 201:
                post.answer_text = response.text
                post.answer = response.json()
                post.replayed = response.headers.get("idempotent-replayed", "").lower() == "true"
            else:
                self.problems.append(f"{post.key}: status {response.status_code}: {response.text[:300]}")
            return

    def _check_503(self, key: str, response: httpx.Response) -> float | None:
        """The 503's Retry-After in seconds; a problem recorded when the 503 is not the contract's."""
        return check_503(key, response, self.problems)


def check_503(what: str, response: httpx.Response, problems: list[str]) -> float | None:
    """A 503's Retry-After in seconds; a problem added to ``problems`` when the 503 is not the
    contract's (the JSON error of a retryable storage or model failure, with Retry-After)."""
    retry_after = response.headers.get("retry-after")
    if retry_after is None:
        problems.append(f"{what}: 503 without Retry-After: {response.text[:200]}")
    try:
        body = response.json()
    except ValueError:
        problems.append(f"{what}: 503 without a JSON body: {response.text[:200]!r}")
        body = {}
    if not (
        isinstance(body, dict)
        and body.get("error") in RETRYABLE_ERRORS
        and isinstance(body.get("detail"), str)
        and "field" in body
        and body["field"] is None
    ):
        problems.append(f"{what}: 503 body is not one of {sorted(RETRYABLE_ERRORS)}: {response.text[:200]}")
    try:
        return float(retry_after) if retry_after is not None else None
    except ValueError:
        problems.append(f"{what}: Retry-After is not a number of seconds: {retry_after!r}")
        return None


@dataclass
class Reader:
    """An operator's dashboard: reads a model over and over (the model, its contexts, a page of its
    scenes) until stopped, on one keep-alive connection. Every answer must be a 200 or the
    contract's 503 (:func:`check_503`); anything else, a transport error included, is a problem."""

    base_url: str
    model_id: str
    statuses: list[int | str] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)
    _thread: threading.Thread | None = None
    _stop: threading.Event = field(default_factory=threading.Event)

    def start(self) -> Reader:
        self._thread = threading.Thread(target=self._run, name="reader", daemon=True)
        self._thread.start()
        return self

    def stop(self, join_seconds: float) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(join_seconds)
            if self._thread.is_alive():
                self.problems.append(f"the reader still ran {join_seconds:.0f} s after it was stopped")

    def _run(self) -> None:
        paths = [f"/v1/models/{self.model_id}{suffix}" for suffix in ("", "/contexts", "/scenes?limit=5")]
        with httpx.Client(base_url=self.base_url, timeout=20.0) as client:
            for path in itertools.cycle(paths):
                if self._stop.is_set():
                    return
                try:
                    response = client.get(path)
                except httpx.TransportError as error:
                    self.statuses.append(f"transport:{type(error).__name__}")
                    self.problems.append(f"GET {path}: {type(error).__name__}: {error}")
                    continue
                self.statuses.append(response.status_code)
                if response.status_code == 503:
                    check_503(f"GET {path}", response, self.problems)
                    time.sleep(0.05)
                elif response.status_code != 200:
                    self.problems.append(f"GET {path}: status {response.status_code}: {response.text[:300]}")


def _local_port(response: httpx.Response) -> int | None:
    """The client-side port of the connection that carried ``response`` (None when httpx does not say)."""
    stream = response.extensions.get("network_stream")
    if stream is None:
        return None
    try:
        address = stream.get_extra_info("client_addr")
    except Exception:  # noqa: BLE001 - an httpcore detail; without it the check is skipped
        return None
    return int(address[1]) if address else None


def run_clients(clients: Sequence[KeyedClient], join_seconds: float) -> None:
    """Start every client, then join each (at most ``join_seconds`` in all)."""
    for client in clients:
        client.start()
    wait_clients(clients, join_seconds)


def stop_clients(clients: Sequence[KeyedClient], join_seconds: float) -> None:
    """Ask every client to post no new scene, then join them (at most ``join_seconds`` in all)."""
    for client in clients:
        client.stop_posting()
    wait_clients(clients, join_seconds)


def unfinished(clients: Sequence[KeyedClient]) -> list[str]:
    """The keys still unanswered (deadline passed while retrying), with their statuses."""
    return [f"{post.key}: {post.statuses}" for post in all_posts(clients) if post.final_status is None]


def wait_clients(clients: Sequence[KeyedClient], join_seconds: float) -> None:
    end = time.monotonic() + join_seconds
    for client in clients:
        client.join(max(0.1, end - time.monotonic()))


def all_posts(clients: Sequence[KeyedClient]) -> list[KeyedPost]:
    return [post for client in clients for post in client.posts]


def status_summary(posts: Sequence[KeyedPost]) -> dict[str, int]:
    """How many attempts ended with each status (for assertion messages)."""
    summary: dict[str, int] = {}
    for post in posts:
        for status in post.statuses:
            summary[str(status)] = summary.get(str(status), 0) + 1
    return dict(sorted(summary.items()))


def contract_problems(
    clients: Sequence[KeyedClient], *, allowed: frozenset[int | str] = frozenset({201, 503})
) -> list[str]:
    """Every problem the clients recorded, plus every status outside ``allowed``."""
    problems = [problem for client in clients for problem in client.problems]
    for post in all_posts(clients):
        unexpected = [status for status in post.statuses if status not in allowed]
        if unexpected:
            problems.append(f"{post.key}: statuses {post.statuses} (outside {sorted(map(str, allowed))})")
    return problems


# --------------------------------------------------------------------------- invariants


def wait_ready(base_url: str, seconds: float) -> tuple[int, str]:
    """Poll ``/readyz`` until 200 or ``seconds`` pass; the last (status, body) seen."""
    deadline = time.monotonic() + seconds
    last: tuple[int, str] = (0, "no answer")
    while time.monotonic() < deadline:
        try:
            response = httpx.get(f"{base_url}/readyz", timeout=5)
            last = (response.status_code, response.text)
            if response.status_code == 200:
                return last
        except httpx.TransportError as error:
            last = (0, type(error).__name__)
        time.sleep(0.2)
    return last


def readiness_problem(response: httpx.Response) -> str | None:
    """None when ``response`` is the contract's not-ready answer: 503, JSON error with a reason, ``Retry-After``."""
    if response.status_code != 503:
        return f"/readyz answered {response.status_code}, not 503: {response.text[:200]}"
    try:
        body = response.json()
    except ValueError:
        return f"/readyz 503 without a JSON body: {response.text[:200]!r}"
    if not isinstance(body, dict) or not body.get("error") or not body.get("detail"):
        return f"/readyz 503 body without error and detail: {response.text[:200]}"
    if not response.headers.get("retry-after"):
        return f"/readyz 503 without Retry-After (every 503 carries one): {response.text[:200]}"
    return None


def _token_gap(session: Session, model_id: str) -> str | None:
    """Why the model's stored tokens (checkpoint and batches) do not run 0..m-1 without a gap, or None."""
    try:
        lda_repository.load_assignments(session, model_id)
    except lda_repository.DamagedBatchError as error:
        return str(error)
    return None


def model_invariants(
    database_url: str,
    base_urls: Sequence[str],
    model_id: str,
    posts: Sequence[KeyedPost],
    *,
    sample_other_servers: int = 200,
) -> list[str]:
    """What must hold after any fault; the list of what does not (empty: all good).

    - every acknowledged answer is stored as it was sent: GET of its scene gives the same JSON,
      on every server of ``base_urls``;
    - two acknowledged keys never share a scene id; a key's stored scene is the acknowledged one;
    - scene ids 0..n-1 and the model's token ids 0..m-1 have no gap;
    - every acknowledged key is stored; every stored key was posted (acknowledged, or left
      unfinished at the deadline);
    - n_kw equals the counts of the stored assignments;
    - every server reports ``scene_count`` n.

    The first server of ``base_urls`` is asked for every acknowledged scene, the others
    for ``sample_other_servers`` of them.
    """
    problems: list[str] = []
    engine = create_database_engine(database_url, pool_size=1)
    read, _ = create_session_makers(engine)
    try:
        with read() as session:
            scene_rows = session.execute(
                sql_select(Scene.id, Scene.idempotency_key).where(Scene.model_id == model_id)
            ).all()
            token_gap = _token_gap(session, model_id)
            stored_counts = lda_repository.stored_counts(session, model_id)
            assignment_counts = {} if token_gap else lda_repository.assignment_counts(session, model_id)
    finally:
        engine.dispose()
    scene_ids = sorted(row[0] for row in scene_rows)
    stored_keys = {row[1]: row[0] for row in scene_rows}
    n = len(scene_ids)
    if scene_ids != list(range(n)):
        missing = sorted(set(range(max(scene_ids, default=-1) + 1)) - set(scene_ids))
        problems.append(
            f"scene ids have gaps: {n} scenes, max id {max(scene_ids, default=None)}, missing {missing[:20]}"
        )
    if token_gap is not None:
        problems.append(f"token ids have gaps: {token_gap}")
    if stored_counts != assignment_counts:
        differing = {
            key: (stored_counts.get(key), assignment_counts.get(key))
            for key in set(stored_counts) | set(assignment_counts)
            if stored_counts.get(key) != assignment_counts.get(key)
        }
        problems.append(
            f"n_kw differs from the stored assignments at {len(differing)} entries, "
            f"e.g. (context, word): (stored, assigned) {list(differing.items())[:5]}"
        )

    acknowledged = [post for post in posts if post.acknowledged]
    posted_keys = {post.key for post in posts}
    by_scene: dict[int, str] = {}
    for post in acknowledged:
        assert post.answer is not None
        scene_id = post.answer.get("scene_id")
        if scene_id in by_scene:
            problems.append(f"keys {by_scene[scene_id]} and {post.key} were both acknowledged as scene {scene_id}")
        by_scene[scene_id] = post.key
        if post.key not in stored_keys:
            problems.append(f"{post.key} was acknowledged (scene {scene_id}) but no scene has its key")
        elif stored_keys[post.key] != scene_id:
            problems.append(f"{post.key} was acknowledged as scene {scene_id} but is stored as {stored_keys[post.key]}")
    stray = sorted(key for key in stored_keys if key not in posted_keys)
    if stray:
        problems.append(f"{len(stray)} stored scenes have keys no client posted: {stray[:5]}")

    for position, base_url in enumerate(base_urls):
        checked = acknowledged
        if position > 0 and len(acknowledged) > sample_other_servers:
            checked = acknowledged[:: len(acknowledged) // sample_other_servers + 1]
        with httpx.Client(base_url=base_url, timeout=20) as client:
            model = client.get(f"/v1/models/{model_id}")
            if model.status_code != 200:
                problems.append(f"{base_url}: GET model {model.status_code}: {model.text[:200]}")
            elif model.json().get("scene_count") != n:
                problems.append(f"{base_url}: scene_count {model.json().get('scene_count')} but {n} scenes stored")
            mismatched = 0
            for post in checked:
                assert post.answer is not None
                stored = client.get(f"/v1/models/{model_id}/scenes/{post.answer['scene_id']}")
                if stored.status_code != 200 or stored.json() != post.answer:
                    mismatched += 1
                    if mismatched <= 3:
                        problems.append(
                            f"{base_url}: scene {post.answer['scene_id']} ({post.key}) is not the acknowledged answer: "
                            f"{stored.status_code} {stored.text[:200]}"
                        )
            if mismatched > 3:
                problems.append(f"{base_url}: {mismatched} acknowledged answers differ from the stored ones in all")
    return problems


def replay_problems(base_url: str, model_id: str, posts: Sequence[KeyedPost], sample: int = 10) -> list[str]:
    """Re-post up to ``sample`` acknowledged keys with their bodies: each must be a 201 replay
    (``Idempotent-Replayed: true``) of the acknowledged answer, changing nothing."""
    problems: list[str] = []
    acknowledged = [post for post in posts if post.acknowledged]
    step = max(1, len(acknowledged) // sample)
    with httpx.Client(base_url=base_url, timeout=20) as client:
        for post in acknowledged[::step][:sample]:
            response = client.post(
                f"/v1/models/{model_id}/scenes", json=post.body, headers={"Idempotency-Key": post.key}
            )
            if response.status_code != 201:
                problems.append(f"replay of {post.key}: {response.status_code} {response.text[:200]}")
            elif response.headers.get("idempotent-replayed", "").lower() != "true":
                problems.append(f"replay of {post.key}: 201 without Idempotent-Replayed: true")
            elif response.json() != post.answer:
                problems.append(f"replay of {post.key}: the answer differs from the acknowledged one")
    return problems


def stored_scene_count(database_url: str, model_id: str) -> int:
    engine = create_database_engine(database_url, pool_size=1)
    try:
        with engine.connect() as connection:
            query = sql_select(func.count()).select_from(Scene).where(Scene.model_id == model_id)
            return int(connection.execute(query).scalar_one())
    finally:
        engine.dispose()


def model_summary(base_url: str, model_id: str) -> tuple[int, dict[str, Any] | None, Any]:
    """(status, ModelRead JSON, /contexts JSON) of one server."""
    with httpx.Client(base_url=base_url, timeout=20) as client:
        model = client.get(f"/v1/models/{model_id}")
        contexts = client.get(f"/v1/models/{model_id}/contexts")
    return (
        model.status_code,
        model.json() if model.status_code == 200 else None,
        contexts.json() if contexts.status_code == 200 else (contexts.status_code, contexts.text[:200]),
    )


def create_model(base_url: str, hyperparameters: dict[str, Any], *, name: str = "fault", seed: int = 5) -> str:
    response = httpx.post(
        f"{base_url}/v1/models", json={"name": name, "seed": seed, "hyperparameters": hyperparameters}, timeout=20
    )
    assert response.status_code == 201, response.text
    return str(response.json()["id"])


def assert_nothing_lost_then_restart(
    url: str, server: Any, model_id: str, clients: Sequence[KeyedClient], readiness: Sequence[str], log_dir: Path
) -> None:
    """The checks of issue 13 after a storage fault under load, then a restart that must load the model.

    The server stayed up; writes failed during the fault (some 503) and every attempt kept the
    error contract; readiness behaved (``readiness`` lists what it did wrong); every scene was
    finally acknowledged and is stored as acknowledged, without id gaps, with n_kw equal to the
    assignments; committed keys replay; a new server process loads the model with every scene.
    """
    from tests.servers import start_server_or_fail  # the server helpers import nothing from here

    posts = all_posts(clients)
    summary = status_summary(posts)
    print(f"statuses of {len(posts)} scenes: {summary}")
    assert server.running, f"the server exited ({server.process.returncode}) during the fault:\n{server.log()}"
    assert sum(post.acknowledged for post in posts) >= 40, f"too little load to test anything: {summary}"
    problems = contract_problems(clients)
    assert not problems, f"statuses {summary}; {len(problems)} problems:\n" + "\n".join(problems[:20])
    assert not readiness, "\n".join(readiness)
    assert any(503 in post.statuses for post in posts), f"no write failed during the fault: {summary}"
    assert not unfinished(clients), f"scenes never acknowledged: {unfinished(clients)[:10]}"
    invariants = model_invariants(url, [server.base_url], model_id, posts)
    assert not invariants, "\n".join(invariants)
    replays = replay_problems(server.base_url, model_id, posts)
    assert not replays, "\n".join(replays)
    stored = stored_scene_count(url, model_id)

    server.stop()
    restarted = start_server_or_fail(url, log_dir, name="restarted")
    try:
        model = httpx.get(f"{restarted.base_url}/v1/models/{model_id}", timeout=20)
        assert model.status_code == 200, model.text
        assert model.json()["scene_count"] == stored
    finally:
        restarted.stop()
