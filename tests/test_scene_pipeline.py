"""core.scene: the experiments' document of a recorded object is the service's, and Table V's rule.

The world's seed (11) is none of the report's seeds.
"""

from __future__ import annotations

import doctest
from typing import Any

import numpy as np
import pytest

import core.scene.pipeline
from app.schemas.scenes import SceneCreate
from app.services.perception import analyse_objects
from core.concept_web import ConceptWeb
from core.concept_web.active import active_concepts, carries_evidence, perception_map
from core.features import recording_features
from core.payloads import ObjectRecording
from core.prototypes import fit_prototypes
from core.scene import MeasuredObject, NamedObject, Perception, perceive_scene, perceived_concepts
from core.vocabulary import Vocabulary, paper_vocabulary
from sim.world import World

SEED = 11


@pytest.fixture(scope="module")
def world() -> World:
    return World.paper(seed=SEED)


@pytest.fixture(scope="module")
def perception(world: World) -> Perception:
    """Prototypes and concept web fitted on the world's training objects, as the experiments fit them."""
    train = world.train_objects
    recordings = world.recordings(train, seed=SEED)
    features = [recording_features(recordings[obj.object_id]) for obj in train]
    prototypes = fit_prototypes(
        world.vocabulary,
        np.array([entity for entity, _ in features]),
        [list(obj.concepts) for obj in train],
        np.array([effect for _, effects in features for effect in effects.values()]),
        [verb for _, effects in features for verb in effects],
        seed=SEED,
    )
    web = ConceptWeb.fit(world.vocabulary, [[*obj.concepts, *obj.behaviours] for obj in train])
    return Perception(world.vocabulary, prototypes, web)


@pytest.fixture(scope="module")
def test_recordings(world: World) -> dict[str, ObjectRecording]:
    """One test object of each of six nouns, recorded afresh."""
    objects = {obj.noun: obj for obj in world.test_objects}
    return world.recordings([objects[noun] for noun in world.vocabulary.nouns[:6]], seed=SEED + 1)


def _raw_object(recording: ObjectRecording) -> dict[str, Any]:
    """The service's raw payload of a recording, as JSON arrays (float64, so nothing is rounded on the way)."""

    def cloud(points: np.ndarray) -> dict[str, Any]:
        return {"points": points.tolist()}

    interactions = []
    for interaction in recording.interactions:
        posted: dict[str, Any] = {
            "behaviour": interaction.behaviour,
            "before": cloud(interaction.before.points),
            "after": cloud(interaction.after.points),
        }
        if interaction.audio is not None:
            posted["audio"] = {
                "samples": interaction.audio.samples.tolist(),
                "sample_rate": interaction.audio.sample_rate,
            }
        if interaction.finger is not None:
            posted["finger"] = {
                "haptic": interaction.finger.haptic.tolist(),
                "proprioceptive": interaction.finger.proprioceptive.tolist(),
            }
        interactions.append(posted)
    return {"raw": {"look": cloud(recording.look.points), "interactions": interactions}}


def test_a_recorded_objects_document_is_what_the_service_answers_for_it(
    world: World, perception: Perception, test_recordings: dict[str, ObjectRecording]
) -> None:
    """Objects of the world posted raw, all in one scene, through the service's pipeline: each one's
    active concepts are those :func:`perceived_concepts` gives its recording alone, and its features
    (step 0 is ``recording_features``) give them too, at the features level."""
    recordings = list(test_recordings.values())
    body = {"objects": [_raw_object(recording) for recording in recordings]}
    answered = analyse_objects(perception, SceneCreate.model_validate(body).objects, "m").objects
    alone = [perceived_concepts(perception, recording) for recording in recordings]
    assert [list(words) for words in alone] == [result.active_concepts for result in answered]
    measured = [MeasuredObject(*recording_features(recording)) for recording in recordings]
    features_scene = perceive_scene(perception, measured)
    assert [obj.active_concepts for obj in features_scene.objects] == alone
    assert {obj.level for obj in features_scene.objects} == {"features"}
    vocabulary = world.vocabulary
    for recording, words in zip(recordings, alone, strict=True):
        assert sum(word in vocabulary.nouns for word in words) == 1
        assert len([word for word in words if word in vocabulary.adjectives]) == len(vocabulary.adjective_pairs)
        applied = {interaction.behaviour for interaction in recording.interactions}
        assert {word for word in words if word in vocabulary.verbs} <= applied  # Table V: applied verbs only
    assert any(set(words) & set(vocabulary.verbs) for words in alone)


def test_the_document_is_the_map_concepts_that_carry_evidence(
    world: World, perception: Perception, test_recordings: dict[str, ObjectRecording]
) -> None:
    """With a web the words are its MAP concepts minus the verbs not applied; without one, the
    perception's own MAP (its most probable noun first)."""
    vocabulary = world.vocabulary
    measured = [MeasuredObject.from_recording(recording) for recording in test_recordings.values()]
    scene = perceive_scene(perception, measured)
    without_web = perceive_scene(Perception(vocabulary, perception.prototypes), measured)
    for obj, bare in zip(scene.objects, without_web.objects, strict=True):
        assert obj.web is not None and bare.web is None
        predicted_only = ~carries_evidence(vocabulary, obj.evidence.applied)
        assert obj.active_concepts == tuple(np.array(vocabulary.concepts)[obj.web.map_configuration & ~predicted_only])
        p = obj.evidence.probabilities
        assert bare.active_concepts[0] == vocabulary.nouns[int(np.argmax(p[: len(vocabulary.nouns)]))]
    assert scene.words == [word for obj in scene.objects for word in obj.active_concepts]


def test_the_rule_drops_predicted_affordances_and_reads_the_perception_without_a_web() -> None:
    vocabulary = Vocabulary(nouns=("cup", "ball"), adjective_pairs=(("soft", "hard"),), verbs=("grasp", "throw"))
    applied = np.array([True, False])
    evidence = carries_evidence(vocabulary, applied)
    assert evidence.tolist() == [True, True, True, True, True, False]
    web_map = np.array([False, True, True, False, True, True])  # ball, soft, grasp; throw only predicted
    assert active_concepts(web_map, evidence).tolist() == [False, True, True, False, True, False]
    # Without a web: argmax noun, the first adjective on a tie, verbs at >= 0.5.
    probabilities = np.array([0.3, 0.7, 0.5, 0.5, 0.5, 0.9])
    assert perception_map(vocabulary, probabilities).tolist() == [False, True, True, False, True, True]
    rows = np.stack([web_map, ~web_map])
    assert active_concepts(rows, carries_evidence(vocabulary, np.stack([applied, applied]))).shape == (2, 6)


def test_names_outside_the_vocabulary_are_words_when_probable_enough() -> None:
    perception = Perception(paper_vocabulary())
    scene = perceive_scene(perception, [NamedObject.of({"cup": 1.0, "mug": 0.7, "vase": 0.3})])
    assert scene.objects[0].active_concepts == ("cup", "mug")


@pytest.mark.slow
def test_the_module_example_runs() -> None:
    results = doctest.testmod(core.scene.pipeline, optionflags=doctest.ELLIPSIS)
    assert results.attempted > 0 and results.failed == 0
