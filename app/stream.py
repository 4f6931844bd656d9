"""The websocket hub: events of each model fanned out to its dashboards (docs/stream.md).

Events come from the scene feed (app/feed.py), which reads them from the
database on a thread and hands them to the event loop; there they are put in
every subscriber's bounded queue. A subscriber whose queue is full is dropped:
its queue is replaced by a single close instruction, so one slow dashboard
never holds memory or slows the robots down.

A subscriber gets ``scene`` events with consecutive ids from the position it
subscribed at (the hello's ``scene_count``), each once: a scene event out of
that sequence, and the ``context_discovered`` event of a scene it did not get,
are not queued for it.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

#: Close codes (docs/stream.md). 4000 + the HTTP status for refusals, RFC 6455 codes otherwise.
CLOSE_NORMAL = 1000
CLOSE_INTERNAL_ERROR = 1011
CLOSE_SERVICE_RESTART = 1012
CLOSE_TOO_SLOW = 1013
CLOSE_UNAUTHORIZED = 4401
CLOSE_FORBIDDEN = 4403
CLOSE_MODEL_NOT_FOUND = 4404


@dataclass(frozen=True)
class CloseInstruction:
    code: int
    reason: str


@dataclass(eq=False)
class Subscriber:
    """One connected dashboard: its model, its bounded queue of events and its place in the scenes."""

    model_id: str
    queue: asyncio.Queue[dict[str, Any] | CloseInstruction] = field(repr=False)
    next_scene_id: int | None = None
    """The id of the next ``scene`` event it takes (None: it takes every event as published)."""
    last_scene_id: int | None = None
    """The id of the last ``scene`` event it took."""
    discovered_scene_id: int | None = None
    """The scene of the last ``context_discovered`` event it took."""
    key_id: str | None = None
    """The stored API key it connected with (app/auth.py closes it when that key is revoked)."""

    def takes(self, event: dict[str, Any]) -> bool:
        """Whether ``event`` is next for this subscriber (and if so, count it as taken)."""
        if self.next_scene_id is None:
            return True
        kind = event.get("type")
        if kind in ("scene", "scene_unreadable"):  # a scene's place in the order, its answer or not
            if event["scene_id"] != self.next_scene_id:
                return False
            self.last_scene_id = self.next_scene_id
            self.next_scene_id += 1
        elif kind == "context_discovered":
            if event["scene_id"] != self.last_scene_id or event["scene_id"] == self.discovered_scene_id:
                return False
            self.discovered_scene_id = event["scene_id"]
        return True


class StreamHub:
    """Per-model fan-out of events to websocket subscribers, with bounded queues.

    Methods ending in ``_now`` run on the event loop; the others are safe from any thread.
    """

    def __init__(self, queue_size: int) -> None:
        self.queue_size = queue_size
        self._subscribers: dict[str, set[Subscriber]] = {}
        self._loop: asyncio.AbstractEventLoop | None = None

    def bind(self, loop: asyncio.AbstractEventLoop) -> None:
        """Deliver on ``loop`` (the server's event loop); called by the lifespan."""
        self._loop = loop

    def subscribe(self, model_id: str, next_scene_id: int | None = None) -> Subscriber:
        """A new subscriber of ``model_id`` whose first scene event will be ``next_scene_id``; on the loop."""
        subscriber = Subscriber(model_id, asyncio.Queue(maxsize=self.queue_size), next_scene_id)
        self._subscribers.setdefault(model_id, set()).add(subscriber)
        return subscriber

    def unsubscribe(self, subscriber: Subscriber) -> None:
        subscribers = self._subscribers.get(subscriber.model_id)
        if subscribers is not None:
            subscribers.discard(subscriber)
            if not subscribers:
                del self._subscribers[subscriber.model_id]

    def subscriber_count(self, model_id: str) -> int:
        return len(self._subscribers.get(model_id, ()))

    def call_soon(self, callback: Callable[..., None], *args: Any) -> None:
        """Run ``callback(*args)`` on the event loop, in call order; nothing once the loop is gone."""
        if self._loop is None:
            return
        with contextlib.suppress(RuntimeError):  # the loop is closed: the server is shutting down
            self._loop.call_soon_threadsafe(callback, *args)

    def publish(self, model_id: str, event: dict[str, Any]) -> None:
        """Queue ``event`` for every subscriber of ``model_id``."""
        if model_id in self._subscribers:
            self.call_soon(self.deliver_now, model_id, event)

    def close_model(self, model_id: str, code: int, reason: str) -> None:
        """Close every subscriber of ``model_id`` (the model was deleted)."""
        self.call_soon(self.close_model_now, model_id, code, reason)

    def deliver_now(self, model_id: str, event: dict[str, Any]) -> None:
        """Queue ``event`` for every subscriber of ``model_id`` it is next for; drop the ones whose queue is full."""
        for subscriber in list(self._subscribers.get(model_id, ())):
            if not subscriber.takes(event):
                continue
            try:
                subscriber.queue.put_nowait(event)
            except asyncio.QueueFull:
                self._drop(subscriber, CloseInstruction(CLOSE_TOO_SLOW, "client too slow: event queue full"))

    def close_model_now(self, model_id: str, code: int, reason: str) -> None:
        for subscriber in list(self._subscribers.get(model_id, ())):
            self._drop(subscriber, CloseInstruction(code, reason))

    def stream_key_ids_now(self) -> set[str]:
        """The stored keys of the open subscribers."""
        return {s.key_id for subscribers in self._subscribers.values() for s in subscribers if s.key_id is not None}

    def close_key_now(self, key_id: str, code: int, reason: str) -> None:
        """Close every subscriber connected with the stored key ``key_id`` (it was revoked)."""
        for subscribers in list(self._subscribers.values()):
            for subscriber in [s for s in subscribers if s.key_id == key_id]:
                self._drop(subscriber, CloseInstruction(code, reason))

    def close_everyone(self, reason: str) -> None:
        """Close every subscriber (shutdown); called on the event loop.

        1012 like uvicorn, which closes every websocket with 1012 itself before the
        lifespan's shutdown calls this: under ``contextweb serve`` nobody is left by
        then, under another server the code is the same (docs/stream.md).
        """
        for model_id in list(self._subscribers):
            self.close_model_now(model_id, CLOSE_SERVICE_RESTART, reason)

    def _drop(self, subscriber: Subscriber, instruction: CloseInstruction) -> None:
        """Forget the queued events and leave only the close instruction."""
        self.unsubscribe(subscriber)
        while not subscriber.queue.empty():
            subscriber.queue.get_nowait()
        subscriber.queue.put_nowait(instruction)
