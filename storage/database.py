"""Engines and sessions for SQLite (embedded, WAL) and PostgreSQL, with the same code.

SQLite is tuned for an embedded single-process server: WAL journal (readers
never wait for the writer), ``synchronous`` FULL by default (an acknowledged
commit survives a power loss, not only a crash), foreign keys on, and a busy
timeout. Write transactions start with ``BEGIN IMMEDIATE``: in WAL mode a
deferred transaction that reads first and writes later fails at once with
SQLITE_BUSY_SNAPSHOT when another model committed meanwhile, whereas an
immediate one queues on the busy timeout. The busy timeout
(``CONTEXTWEB_SQLITE_BUSY_TIMEOUT_MS``, 5 s by default) is shorter than any
client's request deadline (the bridge's is 30 s): a write lock held elsewhere
for longer (an outside ``sqlite3`` shell, a backup) is a prompt 503
``storage_busy``, never a request that hangs until the client gives up. Reads
use deferred transactions: in WAL mode they never wait for the writer.
"""

from __future__ import annotations

import os
import select
import sqlite3
import weakref
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from sqlalchemy import Engine, create_engine, event
from sqlalchemy.engine import Connection, Dialect, make_url
from sqlalchemy.exc import DBAPIError, DisconnectionError, StatementError
from sqlalchemy.orm import Session, sessionmaker
from sqlalchemy.pool import Pool
from sqlalchemy.types import TypeEngine

from storage.deadlines import DEADLINES
from storage.unit_of_work import commit_sent, deadline_passed, mark_failure
from storage.write_turns import WriteTurn

PROJECT_ROOT = Path(__file__).resolve().parents[1]
DEFAULT_SQLITE_PATH = PROJECT_ROOT / "var" / "contextweb.sqlite3"
DEFAULT_DATABASE_URL = f"sqlite:///{DEFAULT_SQLITE_PATH}"
SQLITE_BUSY_TIMEOUT_MS = 5_000
_WRITE_OPTION = "contextweb_write"
_LOCK_WAIT_OPTION = "contextweb_lock_wait_ms"
_DRIVER_OF_TRANSACTION = "contextweb_driver"
_COMBINED = "contextweb_combined"
_DEADLINE_TOKEN = "contextweb_deadline"
_DEADLINE_OPTION = "contextweb_deadline_seconds"
_DEADLINE_NAME_OPTION = "contextweb_deadline_name"


def is_sqlite(url: str) -> bool:
    return make_url(url).get_backend_name() == "sqlite"


def normalise_url(url: str) -> str:
    """``postgresql://`` means psycopg 3 here (the driver installed), not psycopg2."""
    parsed = make_url(url)
    if parsed.drivername in ("postgresql", "postgres"):
        parsed = parsed.set(drivername="postgresql+psycopg")
    return parsed.render_as_string(hide_password=False)


#: libpq connection parameters of every PostgreSQL connection: a server that cannot be reached is
#: an error within seconds, not a hang (``connect_timeout``; ``tcp_user_timeout``, in ms, for sent
#: data that stays unacknowledged, as on a cut link; client keepalives for an idle connection).
POSTGRES_CONNECT_ARGS: dict[str, Any] = {
    "connect_timeout": 3,
    "tcp_user_timeout": 5_000,
    "keepalives": 1,
    "keepalives_idle": 5,
    "keepalives_interval": 2,
    "keepalives_count": 2,
}
#: Session settings sent with every PostgreSQL connection: a writer waits at most ``lock_timeout``
#: for a model's lock (then a 503, never an endless wait), and the server notices a client that
#: vanished mid-transaction and releases its locks: within ~9 s by its keepalives when the
#: connection was quiet, within 5 s by ``tcp_user_timeout`` when the server's last answer was still
#: on its way (keepalives are not sent while sent data waits for its acknowledgement, and the kernel
#: would retransmit it for ~15 minutes). A transaction left idle (never one of ours: they are
#: milliseconds) ends after a minute. ``tcp_user_timeout`` needs PostgreSQL 12 or newer.
#:
#: Why ``tcp_user_timeout``: a ``--workers 2`` server in a network namespace whose veth link to
#: PostgreSQL was taken down for 20 s while it wrote (docs/scaling.md, "Failure cases") left a
#: backend idle in transaction holding the model's row lock, its last answer unacknowledged, and
#: another server's writes to that model waited behind it: 1 and 1,978 scenes acknowledged during
#: the cut in two runs (longest attempts 20.0 and 9.2 s); with the setting, 3,735, 3,646 and 3,512
#: in three (longest 0.2, 5.5 and 0.2 s).
POSTGRES_SESSION_OPTIONS = (
    "-c lock_timeout=10s -c idle_in_transaction_session_timeout=60s "
    "-c tcp_keepalives_idle=5 -c tcp_keepalives_interval=2 -c tcp_keepalives_count=2 -c tcp_user_timeout=5000"
)


def create_database_engine(
    url: str,
    *,
    sqlite_synchronous: str = "FULL",
    pool_size: int = 8,
    sqlite_busy_timeout_ms: int = SQLITE_BUSY_TIMEOUT_MS,
    write_deadline_seconds: float | None = None,
) -> Engine:
    """An engine for ``url``; SQLite files get their folder created and the pragmas above; PostgreSQL
    connections the time-outs above, and with ``write_deadline_seconds`` a deadline on each write
    transaction (:func:`_arm_deadline`; the server's is ``CONTEXTWEB_WRITE_DEADLINE_SECONDS``)."""
    url = normalise_url(url)
    if not is_sqlite(url):
        engine = create_engine(
            url,
            pool_size=pool_size,
            max_overflow=pool_size,
            connect_args={**POSTGRES_CONNECT_ARGS, "options": POSTGRES_SESSION_OPTIONS},
        )
        _install_postgres_liveness_check(engine)
        if write_deadline_seconds is not None:
            _WRITE_DEADLINE_SECONDS[engine.pool] = write_deadline_seconds
        return engine
    database = make_url(url).database
    if database and database != ":memory:":
        Path(database).parent.mkdir(parents=True, exist_ok=True)
    engine = create_engine(url, pool_size=pool_size, max_overflow=pool_size, connect_args={"check_same_thread": False})
    _install_sqlite_pragmas(engine, sqlite_synchronous, database, sqlite_busy_timeout_ms)
    _WRITE_TURNS[engine.pool] = WriteTurn(database, sqlite_busy_timeout_ms / 1000)
    return engine


#: Per SQLite engine (its pool, which its option engines share): the turn this process's write
#: transactions take at the database's write lock (storage/write_turns.py).
_WRITE_TURNS: weakref.WeakKeyDictionary[Pool, WriteTurn] = weakref.WeakKeyDictionary()
#: Per PostgreSQL engine given one: how long a write transaction may run (storage/deadlines.py).
_WRITE_DEADLINE_SECONDS: weakref.WeakKeyDictionary[Pool, float] = weakref.WeakKeyDictionary()


@event.listens_for(Session, "after_begin")
def _arm_deadline(session: Session, _transaction: Any, connection: Connection) -> None:
    """A PostgreSQL transaction with a deadline has its connection cut once the deadline passes
    (storage/deadlines.py), counted from its ``BEGIN``: a write on an engine with a write deadline,
    or a read on sessions made by :func:`with_deadline`.

    A write's deadline is the transaction's, not a statement's: its statements are milliseconds,
    and its one long wait, for a model's lock elsewhere, ends at ``lock_timeout`` (10 s), so the
    deadline only ends a database that stopped answering. The reads of :func:`with_deadline` sessions
    have theirs: a request's version check a short one, a model's load (which may rightly take
    seconds) a long one (app/registry.py)."""
    options = connection.get_execution_options()
    seconds = options.get(_DEADLINE_OPTION)
    what = options.get(_DEADLINE_NAME_OPTION, "the deadline")
    if seconds is None and options.get(_WRITE_OPTION, False):
        seconds = _WRITE_DEADLINE_SECONDS.get(connection.engine.pool)
        what = "the write deadline"
    if seconds is None or connection.dialect.name != "postgresql":
        return
    driver = connection.connection.driver_connection
    assert driver is not None  # a connection just begun on is not invalidated
    description = f"{what} of {seconds:g} s"
    session.info[_DEADLINE_TOKEN] = DEADLINES.arm(
        driver.fileno(), seconds, lambda: deadline_passed(session, description)
    )


@event.listens_for(Session, "after_transaction_end")
def _disarm_deadline(session: Session, transaction: Any) -> None:
    if transaction.parent is None and _DEADLINE_TOKEN in session.info:
        DEADLINES.disarm(session.info.pop(_DEADLINE_TOKEN))


@contextmanager
def write_turn(sessions: sessionmaker[Session]) -> Iterator[None]:
    """This process's turn to run a write transaction on the database of ``sessions``.

    SQLite: one writer at a time, handed on at once from one thread to the next (a mutex) and from
    one process to the next (a ``flock`` on a file beside the database), rather than by SQLite's
    busy handler, which sleeps up to 100 ms between tries, so the lock sat free while its waiters
    slept (tails of seconds and fewer scenes a second: docs/benchmarks.md). The wait is bounded by
    the busy timeout, then it fails as a ``BEGIN IMMEDIATE`` would (SQLITE_BUSY: a 503
    ``storage_busy``). PostgreSQL: nothing (its writers wait on row locks, without polling)."""
    turn = _WRITE_TURNS.get(sessions.kw["bind"].pool)
    if turn is None:
        yield
        return
    with turn.held():
        yield


def _install_postgres_liveness_check(engine: Engine) -> None:
    """A pooled PostgreSQL connection is checked before each use without a round trip when it can be.

    SQLAlchemy's ``pool_pre_ping`` sends ``SELECT 1`` at every checkout: one more round trip per
    request (the scene path's cost of it: docs/benchmarks.md). A server that ends a session (a
    terminated backend, a restart, an idle timeout) sends its error and closes the socket, so an
    idle pooled connection that is still healthy has nothing to read: only one whose socket is
    readable, or that psycopg already knows is broken, is pinged (or dropped), and a failed ping
    makes the pool open a new connection (``DisconnectionError``), as the pre-ping did. A link cut
    silently (no close reaches the client) is found by the request's first statement instead, within
    the connection's ``tcp_user_timeout`` (what the pre-ping itself waited for), and answered 503.
    """

    @event.listens_for(engine, "checkout")
    def _check_alive(dbapi_connection: Any, _record: Any, _proxy: Any) -> None:
        if dbapi_connection.closed or dbapi_connection.broken:
            raise DisconnectionError("the pooled PostgreSQL connection is closed")
        poller = select.poll()  # not select.select: it refuses descriptors past 1023, and a server has sockets
        poller.register(dbapi_connection.fileno(), select.POLLIN)
        if not poller.poll(0):
            return
        try:
            engine.dialect.do_ping(dbapi_connection)
        except Exception as error:  # any failure of the ping means a new connection
            raise DisconnectionError(f"the pooled PostgreSQL connection failed its ping: {error}") from error


def _install_sqlite_pragmas(engine: Engine, synchronous: str, database: str | None, busy_timeout_ms: int) -> None:
    @event.listens_for(engine, "connect")
    def _on_connect(dbapi_connection: Any, _record: Any) -> None:
        dbapi_connection.isolation_level = None  # transactions are begun by _on_begin, not by pysqlite
        cursor = dbapi_connection.cursor()
        cursor.execute("PRAGMA journal_mode=WAL")
        cursor.execute(f"PRAGMA synchronous={synchronous}")
        cursor.execute("PRAGMA foreign_keys=ON")
        cursor.execute(f"PRAGMA busy_timeout={int(busy_timeout_ms)}")
        cursor.close()
        _record.info[_LOCK_WAIT_OPTION] = busy_timeout_ms

    @event.listens_for(engine, "do_connect")
    def _refuse_read_only_file(_dialect: Any, _record: Any, _args: Any, _kwargs: Any) -> None:
        # SQLite opens a file it may not write (chattr +i, a read-only remount) read-only without a
        # word, and the pool would keep that connection after the file is writable again: every later
        # write on it would fail. The connection is refused instead (an OperationalError, so a 503),
        # and the next attempt opens the file as it is then.
        for path in (database, f"{database}-wal"):
            if path and path != ":memory:" and os.path.exists(path) and not os.access(path, os.W_OK):
                raise sqlite3.OperationalError(f"attempt to write a readonly database: {path} is not writable")

    @event.listens_for(engine, "begin")
    def _on_begin(connection: Any) -> None:
        # Straight to the driver: exec_driver_sql's cost a scene is in docs/benchmarks.md.
        options = connection.get_execution_options()
        driver, info = connection.connection.driver_connection, connection.connection.info
        lock_wait = options.get(_LOCK_WAIT_OPTION, busy_timeout_ms)
        statement = "BEGIN IMMEDIATE" if options.get(_WRITE_OPTION, False) else "BEGIN"
        try:
            if info.get(_LOCK_WAIT_OPTION) != lock_wait:  # a probe's shorter wait, or back to the default after one
                driver.execute(f"PRAGMA busy_timeout={int(lock_wait)}")
                info[_LOCK_WAIT_OPTION] = lock_wait
            driver.execute(statement)
        except sqlite3.Error as error:
            # SQLAlchemy wraps the driver's errors of its own statements, not those of a listener: the
            # busy timeout running out here must still be an OperationalError (a 503), not a bare 500.
            raise DBAPIError.instance(statement, (), error, sqlite3.Error) from error


LOCK_NOT_AVAILABLE = "55P03"
"""PostgreSQL's SQLSTATE ``lock_not_available``: a lock wait that ran out (``lock_timeout``) or was refused (``NOWAIT``)."""


class DriverStatements:
    """Statements sent straight to the DB-API driver on a session's connection, in its transaction.

    The hot path of a learned scene (a few statements and ~100 rows) spent more in
    SQLAlchemy's per-statement machinery than the database took to store the rows;
    this skips it. Statements use ``?`` placeholders (rewritten to ``%s`` for
    psycopg); values go to the driver as they are, so the caller converts what
    SQLAlchemy would (:meth:`bind` gives a column type's own conversion). Driver
    errors are raised as SQLAlchemy's (``IntegrityError`` …), as through the engine.
    """

    def __init__(self, session: Session) -> None:
        # A scene's transaction makes several of these: the connection is looked up once per transaction.
        transaction = session.get_transaction()
        cached = session.info.get(_DRIVER_OF_TRANSACTION)
        if cached is not None and transaction is not None and cached[0] is transaction and transaction.is_active:
            _, self._connection, self._driver = cached
        else:
            self._connection = session.connection()
            driver = self._connection.connection.driver_connection
            # None only once the pool has invalidated the connection, which the session just checked out is not.
            assert driver is not None
            self._driver = driver
            session.info[_DRIVER_OF_TRANSACTION] = (session.get_transaction(), self._connection, driver)
        self.dialect = self._connection.dialect
        self._qmark = self.dialect.paramstyle == "qmark"
        self._session = session

    def execute(self, statement: str, parameters: Sequence[Any]) -> None:
        """Run a statement that answers no rows (inside :func:`combined`, queue it)."""
        queued = self._session.info.get(_COMBINED)
        if queued is not None:
            queued.append((statement, parameters))
            return
        self._run(statement, parameters, many=False)

    def executemany(self, statement: str, rows: Sequence[Sequence[Any]]) -> None:
        if rows:
            self.send_combined()
            self._run(statement, rows, many=True)

    def fetchone(self, statement: str, parameters: Sequence[Any]) -> tuple[Any, ...] | None:
        """The first row a query answers (values as the driver gives them), or None."""
        self.send_combined()
        return self._run(statement, parameters, many=False, fetch=True)

    def fetchall(self, statement: str, parameters: Sequence[Any]) -> list[tuple[Any, ...]]:
        """Every row a query answers, as the driver's plain tuples (what numpy converts fast)."""
        self.send_combined()
        return self._run(statement, parameters, many=False, fetch_all=True)

    def submit(self, statement: str, parameters: Sequence[Any]) -> QueuedRows:
        """A query whose rows are read later (:meth:`QueuedRows.all`). Inside :func:`pipelined` it
        goes to PostgreSQL with the block's other statements, and its rows are read after the block
        (reading them inside would cost a round trip of its own); elsewhere it runs at once."""
        self.send_combined()
        return QueuedRows(self._cursor(statement, parameters, many=False))

    def send_combined(self) -> None:
        """Send the statements :func:`combined` queued so far, as one statement (the ones after it
        must come after them)."""
        queued = self._session.info.get(_COMBINED)
        if not queued:
            return
        statements = list(queued)
        queued.clear()
        *first, (last, last_parameters) = statements
        if not first:
            self._run(last, last_parameters, many=False)
            return
        # Data-modifying common table expressions all run, whether the main statement reads them or not.
        parts = ", ".join(f"s{i} AS ({statement})" for i, (statement, _) in enumerate(first))
        parameters = [value for _, values in statements for value in values]
        self._run(f"WITH {parts} {last}", parameters, many=False)

    def bind(self, column: Any) -> Callable[[Any], Any]:
        """SQLAlchemy's conversion of a value for ``column`` (a Column) on this dialect."""
        return _bind_processor(self.dialect, column.type)

    def _run(self, statement: str, parameters: Any, *, many: bool, fetch: bool = False, fetch_all: bool = False) -> Any:
        cursor = self._cursor(statement, parameters, many=many)
        try:
            if fetch_all:
                return cursor.fetchall()
            return cursor.fetchone() if fetch else None
        finally:
            cursor.close()

    def _cursor(self, statement: str, parameters: Any, *, many: bool) -> Any:
        """A cursor that has run ``statement`` (closed, and the error raised as SQLAlchemy's, if it failed)."""
        if not self._qmark:
            statement = statement.replace("?", "%s")
        cursor = self._driver.cursor()
        try:
            if many:
                cursor.executemany(statement, parameters)
            else:
                cursor.execute(statement, parameters)
        except self.dialect.loaded_dbapi.Error as error:
            cursor.close()
            raise _as_sqlalchemy_error(self._connection, statement, parameters, error) from error
        return cursor


class QueuedRows:
    """The rows of a query sent by :meth:`DriverStatements.submit`."""

    def __init__(self, cursor: Any) -> None:
        self._cursor = cursor

    def all(self) -> list[tuple[Any, ...]]:
        """Every row, as the driver's plain tuples (once; the cursor is closed after)."""
        try:
            return self._cursor.fetchall()
        finally:
            self._cursor.close()

    def close(self) -> None:
        self._cursor.close()


def _as_sqlalchemy_error(connection: Connection, statement: str, parameters: Any, error: Any) -> StatementError:
    """A driver error as SQLAlchemy would raise it (``IntegrityError``, ``OperationalError`` …).
    As in SQLAlchemy's own handling (``Connection._handle_dbapi_exception``), an error that means
    the connection is lost invalidates it, so that the session's rollback does not try to use it,
    and invalidates the pool's older connections too, so that each is replaced at its next checkout:
    they reach the same server, which has just been lost (restarted, partitioned, frozen). Without
    that, the writes queued behind one cut by its deadline each took another frozen pooled
    connection and waited out a deadline of its own (tests/test_database_deadlines.py)."""
    dialect = connection.dialect
    lost = dialect.is_disconnect(error, connection.connection.driver_connection, None)
    if lost and not connection.invalidated:
        connection.engine.pool._invalidate(connection.connection, error)
        connection.invalidate(error)
    return DBAPIError.instance(
        statement, parameters, error, dialect.loaded_dbapi.Error, dialect=dialect, connection_invalidated=lost
    )


def _bind_processor(dialect: Dialect, column_type: TypeEngine[Any]) -> Callable[[Any], Any]:
    key = (dialect.name, dialect.driver, id(column_type))
    processor = _BIND_PROCESSORS.get(key)
    if processor is None:
        found = column_type.dialect_impl(dialect).bind_processor(dialect)
        processor = found if found is not None else _identity
        _BIND_PROCESSORS[key] = processor
    return processor


def _identity(value: Any) -> Any:
    return value


_BIND_PROCESSORS: dict[tuple[str, str, int], Callable[[Any], Any]] = {}


@contextmanager
def combined(session: Session) -> Iterator[None]:
    """PostgreSQL: the block's :meth:`DriverStatements.execute` calls (statements that answer no
    rows) go to the database as one statement when the block ends, the first ones as
    data-modifying common table expressions of the last (``WITH s0 AS (…), s1 AS (…) last``).
    psycopg's Python work per statement (its cursor, the parameters' conversion, the pipeline's
    bookkeeping) was the largest part of a scene's save on the server (docs/benchmarks.md).

    PostgreSQL runs the parts on one snapshot, and none sees another's rows, so a block may only
    hold statements on different rows that need nothing from each other (a scene's rows); any other
    :class:`DriverStatements` call in the block (a query, ``executemany``) first sends what is
    queued, so their order never changes. Statements run through the session itself (SQLAlchemy's
    ``session.execute``, the ORM's flush) are not held back: they go before the queued ones. An
    error in one part fails the statement, as it would have failed the transaction. SQLite: no
    effect (its statements cost no round trip)."""
    if session.get_bind().dialect.name != "postgresql" or _COMBINED in session.info:
        yield
        return
    session.info[_COMBINED] = []
    try:
        yield
        DriverStatements(session).send_combined()
    finally:
        del session.info[_COMBINED]


@contextmanager
def pipelined(session: Session, *, begin: bool = False, commit: bool = False) -> Iterator[None]:
    """Send the block's statements to PostgreSQL in one round trip (psycopg's pipeline mode);
    no effect on SQLite, whose statements make no round trip.

    The errors the database reports when the block ends (in pipeline mode, a failed statement's
    error, or a lost connection, arrives then, not at the statement) are raised as SQLAlchemy's,
    as a statement's are (``OperationalError`` …): a storage failure, never a bare driver error.

    ``begin``: when the session has not begun its transaction yet, the block begins it, its
    ``BEGIN`` going in the same round trip. psycopg sends a transaction's implicit ``BEGIN`` with
    a sync of its own, which waits for the server: one more round trip a write (docs/benchmarks.md).
    The transaction's connection is then taken with SQLAlchemy's ``AUTOCOMMIT`` isolation level
    (psycopg's autocommit: it sends no ``BEGIN`` of its own) and the block sends ``BEGIN`` first, so
    the transaction is the same as the implicit one (the default isolation level); the session's
    commit and rollback still reach the server (psycopg's follow the transaction's status, not its
    autocommit flag), and SQLAlchemy resets the level when the connection returns to its pool.
    In a session already in its transaction, and on SQLite, ``begin`` changes nothing.

    ``commit``: the block ends the session's transaction, its ``COMMIT`` going in the same round
    trip (pending ORM changes are flushed first). Nothing may run in the session after the block
    but its commit, which then finds the transaction ended (psycopg's commit of an idle connection
    sends nothing). On SQLite the session commits as usual."""
    explicit_begin = begin and not session.in_transaction() and session.get_bind().dialect.name == "postgresql"
    connection = session.connection(execution_options={"isolation_level": "AUTOCOMMIT"} if explicit_begin else None)
    driver = connection.connection.driver_connection
    pipeline = getattr(driver, "pipeline", None)
    if driver is None or pipeline is None:
        yield
        return
    driver_error = connection.dialect.loaded_dbapi.Error
    failed: Exception | None = None
    try:
        with pipeline():
            try:
                if explicit_begin:
                    with driver.cursor() as cursor:
                        cursor.execute("BEGIN", prepare=False)
                yield
                if commit:
                    session.flush()
                    commit_sent(session)
                    with driver.cursor() as cursor:
                        cursor.execute("COMMIT", prepare=False)
            except (driver_error, DBAPIError) as error:
                # Kept, and the pipeline left as if the block had ended: leaving it with the error
                # made psycopg log "error ignored terminating <Pipeline>: pipeline aborted" for the
                # statements queued behind the failed one (a lock refused with NOWAIT, whose error
                # reaches the block's next statement, every time two processes write one model),
                # which says nothing this error does not.
                failed = error
    except driver_error as error:
        failed = failed or error  # ending an aborted pipeline fails too: the block's error is the cause
    if isinstance(failed, DBAPIError):
        raise failed
    if failed is not None:
        raise _as_sqlalchemy_error(connection, "(pipeline)", (), failed) from failed


@contextmanager
def snapshot(sessions: sessionmaker[Session]) -> Iterator[Session]:
    """A read-only session whose queries all see one consistent state of the database: PostgreSQL's
    REPEATABLE READ (one snapshot for the whole transaction); on SQLite a WAL read transaction is
    one snapshot from its first read on."""
    with _read_session(sessions, {"isolation_level": "REPEATABLE READ", "postgresql_readonly": True}) as session:
        yield session


@contextmanager
def autocommit_reads(sessions: sessionmaker[Session]) -> Iterator[Session]:
    """A session for reads that need no snapshot across statements: on PostgreSQL each statement
    sees the database as of its own start, as in a transaction of PostgreSQL's default READ
    COMMITTED level, but without the transaction: its connection is in autocommit (SQLAlchemy's
    ``AUTOCOMMIT`` level, reset when the connection returns to the pool), which spares psycopg's
    ``BEGIN`` and the ``ROLLBACK`` at the end, each a round trip it waits for (a one-query read: one
    round trip instead of three). For reads only: a write in it would commit statement by statement.
    On SQLite the same as :func:`snapshot`."""
    with _read_session(sessions, {"isolation_level": "AUTOCOMMIT"}) as session:
        yield session


@contextmanager
def _read_session(sessions: sessionmaker[Session], postgres_options: dict[str, Any]) -> Iterator[Session]:
    with sessions() as session:
        try:
            if session.get_bind().dialect.name == "postgresql":
                session.connection(execution_options=postgres_options)
            yield session
        except BaseException as error:
            mark_failure(session, error)
            raise
        finally:
            session.rollback()


def with_lock_wait(sessions: sessionmaker[Session], milliseconds: int) -> sessionmaker[Session]:
    """``sessions`` whose SQLite transactions wait at most ``milliseconds`` for the write lock instead
    of the busy timeout (the readiness probe must answer promptly); no effect on PostgreSQL."""
    bind = sessions.kw["bind"].execution_options(**{_LOCK_WAIT_OPTION: milliseconds})
    return sessionmaker(bind=bind, expire_on_commit=False, autoflush=False)


def with_deadline(sessions: sessionmaker[Session], seconds: float, name: str = "the deadline") -> sessionmaker[Session]:
    """``sessions`` whose PostgreSQL transactions are cut after ``seconds`` (:func:`_arm_deadline`),
    which a frozen database would otherwise hold for as long as the freeze; ``name`` names the
    deadline in the 503 ("did not answer within {name} of {seconds} s"). No effect on SQLite."""
    bind = sessions.kw["bind"].execution_options(**{_DEADLINE_OPTION: seconds, _DEADLINE_NAME_OPTION: name})
    return sessionmaker(bind=bind, expire_on_commit=False, autoflush=False)


def create_session_makers(engine: Engine) -> tuple[sessionmaker[Session], sessionmaker[Session]]:
    """(read sessions, write sessions); on SQLite the write ones take the write lock up front."""
    read = sessionmaker(bind=engine, expire_on_commit=False, autoflush=False)
    write = sessionmaker(
        bind=engine.execution_options(**{_WRITE_OPTION: True}), expire_on_commit=False, autoflush=False
    )
    return read, write
