"""The model's writer (app/registry.py ``ModelWriter``, docs/scaling.md "A model in memory"): the one
place a model's memory changes, inside a write that it commits or undoes.

A write is failed for real here: the block of a real transaction raises after the scene
was learned in memory (as a failed flush or commit would), and the writer must leave memory
equal to the database, as a fresh load from it shows array by array.
"""

from __future__ import annotations

import time

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app import registry
from app.registry import FittedPerception, ModelRuntime, load_runtime
from app.services.perception import Perception
from app.state import AppState
from storage.repositories import models as model_repository
from tests.conftest import concept_scenes, state_and_model


class WriteFailed(Exception):
    """The failure the test causes inside the write, after memory changed."""


def _assert_memory_equals_database(state: AppState, model: ModelRuntime) -> None:
    with state.read_sessions() as session:
        row = model_repository.get_model(session, model.id)
        assert row is not None
        stored = load_runtime(session, row)
    memory, expected = model.incremental_lda.to_state(), stored.incremental_lda.to_state()
    for name in ("words", "assignments", "doc_offsets", "n_kw"):
        assert np.array_equal(getattr(memory, name), getattr(expected, name)), name
    assert memory.rng_state == expected.rng_state and list(model.word_kinds) == list(stored.word_kinds)
    assert model.version == stored.version and model.summary == stored.summary


def test_a_change_outside_a_write_is_refused(client: TestClient, model_id: str) -> None:
    _, model = state_and_model(client, model_id)
    scenes_before = model.incremental_lda.n_scenes
    with pytest.raises(RuntimeError, match="outside a write"):
        model.writer.learn_scene(["cup", "plate"], lambda _: None)
    with pytest.raises(RuntimeError, match="outside a write"):
        model.writer.count_training_objects(3)
    assert model.incremental_lda.n_scenes == scenes_before


def test_a_scene_write_that_fails_after_learning_is_taken_back_exactly(client: TestClient, model_id: str) -> None:
    """The scene is taken back out of the same memory (no reload): it equals a fresh load from the
    database, the model serves on, and the next scene gets the id the failed one had."""
    for scene in concept_scenes(3, seed=5):
        assert client.post(f"/v1/models/{model_id}/scenes", json=scene).status_code == 201
    state, model = state_and_model(client, model_id)
    learned_before, kinds_before = model.incremental_lda, list(model.word_kinds)
    with pytest.raises(WriteFailed), model.writer.transaction(state.write_sessions, state.registry):
        model.writer.learn_scene(["cup", "plate", "a-new-word"], lambda _: "noun")
        assert model.incremental_lda.n_scenes == 4, "memory holds the scene until the write ends"
        assert len(model.word_kinds) == len(kinds_before) + 1
        raise WriteFailed
    assert model.unavailable is None
    assert model.incremental_lda is learned_before, "taken back in place, not reloaded"
    assert model.incremental_lda.n_scenes == 3 and "a-new-word" not in model.incremental_lda.vocabulary
    assert list(model.word_kinds) == kinds_before
    _assert_memory_equals_database(state, model)
    response = client.post(f"/v1/models/{model_id}/scenes", json=concept_scenes(1, seed=9)[0])
    assert response.status_code == 201 and response.json()["scene_id"] == 3


def test_a_failed_write_that_changed_more_than_one_scene_is_reloaded(client: TestClient, model_id: str) -> None:
    """Only a write whose one change to memory is one scene is taken back; any other is reloaded
    from the database at once (it answers), and memory equals it."""
    for scene in concept_scenes(3, seed=5):
        assert client.post(f"/v1/models/{model_id}/scenes", json=scene).status_code == 201
    state, model = state_and_model(client, model_id)
    learned_before = model.incremental_lda
    with pytest.raises(WriteFailed), model.writer.transaction(state.write_sessions, state.registry):
        model.writer.learn_scene(["cup", "plate"], lambda _: "noun")
        model.writer.learn_scene(["cup", "plate", "a-new-word"], lambda _: "noun")
        raise WriteFailed
    assert model.unavailable is None, "the database answers, so the model was reloaded at once"
    assert model.incremental_lda is not learned_before and model.incremental_lda.n_scenes == 3
    _assert_memory_equals_database(state, model)
    response = client.post(f"/v1/models/{model_id}/scenes", json=concept_scenes(1, seed=9)[0])
    assert response.status_code == 201 and response.json()["scene_id"] == 3


def test_changes_that_wait_for_the_commit_are_dropped_with_it(client: TestClient, model_id: str) -> None:
    state, model = state_and_model(client, model_id)
    fitted, count, learned = model.fitted, model.training_object_count, model.incremental_lda
    replacement = FittedPerception(Perception(model.vocabulary))
    with pytest.raises(WriteFailed), model.writer.transaction(state.write_sessions, state.registry):
        model.writer.install_fit(replacement)
        model.writer.count_training_objects(count + 5)
        raise WriteFailed
    assert model.fitted is fitted and model.training_object_count == count
    assert model.unavailable is None and model.incremental_lda is learned, "memory never changed: no reload"

    with model.writer.transaction(state.write_sessions, state.registry):
        model.writer.install_fit(replacement)
        assert model.fitted is fitted, "a fit takes effect when its write commits"
    assert model.fitted is replacement and model.perception is replacement.perception


def test_a_failed_check_is_repeated_when_the_version_moves_or_after_a_doubling_backoff(
    client: TestClient, model_id: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A model whose stored state failed its check is loaded again at once when its stored version
    moves, and at the same version only after the recheck backoff, which doubles up to its cap."""
    _, model = state_and_model(client, model_id)
    writer = model.writer
    monkeypatch.setattr(registry, "FAILED_CHECK_RECHECK_SECONDS", 0.05)
    monkeypatch.setattr(registry, "FAILED_CHECK_RECHECK_MAX_SECONDS", 0.15)
    waits = []
    for _ in range(4):
        marked = time.monotonic()
        writer.mark_unavailable("its stored state failed its check", failed_version=7)
        assert not writer.check_due(7) and writer.check_due(8)
        waits.append(writer.recheck_after - marked)
        time.sleep(max(0.0, writer.recheck_after - time.monotonic()) + 0.005)
        assert writer.check_due(7)
    assert waits == pytest.approx([0.05, 0.1, 0.15, 0.15], abs=0.01)
    marked = time.monotonic()
    writer.mark_unavailable("its stored state failed its check", failed_version=8)  # another version: from the start
    assert writer.recheck_after - marked == pytest.approx(0.05, abs=0.01)
