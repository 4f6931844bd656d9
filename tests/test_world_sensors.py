"""Simulated payloads (§II-C): the protocol's shape, physical units, and adjectives that show in the data."""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import InvalidInputError
from core.payloads import ObjectRecording
from sim.sensors import AUDIO_SAMPLE_RATE, FINGER_SAMPLES, MAX_POINTS, MIN_POINTS, BehaviourEffect, make_body
from sim.world import World, WorldConfig, WorldObject


@pytest.fixture(scope="module")
def paper_world() -> World:
    return World.paper(seed=0)


@pytest.fixture(scope="module")
def recordings(paper_world: World) -> dict[str, ObjectRecording]:
    return paper_world.recordings(seed=0)


def _extent(recording: ObjectRecording, axis: int) -> float:
    return float(np.ptp(recording.look.points[:, axis]))


def _with(world: World, adjective: str) -> list[WorldObject]:
    return [obj for obj in world.objects if adjective in obj.adjectives]


def test_recordings_follow_the_protocol_with_sane_units(paper_world: World, recordings: dict) -> None:
    for obj in paper_world.objects:
        recording = recordings[obj.object_id]
        assert tuple(i.behaviour for i in recording.interactions) == obj.behaviours
        clouds = [recording.look] + [c for i in recording.interactions for c in (i.before, i.after)]
        for cloud in clouds:
            points = cloud.points
            assert MIN_POINTS <= len(points) <= MAX_POINTS
            assert points[:, 2].min() > -0.01 and points[:, 2].max() < 0.3  # metres above the table
            assert np.abs(points[:, 0]).max() < 0.7 and -0.3 < points[:, 1].min() and points[:, 1].max() < 1.0
        (grasp,) = [i for i in recording.interactions if i.behaviour == "grasp"]
        assert grasp.finger is not None and grasp.finger.haptic.shape == (FINGER_SAMPLES,)
        assert all(i.finger is None for i in recording.interactions if i.behaviour != "grasp")
        with_audio = [i.behaviour for i in recording.interactions if i.audio is not None]
        # Shake records the audio (§II-C 3.3); objects that may not be shaken are heard while grasped.
        assert with_audio == (["shake"] if "shake" in obj.behaviours else ["grasp"])
        audio = recording.audio
        assert audio.sample_rate == AUDIO_SAMPLE_RATE and audio.samples.shape == (AUDIO_SAMPLE_RATE,)
        assert audio.samples.dtype == np.float32 and np.abs(audio.samples).max() <= 1.0


def _ordered(high: list[float], low: list[float]) -> float:
    """The fraction of (high, low) pairs in that order: 1 when the two groups do not overlap."""
    return float((np.array(high)[:, None] > np.array(low)[None, :]).mean())


# Labels are human judgements, so the physical ranges of the two adjectives of a pair overlap
# slightly at their boundary (docs/world.md): the groups are almost, not perfectly, apart.
def test_tall_objects_look_taller_and_thick_ones_wider(paper_world: World, recordings: dict) -> None:
    tall = [_extent(recordings[o.object_id], 2) for o in _with(paper_world, "tall")]
    short = [_extent(recordings[o.object_id], 2) for o in _with(paper_world, "short")]
    assert _ordered(tall, short) > 0.95
    assert np.mean(tall) > np.mean(short) + 0.07
    thin = [_extent(recordings[o.object_id], 0) for o in _with(paper_world, "thin")]
    thick = [_extent(recordings[o.object_id], 0) for o in _with(paper_world, "thick")]
    assert _ordered(thick, thin) > 0.95
    assert np.mean(thick) > np.mean(thin) + 0.04


def test_noisy_objects_rattle_and_silent_ones_are_near_silence(paper_world: World, recordings: dict) -> None:
    def rms(obj: WorldObject) -> float:
        return float(np.sqrt(np.mean(recordings[obj.object_id].audio.samples.astype(float) ** 2)))

    noisy = [rms(obj) for obj in _with(paper_world, "noisy")]
    silent = [rms(obj) for obj in _with(paper_world, "silent")]
    assert max(silent) < 0.01
    assert _ordered(noisy, silent) > 0.95
    assert np.median(noisy) > 4 * np.median(silent)


def test_soft_objects_give_a_slow_pressure_rise_and_let_the_finger_close_further(
    paper_world: World, recordings: dict
) -> None:
    def rise_samples(obj: WorldObject) -> int:
        haptic = recordings[obj.object_id].finger.haptic
        return int(np.argmax(haptic >= 0.9 * haptic.max()) - np.argmax(haptic >= 0.1 * haptic.max()))

    def squeeze(obj: WorldObject) -> float:
        finger = recordings[obj.object_id].finger
        contact = int(np.argmax(finger.haptic >= 0.1 * finger.haptic.max()))
        return float(finger.proprioceptive[-5:].mean() - finger.proprioceptive[contact])

    soft, hard = _with(paper_world, "soft"), _with(paper_world, "hard")
    assert _ordered([rise_samples(o) for o in soft], [rise_samples(o) for o in hard]) > 0.9
    assert np.median([rise_samples(o) for o in soft]) > 2 * np.median([rise_samples(o) for o in hard])
    assert np.median([squeeze(o) for o in soft]) > np.median([squeeze(o) for o in hard]) + 0.1
    peak = {o.object_id: recordings[o.object_id].finger.haptic.max() for o in paper_world.objects}
    assert np.mean([peak[o.object_id] for o in hard]) > np.mean([peak[o.object_id] for o in soft])


def _displacements(world: World, recordings: dict, behaviour: str) -> np.ndarray:
    moves = []
    for obj in world.objects:
        for interaction in recordings[obj.object_id].interactions:
            if interaction.behaviour == behaviour:
                moves.append(interaction.after.points.mean(axis=0) - interaction.before.points.mean(axis=0))
    return np.array(moves)


def test_behaviours_move_objects_consistently(paper_world: World, recordings: dict) -> None:
    move_left = _displacements(paper_world, recordings, "move_left")
    push_left = _displacements(paper_world, recordings, "push_left")
    assert move_left[:, 0].mean() == pytest.approx(-0.10, abs=0.01)
    assert push_left[:, 0].mean() == pytest.approx(-0.15, abs=0.015)
    assert push_left[:, 0].std() > 2 * move_left[:, 0].std()
    forward = _displacements(paper_world, recordings, "move_forward")
    assert forward[:, 1].mean() == pytest.approx(0.10, abs=0.01) and abs(forward[:, 0].mean()) < 0.01
    assert _displacements(paper_world, recordings, "throw")[:, 1].mean() > 0.25
    assert np.abs(_displacements(paper_world, recordings, "grasp")[:, :2]).max() < 0.03


def test_knocking_down_a_tall_object_lays_it_on_its_side(paper_world: World, recordings: dict) -> None:
    for obj in _with(paper_world, "tall"):
        if "knock_down" not in obj.behaviours:
            continue
        (knock,) = [i for i in recordings[obj.object_id].interactions if i.behaviour == "knock_down"]
        before, after = knock.before.points, knock.after.points
        assert np.ptp(after[:, 2]) < 0.6 * np.ptp(before[:, 2])  # height and depth swap
        assert np.ptp(after[:, 1]) > 1.5 * np.ptp(before[:, 1])


def test_payloads_are_a_function_of_the_seed(paper_world: World) -> None:
    obj = paper_world.objects[20]
    first, again, other = paper_world.record(obj, 5), paper_world.record(obj, 5), paper_world.record(obj, 6)
    assert np.array_equal(first.look.points, again.look.points)
    assert np.array_equal(first.audio.samples, again.audio.samples)
    assert np.array_equal(first.finger.haptic, again.finger.haptic)
    assert not np.array_equal(first.look.points[:100], other.look.points[:100])
    # The body is the object's own: the same in every recording and in a world rebuilt from the seed.
    assert World.paper(seed=0).body(obj.object_id) == paper_world.body(obj)
    assert World.paper(seed=1).body(obj.object_id) != paper_world.body(obj)
    recorded_alone = paper_world.recordings([obj], seed=3)[obj.object_id]
    recorded_with_others = paper_world.recordings(paper_world.objects[18:22], seed=3)[obj.object_id]
    assert np.array_equal(recorded_alone.look.points, recorded_with_others.look.points)


def test_generic_worlds_are_recorded_too() -> None:
    world = World.generic(2, seed=1)
    for obj in world.objects[::5]:
        recording = world.record(obj, 0)
        assert tuple(i.behaviour for i in recording.interactions) == obj.behaviours
        assert recording.audio is not None and recording.finger is not None


def test_bad_recording_requests_name_the_field(paper_world: World) -> None:
    stranger = World.generic(2, seed=1).objects[0]
    with pytest.raises(InvalidInputError, match="object_id"):
        paper_world.record(stranger, 0)
    with pytest.raises(InvalidInputError, match="adjectives"):
        make_body("box", ["hard", "soft", "noisy", "tall", "thin", "round"], np.random.default_rng(0))
    with pytest.raises(InvalidInputError, match="primitive"):
        make_body("pyramid", ["hard", "noisy", "tall", "thin", "round"], np.random.default_rng(0))
    data = WorldConfig.paper().to_dict()
    data["shapes"].pop("tool")
    data["vocabulary"]["nouns"][5] = "hammer"
    for table in ("noun_adjective_counts", "applicability"):
        data[table]["hammer"] = data[table].pop("tool")
    data["contexts"]["workshop"]["nouns"] = ["hammer", "cylinder"]
    data["contexts"]["workshop"]["prevalent"] = ["hammer", "cylinder"]
    hammer_world = World(WorldConfig.from_dict(data))
    with pytest.raises(InvalidInputError, match="shapes"):
        hammer_world.record(hammer_world.objects[-1], 0)
    with pytest.raises(InvalidInputError, match="behaviour_effect.spread"):
        BehaviourEffect("slide", direction=(1, 0), spread=-0.1)
