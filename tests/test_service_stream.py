"""The websocket stream: an event per scene, one per discovered context, slow clients dropped."""

from __future__ import annotations

import asyncio

import pytest
from fastapi.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

from app.stream import CLOSE_MODEL_NOT_FOUND, CLOSE_NORMAL, CLOSE_TOO_SLOW, CloseInstruction, StreamHub
from tests.conftest import concept_scenes


def test_scene_and_context_events_reach_the_dashboard(client: TestClient, model_id: str) -> None:
    with client.websocket_connect(f"/v1/models/{model_id}/stream") as ws:
        assert ws.receive_json() == {"type": "hello", "model_id": model_id, "context_count": 1, "scene_count": 0}
        answers = [
            client.post(f"/v1/models/{model_id}/scenes", json=body).json() for body in concept_scenes(12, seed=3)
        ]
        events = []
        while len([e for e in events if e["type"] == "scene"]) < len(answers):
            events.append(ws.receive_json())
    scenes = [event for event in events if event["type"] == "scene"]
    assert [event["scene_id"] for event in scenes] == list(range(len(answers)))
    assert [event["context_posterior"] for event in scenes] == [answer["context_posterior"] for answer in answers]
    assert scenes[0]["active_concepts"] == [obj["active_concepts"] for obj in answers[0]["objects"]]
    discovered = [event for event in events if event["type"] == "context_discovered"]
    grew = [a for a in answers if a["context_count"] > a["previous_context_count"]]
    assert grew, "the scenes should make K grow"
    assert [(e["scene_id"], e["context_count"]) for e in discovered] == [
        (a["scene_id"], a["context_count"]) for a in grew
    ]


def test_deleting_the_model_closes_its_streams(client: TestClient, model_id: str) -> None:
    with pytest.raises(WebSocketDisconnect) as closed, client.websocket_connect(f"/v1/models/{model_id}/stream") as ws:
        ws.receive_json()
        client.delete(f"/v1/models/{model_id}")
        ws.receive_json()
    assert closed.value.code == CLOSE_NORMAL
    with pytest.raises(WebSocketDisconnect) as unknown, client.websocket_connect(f"/v1/models/{model_id}/stream") as ws:
        ws.receive_json()
    assert unknown.value.code == CLOSE_MODEL_NOT_FOUND


def test_a_client_whose_queue_overflows_is_dropped_and_the_others_are_not() -> None:
    async def scenario() -> tuple[list, list]:
        hub = StreamHub(queue_size=3)
        hub.bind(asyncio.get_running_loop())
        slow, fast = hub.subscribe("m"), hub.subscribe("m")
        received = []
        for n in range(5):
            hub.publish("m", {"n": n})
            await asyncio.sleep(0)
            received.append(await fast.queue.get())
        slow_events = [slow.queue.get_nowait() for _ in range(slow.queue.qsize())]
        assert hub.subscriber_count("m") == 1
        return slow_events, received

    slow_events, received = asyncio.run(scenario())
    assert slow_events == [CloseInstruction(CLOSE_TOO_SLOW, "client too slow: event queue full")]
    assert received == [{"n": n} for n in range(5)]


def test_a_subscriber_takes_each_scene_once_from_its_position() -> None:
    async def scenario() -> list:
        hub = StreamHub(queue_size=16)
        hub.bind(asyncio.get_running_loop())
        subscriber = hub.subscribe("m", next_scene_id=5)
        for scene_id in (4, 5, 5, 7, 6, 6, 7):
            hub.deliver_now("m", {"type": "scene", "scene_id": scene_id})
            hub.deliver_now("m", {"type": "context_discovered", "scene_id": scene_id})
        hub.deliver_now("m", {"type": "model_fitted"})
        return [subscriber.queue.get_nowait() for _ in range(subscriber.queue.qsize())]

    taken = [(event["type"], event.get("scene_id")) for event in asyncio.run(scenario())]
    assert taken == [
        ("scene", 5),
        ("context_discovered", 5),
        ("scene", 6),
        ("context_discovered", 6),
        ("scene", 7),
        ("context_discovered", 7),
        ("model_fitted", None),
    ]
