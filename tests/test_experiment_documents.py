"""The experiments' LDA documents (experiments.documents): Table V's words of perceived webs by
default, labels for the ablation, and the report's feature cache."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from core.scene import MeasuredObject, perceived_concepts
from experiments import context_scenes, documents
from experiments.recognition import experiment_objects
from sim.world import World

#: Not one of the report's seeds (0-4); the other experiment tests share its quick world.
TEST_SEED = 7


@pytest.fixture(scope="module")
def perceived() -> documents.Documents:
    return documents.experiment_documents("hard", TEST_SEED, documents.PERCEIVED, quick=True)


def test_perceived_documents_are_the_pipelines_active_concepts(perceived: documents.Documents) -> None:
    world = perceived.world
    train, test = experiment_objects(world, quick=True)
    assert set(perceived.objects) == {*train, *test} and world.config.difficulty.name == "hard"
    features = context_scenes.object_features(world, perceived.objects, TEST_SEED)
    perception = documents.fitted_perception(world, train, features, TEST_SEED)
    for obj in (test[0], train[0]):
        assert perceived.words[obj.object_id] == perceived_concepts(
            perception, MeasuredObject(*features[obj.object_id])
        )
    vocabulary = world.vocabulary
    assert all(set(words) <= set(vocabulary.concepts) for words in perceived.words.values())
    # Perception is imperfect on the hard world: some documents differ from the labels.
    labelled = {obj.object_id: (*obj.concepts, *obj.behaviours) for obj in perceived.objects}
    assert any(set(perceived.words[k]) != set(labelled[k]) for k in labelled)


def test_a_scenes_document_is_its_objects_words_and_labels_are_scene_tokens(perceived: documents.Documents) -> None:
    scene = perceived.scenes(1, 11)[0]
    assert perceived.scene(scene) == [w for obj in scene.objects for w in perceived.words[obj.object_id]]
    labels = documents.experiment_documents("hard", TEST_SEED, documents.LABELS, quick=True)
    assert labels.objects == World.paper(TEST_SEED, "hard").objects
    labelled = labels.scenes(1, 11)[0]
    assert labels.scene(labelled) == labelled.tokens(with_verbs=True)


def test_the_feature_cache_gives_back_the_very_arrays(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    world = World.paper(TEST_SEED + 1, "hard")
    obj = world.test_objects[0]
    monkeypatch.setattr(context_scenes, "FEATURE_CACHE", tmp_path)
    entity, effects = context_scenes.object_features(world, [obj], TEST_SEED)[obj.object_id]
    monkeypatch.setattr(context_scenes, "_FEATURES", {})  # a new process: memory empty, the disk kept
    cached_entity, cached_effects = context_scenes.object_features(world, [obj], TEST_SEED)[obj.object_id]
    assert len(list(tmp_path.rglob("*.npz"))) == 1
    assert cached_entity.tobytes() == entity.tobytes() and cached_effects.keys() == effects.keys()
    assert all(np.array_equal(cached_effects[verb], effects[verb]) for verb in effects)
