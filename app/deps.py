"""Dependencies as ``Annotated`` aliases: state, sessions, API keys, models (404 once, here).

Sessions follow the unit-of-work rule: services never commit; the session
dependency commits when the route returned and rolls back when it raised. Both
session dependencies use ``scope="function"``: they close *before* the response
is sent, so an acknowledgement always follows a durable commit.

A write to a model goes through :func:`model_write`, which runs it as a
transaction of the model's writer (app/registry.py ``ModelWriter``): the model's
lock in this process and in the database are held around the whole unit of work
(catch-up, in-memory update, flush, commit, then the events) so that memory
follows the database: if anything fails, the writer reloads the model from the
database (a scene: takes it back out of memory exactly) or marks it unavailable
before the lock is released. It is a context
manager the route opens around its one service call, not a dependency: a sync
dependency with ``yield`` costs two extra hops to the thread pool (enter and
exit), and the scene route is the hot path.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from functools import partial
from typing import Annotated, TypeVar

import anyio
from fastapi import Depends, Header, Path, Security
from fastapi.security import APIKeyHeader
from sqlalchemy.orm import Session
from starlette.requests import HTTPConnection, Request

from app.admission import Admission, Postponed, client_identity
from app.auth import Principal, authenticate, authorise
from app.errors import (
    StorageUnavailable,
    Unauthorized,
    is_storage_busy,
    is_storage_failure,
    is_unresponsive_database,
    is_write_conflict,
    storage_error,
    storage_failure_reason,
    write_conflict,
)
from app.registry import ModelRuntime, ModelWrite
from app.schemas.common import PRINTABLE_ASCII
from app.schemas.keys import Role
from app.state import AppState
from storage.database import autocommit_reads
from storage.repositories.incremental_lda import LockHeldElsewhere
from storage.unit_of_work import unit_of_work

T = TypeVar("T")
logger = logging.getLogger("contextweb")

API_KEY_HEADER = "X-API-Key"
_api_key = APIKeyHeader(
    name=API_KEY_HEADER,
    auto_error=False,
    description="A key of `/v1/keys` (`cw_…`), or CONTEXTWEB_WRITE_KEY / CONTEXTWEB_READ_KEY; not needed when none is set.",
)


async def get_state(connection: HTTPConnection) -> AppState:
    """The lifespan's state (async: a plain ``def`` dependency would cost a thread-pool hop)."""
    return connection.state.contextweb


StateDep = Annotated[AppState, Depends(get_state)]


async def _principal(connection: HTTPConnection, state: AppState, key: str | None, role: Role) -> Principal:
    """The caller, allowed ``role`` on the path's model (app/auth.py has the rules)."""
    principal = await authenticate(state.settings, state.read_sessions, key)
    if principal is None:
        raise Unauthorized()
    authorise(principal, role, connection.path_params.get("model_id"))
    return principal


async def read_access(
    connection: HTTPConnection, state: StateDep, key: Annotated[str | None, Security(_api_key)]
) -> Principal:
    return await _principal(connection, state, key, "read")


async def write_access(
    connection: HTTPConnection, state: StateDep, key: Annotated[str | None, Security(_api_key)]
) -> Principal:
    return await _principal(connection, state, key, "write")


async def admin_access(
    connection: HTTPConnection, state: StateDep, key: Annotated[str | None, Security(_api_key)]
) -> Principal:
    return await _principal(connection, state, key, "admin")


ReadAccess = Depends(read_access)
WriteAccess = Depends(write_access)
AdminAccess = Depends(admin_access)
#: The caller of a read route (FastAPI solves ``ReadAccess`` once per request, however often it is named).
ReadPrincipal = Annotated[Principal, ReadAccess]

IdempotencyKey = Annotated[
    str | None,
    Header(
        alias="Idempotency-Key",
        min_length=1,
        max_length=200,
        pattern=PRINTABLE_ASCII,
        description="Makes retries safe: the same key and body return the stored answer and change nothing.",
    ),
]
"""A keyed write's Idempotency-Key (a scene's, per model; a model's creation, one namespace for all)."""

ModelId = Annotated[
    str, Path(description="The model's id.", max_length=64, examples=["3f2c0b9e5d7a4e1f8a6b2c4d9e0f1a2b"])
]


def current_model(model_id: ModelId, state: StateDep) -> ModelRuntime:
    """The model ``model_id`` as stored now, for a read: 404 if it does not exist (on any process),
    503 while it cannot serve. One primary-key read when memory is current (read-your-writes)."""
    return state.registry.resolve(model_id)


async def known_model(model_id: ModelId, state: StateDep) -> ModelRuntime:
    """The model ``model_id`` for a write, without a database round trip when it is in memory: the
    write itself checks the stored version under the model's lock (:func:`model_write`)."""
    model = state.registry.get(model_id)
    if model is None:
        return await anyio.to_thread.run_sync(state.registry.resolve, model_id)
    return model


ModelDep = Annotated[ModelRuntime, Depends(current_model)]
WriteModelDep = Annotated[ModelRuntime, Depends(known_model)]


async def get_admission(connection: HTTPConnection) -> Admission:
    """The lifespan's admission control (app/admission.py)."""
    return connection.state.admission


AdmissionDep = Annotated[Admission, Depends(get_admission)]


async def limit_write_rate(connection: HTTPConnection, admission: AdmissionDep) -> None:
    """A token of the client's bucket, or a 429 ``rate_limited``. List it after the key check, so that
    only clients with a valid key get a bucket. The header's bytes as sent (Starlette decodes latin-1)."""
    key = connection.headers.get(API_KEY_HEADER)
    address = connection.client.host if connection.client else None
    admission.check_rate(client_identity(None if key is None else key.encode("latin-1"), address))


WriteRate = Depends(limit_write_rate)


async def body_size(request: Request) -> int:
    """The request body's length in bytes (already read and cached by FastAPI: no second read)."""
    return len(await request.body())


BodySizeDep = Annotated[int, Depends(body_size)]


def read_session(state: StateDep) -> Iterator[Session]:
    """A read route's session: read-only, each statement seeing the database as of its start (no
    transaction on PostgreSQL: ``storage.database.autocommit_reads``)."""
    with autocommit_reads(state.read_sessions) as session:
        yield session


def write_session(state: StateDep) -> Iterator[Session]:
    """A session committed when the route returns, rolled back when it raises."""
    with unit_of_work(state.write_sessions) as session:
        yield session


ReadSessionDep = Annotated[Session, Depends(read_session, scope="function")]
WriteSessionDep = Annotated[Session, Depends(write_session, scope="function")]


@contextmanager
def model_write(
    state: AppState, model: ModelRuntime, *, wait: bool = True, idempotency_key: str | None = None
) -> Iterator[ModelWrite]:
    """The unit of work of a write to ``model`` (docs/scaling.md): the model's writer runs it
    (``ModelWriter.transaction`` in app/registry.py), and here its storage failures are counted
    and answered as a 503 ``storage_unavailable``, or ``storage_busy`` when the database's lock
    stayed held elsewhere past the busy timeout (that wait is the transaction's first statement:
    memory is untouched then, and nothing is reloaded).

    Under the model's lock in this process and its lock in the database (its state row, or
    SQLite's write lock): the stored version is read; memory that is behind catches up from the
    rows written since; the write runs; the version is bumped and the other processes notified;
    then the commit. Memory follows the database: a service asks the writer to change memory
    ahead of the commit (a scene) only once the request is accepted, so that a request refused
    before that (a 422) costs no reload; if anything fails once memory may hold the write, the
    writer's one undo takes a scene back out of memory exactly, or else marks the model
    unavailable and reloads it from one snapshot (at once if the database answers, else on a
    later request).

    A write that collides with a row the database already holds (a unique key: a writer elsewhere
    that ignored the model's lock, or rows restored under it) is a 503 ``model_unavailable`` too,
    not a 500: nothing of it was stored, the undo has taken it back out of memory, and the
    client's retry meets the stored rows (a keyed scene then replays, or the reload names the
    stored state's problem for ``contextweb models check``).

    Call it on a worker thread admitted by ``Admission.run_write`` (app/admission.py): then no other
    write of this process waits on ``model.lock``, only the reads that need it for a moment.

    The database's lock is taken first and the model's after it, then both are held through the
    commit: while the write waits for a lock held elsewhere (another process's write, an outside
    ``sqlite3`` shell), the model's reads go on, from memory that still equals the database.
    ``wait=False`` (a scene on its scene thread, app/routers/scenes.py): on PostgreSQL, a lock held
    by another transaction raises ``LockHeldElsewhere`` at once instead (nothing changed, nothing counted).
    ``idempotency_key``: a keyed scene's key, looked up with the lock (``ModelWrite.locked``).
    """
    unresponsive = state.storage.unresponsive()
    if unresponsive is not None:  # a write a moment ago waited out its time-out: do not queue another behind it
        raise StorageUnavailable(f"{unresponsive} (a write a moment ago; this one was not sent)")
    try:
        with model.writer.transaction(
            state.write_sessions, state.registry, wait=wait, idempotency_key=idempotency_key
        ) as write:
            yield write
        state.storage.record_success()
    except BaseException as error:
        failed = is_storage_failure(error)
        if failed and state.metrics is not None:
            state.metrics.storage_failed("busy" if is_storage_busy(error) else "unavailable")
        if failed and not is_storage_busy(error):  # a lock held elsewhere says nothing of the database's health
            state.storage.record_failure(storage_failure_reason(error), unresponsive=is_unresponsive_database(error))
        if failed:
            answer = storage_error(error)
            answer.recorded = True  # counted above (a lock held elsewhere is not a failure of the database)
            raise answer from error
        if is_write_conflict(error):
            logger.warning(
                "model %s: a write conflicts with a stored row and stored nothing: %s",
                model.id,
                storage_failure_reason(error),
            )
            raise write_conflict(model.id, error) from error
        raise


def write_or_postpone(write: Callable[[bool], T]) -> T:
    """``write(wait=False)`` (it calls :func:`model_write` with that ``wait``) on a scene thread; if
    another process holds the model's lock, :class:`Postponed` to ``write(wait=True)`` on a write
    thread (``Admission.run_scene``), so that the wait for that lock holds no scene thread."""
    try:
        return write(False)
    except LockHeldElsewhere as held:
        raise Postponed(partial(write, True)) from held


def write_model(state: AppState, model: ModelRuntime, work: Callable[[Session], T]) -> T:
    """``work(session)`` as one unit of work of ``model`` (:func:`model_write`): what a route hands to
    ``Admission.run_write`` when its service needs nothing else of :class:`ModelWrite`."""
    with model_write(state, model) as write:
        return work(write.session)
