"""One error tree and one handler: every 4xx/5xx body is ``{"error", "detail", "field"}``.

Routes raise :class:`ContextwebError` subclasses (and declare them in
``responses=`` so the OpenAPI schema shows them); core's
:class:`~core.errors.InvalidInputError`, pydantic's request validation errors and
Starlette's routing errors are rendered in the same shape. There is deliberately
no catch-all: an unexpected exception stays a visible 500 and a logged traceback. Database
failures are not unexpected in the field (a lost connection, a full disk, an I/O
error, a lock timeout): each such failure (:func:`is_storage_failure`) that reaches a
route is a 503 ``storage_unavailable`` with ``Retry-After``, and a model write that one of the
database's constraints refuses (:func:`is_write_conflict`) a 503 ``model_unavailable``.
"""

from __future__ import annotations

import logging
import sqlite3
from collections.abc import Sequence
from typing import Any

import psycopg
from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from sqlalchemy.exc import (
    DBAPIError,
    DisconnectionError,
    IntegrityError,
    InterfaceError,
    InternalError,
    OperationalError,
    PendingRollbackError,
    SQLAlchemyError,
)
from sqlalchemy.exc import TimeoutError as PoolTimeoutError
from starlette.exceptions import HTTPException as StarletteHTTPException

from app.schemas.common import PATTERN_MEANINGS, UNION_TAGS, ErrorRead
from core.errors import InvalidInputError
from storage.database import LOCK_NOT_AVAILABLE
from storage.unit_of_work import commit_outcome_unknown, deadline_that_passed

logger = logging.getLogger("contextweb")


class ContextwebError(Exception):
    """Base of every error the service answers on purpose."""

    error = "contextweb_error"
    status_code = 500

    def __init__(self, message: str, status_code: int | None = None, *, field: str | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.status_code = status_code or type(self).status_code
        self.field = field

    def headers(self) -> dict[str, str] | None:
        return None


class InvalidInput(ContextwebError):
    error = "invalid_input"
    status_code = 422

    def __init__(self, field: str, problem: str) -> None:
        super().__init__(problem, field=field)


class ModelNotFound(ContextwebError):
    error = "model_not_found"
    status_code = 404

    def __init__(self, model_id: str) -> None:
        super().__init__(f"no model {model_id!r}", field="path.model_id")


class SceneNotFound(ContextwebError):
    error = "scene_not_found"
    status_code = 404

    def __init__(self, model_id: str, scene_id: int) -> None:
        super().__init__(f"model {model_id!r} has no scene {scene_id}", field="path.scene_id")


class ContextNotFound(ContextwebError):
    error = "context_not_found"
    status_code = 404

    def __init__(self, model_id: str, context: int, context_count: int) -> None:
        super().__init__(
            f"model {model_id!r} has {context_count} context(s), no context {context}", field="path.context"
        )


class ModelNotFitted(ContextwebError):
    error = "model_not_fitted"
    status_code = 409

    def __init__(self, model_id: str, what: str) -> None:
        super().__init__(f"model {model_id!r} has no fitted {what}: post training objects and fit first")


class IdempotencyKeyReused(ContextwebError):
    error = "idempotency_key_reused"
    status_code = 422

    def __init__(self, key: str) -> None:
        super().__init__(
            f"Idempotency-Key {key!r} was already used with a different body", field="header.Idempotency-Key"
        )


class KeyAlreadyCreated(ContextwebError):
    """A retry of a keyed ``POST /v1/keys`` whose key was made: its secret was in the first answer
    only (only its hash is stored), so it cannot be answered again (app/services/keys.py)."""

    error = "key_already_created"
    status_code = 409

    def __init__(self, idempotency_key: str, key_id: str) -> None:
        super().__init__(
            f"Idempotency-Key {idempotency_key!r} already created key {key_id!r}, whose secret was shown "
            f"in that answer only: if it was lost, revoke {key_id!r} (DELETE /v1/keys/{key_id}) and create "
            "another under a new Idempotency-Key",
            field="header.Idempotency-Key",
        )


class Unauthorized(ContextwebError):
    error = "unauthorized"
    status_code = 401

    def __init__(self) -> None:
        super().__init__("a valid API key is required in the X-API-Key header", field="header.X-API-Key")

    def headers(self) -> dict[str, str]:
        return {"WWW-Authenticate": "ApiKey"}


class Forbidden(ContextwebError):
    error = "forbidden"
    status_code = 403

    def __init__(self, message: str = "the read key cannot use a write route") -> None:
        super().__init__(message, field="header.X-API-Key")


class KeyNotFound(ContextwebError):
    error = "key_not_found"
    status_code = 404

    def __init__(self, key_id: str) -> None:
        super().__init__(f"no API key {key_id!r}", field="path.key_id")


class PayloadTooLarge(ContextwebError):
    error = "payload_too_large"
    status_code = 413

    def __init__(self, limit: int) -> None:
        super().__init__(f"the request body exceeds {limit} bytes (CONTEXTWEB_MAX_BODY_BYTES)", field="body")


class RequestTimeout(ContextwebError):
    """The request body did not arrive in time (a slow or stalled client); the connection is closed."""

    error = "request_timeout"
    status_code = 408

    def __init__(self, seconds: float) -> None:
        super().__init__(
            f"the request body did not arrive within {seconds:g} s (CONTEXTWEB_BODY_READ_TIMEOUT_SECONDS)", field="body"
        )


class HeadersTimeout(ContextwebError):
    """A request's line and headers did not arrive in time (a "slowloris" client, or a connection
    that sends nothing); the connection is closed (app/connections.py). Its body's sibling is
    :class:`RequestTimeout`, whose error it shares."""

    error = RequestTimeout.error
    status_code = RequestTimeout.status_code

    def __init__(self, seconds: float) -> None:
        super().__init__(
            f"the request line and headers did not arrive within {seconds:g} s (CONTEXTWEB_HEADER_READ_TIMEOUT_SECONDS)"
        )


class BadHttpRequest(ContextwebError):
    """Bytes that are not an HTTP/1.1 request (an unknown method, a control character in a header,
    a malformed ``Content-Length`` or chunk size): uvicorn's parser refuses them before any route
    runs, and the connection is closed (app/connections.py). The detail quotes the parser."""

    error = "bad_request"
    status_code = 400

    def __init__(self, reason: str) -> None:
        super().__init__(f"not a valid HTTP/1.1 request: {reason}; the connection is closed")


class ServiceUnavailable(ContextwebError):
    """A 503 the client should retry after ``retry_after`` seconds (the bridge retries every 5xx)."""

    status_code = 503

    def __init__(self, message: str, retry_after: int) -> None:
        super().__init__(message)
        self.retry_after = retry_after
        self.recorded = False
        """Whether the process's storage health has counted it (app/deps.py ``model_write`` does, for a write)."""

    def headers(self) -> dict[str, str]:
        return {"Retry-After": str(self.retry_after)}


class StorageUnavailable(ServiceUnavailable):
    """The database could not take the request: lost connection, full disk, I/O error, lock timeout."""

    error = "storage_unavailable"

    def __init__(self, reason: str, retry_after: int = 1, *, outcome_unknown: bool = False) -> None:
        self.reason = reason
        outcome = (
            "the connection was lost after the commit was sent, so the database may have stored the write: "
            "retry a keyed write with the same Idempotency-Key to get its stored answer, and check before "
            "repeating any other"
            if outcome_unknown
            else "nothing was changed, retry later"
        )
        super().__init__(f"storage unavailable: {reason}; {outcome}", retry_after)


class StorageBusy(ServiceUnavailable):
    """The database's write lock stayed held by another transaction longer than the busy timeout
    (SQLite ``CONTEXTWEB_SQLITE_BUSY_TIMEOUT_MS``, PostgreSQL ``lock_timeout``): transient, the
    database itself is fine, so it does not make the service unready."""

    error = "storage_busy"

    def __init__(self, reason: str, retry_after: int = 1) -> None:
        super().__init__(f"storage busy: {reason}; nothing was changed, retry later", retry_after)


class ModelUnavailable(ServiceUnavailable):
    """The model's memory could not be proven equal to the database: it is reloaded before it serves again."""

    error = "model_unavailable"

    def __init__(self, model_id: str, reason: str, retry_after: int = 1) -> None:
        super().__init__(f"model {model_id!r} is unavailable: {reason}", retry_after)


class StoredDataDamaged(ContextwebError):
    """Stored bytes the server cannot read (a damaged answer blob, a corrupt database page): not the
    client's fault and not transient, so neither a 4xx nor a 503 to retry. ``contextweb models
    check`` names the damage (docs/operations.md, "Damaged storage")."""

    error = "stored_data_damaged"
    status_code = 500


class UnexpectedError(ContextwebError):
    """An error no route expected (a bug): answered in the documented shape, logged with its traceback
    (app/middleware.py ``UnexpectedErrors``)."""

    error = "internal_error"
    status_code = 500


class TooManyRequests(ContextwebError):
    """A 429 the client should retry after ``retry_after`` seconds (app/admission.py)."""

    status_code = 429

    def __init__(self, message: str, retry_after: int) -> None:
        super().__init__(message)
        self.retry_after = retry_after

    def headers(self) -> dict[str, str]:
        return {"Retry-After": str(self.retry_after)}


class ModelBusy(TooManyRequests):
    """The model's queue of waiting writes is full (``CONTEXTWEB_MODEL_WRITE_QUEUE``)."""

    error = "model_busy"

    def __init__(self, model_id: str, waiting: int, retry_after: int) -> None:
        super().__init__(f"model {model_id!r} already has {waiting} write(s) waiting; retry later", retry_after)


class RateLimited(TooManyRequests):
    """The client's token bucket is empty (``CONTEXTWEB_RATE_LIMIT_PER_SECOND``, ``..._BURST``)."""

    error = "rate_limited"

    def __init__(self, rate: float, burst: int, retry_after: int) -> None:
        super().__init__(f"more than {burst} writes at once or {rate:g} a second from this client", retry_after)


class NotReady(ServiceUnavailable):
    """``/readyz``'s 503: a load balancer or orchestrator probes again (``Retry-After`` says when)."""

    error = "not_ready"

    def __init__(self, reason: str) -> None:
        super().__init__(reason, retry_after=1)


def error_response(error: str, detail: str, status_code: int, field: str | None = None, **kwargs: Any) -> JSONResponse:
    body = ErrorRead(error=error, detail=detail, field=field).model_dump()
    return JSONResponse(body, status_code=status_code, **kwargs)


def error_responses(*errors: type[ContextwebError]) -> dict[int | str, dict[str, Any]]:
    """The ``responses=`` entry of a route that may raise these errors (for OpenAPI)."""
    statuses: dict[int, list[str]] = {}
    for error_type in errors:
        statuses.setdefault(error_type.status_code, []).append(error_type.error)
    return {
        status: {"model": ErrorRead, "description": " or ".join(names)} for status, names in sorted(statuses.items())
    }


def field_name(location: Sequence[Any]) -> str:
    """``("body", "objects", 0, "features", "entity")`` -> ``objects[0].features.entity``."""
    parts = list(location)
    if parts and parts[0] == "body":
        parts = parts[1:]
    name = ""
    for part in parts:
        if part in UNION_TAGS:
            continue
        if isinstance(part, int):
            name += f"[{part}]"
        else:
            name += f".{part}" if name else str(part)
    return name or "body"


async def _contextweb_error(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, ContextwebError)
    if isinstance(exc, StorageUnavailable) and not exc.recorded:
        _record_storage_failure(request, exc.reason)
    return error_response(exc.error, exc.message, exc.status_code, exc.field, headers=exc.headers())


def _record_storage_failure(request: Request, reason: str) -> None:
    """A read's storage failure, counted in the process's storage health (``app.storage_health``:
    readiness, and the log lines of a failure's start and end)."""
    state = getattr(request.state, "contextweb", None)
    if state is not None:
        state.storage.record_failure(reason)


async def _invalid_input(_request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, InvalidInputError)
    return error_response(InvalidInput.error, exc.problem, 422, exc.field)


async def _request_validation(_request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, RequestValidationError)
    errors = [_located(error) for error in exc.errors()]
    first = errors[0] if errors else {"loc": ("body",), "msg": "invalid request"}
    detail = "; ".join(f"{field_name(e['loc'])}: {e['msg']}" for e in errors[:5])
    return error_response(InvalidInput.error, detail, 422, field_name(first["loc"]))


def _located(error: dict[str, Any]) -> dict[str, Any]:
    """FastAPI locates a JSON syntax error at ``("body", <character offset>)``, which would read as
    the field ``[17]``: the field is the body, and the offset and the parser's words go in the message.
    A body FastAPI did not parse (no JSON content type) is validated as bytes: say what to send.
    A refused pattern is said in words (``PATTERN_MEANINGS``), not as its regular expression."""
    if tuple(error.get("loc", ())) == ("body",) and isinstance(error.get("input"), bytes):
        return {**error, "msg": "not read as JSON: send a JSON object with Content-Type: application/json"}
    if error.get("type") == "string_pattern_mismatch":
        meaning = PATTERN_MEANINGS.get(str((error.get("ctx") or {}).get("pattern")))
        return error if meaning is None else {**error, "msg": meaning}
    if error.get("type") != "json_invalid":
        return error
    # A repeated key has no position (app/routing.py: NO_POSITION).
    position = next((part for part in error["loc"][1:] if isinstance(part, int) and part >= 0), None)
    reason = (error.get("ctx") or {}).get("error", "")
    where = f" at character {position}" if position is not None else ""
    return {**error, "loc": ("body",), "msg": f"not valid JSON{where}" + (f" ({reason})" if reason else "")}


#: Database failures of the field: the driver's operational errors (lost connection, refused
#: connection, full disk, I/O error, lock timeout, read-only file), the pool's time-out and an
#: aborted transaction. A ProgrammingError or DataError is a bug and stays a 500.
STORAGE_FAILURES: tuple[type[BaseException], ...] = (
    OperationalError,
    InterfaceError,
    InternalError,
    PoolTimeoutError,
    DisconnectionError,
    PendingRollbackError,
)


def is_storage_failure(exc: BaseException) -> bool:
    return isinstance(exc, STORAGE_FAILURES) or (
        isinstance(exc, DBAPIError) and bool(getattr(exc, "connection_invalidated", False))
    )


def is_write_conflict(exc: BaseException) -> bool:
    """A write refused by one of the database's constraints (a unique key, a foreign key)."""
    return isinstance(exc, IntegrityError)


def write_conflict(model_id: str, exc: BaseException) -> ModelUnavailable:
    """The 503 of a write that collided with stored rows (app/deps.py ``model_write``)."""
    return ModelUnavailable(
        model_id, f"the write conflicts with a stored row ({storage_failure_reason(exc)}); nothing was stored, retry"
    )


def is_storage_busy(exc: BaseException) -> bool:
    """A lock wait that ran out: SQLite's busy timeout (SQLITE_BUSY, "database is locked") or
    PostgreSQL's ``lock_timeout`` (SQLSTATE 55P03)."""
    original = getattr(exc, "orig", None) or exc
    if isinstance(original, sqlite3.OperationalError):
        return getattr(original, "sqlite_errorcode", 0) & 0xFF == sqlite3.SQLITE_BUSY
    return getattr(original, "sqlstate", None) == LOCK_NOT_AVAILABLE


def is_unresponsive_database(exc: BaseException) -> bool:
    """A storage failure in which the database did not answer in time at all: a deadline cut the
    connection (storage/deadlines.py), or a new connection's ``connect_timeout`` ran out."""
    original = getattr(exc, "orig", None) or exc
    return deadline_that_passed(exc) is not None or isinstance(original, psycopg.errors.ConnectionTimeout)


def storage_error(exc: BaseException) -> ServiceUnavailable:
    """The 503 of a storage failure: ``storage_busy`` for a lock wait that ran out, else ``storage_unavailable``,
    whose detail says whether the write may have been stored (the connection lost after its commit was sent)."""
    if is_storage_busy(exc):
        return StorageBusy(storage_failure_reason(exc))
    return StorageUnavailable(storage_failure_reason(exc), outcome_unknown=commit_outcome_unknown(exc))


def is_storage_damage(exc: BaseException) -> bool:
    """The database reports its own stored data damaged: SQLite's ``SQLITE_CORRUPT`` or
    ``SQLITE_NOTADB`` ("database disk image is malformed"), PostgreSQL's class XX001/XX002
    (``data_corrupted``, ``index_corrupted``)."""
    original = getattr(exc, "orig", None)
    if original is None:
        return False
    sqlite_code = getattr(original, "sqlite_errorcode", None)
    if sqlite_code is not None:
        return sqlite_code & 0xFF in (
            11,
            26,
        )  # SQLITE_CORRUPT, SQLITE_NOTADB (extended codes keep them in the low byte)
    return getattr(original, "sqlstate", None) in ("XX001", "XX002")


def storage_damage(exc: BaseException, what: str) -> StoredDataDamaged:
    """The 500 of :func:`is_storage_damage`, naming ``what`` was being read."""
    return StoredDataDamaged(
        f"the database reports {what} damaged ({storage_failure_reason(exc)}); "
        "`contextweb models check` names the models it reaches, and the database needs its backup or repair"
    )


async def _storage_error(request: Request, exc: Exception) -> JSONResponse:
    """A database failure that reached a route: a 503 to retry, never a bare 500 (app/deps.py has
    already made sure no memory leads the database); damage the database reports in its own data,
    a 500 ``stored_data_damaged`` (retrying reads the same pages)."""
    if is_storage_damage(exc):
        logger.error("%s", storage_failure_reason(exc))
        damaged = storage_damage(exc, "what this request read")
        return error_response(damaged.error, damaged.message, damaged.status_code)
    if not is_storage_failure(exc):
        raise exc
    error = storage_error(exc)
    if isinstance(error, StorageUnavailable):
        _record_storage_failure(request, error.reason)
    return error_response(error.error, error.message, error.status_code, headers=error.headers())


def storage_failure_reason(exc: BaseException) -> str:
    """A short, key-free description of a database failure (the driver's first line), or the
    deadline that cut the connection of a database that stopped answering."""
    deadline = deadline_that_passed(exc)
    if deadline is not None:
        return f"the database did not answer within {deadline}"
    original = getattr(exc, "orig", None) or exc
    first_line = (str(original).strip().splitlines() or [""])[0][:200]
    return f"{type(original).__name__}: {first_line}" if first_line else type(original).__name__


async def _http_error(_request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, StarletteHTTPException)
    cause = exc.__cause__
    if isinstance(cause, UnicodeDecodeError):  # FastAPI's 400 "error parsing the body": bytes that are not UTF-8
        detail = f"body: not valid JSON: byte {cause.start} is not UTF-8 (JSON text is UTF-8)"
        return error_response(InvalidInput.error, detail, 422, "body")
    error = {404: "not_found", 405: "method_not_allowed", 413: PayloadTooLarge.error}.get(exc.status_code, "http_error")
    return error_response(error, str(exc.detail), exc.status_code, headers=getattr(exc, "headers", None))


def add_exception_handlers(app: FastAPI) -> None:
    app.add_exception_handler(ContextwebError, _contextweb_error)
    app.add_exception_handler(InvalidInputError, _invalid_input)
    app.add_exception_handler(RequestValidationError, _request_validation)
    app.add_exception_handler(StarletteHTTPException, _http_error)
    app.add_exception_handler(SQLAlchemyError, _storage_error)
