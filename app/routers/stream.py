"""WS /v1/models/{model_id}/stream: a dashboard's live feed of one model (docs/stream.md)."""

from __future__ import annotations

import asyncio
import logging

from fastapi import APIRouter, WebSocket

from app.deps import API_KEY_HEADER, access_level
from app.schemas.stream import HelloEvent
from app.state import AppState
from app.stream import CLOSE_INTERNAL_ERROR, CLOSE_MODEL_NOT_FOUND, CLOSE_UNAUTHORIZED, CloseInstruction, Subscriber

router = APIRouter()
logger = logging.getLogger("contextweb")


@router.websocket("/v1/models/{model_id}/stream")
async def stream(websocket: WebSocket, model_id: str) -> None:
    """Accept, check the key (header X-API-Key or query ``api_key``) and the model, then forward events."""
    state: AppState = websocket.state.contextweb
    feed = state.feed
    await websocket.accept()
    key = websocket.headers.get(API_KEY_HEADER) or websocket.query_params.get("api_key")
    if access_level(state, key) is None:
        await websocket.close(CLOSE_UNAUTHORIZED, "a valid API key is required")
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
    try:
        hello = HelloEvent(model_id=model_id, context_count=start.context_count, scene_count=start.scene_count)
        await websocket.send_json(hello.model_dump(mode="json"))
        await _forward(websocket, start.subscriber)
    finally:
        feed.unsubscribe(start.subscriber)


async def _forward(websocket: WebSocket, subscriber: Subscriber) -> None:
    """Send queued events until the hub says close or the client goes (its messages are ignored)."""
    receiving = asyncio.ensure_future(websocket.receive())
    try:
        while True:
            getting = asyncio.ensure_future(subscriber.queue.get())
            await asyncio.wait({receiving, getting}, return_when=asyncio.FIRST_COMPLETED)
            if getting.done():
                event = getting.result()
                if isinstance(event, CloseInstruction):
                    await websocket.close(event.code, event.reason)
                    return
                await websocket.send_json(event)
            else:
                getting.cancel()
            if receiving.done():
                if receiving.result()["type"] == "websocket.disconnect":
                    return
                receiving = asyncio.ensure_future(websocket.receive())
    finally:
        receiving.cancel()
