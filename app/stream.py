"""The websocket hub: events of each model fanned out to its dashboards (docs/stream.md).

Services publish from worker threads after their transaction committed;
:meth:`StreamHub.publish` hands the event to the event loop, which puts it in
every subscriber's bounded queue. A subscriber whose queue is full is dropped:
its queue is replaced by a single close instruction, so one slow dashboard
never holds memory or slows the robots down.
"""

from __future__ import annotations

import asyncio
from dataclasses import dataclass, field
from typing import Any

#: Close codes (docs/stream.md). 4000 + the HTTP status for refusals, RFC 6455 codes otherwise.
CLOSE_NORMAL = 1000
CLOSE_GOING_AWAY = 1001
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
    """One connected dashboard: its model and its bounded queue of events."""

    model_id: str
    queue: asyncio.Queue[dict[str, Any] | CloseInstruction] = field(repr=False)


class StreamHub:
    """Per-model fan-out of events to websocket subscribers, with bounded queues."""

    def __init__(self, queue_size: int) -> None:
        self.queue_size = queue_size
        self._subscribers: dict[str, set[Subscriber]] = {}
        self._loop: asyncio.AbstractEventLoop | None = None

    def bind(self, loop: asyncio.AbstractEventLoop) -> None:
        """Deliver on ``loop`` (the server's event loop); called by the lifespan."""
        self._loop = loop

    def subscribe(self, model_id: str) -> Subscriber:
        subscriber = Subscriber(model_id, asyncio.Queue(maxsize=self.queue_size))
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

    def publish(self, model_id: str, event: dict[str, Any]) -> None:
        """Queue ``event`` for every subscriber of ``model_id``; safe from any thread."""
        if self._loop is None or model_id not in self._subscribers:
            return
        self._loop.call_soon_threadsafe(self._deliver, model_id, event)

    def close_model(self, model_id: str, code: int, reason: str) -> None:
        """Close every subscriber of ``model_id`` (the model was deleted); safe from any thread."""
        if self._loop is not None:
            self._loop.call_soon_threadsafe(self._close_all, model_id, CloseInstruction(code, reason))

    def close_everyone(self, reason: str) -> None:
        """Close every subscriber (shutdown); called on the event loop."""
        for model_id in list(self._subscribers):
            self._close_all(model_id, CloseInstruction(CLOSE_GOING_AWAY, reason))

    def _deliver(self, model_id: str, event: dict[str, Any]) -> None:
        for subscriber in list(self._subscribers.get(model_id, ())):
            try:
                subscriber.queue.put_nowait(event)
            except asyncio.QueueFull:
                self._drop(subscriber, CloseInstruction(CLOSE_TOO_SLOW, "client too slow: event queue full"))

    def _close_all(self, model_id: str, instruction: CloseInstruction) -> None:
        for subscriber in list(self._subscribers.get(model_id, ())):
            self._drop(subscriber, instruction)

    def _drop(self, subscriber: Subscriber, instruction: CloseInstruction) -> None:
        """Forget the queued events and leave only the close instruction."""
        self.unsubscribe(subscriber)
        while not subscriber.queue.empty():
            subscriber.queue.get_nowait()
        subscriber.queue.put_nowait(instruction)
