"""Several processes on one database serve the same models correctly (docs/scaling.md).

Two apps on one database stand for two server processes here: each has its own
registry of models in memory, its own locks and its own connections, exactly as
two ``contextweb serve`` processes (tests/test_multiprocess.py starts real ones).
A model written through both continues exactly as if one process had learned
every scene: memory follows the database, and catching up reads only what
changed, so the interleaved answers equal those of an uninterrupted run.
"""

from __future__ import annotations

import argparse
import itertools
import threading
from collections.abc import Iterator
from contextlib import ExitStack

import pytest
from fastapi.testclient import TestClient

from app.main import create_app
from app.models_cli import SOUND, run_check
from app.registry import ModelRegistry, load_runtime
from app.state import AppState
from storage.repositories import incremental_lda as lda_repository
from storage.repositories import models as model_repository
from tests.conftest import FAST_HYPERPARAMETERS, assert_same_state, concept_scenes, make_settings, memory_state


@pytest.fixture
def two_processes(database_url: str) -> Iterator[tuple[TestClient, TestClient]]:
    with ExitStack() as stack:
        first = stack.enter_context(TestClient(create_app(make_settings(database_url))))
        second = stack.enter_context(TestClient(create_app(make_settings(database_url))))
        yield first, second


def _create(client: TestClient, seed: int = 42) -> str:
    body = {"name": "robot", "seed": seed, "hyperparameters": FAST_HYPERPARAMETERS}
    response = client.post("/v1/models", json=body)
    assert response.status_code == 201, response.text
    return response.json()["id"]


def _learn(client: TestClient, model_id: str, body: dict) -> dict:
    response = client.post(f"/v1/models/{model_id}/scenes", json=body)
    assert response.status_code == 201, response.text
    return {k: v for k, v in response.json().items() if k not in ("model_id", "created_at")}


def test_interleaved_writes_continue_exactly_like_one_process(two_processes: tuple[TestClient, TestClient]) -> None:
    first, second = two_processes
    scenes = concept_scenes(30, seed=5)
    alone = _create(first)
    expected = [_learn(first, alone, body) for body in scenes]
    shared = _create(first)
    # Runs of 1, 2 and 3 scenes on each side: catching up from one scene and from several.
    sides = [first, second, second, first, first, first, second] * 5
    answers = [_learn(sides[i], shared, body) for i, body in enumerate(scenes)]
    assert answers == expected
    assert max(answer["context_count"] for answer in expected) > 1, "the scenes should make K grow"
    for client in (first, second):
        assert client.get(f"/v1/models/{shared}").json()["scene_count"] == len(scenes)
    assert_same_state(memory_state(first, shared), memory_state(second, shared))
    assert_same_state(memory_state(second, shared), memory_state(first, alone))


def test_reads_see_every_write_of_the_other_process(two_processes: tuple[TestClient, TestClient]) -> None:
    first, second = two_processes
    model_id = _create(first)
    assert second.get(f"/v1/models/{model_id}").status_code == 200, "a model created on one is usable on the other"
    for i, body in enumerate(concept_scenes(12, seed=8)):
        _learn(first, model_id, body)
        seen = second.get(f"/v1/models/{model_id}").json()
        assert seen["scene_count"] == i + 1
        assert (
            second.get(f"/v1/models/{model_id}/contexts").json() == first.get(f"/v1/models/{model_id}/contexts").json()
        )
    listed = {model["id"]: model for model in second.get("/v1/models").json()}
    assert listed[model_id]["scene_count"] == 12 and listed[model_id]["status"] == "available"


def test_a_model_deleted_on_one_process_is_gone_on_the_other(two_processes: tuple[TestClient, TestClient]) -> None:
    first, second = two_processes
    model_id = _create(first)
    _learn(second, model_id, concept_scenes(1, seed=1)[0])
    assert first.delete(f"/v1/models/{model_id}").status_code == 204
    assert second.get(f"/v1/models/{model_id}").status_code == 404
    response = second.post(f"/v1/models/{model_id}/scenes", json=concept_scenes(1, seed=2)[0])
    assert response.status_code == 404 and response.json()["error"] == "model_not_found"
    assert model_id not in {model["id"] for model in second.get("/v1/models").json()}


def test_catching_up_equals_loading_from_scratch(two_processes: tuple[TestClient, TestClient]) -> None:
    first, second = two_processes
    model_id = _create(first, seed=3)
    _learn(second, model_id, concept_scenes(1, seed=0)[0])  # the second process has the model in memory
    for body in concept_scenes(20, seed=9):
        _learn(first, model_id, body)
    assert second.get(f"/v1/models/{model_id}").json()["scene_count"] == 21  # caught up: 20 scenes behind
    state: AppState = second.app_state["contextweb"]
    with state.read_sessions() as session:
        loaded = load_runtime(session, model_repository.get_model(session, model_id))
        assert lda_repository.stored_version(session, model_id) == 21
    assert_same_state(memory_state(second, model_id), loaded.incremental_lda.to_state())
    assert state.registry.get(model_id).version == loaded.version == 21


def test_a_process_starting_or_checking_while_another_writes_finds_every_model_sound(
    database_url: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """A start-up's load (``ModelRegistry.load_all``) and ``contextweb models check`` read each model
    in one snapshot: while another process commits scene after scene, a sound model is never taken
    for a damaged one. On PostgreSQL each read a model's state row and its batches as of two moments
    before, and a ``--workers 2`` worker restarted under load registered a sound model unavailable
    ("846 stored, 848 after catching up")."""
    monkeypatch.setenv("CONTEXTWEB_DATABASE_URL", database_url)
    with TestClient(create_app(make_settings(database_url))) as writer:
        model_id = _create(writer)
        for body in concept_scenes(5, seed=1):
            _learn(writer, model_id, body)
        state: AppState = writer.app_state["contextweb"]
        stop, failures, learned = threading.Event(), [], []

        def write() -> None:
            for body in itertools.cycle(concept_scenes(40, seed=2)):
                if stop.is_set():
                    return
                response = writer.post(f"/v1/models/{model_id}/scenes", json=body)
                if response.status_code != 201:
                    failures.append(response.text)
                    return
                learned.append(response.json()["scene_id"])

        thread = threading.Thread(target=write)
        thread.start()
        try:
            loads = checks = 0
            while thread.is_alive() and (loads < 30 or len(learned) < 60):
                registry = ModelRegistry(state.read_sessions)
                registry.load_all()
                model = registry.get(model_id)
                assert model is not None and model.unavailable is None, model.unavailable if model else "not loaded"
                loads += 1
                if loads % 3 == 0:
                    assert run_check(argparse.Namespace(model_id=model_id)) == SOUND, capsys.readouterr().out
                    checks += 1
        finally:
            stop.set()
            thread.join()
        assert not failures, failures
        assert len(learned) >= 60 and checks >= 10, (len(learned), checks)
