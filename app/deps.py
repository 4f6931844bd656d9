"""Dependencies as ``Annotated`` aliases: state, sessions, API keys, models (404 once, here).

Sessions follow the unit-of-work rule: services never commit; the session
dependency commits when the route returned and rolls back when it raised. Both
session dependencies use ``scope="function"``: they close *before* the response
is sent, so an acknowledgement always follows a durable commit.

A write to a model goes through :func:`model_write`, which holds the model's
lock in this process and in the database around the whole unit of work
(catch-up, in-memory update, flush, commit, then the events) so that memory
follows the database: if anything fails, the model is reloaded from the
database or marked unavailable before the lock is released. It is a context
manager the route opens around its one service call, not a dependency: a sync
dependency with ``yield`` costs two extra hops to the thread pool (enter and
exit), and the scene route is the hot path.
"""

from __future__ import annotations

import logging
import secrets
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Annotated

import anyio
from fastapi import Depends, Path, Security
from fastapi.security import APIKeyHeader
from pydantic import SecretStr
from sqlalchemy.orm import Session
from starlette.requests import HTTPConnection

from app.errors import (
    Forbidden,
    ModelNotFound,
    ModelUnavailable,
    StorageUnavailable,
    Unauthorized,
    is_storage_failure,
    storage_failure_reason,
)
from app.registry import ModelRuntime, catch_up
from app.state import AppState
from storage.repositories import feed as feed_repository
from storage.repositories import incremental_lda as lda_repository
from storage.unit_of_work import unit_of_work

logger = logging.getLogger("contextweb")

API_KEY_HEADER = "X-API-Key"
_api_key = APIKeyHeader(
    name=API_KEY_HEADER,
    auto_error=False,
    description="CONTEXTWEB_WRITE_KEY (robots) or CONTEXTWEB_READ_KEY (dashboards); not needed when none is configured.",
)


async def get_state(connection: HTTPConnection) -> AppState:
    """The lifespan's state (async: a plain ``def`` dependency would cost a thread-pool hop)."""
    return connection.state.contextweb


StateDep = Annotated[AppState, Depends(get_state)]


def access_level(state: AppState, key: str | None) -> str | None:
    """``"write"``, ``"read"`` or None (no valid key); everything is ``"write"`` when no key is configured."""
    settings = state.settings
    if not settings.auth_enabled:
        return "write"
    if not key:  # an empty key never matches, whatever is configured
        return None
    presented = key.encode("utf-8", "surrogateescape")  # any header value; compared as bytes in constant time
    if settings.write_key is not None and secrets.compare_digest(presented, _key_bytes(settings.write_key)):
        return "write"
    if settings.read_key is not None and secrets.compare_digest(presented, _key_bytes(settings.read_key)):
        return "read"
    return None


def _key_bytes(key: SecretStr) -> bytes:
    return key.get_secret_value().encode("utf-8")


async def require_read_key(state: StateDep, key: Annotated[str | None, Security(_api_key)]) -> None:
    if access_level(state, key) is None:
        raise Unauthorized()


async def require_write_key(state: StateDep, key: Annotated[str | None, Security(_api_key)]) -> None:
    level = access_level(state, key)
    if level is None:
        raise Unauthorized()
    if level != "write":
        raise Forbidden()


ReadAccess = Depends(require_read_key)
WriteAccess = Depends(require_write_key)

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


def read_session(state: StateDep) -> Iterator[Session]:
    with state.read_sessions() as session:
        yield session


def write_session(state: StateDep) -> Iterator[Session]:
    """A session committed when the route returns, rolled back when it raises."""
    with unit_of_work(state.write_sessions) as session:
        yield session


ReadSessionDep = Annotated[Session, Depends(read_session, scope="function")]
WriteSessionDep = Annotated[Session, Depends(write_session, scope="function")]


@dataclass(eq=False)
class ModelWrite:
    """One write to a model: its transaction and the version the model has once it commits."""

    session: Session
    version: int
    version_saved: bool = False
    """Set by a service whose own statements stored :attr:`version` (a scene's state row)."""
    unchanged: bool = False
    """Set when the write changed nothing (an idempotent replay): no new version, no notification."""


@contextmanager
def model_write(state: AppState, model: ModelRuntime) -> Iterator[ModelWrite]:
    """The unit of work of a write to ``model`` (docs/scaling.md). A service sets ``model.changing``
    before it changes the model's memory ahead of the commit (a scene), so that a request refused
    before that (a 422) costs no reload.

    Under the model's lock in this process and its lock in the database (its state row, or
    SQLite's write lock): the stored version is read; memory that is behind catches up from the
    rows written since; the write runs; the version is bumped and the other processes notified;
    then the commit. Memory follows the database: if anything fails once memory may hold the
    write, the model is marked unavailable and reloaded from one snapshot (at once if the
    database answers, else on a later request); a storage failure is a 503 ``storage_unavailable``.
    """
    with model.lock:
        if model.deleted:
            raise ModelNotFound(model.id)
        if model.unavailable is not None:
            state.registry.reload(model)
        try:
            with unit_of_work(state.write_sessions) as session:
                stored = lda_repository.lock_version(session, model.id)
                if stored is None:
                    state.registry.forget(model)
                    raise ModelNotFound(model.id)
                if stored != model.version:
                    _catch_up_for_write(state, session, model)
                write = ModelWrite(session, stored + 1)
                yield write
                if not write.unchanged:
                    if not write.version_saved:
                        lda_repository.set_version(session, model.id, write.version)
                    feed_repository.notify_change(session, model.id)
            if not write.unchanged:
                model.version = write.version
            state.storage.record_success()
        except BaseException as error:
            if is_storage_failure(error):
                state.storage.record_failure(storage_failure_reason(error))
            if model.changing:
                _restore(state, model, error)
            if is_storage_failure(error):
                raise StorageUnavailable(storage_failure_reason(error)) from error
            raise
        finally:
            model.changing = False


def _catch_up_for_write(state: AppState, session: Session, model: ModelRuntime) -> None:
    """Catch up under the write lock; changes that do not fit memory make the model unavailable
    (a consistency problem of the stored state, never the client's invalid input)."""
    model.changing = True  # until the catch-up completes, memory is unproven
    try:
        catch_up(session, model)
    except Exception as error:
        if is_storage_failure(error):
            raise
        _restore(state, model, error)
        raise ModelUnavailable(model.id, model.unavailable or "its stored changes do not fit memory") from error
    model.changing = False


def _restore(state: AppState, model: ModelRuntime, error: BaseException) -> None:
    """Memory may hold a write the database does not: reload it now, or leave it unavailable."""
    model.changing = False
    if model.deleted:
        return
    model.mark_unavailable(f"a write failed ({type(error).__name__}) and its model is being reloaded")
    model.reload_after = 0.0
    try:
        state.registry.reload(model)
    except Exception:  # noqa: BLE001 - the model stays unavailable; a later request reloads it
        logger.warning("model %s stays unavailable until the database answers: %s", model.id, model.unavailable)
