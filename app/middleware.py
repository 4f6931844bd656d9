"""ASGI middleware: the request body's limits, and the answer to an error no route expected.

:class:`UnexpectedErrors` answers an exception that no handler took (a bug, or damage the code
did not foresee) as a 500 ``internal_error`` in the documented error shape, logs its traceback,
and keeps the connection: without it Starlette answers ``text/plain`` and re-raises, and uvicorn
then closes the keep-alive connection, so the client's next request on it fails too.

:class:`RequestBodyLimits` reads every HTTP request body before the routes see it
and answers in the documented error shape (``field: "body"``) when it is
unacceptable, so that no such body reaches the JSON parser:

- over ``CONTEXTWEB_MAX_BODY_BYTES``: 413 ``payload_too_large``, at once for a
  declared ``Content-Length``, as soon as the count passes the limit for a chunked body;
- not complete within ``CONTEXTWEB_BODY_READ_TIMEOUT_SECONDS`` of the request's
  start: 408 ``request_timeout`` (a client that stalls must not hold a connection,
  a task and its buffer forever);
- a JSON body in another encoding than UTF-8 (a declared ``charset`` or UTF-16/32
  bytes, which Python's parser would otherwise detect and accept), nested deeper than
  :data:`MAX_JSON_DEPTH` or with a number longer than :data:`MAX_NUMBER_LENGTH`
  characters: 422 ``invalid_input``. Python's parser answers the last two with a
  ``RecursionError`` or an int conversion error (a 400 outside the contract), and a
  5,000-digit integer costs quadratic time to convert.

413 and 408 close the connection (``Connection: close``): the rest of the body is
not worth reading. Reading the whole body here costs nothing extra, as the routes
read it whole anyway; the JSON checks' cost on a typical scene is in docs/benchmarks.md (docs/api.md, "Limits").
"""

from __future__ import annotations

import email.message
import functools
import json
import logging
from itertools import accumulate

import anyio
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from app.errors import ContextwebError, InvalidInput, PayloadTooLarge, RequestTimeout, UnexpectedError, error_response

logger = logging.getLogger("contextweb")

#: Deepest nesting of arrays and objects a JSON body may have. The deepest request
#: (a raw scene's interaction points) nests 10 levels; 32 leaves room and keeps every
#: parse far from Python's recursion limit.
MAX_JSON_DEPTH = 32
#: Longest number of a JSON body, in characters. A float64 needs at most 24
#: (17 significant digits, sign, point, exponent), an int64 20; 100 allows any
#: serialiser's padding, and stops the quadratic conversion of huge integers.
MAX_NUMBER_LENGTH = 100

_NOT_BRACKETS = bytes(byte for byte in range(256) if byte not in b"[]{}")
_BRACKET_STEP = tuple(1 if byte in b"[{" else -1 if byte in b"]}" else 0 for byte in range(256))
_NUMBER_CHARACTERS = bytes(ord("0") if byte in b"+-.0123456789Ee" else ord(" ") for byte in range(256))
_TOO_LONG_NUMBER = b"0" * (MAX_NUMBER_LENGTH + 1)
_UTF8 = frozenset({"utf-8", "utf8"})
#: Distinct Content-Type headers whose parse is kept (least recently used dropped first).
CONTENT_TYPES_KEPT = 64


def json_body_problem(body: bytes) -> str | None:
    """Why a JSON body is refused before parsing (encoding, depth, number length), or None.

    Linear and in C loops (bytes methods, ``translate``, ``accumulate``): the text outside
    strings is found by dropping escaped backslashes and quotes, then splitting at the
    quotes. On a body that is not JSON the answer may be any of these or None; the
    parser then refuses it anyway.
    """
    encoding = json.detect_encoding(body)
    if encoding not in ("utf-8", "utf-8-sig"):
        return f"JSON text must be UTF-8, and this body is {encoding.upper()}"
    if b"\\" in body:
        body = body.replace(b"\\\\", b"").replace(b'\\"', b"")
    outside_strings = b"".join(body.split(b'"')[::2])
    brackets = outside_strings.translate(None, _NOT_BRACKETS)
    depth = max(accumulate(map(_BRACKET_STEP.__getitem__, brackets)), default=0)
    if depth > MAX_JSON_DEPTH:
        return f"JSON nested {depth} levels deep; the limit is {MAX_JSON_DEPTH}"
    if _TOO_LONG_NUMBER in outside_strings.translate(_NUMBER_CHARACTERS):
        return f"a number longer than {MAX_NUMBER_LENGTH} characters"
    return None


def declared_charset_problem(content_type: str | None) -> str | None:
    """Why a JSON content type is refused: it declares a charset other than UTF-8 (RFC 8259 §8.1)."""
    if not content_type:
        return None
    return _content_type(content_type)[1]


def is_json_content_type(content_type: str) -> bool:
    """The media types FastAPI parses as JSON (``application/json`` and ``application/*+json``)."""
    return _content_type(content_type)[0]


@functools.lru_cache(maxsize=CONTENT_TYPES_KEPT)
def _content_type(content_type: str) -> tuple[bool, str | None]:
    """(JSON?, the charset problem) of one Content-Type header, parsed once: a client sends the same
    header with every request, and ``email.message`` parsing it twice a request was a visible part
    of the event loop's time per scene (docs/benchmarks.md)."""
    message = email.message.Message()
    message["content-type"] = content_type
    subtype = message.get_content_subtype()
    is_json = message.get_content_maintype() == "application" and (subtype == "json" or subtype.endswith("+json"))
    charset = message.get_param("charset")
    if not is_json or not isinstance(charset, str) or charset.lower() in _UTF8:
        return is_json, None
    return is_json, f"JSON text must be UTF-8, and the Content-Type declares charset={charset}"


class _BodyTooLarge(Exception):
    pass


class _Disconnected(Exception):
    pass


class RequestBodyLimits:
    """Pure ASGI middleware (no response buffering, no effect on websockets or the lifespan)."""

    def __init__(self, app: ASGIApp, max_bytes: int, read_timeout_seconds: float) -> None:
        self.app = app
        self.max_bytes = max_bytes
        self.read_timeout_seconds = read_timeout_seconds

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = dict(scope["headers"])
        declared = headers.get(b"content-length")
        if declared is not None and declared.isdigit() and int(declared) > self.max_bytes:
            await _refuse(PayloadTooLarge(self.max_bytes), scope, receive, send, close=True)
            return
        content_type = headers.get(b"content-type", b"").decode("latin-1")
        if problem := declared_charset_problem(content_type):
            await _refuse(InvalidInput("body", problem), scope, receive, send, close=True)
            return
        body: bytes | None = None
        try:
            with anyio.move_on_after(self.read_timeout_seconds):
                body = await self._read_body(receive)
        except _BodyTooLarge:
            await _refuse(PayloadTooLarge(self.max_bytes), scope, receive, send, close=True)
            return
        except _Disconnected:  # the route meets the disconnect on its own read, as without this middleware
            await self.app(scope, receive, send)
            return
        if body is None:
            await _refuse(RequestTimeout(self.read_timeout_seconds), scope, receive, send, close=True)
            return
        if body and content_type and is_json_content_type(content_type) and (problem := json_body_problem(body)):
            await _refuse(InvalidInput("body", problem), scope, receive, send)
            return
        await self.app(scope, _replaying(body, receive), send)

    async def _read_body(self, receive: Receive) -> bytes:
        """The whole body; :class:`_BodyTooLarge` as soon as it passes the limit, :class:`_Disconnected`
        when the client leaves first."""
        chunks: list[bytes] = []
        received = 0
        while True:
            message = await receive()
            if message["type"] != "http.request":
                raise _Disconnected
            chunk = message.get("body", b"")
            received += len(chunk)
            if received > self.max_bytes:
                raise _BodyTooLarge
            chunks.append(chunk)
            if not message.get("more_body", False):
                return b"".join(chunks)


def _replaying(body: bytes, receive: Receive) -> Receive:
    """A ``receive`` that gives the body read in one message, then the connection's own messages."""
    sent = False

    async def replay() -> Message:
        nonlocal sent
        if sent:
            return await receive()
        sent = True
        return {"type": "http.request", "body": body, "more_body": False}

    return replay


async def _refuse(error: ContextwebError, scope: Scope, receive: Receive, send: Send, *, close: bool = False) -> None:
    headers = {"Connection": "close"} if close else None
    response = error_response(error.error, error.message, error.status_code, error.field, headers=headers)
    await response(scope, receive, send)


class UnexpectedErrors:
    """A 500 ``internal_error`` JSON answer for an exception no handler took (module docstring).

    Innermost of the middlewares (just outside FastAPI's exception handlers), so that the others
    (the metrics, the body limits) see an ordinary 500 response. An exception raised after the
    response began cannot be answered: it is re-raised, and the server ends that connection.
    """

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        started = False

        async def send_watched(message: Message) -> None:
            nonlocal started
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, receive, send_watched)
        except Exception as error:
            if started:
                raise
            logger.exception("%s %s: an unexpected error", scope.get("method"), scope.get("path"))
            unexpected = UnexpectedError(
                f"an unexpected error ({type(error).__name__}); it is logged with its traceback, and retrying "
                "may meet it again"
            )
            response = error_response(unexpected.error, unexpected.message, unexpected.status_code)
            await response(scope, receive, send)
