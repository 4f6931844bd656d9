"""ASGI middleware: the body size limit, and the Prometheus middleware with its route names memoised.

:class:`BodySizeLimit` refuses request bodies above ``CONTEXTWEB_MAX_BODY_BYTES``
with a 413 before parsing them: a declared ``Content-Length`` over the limit is
answered at once; a chunked body is counted as it streams in and cut off as soon
as it passes the limit.
"""

from __future__ import annotations

import threading
from collections import OrderedDict

from fastapi import FastAPI
from prometheus_fastapi_instrumentator.middleware import PrometheusInstrumentatorMiddleware
from starlette.exceptions import HTTPException
from starlette.middleware import Middleware
from starlette.requests import Request
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from app.errors import PayloadTooLarge, error_response


class BodySizeLimit:
    """Pure ASGI middleware (no response buffering, no effect on websockets)."""

    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        declared = dict(scope["headers"]).get(b"content-length")
        if declared is not None and declared.isdigit() and int(declared) > self.max_bytes:
            error = PayloadTooLarge(self.max_bytes)
            response = error_response(error.error, error.message, error.status_code, error.field)
            await response(scope, receive, send)
            return
        await self.app(scope, self._counting(receive), send)

    def _counting(self, receive: Receive) -> Receive:
        received = 0

        async def counted() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.max_bytes:
                    raise HTTPException(413, PayloadTooLarge(self.max_bytes).message)
            return message

        return counted


class MemoisedRouteMetrics(PrometheusInstrumentatorMiddleware):
    """The instrumentator's middleware, resolving each request path to its route template once.

    The stock middleware matches the path against every route of the app on every
    request (≈ 0.3 ms a scene post); the routes never change once the app is
    built, so (method, root path, path) → template is memoised, for the
    ``ROUTE_NAMES_CACHED`` most recent paths (a robot posts to one path).
    """

    ROUTE_NAMES_CACHED = 1024

    def __init__(self, *args: object, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        self._route_names: OrderedDict[tuple[str, str, str], tuple[str, bool]] = OrderedDict()
        self._route_names_lock = threading.Lock()

    def _get_handler(self, request: Request) -> tuple[str, bool]:
        scope = request.scope
        key = (scope["method"], scope.get("root_path", ""), scope["path"])
        with self._route_names_lock:
            found = self._route_names.get(key)
            if found is not None:
                self._route_names.move_to_end(key)
                return found
        found = super()._get_handler(request)
        with self._route_names_lock:
            self._route_names[key] = found
            while len(self._route_names) > self.ROUTE_NAMES_CACHED:
                self._route_names.popitem(last=False)
        return found


def memoise_route_metrics(app: FastAPI) -> None:
    """Swap the middleware ``Instrumentator.instrument`` added for :class:`MemoisedRouteMetrics`
    (same arguments); call it after ``instrument`` and before the app starts."""
    app.user_middleware = [
        Middleware(MemoisedRouteMetrics, *entry.args, **entry.kwargs)
        if entry.cls is PrometheusInstrumentatorMiddleware
        else entry
        for entry in app.user_middleware
    ]
