"""The scene feed: each process streams every model's events from the database (docs/stream.md).

Several server processes serve one database, and a dashboard may be connected
to any of them, so events are not published by the process that learned the
scene: every model write notifies (storage/repositories/feed.py) and each
process's :class:`SceneFeed` reads what changed from the database, on one
daemon thread.

For each model with at least one local subscriber the feed keeps a cursor, the
next scene id to read. On each wake it reads the models' marks (one query for
all of them), then the stored answers of the scenes after each cursor, and
hands the events to the event loop, where the hub queues them (app/stream.py):
``scene`` and ``context_discovered`` from each stored answer, ``model_fitted``
when ``fitted_at`` changed, and a close with 1000 when the model row is gone.

Wake-ups: on PostgreSQL a dedicated connection ``LISTEN``s on the channel the
writes notify, with a fallback read every ``fallback_interval`` seconds (a lost
notification, a dropped connection: it reconnects with backoff); on SQLite the
feed reads every ``poll_interval`` seconds. Models without local subscribers
cost nothing, and a process without any holds no LISTEN connection: it is opened
with the first local subscriber (and read at once, so nothing committed before
the LISTEN is missed) and closed after the last. Otherwise every scene learned
on any process would wake each process's feed thread and its listening backend
for nothing (with two workers, 0.4 ms of CPU a scene: docs/benchmarks.md). The thread
never takes a model's lock.

Positions: a cursor starts at the model's stored scene count when its first
local subscriber arrives; a subscriber's hello reports the count of scenes
delivered so far on that cursor, and its first scene event is that id.
"""

from __future__ import annotations

import contextlib
import json
import logging
import select
import socket
import threading
import time
from dataclasses import dataclass
from datetime import datetime
from typing import Any

import anyio
import psycopg
from sqlalchemy import Engine
from sqlalchemy.exc import DBAPIError
from sqlalchemy.orm import Session, sessionmaker

from app.schemas.stream import ContextDiscoveredEvent, ModelFittedEvent, SceneEvent, SceneUnreadableEvent
from app.stream import CLOSE_NORMAL, StreamHub, Subscriber
from storage.compression import DamagedAnswerError, decompress_answer
from storage.repositories import feed as feed_repository
from storage.repositories.feed import ModelMark

logger = logging.getLogger("contextweb.feed")

#: Scenes read per query while a cursor catches up.
SCENES_PER_QUERY = 256
#: A missing scene id (never expected: writes to a model are serialised) is reported after this long.
GAP_WARNING_SECONDS = 5.0
#: ``application_name`` of the LISTEN connection (visible in ``pg_stat_activity``).
LISTEN_APPLICATION_NAME = "contextweb-feed"
#: Reconnection delays of the LISTEN connection: doubled from the first up to the last.
LISTEN_BACKOFF_SECONDS = (0.25, 5.0)


@dataclass(frozen=True)
class StreamStart:
    """Where a new subscriber starts: its first scene event will be ``scene_id == scene_count``."""

    subscriber: Subscriber
    scene_count: int
    context_count: int


@dataclass(eq=False)
class _Cursor:
    """The feed's position in one model with local subscribers.

    ``next_scene_id``, ``fitted_at`` and ``gap_since`` belong to the feed's thread (what it has read);
    ``delivered_scene_count`` and ``context_count`` to the event loop (what the subscribers were sent).
    """

    next_scene_id: int
    fitted_at: datetime | None
    delivered_scene_count: int
    context_count: int
    gap_since: float | None = None


class SceneFeed:
    """One process's reader of model changes, delivering them to the local websocket subscribers."""

    def __init__(
        self,
        hub: StreamHub,
        engine: Engine,
        sessions: sessionmaker[Session],
        *,
        poll_interval: float = 0.05,
        fallback_interval: float = 1.0,
    ) -> None:
        self._hub = hub
        self._sessions = sessions
        self._listener = _Listener(engine) if engine.dialect.name == "postgresql" else None
        self.interval = fallback_interval if self._listener is not None else poll_interval
        """Seconds between two reads when nothing woke the feed."""
        self._cursors: dict[str, _Cursor] = {}  # changed on the event loop, under _lock
        self._lock = threading.Lock()
        self._wake_receiver, self._wake_sender = socket.socketpair()
        self._wake_sender.setblocking(False)
        self._stopping = threading.Event()
        self._thread: threading.Thread | None = None
        self._read_failing = False

    @property
    def listener_backend_pid(self) -> int | None:
        """The PostgreSQL backend pid of the LISTEN connection (None: SQLite, or not connected)."""
        return None if self._listener is None else self._listener.backend_pid

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="contextweb-scene-feed", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 5.0) -> None:
        """Stop the thread (blocking, up to ``timeout`` seconds)."""
        self._stopping.set()
        self._wake()
        if self._thread is not None:
            self._thread.join(timeout)
            if self._thread.is_alive():
                logger.warning("the scene feed did not stop within %.1f s", timeout)
                return
        self._wake_receiver.close()
        self._wake_sender.close()

    async def subscribe(self, model_id: str) -> StreamStart | None:
        """A new local subscriber of ``model_id`` and where it starts; None if the model does not exist.

        On the event loop. The first subscriber of a model reads its mark (off the loop) and starts
        the cursor at its stored scene count; later ones start where the cursor has delivered to.
        """
        if model_id not in self._cursors:
            mark = await anyio.to_thread.run_sync(self._read_mark, model_id)
            if mark is None:
                return None
            if model_id not in self._cursors:  # no other subscriber started it meanwhile
                cursor = _Cursor(mark.scene_count, mark.fitted_at, mark.scene_count, mark.context_count)
                with self._lock:
                    self._cursors[model_id] = cursor
                self._wake()
        cursor = self._cursors[model_id]  # no await since the check: the position and the subscription agree
        subscriber = self._hub.subscribe(model_id, next_scene_id=cursor.delivered_scene_count)
        return StreamStart(subscriber, cursor.delivered_scene_count, cursor.context_count)

    def unsubscribe(self, subscriber: Subscriber) -> None:
        """Forget ``subscriber``; its model's cursor goes with its last subscriber. On the event loop."""
        self._hub.unsubscribe(subscriber)
        if not self._hub.subscriber_count(subscriber.model_id):
            with self._lock:
                self._cursors.pop(subscriber.model_id, None)
                last = not self._cursors
            if last:
                self._wake()  # the thread closes the LISTEN connection now, not at its next read

    # The event loop's side: deliveries the thread scheduled, in order.

    def _deliver(self, model_id: str, cursor: _Cursor, events: list[dict[str, Any]]) -> None:
        if self._cursors.get(model_id) is not cursor:
            return  # every subscriber left since the thread read these
        for event in events:
            self._hub.deliver_now(model_id, event)
            if event["type"] == "scene":
                cursor.delivered_scene_count = event["scene_id"] + 1
                cursor.context_count = event["context_count"]

    def _close_deleted(self, model_id: str, cursor: _Cursor) -> None:
        if self._cursors.get(model_id) is not cursor:
            return
        with self._lock:
            del self._cursors[model_id]
        self._hub.close_model_now(model_id, CLOSE_NORMAL, "model deleted")

    # The thread's side.

    def _wake(self) -> None:
        with contextlib.suppress(OSError):  # the buffer is full (a wake is pending anyway) or the feed stopped
            self._wake_sender.send(b"\0")

    def _read_mark(self, model_id: str) -> ModelMark | None:
        with self._sessions() as session:
            return feed_repository.model_marks(session, [model_id]).get(model_id)

    def _run(self) -> None:
        next_read = 0.0
        failing = False
        try:
            while not self._stopping.is_set():
                try:
                    next_read = self._step(next_read)
                    failing = False
                except Exception:
                    if not failing:
                        failing = True
                        logger.exception("the scene feed failed; it retries every %.2f s", self.interval)
                    if self._listener is not None:
                        self._listener.close()
                    self._stopping.wait(self.interval)
        finally:
            if self._listener is not None:
                self._listener.close()

    def _step(self, next_read: float) -> float:
        """Wait for a reason to read, read if there is one; returns when the next read is due."""
        with self._lock:
            watched = bool(self._cursors)
        notified, woken = self._wait(max(0.0, next_read - time.monotonic()) if watched else None, listen=watched)
        if self._stopping.is_set():
            return next_read
        with self._lock:
            cursors = dict(self._cursors)
        if woken or time.monotonic() >= next_read or not notified.isdisjoint(cursors):
            self._read_safely(cursors)
            next_read = time.monotonic() + self.interval
        return next_read

    def _wait(self, timeout: float | None, *, listen: bool) -> tuple[set[str], bool]:
        """Until a notification (``listen``: on PostgreSQL, with the LISTEN connection opened if it is
        not; else closed, as nobody watches), a wake or ``timeout`` (None: no limit): (notified model
        ids, woken)."""
        sockets: list[Any] = [self._wake_receiver]
        listener = self._listener
        if listener is not None and not listen:
            listener.close()  # each notification would only wake this thread and its backend
            listener = None
        if listener is not None:
            if listener.ensure_connected(self.interval):
                return set(), True  # notifications may have been lost while it was disconnected: read now
            if listener.connection is None:
                retry = listener.seconds_to_retry()
                timeout = retry if timeout is None else min(timeout, retry)
            else:
                sockets.append(listener.connection)
        ready, _, _ = select.select(sockets, [], [], timeout)
        woken = self._wake_receiver in ready
        if woken:
            self._wake_receiver.recv(4096)
        if listener is not None and listener.connection is not None and listener.connection in ready:
            return listener.drain(self.interval), woken
        return set(), woken

    def _read_safely(self, cursors: dict[str, _Cursor]) -> None:
        """:meth:`_read`, logging a failure once per outage (the next read retries)."""
        try:
            self._read(cursors)
        except Exception as error:
            if not self._read_failing:
                self._read_failing = True
                database_error = isinstance(error, DBAPIError | psycopg.Error)
                logger.warning(
                    "the scene feed cannot read the database (%s: %s); retrying every %.2f s",
                    type(error).__name__,
                    str(error).splitlines()[0] if str(error) else "",
                    self.interval,
                    exc_info=not database_error,
                )
            return
        if self._read_failing:
            self._read_failing = False
            logger.info("the scene feed reads the database again")

    def _read(self, cursors: dict[str, _Cursor]) -> None:
        if not cursors:
            return
        with self._sessions() as session:
            marks = feed_repository.model_marks(session, list(cursors))
            for model_id, cursor in cursors.items():
                mark = marks.get(model_id)
                if mark is None:
                    self._hub.call_soon(self._close_deleted, model_id, cursor)
                    continue
                events = []
                if mark.scene_count > cursor.next_scene_id:
                    events = self._scene_events(session, model_id, cursor)
                if mark.fitted_at != cursor.fitted_at:
                    cursor.fitted_at = mark.fitted_at
                    if mark.fitted_at is not None:
                        fitted = ModelFittedEvent(model_id=model_id, training_object_count=mark.training_object_count)
                        events.append(fitted.model_dump(mode="json"))
                if events:
                    self._hub.call_soon(self._deliver, model_id, cursor, events)

    def _scene_events(self, session: Session, model_id: str, cursor: _Cursor) -> list[dict[str, Any]]:
        """The events of the stored scenes from the cursor on, up to the first missing id."""
        events: list[dict[str, Any]] = []
        while True:
            rows = feed_repository.scenes_after(session, model_id, cursor.next_scene_id - 1, SCENES_PER_QUERY)
            for scene_id, stored in rows:
                if scene_id != cursor.next_scene_id:
                    self._note_gap(model_id, cursor)
                    return events
                try:
                    events.extend(_events_of_answer(model_id, json.loads(decompress_answer(stored))))
                except DamagedAnswerError as error:  # its place in the order is sent, and the stream goes on
                    logger.error(
                        "model %s: scene %d's stored answer is damaged (%s); its stream sends scene_unreadable",
                        model_id,
                        scene_id,
                        error,
                    )
                    unreadable = SceneUnreadableEvent(model_id=model_id, scene_id=scene_id, detail=str(error))
                    events.append(unreadable.model_dump(mode="json"))
                cursor.next_scene_id += 1
            cursor.gap_since = None
            if len(rows) < SCENES_PER_QUERY:
                return events

    def _note_gap(self, model_id: str, cursor: _Cursor) -> None:
        """A scene id is missing: wait for it (it cannot be skipped), saying so once if it stays missing."""
        now = time.monotonic()
        if cursor.gap_since is None:
            cursor.gap_since = now
        elif now - cursor.gap_since > GAP_WARNING_SECONDS:
            logger.warning("model %s: scene %d is missing; its stream waits for it", model_id, cursor.next_scene_id)
            cursor.gap_since = float("inf")


def _events_of_answer(model_id: str, answer: dict[str, Any]) -> list[dict[str, Any]]:
    """The ``scene`` event of a stored ``SceneRead`` answer, and its ``context_discovered`` if K grew."""
    scene = SceneEvent(
        model_id=model_id,
        scene_id=answer["scene_id"],
        context_count=answer["context_count"],
        context_posterior=answer["context_posterior"],
        map_context=answer["map_context"],
        map_context_label=answer.get("map_context_label"),  # absent from answers stored before labels existed
        active_concepts=[obj["active_concepts"] for obj in answer["objects"]],
        created_at=answer["created_at"],
    )
    events = [scene.model_dump(mode="json")]
    if answer["context_count"] > answer["previous_context_count"]:
        discovered = ContextDiscoveredEvent(
            model_id=model_id,
            scene_id=answer["scene_id"],
            context_count=answer["context_count"],
            previous_context_count=answer["previous_context_count"],
        )
        events.append(discovered.model_dump(mode="json"))
    return events


class _Listener:
    """The PostgreSQL connection that ``LISTEN``s on the models' channel, reconnected with backoff."""

    def __init__(self, engine: Engine) -> None:
        _, parameters = engine.dialect.create_connect_args(engine.url)
        parameters.pop("context", None)  # SQLAlchemy's adapters: not needed to listen
        parameters.setdefault("connect_timeout", 5)
        self._parameters = {
            **parameters,
            "autocommit": True,
            "application_name": LISTEN_APPLICATION_NAME,
            # A peer that vanished without closing is noticed within about 25 s.
            "keepalives": 1,
            "keepalives_idle": 10,
            "keepalives_interval": 5,
            "keepalives_count": 3,
        }
        self.connection: psycopg.Connection[Any] | None = None
        self._retry_at = 0.0
        self._backoff = LISTEN_BACKOFF_SECONDS[0]
        self._outage = False

    @property
    def backend_pid(self) -> int | None:
        connection = self.connection
        return None if connection is None else connection.info.backend_pid

    def seconds_to_retry(self) -> float:
        return max(0.0, self._retry_at - time.monotonic())

    def ensure_connected(self, fallback_interval: float) -> bool:
        """Connect and LISTEN if disconnected and the retry time has come; True when it just did."""
        if self.connection is not None or time.monotonic() < self._retry_at:
            return False
        try:
            connection = psycopg.connect(**self._parameters)
            try:
                connection.execute(f"LISTEN {feed_repository.CHANNEL}")
            except BaseException:
                connection.close()
                raise
        except psycopg.Error as error:
            self._failed(error, fallback_interval)
            return False
        self._backoff = LISTEN_BACKOFF_SECONDS[0]
        if self._outage:
            self._outage = False
            logger.info("the scene feed listens for model changes again")
        self.connection = connection
        return True

    def drain(self, fallback_interval: float) -> set[str]:
        """The model ids notified since the last call (the connection is readable)."""
        assert self.connection is not None
        try:
            return {notify.payload for notify in self.connection.notifies(timeout=0)}
        except psycopg.Error as error:
            self._failed(error, fallback_interval)
            return set()

    def close(self) -> None:
        if self.connection is not None:
            self.connection.close()
            self.connection = None

    def _failed(self, error: psycopg.Error, fallback_interval: float) -> None:
        """Drop the connection and schedule the next attempt; a warning once per outage."""
        self.close()
        self._retry_at = time.monotonic() + self._backoff
        self._backoff = min(2 * self._backoff, LISTEN_BACKOFF_SECONDS[1])
        if not self._outage:
            self._outage = True
            logger.warning(
                "the scene feed lost its LISTEN connection (%s: %s); reading every %.1f s until it is back",
                type(error).__name__,
                str(error).strip().splitlines()[0] if str(error).strip() else "",
                fallback_interval,
            )
