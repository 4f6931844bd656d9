"""Operators name contexts: labels persist, every process sees them, and they stay on their context as K grows."""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.main import create_app
from app.state import AppState
from tests.conftest import CONTEXT_CONCEPTS, FAST_HYPERPARAMETERS, make_settings, two_processes
from tests.faults import at_once
from tests.protocol_trace import ProtocolTrace


def _room_scene(room: str, rng: np.random.Generator) -> dict:
    return {"objects": [{"concepts": list(rng.choice(CONTEXT_CONCEPTS[room], 4, replace=False))} for _ in range(3)]}


def _labels(client: TestClient, model_id: str) -> dict[int, str | None]:
    contexts = client.get(f"/v1/models/{model_id}/contexts").json()["contexts"]
    return {context["context"]: context["label"] for context in contexts}


def test_a_label_persists_is_seen_by_another_process_and_can_be_removed(database_url: str) -> None:
    rng = np.random.default_rng(3)
    with TestClient(create_app(make_settings(database_url))) as first:
        model_id = first.post("/v1/models", json={"name": "t", "hyperparameters": FAST_HYPERPARAMETERS}).json()["id"]
        assert first.post(f"/v1/models/{model_id}/scenes", json=_room_scene("kitchen", rng)).status_code == 201
        with TestClient(create_app(make_settings(database_url))) as second:  # another process on the database
            answer = first.patch(f"/v1/models/{model_id}/contexts/0", json={"label": "  kitchen "})
            assert answer.status_code == 200
            assert answer.json() == {"model_id": model_id, "context": 0, "label": "kitchen"}
            assert _labels(second, model_id) == {0: "kitchen"}
            assert second.patch(f"/v1/models/{model_id}/contexts/0", json={"label": "galley"}).status_code == 200
            assert _labels(first, model_id) == {0: "galley"}
    with TestClient(create_app(make_settings(database_url))) as restarted:
        assert _labels(restarted, model_id) == {0: "galley"}
        assert restarted.patch(f"/v1/models/{model_id}/contexts/0", json={"label": None}).json()["label"] is None
        assert _labels(restarted, model_id) == {0: None}


def test_labels_are_refused_clearly(client: TestClient, model_id: str) -> None:
    url = f"/v1/models/{model_id}/contexts"
    client.post(f"/v1/models/{model_id}/scenes", json=_room_scene("kitchen", np.random.default_rng(0)))
    count = client.get(url).json()["context_count"]
    missing = client.patch(f"{url}/{count}", json={"label": "attic"})
    assert missing.status_code == 404 and missing.json()["error"] == "context_not_found"
    assert missing.json()["field"] == "path.context"
    for label in ("", "   ", "x" * 81, "line\nbreak"):
        refused = client.patch(f"{url}/0", json={"label": label})
        assert refused.status_code == 422 and refused.json()["field"] == "label", (label, refused.json())
    assert client.patch(f"{url}/0", json={}).status_code == 422
    assert client.patch("/v1/models/nope/contexts/0", json={"label": "x"}).status_code == 404


def test_a_label_stays_on_its_context_when_k_grows(client: TestClient, model_id: str) -> None:
    rng = np.random.default_rng(8)
    url = f"/v1/models/{model_id}/contexts"
    for _ in range(6):
        assert client.post(f"/v1/models/{model_id}/scenes", json=_room_scene("kitchen", rng)).status_code == 201
    assert client.get(url).json()["context_count"] == 1
    client.patch(f"{url}/0", json={"label": "kitchen"})
    for scene in range(30):
        room = ("playroom", "workshop")[scene % 2]
        client.post(f"/v1/models/{model_id}/scenes", json=_room_scene(room, rng))
    contexts = client.get(url, params={"top": 4}).json()["contexts"]
    assert len(contexts) >= 2
    assert [context["label"] for context in contexts] == ["kitchen"] + [None] * (len(contexts) - 1)
    kitchen_only = (
        set(CONTEXT_CONCEPTS["kitchen"]) - set(CONTEXT_CONCEPTS["playroom"]) - set(CONTEXT_CONCEPTS["workshop"])
    )
    assert {c["name"] for c in contexts[0]["top_concepts"]} <= kitchen_only | {"hard"}


def test_scene_answers_the_stream_and_inference_carry_the_map_contexts_label(client: TestClient, model_id: str) -> None:
    rng = np.random.default_rng(4)
    scene = _room_scene("kitchen", rng)
    first = client.post(f"/v1/models/{model_id}/scenes", json=scene).json()
    assert first["map_context_label"] is None
    client.patch(f"/v1/models/{model_id}/contexts/{first['map_context']}", json={"label": "kitchen"})
    with client.websocket_connect(f"/v1/models/{model_id}/stream") as stream:
        stream.receive_json()  # hello
        answer = client.post(f"/v1/models/{model_id}/scenes", json=scene).json()
        event = stream.receive_json()
    assert answer["map_context"] == first["map_context"] and answer["map_context_label"] == "kitchen"
    assert event["type"] == "scene" and event["scene_id"] == answer["scene_id"]
    assert event["map_context_label"] == "kitchen"
    assert client.get(f"/v1/models/{model_id}/scenes/{answer['scene_id']}").json() == answer
    # A stored answer keeps the label it was given, like the rest of the answer.
    client.patch(f"/v1/models/{model_id}/contexts/{first['map_context']}", json={"label": "galley"})
    assert client.get(f"/v1/models/{model_id}/scenes/{answer['scene_id']}").json()["map_context_label"] == "kitchen"
    assert client.post(f"/v1/models/{model_id}/infer", json=scene).json()["map_context_label"] == "galley"


def test_labels_written_at_once_from_two_processes_all_succeed(database_url: str) -> None:
    """Two processes, two threads each, name one unlabelled context at the same moment, 25 times:
    each PATCH is a 200 (before, two that both found no row both inserted it, and one was a 500),
    and the label stored is one of those sent."""
    rng = np.random.default_rng(5)
    with two_processes(database_url) as (first, second):
        model_id = first.post("/v1/models", json={"name": "t", "hyperparameters": FAST_HYPERPARAMETERS}).json()["id"]
        assert first.post(f"/v1/models/{model_id}/scenes", json=_room_scene("kitchen", rng)).status_code == 201
        url = f"/v1/models/{model_id}/contexts/0"
        failed = []
        for round_ in range(25):
            assert first.patch(url, json={"label": None}).status_code == 200
            sent = [f"room {round_}.{index}" for index in range(4)]
            clients = [first, first, second, second]
            responses = at_once(
                [partial(client.patch, url, json={"label": label}) for client, label in zip(clients, sent)]
            )
            failed += [
                (response.status_code, response.text[:200]) for response in responses if response.status_code != 200
            ]
            assert _labels(second, model_id)[0] in sent
        assert failed == []


def test_a_label_written_while_another_process_deletes_the_model_is_a_200_or_a_404(database_url: str) -> None:
    """The label's row refers to its model's: a label that loses the race with the model's deletion
    on another process is a 404 (or a 200 before it), never a server error (a 500 before: the
    label was not a write of its model, and its insert met the deleted model)."""
    rng = np.random.default_rng(6)
    with two_processes(database_url) as (first, second):
        unexpected = []
        for round_ in range(20):
            created = first.post("/v1/models", json={"name": "t", "hyperparameters": FAST_HYPERPARAMETERS})
            model_id = created.json()["id"]
            assert first.post(f"/v1/models/{model_id}/scenes", json=_room_scene("kitchen", rng)).status_code == 201
            assert second.get(f"/v1/models/{model_id}").status_code == 200  # loaded there
            label, deleted = at_once(
                [
                    partial(second.patch, f"/v1/models/{model_id}/contexts/0", json={"label": f"room {round_}"}),
                    partial(first.delete, f"/v1/models/{model_id}"),
                ]
            )
            if label.status_code not in (200, 404) or deleted.status_code != 204:
                unexpected.append((label.status_code, label.text[:200], deleted.status_code, deleted.text[:200]))
        assert unexpected == []


def _post(client: TestClient, model_id: str, scene: dict) -> dict:
    answer = client.post(f"/v1/models/{model_id}/scenes", json=scene)
    assert answer.status_code == 201, answer.text
    return answer.json()


def _name_every_context(client: TestClient, model_id: str, name: str | None) -> dict[int, str | None]:
    count = client.get(f"/v1/models/{model_id}/contexts").json()["context_count"]
    for context in range(count):
        label = None if name is None else f"{name}-{context}"
        assert client.patch(f"/v1/models/{model_id}/contexts/{context}", json={"label": label}).status_code == 200
    return _labels(client, model_id)


def test_a_scene_names_the_labels_set_since_its_process_last_wrote(database_url: str) -> None:
    # A process knows its model's labels at the version of its last scene and then takes the lock
    # without reading them; a label written anywhere (here, or on another process) bumps the version,
    # so the next scene on either process names the label as stored.
    rng = np.random.default_rng(5)
    scenes = [_room_scene(room, rng) for room in ("kitchen", "playroom", "kitchen", "workshop")]
    with two_processes(database_url) as (first, second):
        model_id = first.post("/v1/models", json={"name": "t", "hyperparameters": FAST_HYPERPARAMETERS}).json()["id"]
        for scene in scenes:
            assert _post(first, model_id, scene)["map_context_label"] is None
        for writer, poster, name in (
            (second, first, "kitchen"),  # set elsewhere, then a scene here
            (second, second, "galley"),  # set and posted on the same process
            (first, second, "pantry"),  # the other way round
            (first, first, None),  # removed
        ):
            labels = _name_every_context(writer, model_id, name)
            for scene in scenes:
                answer = _post(poster, model_id, scene)
                assert answer["map_context_label"] == labels.get(answer["map_context"])  # a context born since: none
            other = first if poster is second else second
            answer = _post(other, model_id, scenes[0])  # a scene on the other process changes no label
            assert answer["map_context_label"] == labels.get(answer["map_context"])  # a context born since: none


@pytest.mark.postgres
def test_a_process_that_knows_the_labels_takes_the_lock_without_reading_them(postgres_url: str, tmp_path: Path) -> None:
    rng = np.random.default_rng(6)
    scene = _room_scene("kitchen", rng)
    with TestClient(create_app(make_settings(postgres_url))) as client:
        model_id = client.post("/v1/models", json={"name": "t", "hyperparameters": FAST_HYPERPARAMETERS}).json()["id"]
        state: AppState = client.app_state["contextweb"]
        trace = ProtocolTrace(state.engine, tmp_path)

        def statements(post: Callable[[], object]) -> list[str]:
            """The statements a call sent (psycopg binds each one; a prepared one by name only)."""
            start = len(trace.sent())
            post()
            return [message for message in trace.sent()[start:] if message.startswith("Bind")]

        first = statements(lambda: _post(client, model_id, scene))  # a new model: labels not known yet
        assert any("FROM context_label" in message for message in trace.sent()), "the labels were never read"
        steady = len(statements(lambda: _post(client, model_id, scene)))
        assert len(first) > steady  # the first also inserted the scene's new words
        assert len(statements(lambda: _post(client, model_id, scene))) == steady
        _name_every_context(client, model_id, "kitchen")
        # A label write leaves them unknown: the next scene reads them with the lock, one statement more.
        assert len(statements(lambda: _post(client, model_id, scene))) == steady + 1
        assert len(statements(lambda: _post(client, model_id, scene))) == steady
