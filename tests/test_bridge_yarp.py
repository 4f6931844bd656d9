"""yarpdatadumper replay: a session of dump folders (markers, the right arm's state:o, the right hand's
compensated skin) and object cloud folders gives the world's recordings back, posts each scene once, and
names the file, line and stamp of a bad line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from bridge.errors import InvalidRecordingError
from bridge.tools import replay
from bridge.tools.mapping import parse_mapping
from bridge.tools.segments import finger_series
from bridge.tools.yarp import YarpSession, is_yarp_session, read_port_log, replay_yarp
from core.payloads import ObjectRecording
from sim.world import World
from tests.conftest import decoded_recording
from tests.test_bridge_bags import _bridge, _fitted_model, _scene_count, _small, service, world  # noqa: F401

START = 1_700_000_000.0
INDEX_PROXIMAL = 11  # the 16 values of /icub/right_arm/state:o, in degrees
FINGERTIP = list(range(12))  # the index fingertip's taxels of /icub/skin/right_hand_comp (192 values)
MAPPING = {
    "clouds": {"folder": "clouds"},
    "proprioception": {"folder": "icub_right_arm_state", "column": INDEX_PROXIMAL},
    "haptics": {"folder": "icub_skin_right_hand_comp", "columns": FINGERTIP, "reduce": "mean"},
    "segmentation": {"markers": "contextweb_markers"},
    "yarp": {"timestamps": 1},
}


class Dumper:
    """One yarpdatadumper folder, written line by line in its format."""

    def __init__(self, folder: Path, port: str) -> None:
        folder.mkdir(parents=True)
        (folder / "info.log").write_text(f"Type: Bottle;\n[{START:.6f}] {port} [connected]\n", encoding="utf-8")
        self.data = (folder / "data.log").open("w", encoding="utf-8")
        self.counter = 0

    def line(self, stamp: float, values: str) -> None:
        self.data.write(f"{self.counter} {stamp:.6f} {values}\n")
        self.counter += 1


def write_session(folder: Path, scenes: list[list[ObjectRecording]]) -> Path:
    """Markers, joint and skin dumps at 1 kHz stamps; the clouds as object folders."""
    markers = Dumper(folder / "contextweb_markers", "/contextweb/markers:o")
    arm = Dumper(folder / "icub_right_arm_state", "/icub/right_arm/state:o")
    skin = Dumper(folder / "icub_skin_right_hand_comp", "/icub/skin/right_hand_comp")
    stamp = START
    for number, scene in enumerate(scenes):
        markers.line(stamp := stamp + 0.001, "scene")
        for index, recording in enumerate(scene):
            name = f"s{number}_object_{index}"
            replay.write_object(folder / "clouds" / name, recording)
            markers.line(stamp := stamp + 0.001, f"look {name}")
            for interaction in recording.interactions:
                markers.line(stamp := stamp + 0.001, f'"begin {name} {interaction.behaviour}"')  # one quoted string
                if interaction.finger is not None:
                    for haptic, angle in zip(interaction.finger.haptic, interaction.finger.proprioceptive, strict=True):
                        joints = np.zeros(16)
                        joints[INDEX_PROXIMAL] = np.rad2deg(angle)
                        taxels = np.zeros(192)
                        taxels[FINGERTIP] = haptic
                        arm.line(stamp := stamp + 0.001, " ".join(repr(float(v)) for v in joints))
                        skin.line(stamp, " ".join(repr(float(v)) for v in taxels))
                markers.line(stamp := stamp + 0.001, "end")
    for dumper in (markers, arm, skin):
        dumper.data.close()
    return folder


@pytest.fixture(scope="module")
def scenes(world: World) -> list[list[ObjectRecording]]:  # noqa: F811 - the world fixture of test_bridge_bags
    rng = np.random.default_rng(4)
    recordings = [_small(world.record(world.test_objects[i], rng)) for i in (2, 7, 11)]
    return [recordings[:2], recordings[2:]]


def test_a_yarp_session_gives_the_recordings_back(tmp_path: Path, scenes: list[list[ObjectRecording]]) -> None:
    session_folder = write_session(tmp_path / "session", scenes)
    assert is_yarp_session(session_folder) and not is_yarp_session(session_folder / "clouds")
    session = YarpSession(session_folder, parse_mapping(MAPPING))
    replayed = list(session.scenes())
    assert [[obj.name for obj in scene.plan.objects] for scene in replayed] == [
        ["s0_object_0", "s0_object_1"],
        ["s1_object_0"],
    ]
    for scene, recordings in zip(replayed, scenes, strict=True):
        for raw, source in zip(scene.recordings, recordings, strict=True):
            back = decoded_recording(raw)
            np.testing.assert_array_equal(back.look.points, source.look.points.astype(np.float32))
            assert [i.behaviour for i in back.interactions] == [i.behaviour for i in source.interactions]
            for mine, theirs in zip(back.interactions, source.interactions, strict=True):
                assert (mine.finger is None) == (theirs.finger is None)
                assert (mine.audio is None) == (theirs.audio is None)
                if theirs.finger is not None:
                    np.testing.assert_allclose(mine.finger.proprioceptive, theirs.finger.proprioceptive, rtol=1e-6)
                    np.testing.assert_allclose(mine.finger.haptic, theirs.finger.haptic, rtol=1e-6)  # float32 sent
    assert len({scene.key for scene in replayed}) == 2 and all(s.key.startswith("yarp-") for s in replayed)


def test_a_yarp_replay_posts_each_scene_once(
    tmp_path: Path,
    world: World,  # noqa: F811
    scenes: list[list[ObjectRecording]],
    service: TestClient,  # noqa: F811
) -> None:
    session_folder = write_session(tmp_path / "session", scenes)
    model_id = _fitted_model(service, world)
    with _bridge(service) as client:
        first = replay_yarp(client, model_id, session_folder, parse_mapping(MAPPING), limit=1)
        again = replay_yarp(client, model_id, session_folder, parse_mapping(MAPPING))
    assert _scene_count(service, model_id) == 2
    assert again[0] == first[0]


def test_bad_lines_are_named_by_file_line_and_stamp(tmp_path: Path, scenes: list[list[ObjectRecording]]) -> None:
    session_folder = write_session(tmp_path / "session", scenes[1:])
    data = session_folder / "icub_right_arm_state" / "data.log"
    lines = data.read_text().splitlines()
    words = lines[3].split()
    words[2 + INDEX_PROXIMAL] = "nan?"
    lines[3] = " ".join(words)
    data.write_text("\n".join(lines) + "\n")
    with pytest.raises(InvalidRecordingError) as caught:
        list(YarpSession(session_folder, parse_mapping(MAPPING)).scenes())
    assert str(caught.value).startswith(f"{data}: line 4 (stamp {float(words[1]):.6f} s): a value is not a number")

    short = {**MAPPING, "proprioception": {"folder": "icub_right_arm_state", "column": 16}}
    with pytest.raises(InvalidRecordingError, match=r"line 1 \(stamp .*\): has 16 values, the mapping reads column 16"):
        list(YarpSession(session_folder, parse_mapping(short)).scenes())

    lines[5], lines[6] = lines[6], lines[5]
    data.write_text("\n".join(lines) + "\n")
    with pytest.raises(InvalidRecordingError, match="data.log: line 7 goes back in time"):
        read_port_log(data.parent)

    (session_folder / "contextweb_markers" / "info.log").write_text("Type: Image:ppm;\n")
    with pytest.raises(InvalidRecordingError, match="only bottle dumps are read"):
        read_port_log(session_folder / "contextweb_markers")


def test_two_stamps_per_line_use_the_senders(tmp_path: Path) -> None:
    dump = Dumper(tmp_path / "port", "/icub/right_arm/state:o")
    dump.line(12.5, "12.75 1.0 2.0")  # --txTime --rxTime: tx stamp, rx stamp, values
    dump.data.close()
    log = read_port_log(tmp_path / "port", timestamps=2)
    assert log.times.tolist() == [12_500_000_000] and log.numbers(0, 0).tolist() == [1.0, 2.0]


def test_haptics_are_interpolated_at_the_joint_readings() -> None:
    haptic, proprioceptive = finger_series([0, 10, 20], [0.1, 0.2, 0.3], [5, 15], [1.0, 3.0])
    assert haptic.tolist() == [1.0, 2.0, 3.0]  # the ends held, the middle halfway
    assert proprioceptive.tolist() == [0.1, 0.2, 0.3]
