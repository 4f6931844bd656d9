"""ROS bag replay: real bags written with rosbags' own writers (MCAP, sqlite3, ROS 1) from the simulated
world's recordings replay exactly like the same recordings as folders, post each scene once across a
restart, and fail on bad bags with errors naming the topic and the time, posting nothing of that scene."""

from __future__ import annotations

import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any, ClassVar, Self

import httpx
import numpy as np
import pytest
from fastapi.testclient import TestClient
from rosbags.highlevel import AnyReader
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Ros2Writer
from rosbags.typesys import Stores, get_typestore

from app.cli import main
from app.main import create_app
from bridge import Client, RetryPolicy
from bridge.errors import InvalidRecordingError
from bridge.models import RawObject
from bridge.tools import replay
from bridge.tools.bags import (
    BagReplay,
    audio_samples,
    audio_typestore,
    haptic_value,
    joint_angle,
    post_scenes,
    replay_bag,
)
from bridge.tools.mapping import AudioStream, Haptics, Proprioception, parse_mapping
from bridge.tools.segments import plan_from_markers, plan_from_windows
from core.payloads import Interaction, ObjectRecording, PointCloud
from sim.world import World, WorldConfig
from tests.conftest import decoded_recording, make_settings, migrated_database, synthetic_training_objects

START = 1_700_000_000 * 1_000_000_000
STEP = 1_000_000  # 1 ms between messages
POINTS = 120
JOINT = "r_index_proximal"
TAXEL = 3
MAPPING = {
    "clouds": {"topic": "/object/points"},
    "audio": {"topic": "/audio", "sample_rate": 16000, "behaviours": ["shake"]},
    "proprioception": {"topic": "/joint_states", "joint": JOINT},
    "haptics": {"topic": "/fingertip", "indices": [TAXEL], "reduce": "sum"},
    "segmentation": {"markers": "/markers"},
}
KINDS = ["mcap", "sqlite3", "ros1"]
#: audio_common's AudioData (a type rosbags' stores lack, registered from its .msg) in two of the kinds.
PCM_AUDIO = {"/audio": "audio_common_msgs/msg/AudioData"}
PCM_MAPPING = {**MAPPING, "audio": {**MAPPING["audio"], "sample_format": "F32LE"}}


@pytest.fixture(scope="module")
def world() -> World:
    return World(WorldConfig.paper(), seed=0)


@pytest.fixture(scope="module")
def scenes(world: World) -> list[list[ObjectRecording]]:
    """Two scenes of two of the world's objects; clouds cut to a few points (the bytes, not the shapes, cost)."""
    rng = np.random.default_rng(3)
    objects = [world.test_objects[i] for i in (0, 5, 9, 14)]
    recordings = [_small(world.record(obj, rng)) for obj in objects]
    return [recordings[:2], recordings[2:]]


def _small(recording: ObjectRecording) -> ObjectRecording:
    def cut(cloud: PointCloud) -> PointCloud:
        return PointCloud(cloud.points[:POINTS])

    interactions = tuple(
        Interaction(i.behaviour, cut(i.before), cut(i.after), i.audio, i.finger) for i in recording.interactions
    )
    return ObjectRecording(cut(recording.look), interactions)


class BagWriter:
    """One bag of any kind, written message by message with rosbags' own writers."""

    TYPES: ClassVar[dict[str, str]] = {
        "/object/points": "sensor_msgs/msg/PointCloud2",
        "/markers": "std_msgs/msg/String",
        "/audio": "std_msgs/msg/Float32MultiArray",
        "/joint_states": "sensor_msgs/msg/JointState",
        "/fingertip": "std_msgs/msg/Float64MultiArray",
    }

    def __init__(self, path: Path, kind: str, types: dict[str, str] | None = None) -> None:
        self.ros1 = kind == "ros1"
        self.store = audio_typestore(get_typestore(Stores.ROS1_NOETIC if self.ros1 else Stores.LATEST))
        plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
        self.writer = Ros1Writer(path) if self.ros1 else Ros2Writer(path, version=9, storage_plugin=plugin)
        self.types = {**self.TYPES, **(types or {})}
        self.connections: dict[str, Any] = {}
        self.time = START

    def __enter__(self) -> Self:
        self.writer.open()
        for topic, msgtype in self.types.items():
            self.connections[topic] = self.writer.add_connection(topic, msgtype, typestore=self.store)
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.writer.close()

    def write(self, topic: str, message: Any, *, advance: bool = True) -> None:
        msgtype = self.types[topic]
        data = self.store.serialize_ros1(message, msgtype) if self.ros1 else self.store.serialize_cdr(message, msgtype)
        self.writer.write(self.connections[topic], self.time, data)
        self.time += STEP if advance else 0

    def header(self) -> Any:
        stamp = self.store.types["builtin_interfaces/msg/Time"](sec=self.time // 10**9, nanosec=self.time % 10**9)
        extra = {"seq": 0} if self.ros1 else {}
        return self.store.types["std_msgs/msg/Header"](**extra, stamp=stamp, frame_id="table")

    def marker(self, text: str) -> None:
        self.write("/markers", self.store.types["std_msgs/msg/String"](data=text))

    def cloud(self, points: np.ndarray, *, dense: bool = True) -> None:
        field = self.store.types["sensor_msgs/msg/PointField"]
        fields = [field(name=axis, offset=4 * i, datatype=7, count=1) for i, axis in enumerate("xyz")]
        data = np.frombuffer(np.asarray(points, dtype="<f4").tobytes(), dtype=np.uint8)
        message = self.store.types["sensor_msgs/msg/PointCloud2"](
            header=self.header(), height=1, width=len(points), fields=fields, is_bigendian=False,
            point_step=12, row_step=12 * len(points), data=data, is_dense=dense,
        )  # fmt: skip
        self.write("/object/points", message)

    def array(self, topic: str, values: np.ndarray) -> None:
        layout = self.store.types["std_msgs/msg/MultiArrayLayout"](dim=[], data_offset=0)
        self.write(topic, self.store.types[self.types[topic]](layout=layout, data=values))

    def audio(self, samples: np.ndarray) -> None:
        if self.types["/audio"] == "std_msgs/msg/Float32MultiArray":
            self.array("/audio", samples.astype(np.float32))
            return
        pcm = np.frombuffer(samples.astype("<f4").tobytes(), dtype=np.uint8)  # AudioData: F32LE bytes
        self.write("/audio", self.store.types["audio_common_msgs/msg/AudioData"](data=pcm))

    def finger(self, haptic: float, angle: float) -> None:
        joints = self.store.types["sensor_msgs/msg/JointState"](
            header=self.header(), name=["r_wrist_yaw", JOINT], position=np.array([0.1, angle]),
            velocity=np.zeros(2), effort=np.zeros(2),
        )  # fmt: skip
        self.write("/joint_states", joints, advance=False)  # the same instant as the taxels
        taxels = np.zeros(12)
        taxels[TAXEL] = haptic
        self.array("/fingertip", taxels)

    def recording(self, name: str, recording: ObjectRecording) -> None:
        self.marker(f"look {name}")
        self.cloud(recording.look.points)
        for interaction in recording.interactions:
            self.marker(f"begin {name} {interaction.behaviour}")
            self.cloud(interaction.before.points)
            if interaction.audio is not None:
                for chunk in np.array_split(interaction.audio.samples, 4):
                    self.audio(chunk)
            if interaction.finger is not None:
                for haptic, angle in zip(interaction.finger.haptic, interaction.finger.proprioceptive, strict=True):
                    self.finger(haptic, angle)
            self.cloud(interaction.after.points)
            self.marker("end")


def write_bag(path: Path, kind: str, scenes: list[list[ObjectRecording]], **options: Any) -> Path:
    path = path / ("run.bag" if kind == "ros1" else "run")
    with BagWriter(path, kind, **options) as bag:
        for scene in scenes:
            bag.marker("scene")
            for number, recording in enumerate(scene):
                bag.recording(f"object_{number}", recording)
    return path


def _assert_same_recordings(got: list[RawObject], expected: list[ObjectRecording]) -> None:
    """What the service decodes from the raw objects sent is the recordings (at float32, as sent)."""
    assert len(got) == len(expected)
    for raw, source in zip(got, expected, strict=True):
        back = decoded_recording(raw)
        np.testing.assert_array_equal(back.look.points, source.look.points.astype(np.float32))
        theirs_by_behaviour = {i.behaviour: i for i in source.interactions}  # folders list behaviours sorted
        assert sorted(i.behaviour for i in back.interactions) == sorted(theirs_by_behaviour)
        for mine in back.interactions:
            theirs = theirs_by_behaviour[mine.behaviour]
            np.testing.assert_array_equal(mine.before.points, theirs.before.points.astype(np.float32))
            np.testing.assert_array_equal(mine.after.points, theirs.after.points.astype(np.float32))
            assert (mine.audio is None) == (theirs.audio is None) and (mine.finger is None) == (theirs.finger is None)
            if theirs.audio is not None:
                assert mine.audio.sample_rate == theirs.audio.sample_rate
                np.testing.assert_array_equal(mine.audio.samples, theirs.audio.samples)
            if theirs.finger is not None:
                np.testing.assert_array_equal(mine.finger.haptic, theirs.finger.haptic.astype(np.float32))
                np.testing.assert_array_equal(
                    mine.finger.proprioceptive, theirs.finger.proprioceptive.astype(np.float32)
                )


@pytest.mark.parametrize("kind", KINDS)
def test_a_bag_reads_back_the_recordings_a_folder_does(
    tmp_path: Path, kind: str, scenes: list[list[ObjectRecording]]
) -> None:
    pcm = kind != "mcap"
    bag = write_bag(tmp_path, kind, scenes, types=PCM_AUDIO if pcm else None)
    with BagReplay(bag, parse_mapping(PCM_MAPPING if pcm else MAPPING)) as replayed:
        from_bag = list(replayed.scenes())
    for number, (scene, recordings) in enumerate(zip(from_bag, scenes, strict=True)):
        folder = tmp_path / f"scene_{number}"
        for index, recording in enumerate(recordings):
            replay.write_object(folder / f"object_{index}", recording)
        from_folder = [decoded_recording(obj.raw) for obj in replay.read_scene(folder)]
        _assert_same_recordings(scene.recordings, from_folder)
        _assert_same_recordings(scene.recordings, recordings)
        assert [obj.name for obj in scene.plan.objects] == ["object_0", "object_1"]
    assert len({scene.key for scene in from_bag}) == 2
    if kind == "mcap":  # the bare storage file, without its metadata.yaml, is the same bag with the same keys
        with BagReplay(next(bag.glob("*.mcap")), parse_mapping(MAPPING)) as bare:
            assert [scene.key for scene in bare.scenes()] == [scene.key for scene in from_bag]


class AppTransport(httpx.BaseTransport):
    """The bridge's HTTP requests sent into the ASGI app through Starlette's TestClient."""

    def __init__(self, app_client: TestClient) -> None:
        self.app_client = app_client

    def handle_request(self, request: httpx.Request) -> httpx.Response:
        answer = self.app_client.request(
            request.method, str(request.url), content=request.read(), headers=dict(request.headers)
        )
        return httpx.Response(answer.status_code, headers=answer.headers, content=answer.content)


@pytest.fixture(scope="module")
def service(world: World, tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    url = migrated_database("sqlite", None, tmp_path_factory.mktemp("database"))  # type: ignore[arg-type]
    with TestClient(create_app(make_settings(url))) as app_client:
        yield app_client


def _fitted_model(service: TestClient, world: World) -> str:
    """A model fitted on synthetic Table III features (k-means prototypes: fast)."""
    model_id = service.post("/v1/models", json={"name": "bags", "seed": 5}).json()["id"]
    objects = synthetic_training_objects(world, seed=1)
    service.post(f"/v1/models/{model_id}/training-objects", json={"objects": objects}).raise_for_status()
    service.post(f"/v1/models/{model_id}/fit", json={"method": "kmeans"}).raise_for_status()
    return model_id


def _bridge(service: TestClient) -> Client:
    return Client("http://testserver", transport=AppTransport(service), retry_policy=RetryPolicy(max_retries=0))


def _scene_count(service: TestClient, model_id: str) -> int:
    return service.get(f"/v1/models/{model_id}").json()["scene_count"]


def test_bag_and_folder_replays_get_the_same_answers_and_a_restart_posts_each_scene_once(
    tmp_path: Path, world: World, scenes: list[list[ObjectRecording]], service: TestClient
) -> None:
    bag = write_bag(tmp_path, "mcap", scenes)
    mapping = parse_mapping(MAPPING)
    from_folders, from_bag = _fitted_model(service, world), _fitted_model(service, world)
    with _bridge(service) as client:
        folder_answers = []
        for number, recordings in enumerate(scenes):
            for index, recording in enumerate(recordings):
                replay.write_object(tmp_path / f"scene_{number}" / f"object_{index}", recording)
            folder_answers.append(
                replay.replay_scene(client, from_folders, tmp_path / f"scene_{number}", rng=np.random.default_rng(0))
            )
        interrupted = replay_bag(client, from_bag, bag, mapping, limit=1)
        assert _scene_count(service, from_bag) == 1
        restarted = replay_bag(client, from_bag, bag, mapping)
    assert _scene_count(service, from_bag) == 2
    assert restarted[0] == interrupted[0]  # the stored answer, not a second scene
    for bag_answer, folder_answer in zip(restarted, folder_answers, strict=True):
        assert bag_answer.context_posterior == folder_answer.context_posterior
        assert bag_answer.context_count == folder_answer.context_count
        assert bag_answer.objects == folder_answer.objects


def _error_after_posting(
    tmp_path: Path, world: World, service: TestClient, bag: Path, mapping: dict, posted: int
) -> str:
    model_id = _fitted_model(service, world)
    with _bridge(service) as client, pytest.raises(InvalidRecordingError) as caught:
        replay_bag(client, model_id, bag, parse_mapping(mapping))
    assert _scene_count(service, model_id) == posted
    return str(caught.value)


def test_a_missing_topic_or_a_wrong_type_is_named_before_anything_is_posted(
    tmp_path: Path, world: World, scenes: list[list[ObjectRecording]], service: TestClient
) -> None:
    bag = write_bag(tmp_path, "sqlite3", scenes[:1])
    missing = {**MAPPING, "haptics": {**MAPPING["haptics"], "topic": "/skin/right_hand"}}
    message = _error_after_posting(tmp_path, world, service, bag, missing, posted=0)
    assert "/skin/right_hand: topic missing from the bag (mapping haptics)" in message and "/fingertip" in message
    wrong = {**MAPPING, "proprioception": {**MAPPING["proprioception"], "topic": "/markers"}}
    message = _error_after_posting(tmp_path, world, service, bag, wrong, posted=0)
    assert "/markers: carries std_msgs/msg/String, but mapping proprioception needs sensor_msgs/msg/JointState" in (
        message
    )


def test_a_cloud_with_nan_fails_its_scene_only(
    tmp_path: Path, world: World, scenes: list[list[ObjectRecording]], service: TestClient
) -> None:
    path = tmp_path / "run"
    with BagWriter(path, "mcap") as bag:
        bag.marker("scene")
        bag.recording("cup", scenes[0][0])
        bag.marker("scene")
        bag.marker("look ball")
        broken_at = bag.time
        points = scenes[1][0].look.points.copy()
        points[7] = np.nan
        bag.cloud(points)
    message = _error_after_posting(tmp_path, world, service, path, MAPPING, posted=1)
    seconds = (broken_at - START) / 1e9
    assert f"/object/points: message at t = {seconds:.3f} s (stamp {broken_at} ns)" in message
    assert "1 NaN or infinite points of 120, though is_dense is true" in message


def test_an_organised_cloud_drops_its_nan_points(tmp_path: Path, scenes: list[list[ObjectRecording]]) -> None:
    path = tmp_path / "run"
    recording = scenes[0][0]
    with BagWriter(path, "sqlite3") as bag:
        bag.marker("look cup")
        points = recording.look.points.copy()
        points[:5] = np.nan
        bag.cloud(points, dense=False)
        for interaction in recording.interactions[:1]:
            bag.marker(f"begin cup {interaction.behaviour}")
            bag.cloud(interaction.before.points)
            bag.cloud(interaction.after.points)
            bag.marker("end cup grasp")
    with BagReplay(path, parse_mapping(MAPPING)) as replayed:
        (scene,) = replayed.scenes()
    back = decoded_recording(scene.recordings[0])
    np.testing.assert_array_equal(back.look.points, recording.look.points[5:].astype(np.float32))
    assert back.interactions[0].finger is None  # no finger messages in that window


@pytest.mark.parametrize("kind", KINDS)
def test_a_truncated_bag_posts_its_whole_scenes_once_and_refuses_the_cut_one(
    tmp_path: Path, kind: str, world: World, scenes: list[list[ObjectRecording]], service: TestClient
) -> None:
    """A recorder killed mid-write: the bag is cut at several offsets (rosbags cannot open any of them).
    The scenes before the cut are posted, each once across restarts; the scene the cut falls in is
    refused naming the last message read (a real message of the bag); the repaired bag posts the rest."""
    bag = write_bag(tmp_path, kind, scenes)
    data_file = bag if kind == "ros1" else next(bag.glob("*.mcap" if kind == "mcap" else "*.db3"))
    content = data_file.read_bytes()
    with AnyReader([bag], default_typestore=audio_typestore()) as reader:
        recorded = {(connection.topic, time) for connection, time, _ in reader.messages()}
    with BagReplay(bag, parse_mapping(MAPPING)) as whole:
        scene_starts = [plan.window.start for plan in whole.plans()]
    model_id = _fitted_model(service, world)
    answers = []
    for fraction, posted in ((0.3, 0), (0.7, 1), (0.7, 1)):  # the second 0.7: a restart
        data_file.write_bytes(content[: int(len(content) * fraction)])
        with _bridge(service) as client, pytest.raises(InvalidRecordingError) as caught:
            replay_bag(client, model_id, bag, parse_mapping(MAPPING), on_answer=lambda _, a: answers.append(a))
        assert _scene_count(service, model_id) == posted, fraction
        found = re.fullmatch(
            rf"{re.escape(str(bag))} (\S+): message at t = [0-9.]+ s \(stamp (\d+) ns\) is the last one read: "
            rf"the file ends [^;]+; scene {posted} \(from t = [0-9.]+ s \(stamp (\d+) ns\)\) is cut "
            r"and not posted",
            str(caught.value),
        )
        assert found is not None, str(caught.value)
        topic, stamp, scene_start = found[1], int(found[2]), int(found[3])
        assert (topic, stamp) in recorded and scene_start == scene_starts[posted] <= stamp
    # Repaired (or, for MCAP, cut inside its footer: every message is read): the same keys, so only the
    # cut scene is learned now.
    data_file.write_bytes(content[:-10] if kind == "mcap" else content)
    with _bridge(service) as client:
        replayed = replay_bag(client, model_id, bag, parse_mapping(MAPPING))
    assert _scene_count(service, model_id) == 2
    assert [answer.scene_id for answer in answers] == [0, 0] and replayed[0] == answers[0]


def test_a_truncated_bag_cut_by_a_schedule_keeps_the_objects_before_its_cut(
    tmp_path: Path, scenes: list[list[ObjectRecording]]
) -> None:
    """With fixed windows the cut object is never planned: the whole ones are read, then the cut is reported."""
    path, recording = tmp_path / "run", scenes[0][0]
    with BagWriter(path, "mcap") as bag:
        for number in range(4):  # objects of 6 ms: a look cloud, then a before and an after cloud
            for offset, cloud in (
                (0, recording.look),
                (3, recording.interactions[0].before),
                (5, recording.interactions[0].after),
            ):
                bag.time = START + (6 * number + offset) * STEP
                bag.cloud(cloud.points)
    schedule = {"windows": {"behaviours": [recording.interactions[0].behaviour], "look": 0.003, "interaction": 0.003}}
    mapping = parse_mapping({"clouds": MAPPING["clouds"], "segmentation": schedule})
    with BagReplay(path, mapping) as whole:
        stops = [plan.window.stop for plan in whole.plans()]
    data_file = next(path.glob("*.mcap"))
    data_file.write_bytes(data_file.read_bytes()[: data_file.stat().st_size * 6 // 10])
    read = []
    with BagReplay(path, mapping) as cut, pytest.raises(InvalidRecordingError) as caught:
        read.extend(scene.plan.window.stop for scene in cut.scenes())
    found = re.search(
        r"message at t = [0-9.]+ s \(stamp (\d+) ns\) is the last one read: the file ends inside", str(caught.value)
    )
    assert found is not None and str(caught.value).endswith("the recording after it is cut and not posted")
    assert read and read == [stop for stop in stops if stop < int(found[1])] and len(read) < len(stops)


def test_a_bag_cut_before_its_first_message_is_refused_naming_the_file(
    tmp_path: Path, scenes: list[list[ObjectRecording]]
) -> None:
    bag = write_bag(tmp_path, "mcap", scenes[:1])
    data_file = next(bag.glob("*.mcap"))
    data_file.write_bytes(data_file.read_bytes()[:30])
    with pytest.raises(InvalidRecordingError) as caught, BagReplay(bag, parse_mapping(MAPPING)):
        pass
    assert str(caught.value).startswith(f"{bag}: cannot be opened as a ROS bag: ")
    assert "read from its start: the file ends inside a record (at byte 8)" in str(caught.value)


def test_missing_messages_in_a_window_are_named_with_the_window(
    tmp_path: Path, scenes: list[list[ObjectRecording]]
) -> None:
    path = tmp_path / "run"
    with BagWriter(path, "mcap") as bag:
        bag.marker("look cup")
        bag.cloud(scenes[0][0].look.points)
        begun = bag.time
        bag.marker("begin cup grasp")
        bag.cloud(scenes[0][0].look.points)
        bag.finger(0.5, 0.2)
        bag.marker("end")
    with BagReplay(path, parse_mapping(MAPPING)) as replayed, pytest.raises(InvalidRecordingError) as caught:
        list(replayed.scenes())
    message = str(caught.value)
    assert "/object/points: no message in the 'grasp' window of object 'cup' after its before cloud" in message
    assert f"(t = {(begun - START) / 1e9:.3f} s" in message


def test_marker_grammar() -> None:
    markers = [(10, "scene"), (11, "look cup"), (12, "begin cup grasp"), (15, "end cup grasp"), (16, "look ball")]
    markers += [(17, "begin ball shake"), (19, "END"), (20, "scene"), (21, "look box"), (22, "begin box drop")]
    markers += [(25, "end")]
    plans = plan_from_markers(markers, 0, 30, "/markers")
    assert [[obj.name for obj in plan.objects] for plan in plans] == [["cup", "ball"], ["box"]]
    assert [(plan.window.start, plan.window.stop) for plan in plans] == [(10, 19), (20, 30)]
    cup = plans[0].objects[0]
    assert (cup.look.start, cup.look.stop) == (11, 12)
    assert [(i.behaviour, i.window.start, i.window.stop) for i in cup.interactions] == [("grasp", 12, 15)]
    bad = {
        "begin cup grasp": "object 'cup' has no look marker before it in this scene",
        "wave": "not a marker",
        "end": "no interaction is open",
    }
    for text, problem in bad.items():
        with pytest.raises(InvalidRecordingError, match=problem):
            plan_from_markers([(5, text)], 0, 30, "/markers")
    with pytest.raises(InvalidRecordingError, match=r"'end ball grasp' at t = 0.000 s \(stamp 3 ns\).*'cup' 'grasp'"):
        plan_from_markers([(1, "look cup"), (2, "begin cup grasp"), (3, "end ball grasp")], 3, 30, "/markers")
    with pytest.raises(InvalidRecordingError, match="ends before its end marker"):
        plan_from_markers([(1, "look cup"), (2, "begin cup grasp")], 0, 30, "/markers")


def test_fixed_windows_keep_complete_objects() -> None:
    windows = parse_mapping({**MAPPING, "segmentation": {"windows": {
        "behaviours": ["grasp", "shake"], "look": 1.0, "interaction": 2.0, "objects_per_scene": 2,
    }}}).windows  # fmt: skip
    plans = plan_from_windows(windows, 0, 16 * 10**9)  # room for three 5 s objects, not four
    assert [[obj.name for obj in plan.objects] for plan in plans] == [["object_0", "object_1"], ["object_2"]]
    second = plans[0].objects[1]
    assert (second.look.start, second.interactions[1].window.start) == (5 * 10**9, 8 * 10**9)


def test_message_decoders() -> None:
    store = audio_typestore()
    types = store.types
    pcm = np.array([0, 16384, -32768, 32767], dtype="<i2")
    audio = types["audio_common_msgs/msg/AudioData"](data=np.frombuffer(pcm.tobytes(), dtype=np.uint8))
    stereo = AudioStream("/audio", 16000, channels=2)

    def fail(what: str) -> Exception:
        return InvalidRecordingError("msg", what)

    np.testing.assert_allclose(audio_samples(audio, stereo, fail), [0.25, -0.5 + 0.5 * 32767 / 32768])
    joints = types["sensor_msgs/msg/JointState"](
        header=types["std_msgs/msg/Header"](stamp=types["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id=""),
        name=["a", "b"], position=np.array([0.0, 90.0]), velocity=np.zeros(2), effort=np.zeros(2),
    )  # fmt: skip
    assert joint_angle(joints, Proprioception("/j", "b", unit="deg"), fail) == pytest.approx(np.pi / 2)
    with pytest.raises(InvalidRecordingError, match=r"no joint 'c' \(joints: \['a', 'b'\]\)"):
        joint_angle(joints, Proprioception("/j", "c"), fail)
    vector = types["geometry_msgs/msg/Vector3"]
    wrench = types["geometry_msgs/msg/WrenchStamped"](
        header=joints.header,
        wrench=types["geometry_msgs/msg/Wrench"](force=vector(x=3.0, y=0.0, z=4.0), torque=vector(x=0.0, y=0.0, z=1.0)),
    )
    assert haptic_value(wrench, Haptics("/w"), fail) == 5.0
    assert haptic_value(wrench, Haptics("/w", component="force.z"), fail) == 4.0


def test_mapping_errors_name_the_key(tmp_path: Path) -> None:
    cases = {
        "mapping.segmentation": {"clouds": {"topic": "/c"}},
        "mapping.haptics": {**MAPPING, "haptics": None},
        "mapping.haptics.reduce": {**MAPPING, "haptics": {"topic": "/f", "reduce": "median"}},
        "mapping.audio.sample_rate": {**MAPPING, "audio": {"topic": "/audio"}},
        "mapping.clouds": {**MAPPING, "clouds": {"look": "/c"}},
    }
    for field, table in cases.items():
        table = {key: value for key, value in table.items() if value is not None}
        with pytest.raises(InvalidRecordingError) as caught:
            parse_mapping(table)
        assert caught.value.field == field


def test_the_service_never_imports_rosbags_and_a_missing_install_says_what_to_do(tmp_path: Path) -> None:
    code = (
        "import sys\nimport app.main, bridge, bridge.tools.replay, bridge.tools.bags\n"
        "assert 'rosbags' not in sys.modules, 'rosbags imported'\n"
        "sys.modules['rosbags'] = None\n"
        "from pathlib import Path\n"
        "try:\n    bridge.tools.bags.BagReplay(Path(sys.argv[1]), None)\n"
        "except ImportError as error:\n    print(error)\n"
    )
    bag = tmp_path / "run.bag"
    bag.write_bytes(b"")
    result = subprocess.run(
        [sys.executable, "-c", code, str(bag)], check=False, capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stderr
    assert "pip install './bridge[bags]'" in result.stdout and "'contextweb[bags]'" in result.stdout


def test_replay_cli_detects_bags_and_reports_errors_without_a_traceback(
    tmp_path: Path, scenes: list[list[ObjectRecording]], capsys: pytest.CaptureFixture[str]
) -> None:
    bag = write_bag(tmp_path, "ros1", scenes[:1])
    folder = replay.write_object(tmp_path / "cup", scenes[0][0])
    rosbag2 = write_bag(tmp_path / "two", "sqlite3", scenes[:1])
    assert [replay.recording_format(p) for p in (bag, folder, rosbag2, next(rosbag2.glob("*.db3")))] == [
        "bag", "folder", "bag", "bag",
    ]  # fmt: skip
    command = ["bridge", "replay", str(bag), "--model-id", "m", "--url", "http://127.0.0.1:9"]
    assert main(command) == 2
    assert "--mapping: is needed to replay a bag or a yarp session" in capsys.readouterr().err
    mapping = tmp_path / "mapping.toml"
    mapping.write_text(
        '[clouds]\ntopic = "/object/points"\n[segmentation]\nmarkers = "/robot/markers"\n', encoding="utf-8"
    )
    assert main([*command, "--mapping", str(mapping)]) == 2
    assert f"{bag} /robot/markers: topic missing from the bag (mapping segmentation.markers)" in capsys.readouterr().err


def test_a_scene_body_depends_only_on_the_seed_and_its_key(tmp_path: Path, scenes: list[list[ObjectRecording]]) -> None:
    """Clouds subsampled (50 of 120 points) the same whether or not earlier scenes were posted first."""
    bodies: dict[str, list[bytes]] = {}

    def service(request: httpx.Request) -> httpx.Response:
        bodies.setdefault(request.headers["Idempotency-Key"], []).append(request.read())
        answer = {"model_id": "m", "scene_id": 0, "learned": True, "context_count": 1}
        answer |= {"previous_context_count": 1, "context_posterior": [1.0], "map_context": 0}
        return httpx.Response(201, json=answer)

    bag = write_bag(tmp_path, "mcap", scenes)
    with (
        Client("http://service", transport=httpx.MockTransport(service)) as client,
        BagReplay(bag, parse_mapping(MAPPING)) as replayed,
    ):
        plans = replayed.plans()
        post_scenes(client, "m", replayed.scenes(plans, seed=1, max_points=50))
        post_scenes(client, "m", replayed.scenes(plans[1:], seed=1, max_points=50))
        second = bodies[next(replayed.scenes(plans[1:])).key]
    assert len(second) == 2 and second[0] == second[1]
    assert len(bodies) == 2
