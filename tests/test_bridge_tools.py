"""simulate and replay: what they send is what the service's schemas accept; files read back exactly."""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import httpx
import numpy as np
import pytest
import soundfile

from app.schemas.models import ModelCreate as ServiceModelCreate
from app.schemas.plans import PlanCreate as ServicePlanCreate
from app.schemas.scenes import SceneCreate as ServiceSceneCreate
from app.schemas.training import TrainingBatchCreate as ServiceTrainingBatch
from bridge import Client, RetryPolicy
from bridge.errors import InvalidRecordingError
from bridge.models import ModelCreate, PlanCreate, SceneCreate, TrainingBatch, TrainingObject, Vocabulary
from bridge.tools import payloads, replay
from core.payloads import MAX_SAMPLE_RATE, MIN_SAMPLE_RATE
from sim import robot as simulate
from sim.world import World, WorldConfig
from tests.conftest import decoded_recording


@pytest.fixture(scope="module")
def world() -> World:
    return World(WorldConfig.paper(), seed=0)


@pytest.fixture(scope="module")
def recording(world: World):
    return world.record(world.train_objects[0], 7)


def _dump(model) -> dict:
    return model.model_dump(mode="json", exclude_defaults=True)


@pytest.mark.parametrize("level", simulate.LEVELS)
def test_scene_objects_at_every_level_are_accepted_by_the_service_schema(world: World, level: str) -> None:
    scene = world.scenes(1, seed=2, contexts=["playroom"], objects_per_scene=2)[0]
    objects = simulate.scene_objects(world, scene, level, np.random.default_rng(0), max_points=200)
    accepted = ServiceSceneCreate.model_validate(_dump(SceneCreate(objects=objects)))
    assert [obj.level for obj in accepted.objects] == [level] * len(scene.objects)
    if level == "concepts":
        assert accepted.objects[0].concepts == [*scene.objects[0].concepts, *scene.objects[0].behaviours]
    if level == "raw":
        clouds = accepted.objects[0].raw
        assert clouds is not None and clouds.look.array().shape == (200, 3)
        assert {i.behaviour for i in clouds.interactions} == set(scene.objects[0].behaviours)


@pytest.mark.parametrize("level", ["features", "raw"])
def test_training_objects_are_accepted_by_the_service_schema(world: World, recording, level: str) -> None:
    obj = world.train_objects[0]
    labelled = simulate.training_object(obj, recording, level, np.random.default_rng(0), max_points=100)
    accepted = ServiceTrainingBatch.model_validate(_dump(TrainingBatch(objects=[labelled])))
    assert accepted.objects[0].noun == obj.noun and tuple(accepted.objects[0].adjectives) == obj.adjectives
    if level == "features":
        assert set(accepted.objects[0].features.effects) == set(obj.behaviours)


def test_plan_request_is_accepted_by_the_service_schema() -> None:
    request = PlanCreate(object="cup", start=8, goal=5, scene_id=3, mode="paper")
    accepted = ServicePlanCreate.model_validate(_dump(request) | {"mode": "paper"})
    assert (accepted.object, accepted.start, accepted.goal, accepted.scene_id, accepted.mode) == (
        "cup",
        8,
        5,
        3,
        "paper",
    )
    with pytest.raises(ValueError, match="at most one of context, scene_id, scene"):
        PlanCreate(object="cup", start=8, goal=5, scene_id=3, context=1)


def test_model_request_is_accepted_by_the_service_schema(world: World) -> None:
    vocabulary = Vocabulary.model_validate(world.vocabulary.to_dict())
    hyperparameters = {"priors": {"alpha": 0.2}, "k_rule": {"name": "paper", "tau": 0.05}}
    request = ModelCreate(name="robot-7", seed=3, sigma=0.4, hyperparameters=hyperparameters, vocabulary=vocabulary)
    accepted = ServiceModelCreate.model_validate(_dump(request))
    assert (accepted.seed, accepted.sigma, accepted.hyperparameters.priors.alpha) == (3, 0.4, 0.2)
    assert (accepted.hyperparameters.k_rule.name, accepted.hyperparameters.k_rule.tau) == ("paper", 0.05)
    assert accepted.hyperparameters.priors.xi == 0.1 and accepted.hyperparameters.sampler.sweeps == 200
    assert accepted.vocabulary is not None and accepted.vocabulary.verbs == list(world.vocabulary.verbs)


def test_training_batches_stay_under_the_byte_limit(world: World, recording) -> None:
    rng = np.random.default_rng(0)
    objects = [simulate.training_object(world.train_objects[0], recording, "raw", rng, 300) for _ in range(5)]
    size = len(objects[0].model_dump_json())
    batches = list(simulate._batches(iter(objects), max_bytes=2 * size + 10))
    assert [len(b) for b in batches] == [2, 2, 1]


@pytest.mark.parametrize(("cloud_format", "finger_format"), [("ply", "csv"), ("pcd", "npy")])
def test_recordings_round_trip_through_files(tmp_path: Path, recording, cloud_format: str, finger_format: str) -> None:
    folder = replay.write_object(
        tmp_path / "box_00",
        recording,
        noun="box",
        adjectives=("soft", "silent"),
        cloud_format=cloud_format,
        finger_format=finger_format,
    )
    back = replay.read_object(folder, max_points=10**9)
    assert (back.noun, back.adjectives) == ("box", ("soft", "silent"))
    recording_back = decoded_recording(back.raw)
    np.testing.assert_allclose(recording_back.look.points, recording.look.points, rtol=0, atol=1e-6)
    original = {i.behaviour: i for i in recording.interactions}
    assert {i.behaviour for i in recording_back.interactions} == set(original)
    for interaction in recording_back.interactions:
        source = original[interaction.behaviour]
        np.testing.assert_allclose(interaction.after.points, source.after.points, atol=1e-6)
        assert (interaction.audio is None) == (source.audio is None)
        assert (interaction.finger is None) == (source.finger is None)
        if source.audio is not None:
            assert interaction.audio.sample_rate == source.audio.sample_rate
            np.testing.assert_allclose(interaction.audio.samples, source.audio.samples, atol=1e-7)
        if source.finger is not None:
            np.testing.assert_allclose(interaction.finger.proprioceptive, source.finger.proprioceptive, rtol=1e-6)


def test_stereo_wav_is_mixed_down_and_nan_points_dropped(tmp_path: Path) -> None:
    stereo = np.column_stack([np.full(800, 0.5), np.full(800, -0.1)]).astype(np.float32)
    soundfile.write(str(tmp_path / "a.wav"), stereo, 8000)
    samples, sample_rate = replay.read_audio(tmp_path / "a.wav")
    assert sample_rate == 8000 and np.allclose(samples, 0.2, atol=1e-4)  # 16-bit PCM file
    points = np.array([[0.0, 0.1, 0.2], [np.nan, np.nan, np.nan], [1.0, 1.0, 1.0]], dtype=np.float32)
    replay._write_cloud(tmp_path / "organised.pcd", points)
    assert replay.read_point_cloud(tmp_path / "organised.pcd", scale=0.001).shape == (2, 3)


def test_bad_files_are_named_in_the_error(tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    with pytest.raises(InvalidRecordingError, match="neither a look.ply/look.pcd nor object folders"):
        replay.read_scene(tmp_path / "empty")
    (tmp_path / "finger.csv").write_text("pressure,angle\n1,2\n3,4\n")
    with pytest.raises(InvalidRecordingError, match="finger.csv: needs the columns haptic and proprioceptive"):
        replay.read_finger(tmp_path / "finger.csv")
    (tmp_path / "look.ply").write_text("not a ply")
    with pytest.raises(InvalidRecordingError, match="look.ply: cannot be read as a point cloud"):
        replay.read_point_cloud(tmp_path / "look.ply")


def test_the_encoder_refuses_what_the_service_would_with_the_field_named(tmp_path: Path) -> None:
    """bridge.tools.payloads checks before sending; its limits are core's (the bridge cannot import them)."""
    assert (payloads.MIN_SAMPLE_RATE, payloads.MAX_SAMPLE_RATE) == (MIN_SAMPLE_RATE, MAX_SAMPLE_RATE)
    rng = np.random.default_rng(0)
    refused = {
        "look.points: contains 1 NaN or infinite values": lambda: payloads.cloud(
            [[0, 0, np.nan]], rng, 10, "look.points"
        ),
        "look.points: must be (n, 3) xyz rows": lambda: payloads.cloud([[0.0, 1.0]], rng, 10, "look.points"),
        "look.points: is empty": lambda: payloads.cloud(np.empty((0, 3)), rng, 10, "look.points"),
        "audio.sample_rate: 1000 Hz is outside": lambda: payloads.audio([0.1, 0.2], 1000),
        "finger.haptic: needs at least 2 samples, has 1": lambda: payloads.finger([1.0], [0.2]),
        "finger.proprioceptive: length 3 does not match": lambda: payloads.finger([1.0, 2.0], [0.1, 0.2, 0.3]),
    }
    for problem, encode in refused.items():
        with pytest.raises(InvalidRecordingError, match=re.escape(problem)):
            encode()
    replay._write_cloud(tmp_path / "look.ply", np.full((4, 3), np.nan, dtype=np.float32))
    with pytest.raises(InvalidRecordingError, match="look.ply: holds no finite point"):
        replay.read_point_cloud(tmp_path / "look.ply")


def test_replay_posts_a_raw_scene_and_training_objects(tmp_path: Path, world: World, recording) -> None:
    scene_folder = tmp_path / "scene_001"
    for name in ("a", "b"):
        replay.write_object(scene_folder / name, recording, cloud_format="pcd")
    labelled = replay.write_object(
        tmp_path / "labelled", recording, noun="box", adjectives=world.train_objects[0].adjectives
    )
    bodies: dict[str, list[dict]] = {}

    def service(request: httpx.Request) -> httpx.Response:
        bodies.setdefault(request.url.path.rsplit("/", 1)[-1], []).append(json.loads(request.content))
        if request.url.path.endswith("/scenes"):
            return httpx.Response(
                201,
                json={
                    "model_id": "m",
                    "scene_id": 0,
                    "learned": True,
                    "context_count": 1,
                    "previous_context_count": 1,
                    "context_posterior": [1.0],
                    "map_context": 0,
                },
            )
        if request.url.path.endswith("/fit"):
            return httpx.Response(
                200,
                json={
                    "model_id": "m",
                    "method": "rgng",
                    "training_object_count": 1,
                    "concept_web_edges": 0,
                    "behaviours": [],
                },
            )
        return httpx.Response(201, json={"added": 1, "training_object_count": 1})

    with Client(
        "http://service", transport=httpx.MockTransport(service), retry_policy=RetryPolicy(max_retries=0)
    ) as client:
        rng = np.random.default_rng(0)
        replay.replay_scene(client, "m", scene_folder, rng=rng, max_points=50)
        replay.replay_training(client, "m", [labelled], rng=rng, max_points=50)
    scene = ServiceSceneCreate.model_validate(bodies["scenes"][0])
    assert len(scene.objects) == 2 and scene.objects[1].raw.interactions[0].before.array().shape == (50, 3)
    assert ServiceTrainingBatch.model_validate(bodies["training-objects"][0]).objects[0].noun == "box"
    assert "fit" in bodies


def test_simulate_cli_arguments_make_phases(world: World) -> None:
    parser = argparse.ArgumentParser()
    simulate.add_arguments(parser)
    args = parser.parse_args(["--contexts", "kitchen,playroom", "--contexts", "workshop", "--scenes", "4"])
    phases = simulate._phases(world, args)
    assert [len(p) for p in phases] == [4, 4]
    assert {c for s in phases[0] for c in s.mixture} <= {"kitchen", "playroom"}
    assert {c for s in phases[1] for c in s.mixture} == {"workshop"}
    mixed = simulate._phases(world, parser.parse_args(["--mixture", "playroom=0.5,workshop=0.5", "--scenes", "2"]))
    assert all(set(s.mixture) == {"playroom", "workshop"} for s in mixed[0])


def test_training_object_needs_one_level() -> None:
    with pytest.raises(ValueError, match="exactly one of features, raw"):
        TrainingObject(noun="cup", adjectives=["hard"])
