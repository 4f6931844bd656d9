"""The client's logic against a fake service on httpx.MockTransport: keys, offline queue, order, errors."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import httpx
import pytest

from bridge import Client, OfflineQueue, QueuedScene, RetryPolicy, SceneObject
from bridge.errors import APIConnectionError, InvalidRequestError, ModelNotFoundError
from bridge.models import ENTITY_SIZE, ObjectFeatures, SceneRead, TrainingObject

FAST = RetryPolicy(max_retries=2, initial_delay=0.001, max_delay=0.002)
PROJECT = Path(__file__).resolve().parents[1]


class FakeService:
    """Learns scenes keyed by Idempotency-Key like the real one; can go offline or lose its answers."""

    def __init__(self) -> None:
        self.scenes: list[dict] = []
        self.by_key: dict[str, int] = {}
        self.offline = False
        self.lose_answers = 0
        self.requests: list[httpx.Request] = []

    def __call__(self, request: httpx.Request) -> httpx.Response:
        self.requests.append(request)
        if self.offline:
            raise httpx.ConnectError("connection refused", request=request)
        if request.url.path == "/v1/models/missing/scenes":
            return httpx.Response(
                404, json={"error": "model_not_found", "detail": "no model 'missing'", "field": "model_id"}
            )
        body = json.loads(request.content)
        if body["objects"][0].get("concepts") == ["bad"]:
            return httpx.Response(
                422, json={"error": "invalid_input", "detail": "no active concept", "field": "objects"}
            )
        key = request.headers["Idempotency-Key"]
        if key not in self.by_key:
            self.by_key[key] = len(self.scenes)
            self.scenes.append(body)
        if self.lose_answers:
            self.lose_answers -= 1
            raise httpx.ReadError("connection reset after the service learned the scene", request=request)
        scene_id = self.by_key[key]
        answer = {
            "model_id": "m",
            "scene_id": scene_id,
            "learned": True,
            "context_count": 1,
            "previous_context_count": 1,
            "context_posterior": [1.0],
            "map_context": 0,
            "objects": [],
        }
        return httpx.Response(201, json=answer)


def _scene(name: str) -> list[SceneObject]:
    return [SceneObject.from_concepts([name])]


def _client(service: FakeService, queue: Path | None) -> Client:
    return Client(
        "http://service",
        api_key="k",
        retry_policy=FAST,
        offline_queue=queue,
        transport=httpx.MockTransport(service),
        seed=0,
    )


def test_scene_is_sent_with_a_fresh_key_and_the_api_key(tmp_path: Path) -> None:
    service = FakeService()
    with _client(service, tmp_path / "q.sqlite3") as client:
        first = client.scenes.create("m", _scene("cup"))
        second = client.scenes.create("m", _scene("plate"))
    assert isinstance(first, SceneRead) and (first.scene_id, second.scene_id) == (0, 1)
    keys = [r.headers["Idempotency-Key"] for r in service.requests]
    assert len(set(keys)) == 2 and all(len(k) == 32 for k in keys)
    assert {r.headers["X-API-Key"] for r in service.requests} == {"k"}


def test_offline_scenes_wait_on_disk_and_drain_in_order_exactly_once(tmp_path: Path) -> None:
    service = FakeService()
    queue_path = tmp_path / "robot" / "queue.sqlite3"
    with _client(service, queue_path) as client:
        client.scenes.create("m", _scene("s0"))
        service.offline = True
        queued = [client.scenes.create("m", _scene(f"s{i}")) for i in (1, 2, 3)]
        assert all(isinstance(q, QueuedScene) for q in queued)
        assert [q.queued for q in queued] == [1, 2, 3]
    # The robot reboots: a new client finds the queue on disk.
    service.offline = False
    with _client(service, queue_path) as client:
        assert len(client.offline_queue) == 3
        last = client.scenes.create("m", _scene("s4"))
        assert isinstance(last, SceneRead) and last.scene_id == 4
        assert len(client.offline_queue) == 0
    assert [s["objects"][0]["concepts"] for s in service.scenes] == [[f"s{i}"] for i in range(5)]
    sent_keys = [r.headers["Idempotency-Key"] for r in service.requests if r.method == "POST"]
    assert sent_keys[-4:-1] == [q.idempotency_key for q in queued], "a queued scene keeps the key it was made with"


def test_an_answer_lost_after_the_service_learned_the_scene_is_not_counted_twice(tmp_path: Path) -> None:
    service = FakeService()
    service.lose_answers = 1
    with _client(service, tmp_path / "q.sqlite3") as client:
        answer = client.scenes.create("m", _scene("cup"))
    assert isinstance(answer, SceneRead) and answer.scene_id == 0
    assert len(service.requests) == 2 and len(service.scenes) == 1
    assert service.requests[0].headers["Idempotency-Key"] == service.requests[1].headers["Idempotency-Key"]


def test_lost_answers_beyond_the_retries_queue_the_scene_and_the_drain_replays_it(tmp_path: Path) -> None:
    service = FakeService()
    service.lose_answers = FAST.max_retries + 1
    with _client(service, tmp_path / "q.sqlite3") as client:
        assert isinstance(client.scenes.create("m", _scene("cup")), QueuedScene)
        assert client.drain_offline_queue() and len(client.offline_queue) == 0
    assert len(service.scenes) == 1


def test_a_refused_scene_moves_aside_and_does_not_block_the_queue(tmp_path: Path) -> None:
    service = FakeService()
    with _client(service, tmp_path / "q.sqlite3") as client:
        service.offline = True
        client.scenes.create("m", _scene("bad"))
        client.scenes.create("m", _scene("good"))
        service.offline = False
        delivered = client.drain_offline_queue()
        rejected = client.offline_queue.rejected()
    assert len(delivered) == 1 and [s["objects"][0]["concepts"] for s in service.scenes] == [["good"]]
    assert len(rejected) == 1
    request, status, answer = rejected[0]
    assert request.body["objects"][0]["concepts"] == ["bad"] and status == 422 and answer["error"] == "invalid_input"


def test_without_a_queue_offline_is_an_error_and_4xx_is_never_queued(tmp_path: Path) -> None:
    service = FakeService()
    service.offline = True
    with _client(service, None) as client, pytest.raises(APIConnectionError):
        client.scenes.create("m", _scene("cup"))
    service.offline = False
    with _client(service, tmp_path / "q.sqlite3") as client:
        with pytest.raises(ModelNotFoundError, match="no model 'missing'"):
            client.scenes.create("missing", _scene("cup"))
        with pytest.raises(InvalidRequestError) as raised:
            client.scenes.create("m", _scene("bad"))
        assert raised.value.field == "objects"
        assert len(client.offline_queue) == 0


def test_queue_keeps_one_entry_per_key_and_survives_reopening(tmp_path: Path) -> None:
    path = tmp_path / "q.sqlite3"
    queue = OfflineQueue(path)
    first = queue.put("POST", "/a", {"n": 1}, "key-1")
    again = queue.put("POST", "/a", {"n": 2}, "key-1")
    queue.put("POST", "/b", {"n": 3}, "key-2")
    queue.close()
    reopened = OfflineQueue(path)
    assert again == first and [r.body for r in reopened.pending()] == [{"n": 1}, {"n": 3}]
    reopened.remove(first.id)
    assert reopened.oldest().idempotency_key == "key-2"
    reopened.close()


def test_scene_object_takes_exactly_one_level() -> None:
    with pytest.raises(ValueError, match="exactly one of concepts, features, raw"):
        SceneObject(concepts=["cup"], features={"entity": [0.0] * 91})
    with pytest.raises(ValueError, match="not 66"):
        SceneObject.from_features([0.0] * 91, {"push_left": [0.0] * 3})


def test_point_cloud_is_sent_as_little_endian_float32_base64() -> None:
    import base64

    import numpy as np

    points = np.array([[0.1, 0.2, 0.3], [1.0, -2.0, 4.5]])
    from_numpy = SceneObject.from_raw(points).raw.look.points
    from_lists = SceneObject.from_raw(points.tolist()).raw.look.points
    assert from_numpy == from_lists
    decoded = np.frombuffer(base64.b64decode(from_numpy), dtype="<f4").reshape(-1, 3)
    np.testing.assert_allclose(decoded, points, rtol=1e-7)


def test_table_iii_sizes_match_core() -> None:
    from bridge import models
    from core.features.layout import EFFECT_SIZE, ENTITY_SIZE

    assert (models.ENTITY_SIZE, models.EFFECT_SIZE) == (ENTITY_SIZE, EFFECT_SIZE)


def test_bridge_imports_without_the_service_dependencies() -> None:
    """A robot installs httpx and pydantic, not the service: importing the client must not pull it in."""
    blocker = """
import sys
class Block:
    def find_spec(self, name, path=None, target=None):
        if name.split('.')[0] in {'core', 'app', 'storage', 'fastapi', 'numba', 'sqlalchemy', 'numpy', 'starlette'}:
            raise ImportError('blocked for the test: ' + name)
sys.meta_path.insert(0, Block())
import bridge
from bridge import Client, SceneObject
client = Client('http://127.0.0.1:9', offline_queue=':memory:')
SceneObject.from_raw([[0.0, 0.0, 0.0]])
print('ok', sorted(m for m in sys.modules if m.split('.')[0] in {'httpx', 'pydantic', 'sqlite3'})[:3])
"""
    result = subprocess.run(
        [sys.executable, "-c", blocker], check=False, cwd=PROJECT, capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("ok")


def test_a_model_creation_carries_a_key_so_a_503_that_may_have_stored_it_is_retried_with_it() -> None:
    requests: list[httpx.Request] = []
    created: dict[str, dict] = {}

    def service(request: httpx.Request) -> httpx.Response:
        requests.append(request)
        key = request.headers["Idempotency-Key"]
        created.setdefault(key, {"id": f"model-{len(created)}", **json.loads(request.content)})
        if len(requests) == 1:  # stored, but the answer is a 503 that says it may have been
            detail = "storage unavailable: ...; the database may have stored the write: retry a keyed write"
            return httpx.Response(
                503, json={"error": "storage_unavailable", "detail": detail}, headers={"Retry-After": "0"}
            )
        model = created[key]
        answer = {
            "id": model["id"], "name": model["name"], "seed": 0, "hyperparameters": {}, "vocabulary": {},
            "context_count": 1, "vocabulary_size": 29, "scene_count": 0, "training_object_count": 0,
            "prototypes_fitted": False, "concept_web_fitted": False, "created_at": "2026-12-06T00:00:00Z",
        }  # fmt: skip
        return httpx.Response(201, json=answer, headers={"Idempotent-Replayed": "true"})

    with Client("http://service", retry_policy=FAST, transport=httpx.MockTransport(service)) as client:
        model = client.models.create("kitchen")
        other = client.models.create("workshop")
    assert model.id == "model-0" and other.id == "model-1" and len(created) == 2
    keys = [request.headers["Idempotency-Key"] for request in requests]
    assert keys[0] == keys[1] != keys[2] and all(len(key) == 32 for key in keys), keys


def test_a_training_batch_carries_a_key_so_an_answer_lost_is_retried_with_it() -> None:
    requests: list[httpx.Request] = []
    stored: dict[str, int] = {}

    def service(request: httpx.Request) -> httpx.Response:
        requests.append(request)
        key = request.headers["Idempotency-Key"]
        stored.setdefault(key, len(json.loads(request.content)["objects"]))
        if len(requests) == 1:  # stored, then the connection is reset before the answer
            raise httpx.ReadError("connection reset after the service stored the batch", request=request)
        return httpx.Response(201, json={"added": stored[key], "training_object_count": sum(stored.values())})

    objects = [TrainingObject(noun="cup", adjectives=["hard"], features=ObjectFeatures(entity=[0.0] * ENTITY_SIZE))]
    with Client("http://service", retry_policy=FAST, transport=httpx.MockTransport(service)) as client:
        answer = client.training.add_objects("m", objects)
    assert (answer.added, answer.training_object_count) == (1, 1) and len(stored) == 1
    keys = [request.headers["Idempotency-Key"] for request in requests]
    assert len(keys) == 2 and keys[0] == keys[1] and len(keys[0]) == 32, keys


def test_the_bridge_reads_every_stream_event_the_service_sends() -> None:
    """A type the service sends and the bridge's ``StreamEvent`` union lacks would end a robot's
    stream with a validation error (``scene_unreadable`` was added on both sides together)."""
    import typing

    from app.schemas import stream as service_events
    from bridge.models import StreamEvent

    sent = {
        schema.model_fields["type"].default
        for schema in vars(service_events).values()
        if isinstance(schema, type) and issubclass(schema, service_events.ReadSchema) and "type" in schema.model_fields
    }
    union = typing.get_args(StreamEvent)[0]
    read = {typing.get_args(event.model_fields["type"].annotation)[0] for event in typing.get_args(union)}
    assert sent == read, (sent, read)
