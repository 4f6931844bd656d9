"""WS /v1/models/{model_id}/stream: a dashboard's live feed of one model (docs/stream.md)."""

from __future__ import annotations

import asyncio
import logging
from typing import Any

from fastapi import APIRouter, WebSocket, WebSocketDisconnect
from sqlalchemy.exc import SQLAlchemyError

from app.auth import authenticate, stream_subprotocol, websocket_key
from app.routing import JsonBodyRoute
from app.schemas.stream import HelloEvent
from app.settings import Settings, normalise_origin
from app.state import AppState
from app.stream import (
    CLOSE_FORBIDDEN,
    CLOSE_INTERNAL_ERROR,
    CLOSE_MODEL_NOT_FOUND,
    CLOSE_TOO_SLOW,
    CLOSE_UNAUTHORIZED,
    CloseInstruction,
    Subscriber,
)
from app.websocket_protocol import CLOSE_HANDSHAKE_SECONDS, RESET_EXTENSION

router = APIRouter(route_class=JsonBodyRoute)
logger = logging.getLogger("contextweb")


@router.websocket("/v1/models/{model_id}/stream")
async def stream(websocket: WebSocket, model_id: str) -> None:
    """Accept, check the key (app/auth.py :func:`websocket_key`) and the model, then forward events.

    A key scoped to other models is told 4404, as for a model that does not exist."""
    state: AppState = websocket.state.contextweb
    feed = state.feed
    await websocket.accept(subprotocol=stream_subprotocol(websocket))
    if not _origin_allowed(websocket, state.settings.allowed_origins):
        await websocket.close(CLOSE_FORBIDDEN, "origin not allowed")
        return
    try:
        principal = await authenticate(state.settings, state.read_sessions, websocket_key(websocket))
    except SQLAlchemyError as error:
        logger.warning("stream of model %s refused: cannot check its key: %s", model_id, type(error).__name__)
        await websocket.close(CLOSE_INTERNAL_ERROR, "storage unavailable")
        return
    if principal is None:
        await websocket.close(CLOSE_UNAUTHORIZED, "a valid API key is required")
        return
    if not principal.covers(model_id):
        await websocket.close(CLOSE_MODEL_NOT_FOUND, f"no model {model_id!r}")
        return
    try:
        start = await feed.subscribe(model_id)  # the database says whether the model exists, on any process
    except Exception as error:  # noqa: BLE001 - the database did not answer: say so and close
        logger.warning("stream of model %s refused: %s: %s", model_id, type(error).__name__, error)
        await websocket.close(CLOSE_INTERNAL_ERROR, "storage unavailable")
        return
    if start is None:
        await websocket.close(CLOSE_MODEL_NOT_FOUND, f"no model {model_id!r}")
        return
    start.subscriber.key_id = principal.key_id  # before any await: a revocation from now on closes it
    hello = HelloEvent(model_id=model_id, context_count=start.context_count, scene_count=start.scene_count)
    try:
        await _forward(websocket, start.subscriber, hello.model_dump(mode="json"), state.settings)
    finally:
        feed.unsubscribe(start.subscriber)
        _reset(websocket, after=CLOSE_HANDSHAKE_SECONDS)  # a no-op once the connection has closed


def _origin_allowed(websocket: WebSocket, allowed_origins: list[str]) -> bool:
    """Whether a browser's ``Origin`` is allowed; robots send none and always are (docs/stream.md)."""
    origin = websocket.headers.get("origin")
    return not allowed_origins or origin is None or normalise_origin(origin) in allowed_origins


async def _forward(websocket: WebSocket, subscriber: Subscriber, hello: dict[str, Any], settings: Settings) -> None:
    """Send the hello, then queued events until the hub says close, the client goes, or it stops reading.

    Every send waits at most ``stream_send_timeout_seconds``; one that waits longer closes with
    1013. The client's messages are ignored.
    """
    send_seconds = settings.stream_send_timeout_seconds
    too_slow = f"client too slow: a send waited {send_seconds:g} s"
    receiving = asyncio.ensure_future(websocket.receive())
    try:
        if not await _send_within(websocket, hello, send_seconds):
            await _close_slow_client(websocket, subscriber, too_slow)
            return
        while True:
            getting = asyncio.ensure_future(subscriber.queue.get())
            await asyncio.wait({receiving, getting}, return_when=asyncio.FIRST_COMPLETED)
            if receiving.done() and receiving.result()["type"] == "websocket.disconnect":
                getting.cancel()
                return
            if getting.done():
                event = getting.result()
                if isinstance(event, CloseInstruction):
                    if event.code == CLOSE_TOO_SLOW:
                        await _close_slow_client(websocket, subscriber, event.reason)
                    else:
                        await _close(websocket, event.code, event.reason)
                    return
                if not await _send_within(websocket, event, send_seconds):
                    await _close_slow_client(websocket, subscriber, too_slow)
                    return
            else:
                getting.cancel()
            if receiving.done():
                receiving = asyncio.ensure_future(websocket.receive())
    except WebSocketDisconnect:
        return  # the connection was lost under a send: nothing left to close
    finally:
        receiving.cancel()


async def _send_within(websocket: WebSocket, event: dict[str, Any], seconds: float) -> bool:
    """Send ``event``; False when it could not be written within ``seconds`` (the client does not read).

    Cancelling the send is safe: uvicorn's protocol waits for a writable transport before it
    touches any state, and writes without awaiting afterwards (app/websocket_protocol.py).
    """
    try:
        async with asyncio.timeout(seconds):
            await websocket.send_json(event)
    except TimeoutError:
        return False
    return True


async def _close_slow_client(websocket: WebSocket, subscriber: Subscriber, reason: str) -> None:
    """Close with 1013 and say so in the log (one line per dropped client)."""
    client = f"{websocket.client.host}:{websocket.client.port}" if websocket.client else "unknown client"
    logger.info("stream of model %s: dropping %s (%s)", subscriber.model_id, client, reason)
    await _close(websocket, CLOSE_TOO_SLOW, reason)


async def _close(websocket: WebSocket, code: int, reason: str) -> None:
    """Close with ``code``, or reset the connection when the close frame cannot be written in time."""
    try:
        async with asyncio.timeout(CLOSE_HANDSHAKE_SECONDS):
            await websocket.close(code, reason)
    except TimeoutError:
        _reset(websocket)


def _reset(websocket: WebSocket, after: float = 0.0) -> None:
    """Reset the TCP connection, ``after`` seconds from now; only under ``contextweb serve``, which offers it."""
    extension = websocket.scope.get("extensions", {}).get(RESET_EXTENSION)
    if extension is None:
        return
    if after:
        asyncio.get_running_loop().call_later(after, extension["reset"])
    else:
        extension["reset"]()
