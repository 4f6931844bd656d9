"""Dependencies as ``Annotated`` aliases: state, sessions, API keys, models (404 once, here).

Sessions follow the unit-of-work rule: services never commit; the session
dependency commits when the route returned and rolls back when it raised. Both
session dependencies use ``scope="function"``: they close *before* the response
is sent, so an acknowledgement always follows a durable commit.

A write to a model goes through :func:`model_write`, which holds the model's
lock around the whole unit of work (in-memory update, flush, commit, then the
events) so that the in-memory state and the database change together: if the
commit fails, the model is reloaded from the database before the lock is
released. It is a context manager the route opens around its one service
call, not a dependency: a sync dependency with ``yield`` costs two extra hops
to the thread pool (enter and exit), and the scene route is the hot path.
"""

from __future__ import annotations

import secrets
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Annotated

from fastapi import Depends, Path, Security
from fastapi.security import APIKeyHeader
from sqlalchemy.orm import Session
from starlette.requests import HTTPConnection

from app.errors import Forbidden, ModelNotFound, Unauthorized
from app.registry import ModelRuntime
from app.state import AppState
from storage.unit_of_work import unit_of_work

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
    if key is None:
        return None
    if settings.write_key is not None and secrets.compare_digest(key, settings.write_key.get_secret_value()):
        return "write"
    if settings.read_key is not None and secrets.compare_digest(key, settings.read_key.get_secret_value()):
        return "read"
    return None


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


async def valid_model_id(model_id: ModelId, state: StateDep) -> ModelRuntime:
    """The in-memory model ``model_id``, or a 404."""
    model = state.registry.get(model_id)
    if model is None:
        raise ModelNotFound(model_id)
    return model


ModelDep = Annotated[ModelRuntime, Depends(valid_model_id)]


def read_session(state: StateDep) -> Iterator[Session]:
    with state.read_sessions() as session:
        yield session


def write_session(state: StateDep) -> Iterator[Session]:
    """A session committed when the route returns, rolled back when it raises."""
    with unit_of_work(state.write_sessions) as session:
        yield session


ReadSessionDep = Annotated[Session, Depends(read_session, scope="function")]
WriteSessionDep = Annotated[Session, Depends(write_session, scope="function")]


@contextmanager
def model_write(state: AppState, model: ModelRuntime) -> Iterator[Session]:
    """The unit of work of a write to ``model``: its lock, one transaction, memory reloaded on failure."""
    with model.lock:
        if model.deleted:
            raise ModelNotFound(model.id)
        try:
            with unit_of_work(state.write_sessions) as session:
                yield session
        except BaseException:
            if model.changing:
                with state.read_sessions() as session:
                    state.registry.reload(session, model)
            raise
        finally:
            model.changing = False
