"""The robot-side client: one :class:`Client` owning one ``httpx.Client``, resources as attributes.

>>> with Client("http://127.0.0.1:8000", api_key="...", offline_queue="var/bridge-queue.sqlite3") as client:
...     model = client.models.create(name="kitchen-robot")
...     client.scenes.create(model.id, [SceneObject.from_concepts(["cup", "hard", "round"])])

Every request goes through :class:`bridge.transport.RetryTransport` (backoff,
jitter, ``Retry-After``, capped). A scene carries an ``Idempotency-Key`` made
once per scene and kept across its retries and its stay in the offline queue,
so the service counts it once however often it is sent. When the service
cannot be reached (or answers 5xx/429 after the retries), a scene goes to the
offline queue on disk; while anything waits there, each new scene joins the
end of the queue and :meth:`Client.drain_offline_queue` sends it in order
once the service is back.
"""

from __future__ import annotations

import logging
import os
import threading
import uuid
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any, Self, TypeVar

import httpx
from pydantic import TypeAdapter

from bridge.errors import (
    APIConnectionError,
    APIStatusError,
    APITimeoutError,
    InternalServerError,
    RateLimitError,
    error_from_response,
)
from bridge.models import (
    Contexts,
    FitRead,
    Hyperparameters,
    Model,
    ModelCreate,
    Page,
    Plan,
    PlanCreate,
    SceneCreate,
    SceneObject,
    SceneRead,
    SceneSummary,
    StreamEvent,
    TrainingBatch,
    TrainingBatchRead,
    TrainingObject,
    Vocabulary,
)
from bridge.queue import OfflineQueue, QueuedRequest
from bridge.transport import IDEMPOTENCY_HEADER, MAX_RETRIES, RETRY_SAFE, RetryPolicy, RetryTransport

logger = logging.getLogger("bridge")

API_KEY_HEADER = "X-API-Key"
DEFAULT_BASE_URL = "http://127.0.0.1:8000"
#: connect: a service on the robot's LAN that takes longer than 3 s to accept is away, so fail over to
#: the queue quickly; read: a raw scene goes through feature extraction and loopy BP on the service.
DEFAULT_TIMEOUT = httpx.Timeout(30.0, connect=3.0)
R = TypeVar("R")

#: Close codes of a refused stream (4000 + the HTTP status) -> the REST error kind (docs/stream.md).
_STREAM_REFUSALS = {4401: "unauthorized", 4403: "forbidden", 4404: "model_not_found"}
#: How often a stream waiting for an event checks whether the client was closed.
_STREAM_POLL_SECONDS = 1.0
#: Answers after which a write is kept for later rather than dropped: the service was away or overloaded.
_DEFERRABLE = (APIConnectionError, InternalServerError, RateLimitError)


@dataclass(frozen=True)
class QueuedScene:
    """A scene kept in the offline queue; it will be sent with ``idempotency_key`` when the service is back."""

    model_id: str
    idempotency_key: str
    queued: int


class Client:
    """A typed client of the Contextweb service for one robot.

    ``base_url`` and ``api_key`` default to ``CONTEXTWEB_URL`` and
    ``CONTEXTWEB_API_KEY``. ``offline_queue`` is a path (or an
    :class:`OfflineQueue`) on the robot's disk; without one, a scene that cannot
    be delivered raises instead of waiting. ``transport`` replaces the network
    (tests use ``httpx.MockTransport``); retries wrap it either way. ``seed``
    seeds the retry jitter (None: from the system).
    """

    def __init__(
        self,
        base_url: str | None = None,
        api_key: str | None = None,
        *,
        timeout: float | httpx.Timeout = DEFAULT_TIMEOUT,
        retry_policy: RetryPolicy | None = None,
        offline_queue: str | Path | OfflineQueue | None = None,
        transport: httpx.BaseTransport | None = None,
        seed: int | None = None,
    ) -> None:
        self.base_url = (base_url or os.environ.get("CONTEXTWEB_URL") or DEFAULT_BASE_URL).rstrip("/")
        self.api_key = api_key if api_key is not None else os.environ.get("CONTEXTWEB_API_KEY")
        self.retry_policy = retry_policy or RetryPolicy()
        headers = {"User-Agent": "contextweb-bridge/1.0"}
        if self.api_key:
            headers[API_KEY_HEADER] = self.api_key
        self._transport = RetryTransport(transport or httpx.HTTPTransport(), self.retry_policy, seed=seed)
        self._http = httpx.Client(base_url=self.base_url, headers=headers, timeout=timeout, transport=self._transport)
        if isinstance(offline_queue, (str, Path)):
            offline_queue = OfflineQueue(offline_queue)
        self.offline_queue = offline_queue
        self._drain_lock = threading.Lock()
        self._closed = threading.Event()
        self.models = Models(self)
        self.training = Training(self)
        self.scenes = Scenes(self)
        self.contexts = ContextsResource(self)
        self.plans = Plans(self)

    # -- plumbing -------------------------------------------------------------------------------

    def request(
        self,
        method: str,
        path: str,
        *,
        json: Any = None,
        params: dict[str, Any] | None = None,
        idempotency_key: str | None = None,
        retry_safe: bool = False,
    ) -> Any:
        """Send one request (retried by the transport) and return its decoded JSON body.

        Raises :class:`APIConnectionError`/:class:`APITimeoutError` when the
        service could not be reached and an :class:`APIStatusError` subclass
        for an error answer.
        """
        headers = {IDEMPOTENCY_HEADER: idempotency_key} if idempotency_key else None
        extensions = {RETRY_SAFE: True} if retry_safe else None
        try:
            response = self._http.request(
                method, path, json=json, params=params, headers=headers, extensions=extensions
            )
        except httpx.TimeoutException as error:
            raise APITimeoutError(f"{method} {path}: timed out ({error!r})", request=error.request) from error
        except httpx.TransportError as error:
            raise APIConnectionError(f"{method} {path}: {error!r}", request=error.request) from error
        if response.is_error:
            raise error_from_response(response)
        if response.status_code == 204 or not response.content:
            return None
        return response.json()

    def _cast(self, kind: type[R], data: Any) -> R:
        # The ignore: mypy takes a class's __hash__ for the unbound instance method, so it finds no
        # class Hashable, for functools.cache's argument; a class is hashable (its metaclass's __hash__).
        return _adapter(kind).validate_python(data)  # type: ignore[arg-type]

    # -- the offline queue ----------------------------------------------------------------------

    def send_or_queue(self, path: str, body: Any, idempotency_key: str) -> Any | QueuedRequest:
        """POST ``body`` with its key; keep it on disk when the service is away (and a queue is set).

        Anything already waiting is sent first, so requests arrive in the order
        the robot made them. Returns the decoded answer, or the
        :class:`QueuedRequest` when the request is still waiting.
        """
        queue = self.offline_queue
        if queue is None:
            return self.request("POST", path, json=body, idempotency_key=idempotency_key)
        if len(queue):
            queued = queue.put("POST", path, body, idempotency_key)
            return self.drain_offline_queue().get(idempotency_key, queued)
        try:
            return self.request("POST", path, json=body, idempotency_key=idempotency_key)
        except _DEFERRABLE as error:
            logger.warning("POST %s deferred to the offline queue: %s", path, error)
            return queue.put("POST", path, body, idempotency_key)

    def drain_offline_queue(self) -> dict[str, Any]:
        """Send the waiting requests, oldest first, until the queue is empty or the service is away.

        Returns the answers of the requests delivered, by idempotency key. A
        request the service refuses for good (4xx other than 429) moves to the
        queue's ``rejected`` table and the drain goes on.
        """
        queue = self.offline_queue
        delivered: dict[str, Any] = {}
        if queue is None:
            return delivered
        with self._drain_lock:
            while (waiting := queue.oldest()) is not None:
                try:
                    answer = self.request(
                        waiting.method, waiting.path, json=waiting.body, idempotency_key=waiting.idempotency_key
                    )
                except _DEFERRABLE as error:
                    logger.info("offline queue: %d waiting, service still away (%s)", len(queue), error)
                    break
                except APIStatusError as error:
                    logger.error("offline queue: %s %s refused for good: %s", waiting.method, waiting.path, error)
                    queue.reject(waiting.id, error.status_code, {"error": error.error, "detail": error.detail})
                    continue
                queue.remove(waiting.id)
                delivered[waiting.idempotency_key] = answer
        return delivered

    # -- the stream -----------------------------------------------------------------------------

    def stream(self, model_id: str, *, reconnect: bool = True, open_timeout: float = 5.0) -> Iterator[StreamEvent]:
        """The model's live events (docs/stream.md): a ``hello``, then ``scene``, ``context_discovered``, ...

        The stream ends when the client is closed (within a second). With
        ``reconnect`` it outlives the service: a dropped
        connection (service restarted, network lost, this reader too slow) is
        opened again after the retry policy's backoff, forever, and a new
        ``hello`` says where the model stands, so the caller can read the
        scenes it missed from the history. A refusal (bad key, no such model)
        raises the same error class as the REST routes.
        """
        from websockets.exceptions import ConnectionClosed, InvalidHandshake
        from websockets.sync.client import connect

        url = _websocket_url(self.base_url) + f"/v1/models/{model_id}/stream"
        headers = {API_KEY_HEADER: self.api_key} if self.api_key else {}
        events = _adapter(StreamEvent)
        attempt = 0
        while not self._closed.is_set():
            try:
                with connect(url, additional_headers=headers, open_timeout=open_timeout) as socket:
                    while not self._closed.is_set():
                        try:
                            message = socket.recv(timeout=_STREAM_POLL_SECONDS)
                        except TimeoutError:
                            continue
                        attempt = 0
                        yield events.validate_json(message)
                    return
            except ConnectionClosed as error:
                code, reason = (error.rcvd.code, error.rcvd.reason) if error.rcvd else (None, str(error))
            except (OSError, TimeoutError, InvalidHandshake) as error:
                code, reason = None, repr(error)
            if code in _STREAM_REFUSALS:
                raise error_from_response(
                    httpx.Response(code - 4000, json={"error": _STREAM_REFUSALS[code], "detail": reason})
                )
            if not reconnect:
                raise APIConnectionError(f"stream of model {model_id} closed: {code} {reason}")
            delay = self._transport.next_delay(attempt)
            logger.info("stream of model %s closed (%s %s); reconnecting in %.2fs", model_id, code, reason, delay)
            self._closed.wait(delay)
            attempt += 1

    # -- probes ---------------------------------------------------------------------------------

    def health(self) -> bool:
        """True when the service process answers ``/healthz`` (one try, no retries)."""
        try:
            return self._http.get("/healthz", extensions={MAX_RETRIES: 0}).is_success
        except httpx.TransportError:
            return False

    def ready(self) -> dict[str, Any]:
        """``/readyz``: the database is reachable and the models are loaded (else ServiceNotReadyError)."""
        return self.request("GET", "/readyz")

    # -- lifecycle ------------------------------------------------------------------------------

    def close(self) -> None:
        """Close the connections and the queue; open streams end."""
        self._closed.set()
        self._http.close()
        if self.offline_queue is not None:
            self.offline_queue.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()


class _Resource:
    """A group of routes on the client (``client.scenes`` ...), as openai-python's API resources."""

    def __init__(self, client: Client) -> None:
        self._client = client


class Scenes(_Resource):
    """``client.scenes``: post scenes (learned online) and read a model's scene history."""

    def create(
        self,
        model_id: str,
        objects: Sequence[SceneObject] | SceneCreate,
        *,
        idempotency_key: str | None = None,
    ) -> SceneRead | QueuedScene:
        """Post a scene for the model to learn; its analysis, or a :class:`QueuedScene` while offline.

        The ``idempotency_key`` (a fresh UUID unless given) stays with the
        scene through every retry and the offline queue.
        """
        scene = _scene(objects)
        key = idempotency_key or uuid.uuid4().hex
        body = scene.model_dump(mode="json", exclude_defaults=True)
        answer = self._client.send_or_queue(f"/v1/models/{model_id}/scenes", body, key)
        if isinstance(answer, QueuedRequest):
            return QueuedScene(model_id, key, len(self._client.offline_queue or ()))
        return self._client._cast(SceneRead, answer)

    def infer(self, model_id: str, objects: Sequence[SceneObject] | SceneCreate) -> SceneRead:
        """Analyse a scene without learning it: concept webs and context posterior (retried: it changes nothing)."""
        scene = _scene(objects)
        data = self._client.request(
            "POST",
            f"/v1/models/{model_id}/infer",
            json=scene.model_dump(mode="json", exclude_defaults=True),
            retry_safe=True,
        )
        return self._client._cast(SceneRead, data)

    def get(self, model_id: str, scene_id: int) -> SceneRead:
        """One learned scene's stored analysis."""
        return self._client._cast(SceneRead, self._client.request("GET", f"/v1/models/{model_id}/scenes/{scene_id}"))

    def list(self, model_id: str, *, offset: int = 0, limit: int = 100) -> Page[SceneSummary]:
        """One page of the model's scene history, oldest first."""
        data = self._client.request("GET", f"/v1/models/{model_id}/scenes", params={"offset": offset, "limit": limit})
        return self._client._cast(Page[SceneSummary], data)

    def iterate(self, model_id: str, *, page_size: int = 100) -> Iterator[SceneSummary]:
        """Every scene of the model, oldest first, page by page."""
        offset = 0
        while True:
            page = self.list(model_id, offset=offset, limit=page_size)
            yield from page.items
            offset += len(page.items)
            if not page.items or offset >= page.total:
                return


class Models(_Resource):
    """``client.models``: create, list, get, delete, or select a model by name."""

    def create(
        self,
        name: str,
        *,
        seed: int = 0,
        sigma: float | None = None,
        hyperparameters: Hyperparameters | dict[str, Any] | None = None,
        vocabulary: Vocabulary | None = None,
        idempotency_key: str | None = None,
    ) -> Model:
        """A new, empty model (the paper's 29 concepts unless ``vocabulary`` is given).

        The request carries an ``Idempotency-Key`` (``idempotency_key``, or a new UUID for this
        call), so the transport retries it like a scene: a retry of a creation the service may
        have stored answers that model rather than making a second one."""
        body = ModelCreate(
            name=name,
            seed=seed,
            sigma=sigma,
            hyperparameters=hyperparameters or Hyperparameters(),
            vocabulary=vocabulary,
        )
        data = self._client.request(
            "POST",
            "/v1/models",
            json=body.model_dump(mode="json", exclude_defaults=True),
            idempotency_key=idempotency_key or uuid.uuid4().hex,
        )
        return self._client._cast(Model, data)

    def list(self) -> list[Model]:
        return self._client._cast(list[Model], self._client.request("GET", "/v1/models"))

    def get(self, model_id: str) -> Model:
        return self._client._cast(Model, self._client.request("GET", f"/v1/models/{model_id}"))

    def delete(self, model_id: str) -> None:
        self._client.request("DELETE", f"/v1/models/{model_id}")

    def select(self, name: str, **create: Any) -> Model:
        """The oldest model called ``name``, created (with ``create``'s arguments) when there is none."""
        named = sorted((m for m in self.list() if m.name == name), key=lambda m: m.created_at)
        return named[0] if named else self.create(name, **create)


class Training(_Resource):
    """``client.training``: labelled objects in, then a fit of prototypes, concept web and behaviour effects."""

    def add_objects(
        self, model_id: str, objects: Sequence[TrainingObject], *, idempotency_key: str | None = None
    ) -> TrainingBatchRead:
        """Add one batch of labelled objects (the service caps a batch at 500 and a body at its byte limit).

        The batch carries an ``Idempotency-Key`` (``idempotency_key``, or a new UUID for this call),
        so the transport retries it: a retry of a batch the service may have stored is answered as
        that batch was, and never adds its objects twice."""
        body = TrainingBatch(objects=list(objects)).model_dump(mode="json", exclude_defaults=True)
        data = self._client.request(
            "POST",
            f"/v1/models/{model_id}/training-objects",
            json=body,
            idempotency_key=idempotency_key or uuid.uuid4().hex,
        )
        return self._client._cast(TrainingBatchRead, data)

    def fit(self, model_id: str, *, method: str = "rgng", seed: int | None = None) -> FitRead:
        """Fit from every training object so far (``rgng`` as in the paper, or ``kmeans``)."""
        body: dict[str, Any] = {"method": method} | ({"seed": seed} if seed is not None else {})
        return self._client._cast(FitRead, self._client.request("POST", f"/v1/models/{model_id}/fit", json=body))


class ContextsResource(_Resource):
    """``client.contexts``: the contexts a model discovered, with their top concepts."""

    def list(self, model_id: str, *, top: int = 10) -> Contexts:
        data = self._client.request("GET", f"/v1/models/{model_id}/contexts", params={"top": top})
        return self._client._cast(Contexts, data)


class Plans(_Resource):
    """``client.plans``: plan a move over the table with the behaviours the context allows (§V-E)."""

    def create(
        self,
        model_id: str,
        object: str,
        start: int,
        goal: int,
        *,
        obstacles: dict[str, int] | None = None,
        context: int | None = None,
        scene_id: int | None = None,
        scene: Sequence[SceneObject] | SceneCreate | None = None,
        mode: str = "astar",
        node_budget: int | None = None,
        depth_budget: int | None = None,
    ) -> Plan:
        """A plan from ``start`` to ``goal``; the context is ``context``, a learned ``scene_id``'s, or ``scene``'s inferred one."""
        request = PlanCreate(
            object=object,
            start=start,
            goal=goal,
            obstacles=obstacles or {},
            context=context,
            scene_id=scene_id,
            scene=None if scene is None else _scene(scene),
            mode=mode,
            node_budget=node_budget,
            depth_budget=depth_budget,
        )
        body = request.model_dump(mode="json", exclude_none=True, exclude_defaults=True) | {"mode": mode}
        data = self._client.request("POST", f"/v1/models/{model_id}/plans", json=body, retry_safe=True)
        return self._client._cast(Plan, data)


def _websocket_url(base_url: str) -> str:
    """``http(s)://host`` -> ``ws(s)://host``."""
    scheme, rest = base_url.split("://", 1)
    return ("wss" if scheme == "https" else "ws") + "://" + rest


def _scene(objects: Sequence[SceneObject] | SceneCreate) -> SceneCreate:
    return objects if isinstance(objects, SceneCreate) else SceneCreate(objects=list(objects))


@cache
def _adapter(kind: Any) -> TypeAdapter[Any]:
    """One pydantic adapter per response type, built on first use (building one costs more than using it)."""
    return TypeAdapter(kind)
