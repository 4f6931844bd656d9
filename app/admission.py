"""Admission control of the writes: a bounded queue per model and a token bucket per client.

Both act on the event loop, before a write takes a worker thread (docs/scaling.md):

- **One write per model in progress, the others waiting on the loop.** A write to
  a model (a scene, training objects, a fit, a delete) holds the model's lock for
  its unit of work anyway (app/deps.py ``model_write``), so a second thread on the
  same model could only wait for it. :meth:`Admission.run_write` makes it wait
  here instead, on an ``asyncio.Lock`` that costs no thread: 20 clients hammering
  model A take one worker thread, and model B's writes find the others free. The
  perception of the scene runs inside the admission (outside the lock), so one
  model's feature extraction is never spread over every core either. At most
  ``model_write_queue`` writes wait per model, and their bodies total at most
  ``model_write_queue_bytes``; one more is a 429 ``model_busy`` whose
  ``Retry-After`` is the queue's expected wait (its length times the mean time of
  the model's recent writes, at least 1 s). A waiting request holds its parsed
  body (FastAPI parses it before the route runs), so the byte bound is what keeps
  memory bounded: 32 waiting maximum-size raw scenes held ≈ 0.5 GB, whereas 32
  waiting concept scenes hold a few hundred KB. One write may always wait,
  whatever its size, so that a model's queue never refuses everything.
- **A token bucket per client** (``rate_limit_per_second``, ``rate_limit_burst``):
  a write takes a token, tokens come back at the rate up to the burst; an empty
  bucket is a 429 ``rate_limited`` whose ``Retry-After`` is when the next token is
  due. The client is the digest of the ``X-API-Key`` presented (the key itself is
  never kept), or its address when it presents none. Off by default (rate 0):
  the queue bound already keeps one client from delaying the other models, and a
  right rate depends on each robot's sensors (a robot posting at its camera's
  30 Hz, a replay posting as fast as it can), so an operator sets it per fleet.

Both are per process: with ``--workers N`` or replicas each process admits its own
queue and buckets (a client spread over N processes gets up to N times the rate).
Every method runs on the event loop only, so none needs a lock.
"""

from __future__ import annotations

import asyncio
import hashlib
import math
import re
import time
from collections import OrderedDict
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from dataclasses import dataclass, field
from typing import Any, TypeVar

import anyio
from starlette.types import ASGIApp, Receive, Scope, Send

from app.errors import ModelBusy, RateLimited, error_response
from app.settings import Settings

T = TypeVar("T")
R = TypeVar("R")

#: Longest Retry-After answered (seconds): a longer estimate is no better a hint.
MAX_RETRY_AFTER_SECONDS = 60
#: Clients whose buckets are kept (least recently seen dropped first; a dropped bucket was full).
BUCKETS_KEPT = 10_000
#: Threads of the readiness probe (its own: every worker thread may be waiting on a lock).
PROBE_THREADS = 2
#: Weight of the newest write in a model's mean write time.
WRITE_TIME_WEIGHT = 0.2


@dataclass(eq=False)
class _ModelGate:
    """One model's admission: the write in progress and the writes waiting for it."""

    lock: asyncio.Lock = field(default_factory=asyncio.Lock)
    users: int = 0
    """Writes admitted: the one in progress and the waiting ones."""
    waiting_bytes: int = 0
    """The bodies of the waiting writes, in bytes."""
    started: float = 0.0
    mean_seconds: float = 0.0

    def expected_wait(self, now: float) -> int:
        """Seconds until the queue has drained: its length times the mean write (or the current one's age)."""
        per_write = max(self.mean_seconds, now - self.started)
        return min(MAX_RETRY_AFTER_SECONDS, max(1, math.ceil(self.users * per_write)))


@dataclass(eq=False)
class _Bucket:
    tokens: float
    updated: float


class Postponed(Exception):
    """Raised by a scene's ``learn`` on its scene thread when the rest would wait for a lock held by
    another process (app/routers/scenes.py): :meth:`Admission.run_scene` runs ``resume()`` on a
    write thread instead, so the wait holds none of the process's scene threads."""

    def __init__(self, resume: Callable[[], Any]) -> None:
        super().__init__("postponed to a write thread")
        self.resume = resume


class Admission:
    """The per-model write queues and the per-client token buckets of one process."""

    def __init__(
        self,
        *,
        model_write_queue: int,
        model_write_queue_bytes: int = 0,
        rate_per_second: float = 0.0,
        rate_burst: int = 1,
        write_threads: int = 4,
        scene_threads: int = 1,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.model_write_queue = model_write_queue
        self.model_write_queue_bytes = model_write_queue_bytes
        """0: no byte bound."""
        self.rate_per_second = rate_per_second
        self.rate_burst = rate_burst
        self._clock = clock
        self._gates: dict[str, _ModelGate] = {}
        self.write_threads = anyio.CapacityLimiter(write_threads)
        """Threads the admitted writes of every model share, apart from the routes' pool: writes to
        many models wait on the loop for one, not on the database's write lock in a thread that a
        read needs."""
        self.scene_threads = anyio.CapacityLimiter(scene_threads)
        """Threads that learn scenes (:meth:`run_scene`), apart from the other writes' (docs/scaling.md,
        "One scene at a time in a process")."""
        self.probe_threads = anyio.CapacityLimiter(PROBE_THREADS)
        """Threads of ``/readyz`` apart from the routes' pool: a probe never waits behind blocked writes."""
        self._buckets: OrderedDict[str, _Bucket] = OrderedDict()

    def admitted(self, model_id: str) -> int:
        """Writes to ``model_id`` admitted: the one in progress and those waiting behind it."""
        gate = self._gates.get(model_id)
        return 0 if gate is None else gate.users

    def waiting(self, model_id: str) -> int:
        """Writes to ``model_id`` waiting behind the one in progress."""
        gate = self._gates.get(model_id)
        return 0 if gate is None else max(0, gate.users - 1)

    async def run_write(self, model_id: str, work: Callable[..., T], *args: object, body_bytes: int = 0) -> T:
        """``work(*args)`` on a worker thread once the model's earlier writes are done; 429
        ``model_busy`` when the queue is full (``model_write_queue`` writes, or their
        ``body_bytes`` past ``model_write_queue_bytes``). A cancelled request leaves the queue;
        once its work started, the work runs to its end (its thread cannot be interrupted) and
        the next write waits for it."""
        async with self._admitted(model_id, body_bytes):
            return await anyio.to_thread.run_sync(work, *args, limiter=self.write_threads)

    async def run_scene(
        self,
        model_id: str,
        read: Callable[[], R],
        learn: Callable[[R], T],
        *,
        heavy: bool,
        body_bytes: int = 0,
    ) -> T:
        """A scene write, admitted as :meth:`run_write` admits one: ``learn(read())`` on a thread of
        :attr:`scene_threads`; a ``heavy`` scene (raw payloads: feature extraction in GIL-free kernels,
        seconds for the largest) is ``read`` first on any write thread, so that it never holds a
        scene thread that the process's other models wait for. If ``learn`` raises :class:`Postponed`
        (it would wait for a lock that another process holds), the scene thread is given back and
        its ``resume`` runs on a write thread: the wait holds no scene thread either."""
        async with self._admitted(model_id, body_bytes):
            try:
                if heavy:
                    read_scene = await anyio.to_thread.run_sync(read, limiter=self.write_threads)
                    return await anyio.to_thread.run_sync(learn, read_scene, limiter=self.scene_threads)
                return await anyio.to_thread.run_sync(lambda: learn(read()), limiter=self.scene_threads)
            except Postponed as postponed:
                return await anyio.to_thread.run_sync(postponed.resume, limiter=self.write_threads)

    async def run_follow_up(self, work: Callable[..., T], *args: object) -> T:
        """``work(*args)`` that follows a committed write (a scene's checkpoint: seconds at a million
        scenes) on a write thread: never on a scene thread, which the process's other models wait
        for, and outside the model's queue, whose next write need not wait for it."""
        return await anyio.to_thread.run_sync(work, *args, limiter=self.write_threads)

    def refusal(self, model_id: str, body_bytes: int) -> ModelBusy | None:
        """The 429 a write of ``body_bytes`` to ``model_id`` would get now, or None."""
        gate = self._gates.get(model_id)
        if gate is None or (gate.users <= self.model_write_queue and not self._over_bytes(gate, body_bytes)):
            return None
        return ModelBusy(model_id, gate.users - 1, gate.expected_wait(self._clock()))

    @asynccontextmanager
    async def _admitted(self, model_id: str, body_bytes: int) -> AsyncIterator[None]:
        refused = self.refusal(model_id, body_bytes)
        if refused is not None:
            raise refused
        gate = self._gates.get(model_id)
        if gate is None:
            gate = self._gates[model_id] = _ModelGate()
        gate.users += 1
        gate.waiting_bytes += body_bytes
        waiting = True
        try:
            async with gate.lock:
                gate.waiting_bytes -= body_bytes
                waiting = False
                gate.started = self._clock()
                try:
                    yield
                finally:
                    elapsed = self._clock() - gate.started
                    gate.mean_seconds += WRITE_TIME_WEIGHT * (elapsed - gate.mean_seconds)
        finally:
            if waiting:  # cancelled in the queue
                gate.waiting_bytes -= body_bytes
            gate.users -= 1
            if gate.users == 0:  # idle: forgotten, so the gates never outnumber the writes in flight
                del self._gates[model_id]

    def _over_bytes(self, gate: _ModelGate, body_bytes: int) -> bool:
        waiting = gate.users - 1
        limit = self.model_write_queue_bytes
        return limit > 0 and waiting > 0 and gate.waiting_bytes + body_bytes > limit

    def check_rate(self, client: str) -> None:
        """Take a token from ``client``'s bucket (:func:`client_identity`); 429 ``rate_limited`` when empty."""
        if self.rate_per_second <= 0:
            return
        now = self._clock()
        bucket = self._buckets.pop(client, None)
        if bucket is None:
            bucket = _Bucket(float(self.rate_burst), now)
        else:
            refilled = bucket.tokens + (now - bucket.updated) * self.rate_per_second
            bucket.tokens, bucket.updated = min(float(self.rate_burst), refilled), now
        self._buckets[client] = bucket
        while len(self._buckets) > BUCKETS_KEPT:
            self._buckets.popitem(last=False)
        if bucket.tokens >= 1.0:
            bucket.tokens -= 1.0
            return
        due = (1.0 - bucket.tokens) / self.rate_per_second
        retry_after = min(MAX_RETRY_AFTER_SECONDS, max(1, math.ceil(due)))
        raise RateLimited(self.rate_per_second, self.rate_burst, retry_after)


def client_identity(api_key: bytes | None, address: str | None) -> str:
    """Whom a token bucket belongs to: a digest of the presented API key (never the key), else the address."""
    if api_key:
        return "key:" + hashlib.sha256(api_key).hexdigest()[:32]
    return f"address:{address or 'unknown'}"


def admission_of(settings: Settings) -> Admission:
    """The admission control ``settings`` configure."""
    return Admission(
        model_write_queue=settings.model_write_queue,
        model_write_queue_bytes=settings.model_write_queue_bytes,
        rate_per_second=settings.rate_limit_per_second,
        rate_burst=settings.rate_limit_burst,
        write_threads=settings.write_threads,
        scene_threads=settings.scene_threads,
    )


#: The model writes (method, path): a scene, training objects, a fit, a delete.
_MODEL_WRITE = re.compile(r"^/v1/models/(?P<model_id>[^/]+)(?P<action>/scenes|/training-objects|/fit)?$")


class RefuseBusyWrites:
    """Pure ASGI middleware: a write to a model whose queue is already full is answered 429
    ``model_busy`` before its body is parsed (it is read and dropped, so that the client,
    still sending, reads the answer on a connection that stays usable).

    The route's own admission (:meth:`Admission.run_write`, after the key check) is the one
    that queues; this only spares the event loop the parsing of bodies that would be refused
    anyway (the loop's time for an 8 MiB raw scene, docs/benchmarks.md: under a hammering
    client, the other models' latency). It answers before the key is checked, so it tells a client without a
    valid key no more than that a model id is busy; its body size is the declared
    ``Content-Length`` (0 when chunked, so a chunked write is refused here only by the count).
    """

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        refused = self._refusal(scope) if scope["type"] == "http" else None
        if refused is None:
            await self.app(scope, receive, send)
            return
        more_body = True
        while more_body:
            message = await receive()
            more_body = message["type"] == "http.request" and message.get("more_body", False)
        response = error_response(refused.error, refused.message, refused.status_code, headers=refused.headers())
        await response(scope, receive, send)

    @staticmethod
    def _refusal(scope: Scope) -> ModelBusy | None:
        match = _MODEL_WRITE.match(scope["path"])
        if match is None or scope["method"] != ("POST" if match["action"] else "DELETE"):
            return None
        admission = scope.get("state", {}).get("admission")
        if admission is None:
            return None
        declared = dict(scope["headers"]).get(b"content-length", b"0")
        return admission.refusal(match["model_id"], int(declared) if declared.isdigit() else 0)
