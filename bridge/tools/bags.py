"""Replay ROS bags (ROS 1 ``.bag``, rosbag2 with MCAP or sqlite3 storage) as raw scenes.

Bags are read with ``rosbags`` (Apache-2.0, pure Python, no ROS install),
imported only inside these functions: the service never imports it, and the
bridge works without it until a bag is replayed (``pip install './bridge[bags]'``
on a robot, ``'contextweb[bags]'`` with the server). A bag cut short, which
rosbags cannot open, is read up to its cut by :mod:`bridge.tools.truncated`. A
mapping file (:mod:`bridge.tools.mapping`) says which topic carries what;
markers or a fixed schedule (:mod:`bridge.tools.segments`) cut the bag into
scenes, objects and interactions. Within an interaction window:

* before = the first cloud on the before topic, after = the last cloud on the
  after topic (the robot snaps before acting and after it, inside the window);
  look = the last cloud on the look topic in the object's look window;
* audio = every audio message in the window, concatenated in time order;
* finger = one sample per JointState message (the mapped joint), with the
  haptic value linearly interpolated at those instants (``numpy.interp``): a
  tactile sensor and the joint encoders are rarely sampled together.

Times are the bag's log times (every message has one; headers do not). A scene
is read, checked and encoded whole (:mod:`bridge.tools.payloads`) before it is
posted, so a bad message posts nothing of its scene; scenes before it are posted
(each once, thanks to its key).
"""

from __future__ import annotations

import functools
import hashlib
import json
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Self, TypeVar

import numpy as np

from bridge.client import Client, QueuedScene
from bridge.errors import InvalidRecordingError
from bridge.models import Audio, Finger, Interaction, PointCloud, RawObject, SceneObject, SceneRead
from bridge.tools import payloads
from bridge.tools.mapping import AudioStream, Haptics, Mapping, Proprioception
from bridge.tools.payloads import DEFAULT_MAX_POINTS
from bridge.tools.segments import (
    InteractionPlan,
    ObjectPlan,
    ScenePlan,
    SegmentedScene,
    Window,
    applies,
    finger_series,
    format_time,
    plan_from_markers,
    plan_from_windows,
)
from bridge.tools.truncated import Channel, TruncatedBag

if TYPE_CHECKING:
    from rosbags.highlevel import AnyReader
    from rosbags.interfaces import Connection
    from rosbags.typesys.store import Typestore

PayloadT = TypeVar("PayloadT")
INSTALL_HINT = (
    "reading ROS bags needs the rosbags package: pip install 'contextweb-bridge[bags]' on a robot "
    "(pip install './bridge[bags]' from a checkout), or 'contextweb[bags]' with the server"
)
BAG_SUFFIXES = (".bag", ".mcap", ".db3")

#: audio_common's messages (ROS 1 audio_common, ROS 2 audio_common ports): not in rosbags' stores.
AUDIO_MESSAGE_DEFINITIONS = {
    "audio_common_msgs/msg/AudioData": "uint8[] data\n",
    "audio_common_msgs/msg/AudioDataStamped": "std_msgs/Header header\naudio_common_msgs/AudioData audio\n",
}
CLOUD_TYPES = ("sensor_msgs/msg/PointCloud2",)
MARKER_TYPES = ("std_msgs/msg/String",)
AUDIO_TYPES = (*AUDIO_MESSAGE_DEFINITIONS, "std_msgs/msg/Float32MultiArray")
JOINT_TYPES = ("sensor_msgs/msg/JointState",)
HAPTIC_TYPES = ("geometry_msgs/msg/WrenchStamped", "std_msgs/msg/Float32MultiArray", "std_msgs/msg/Float64MultiArray")
#: sensor_msgs/msg/PointField datatypes -> numpy kinds (the ROS constants INT8 = 1 … FLOAT64 = 8).
POINT_FIELD_TYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
SAMPLE_DTYPES = {"S16LE": ("<i2", 2**15), "S32LE": ("<i4", 2**31), "F32LE": ("<f4", 1)}


@dataclass(frozen=True)
class Message:
    """One message of a scene's window, decoded on demand (a 30 Hz camera topic is mostly skipped)."""

    topic: str
    time: int
    connection: Connection | Channel
    raw: bytes


def is_bag(path: Path) -> bool:
    """A ROS 1 bag, a bare rosbag2 storage file, or a rosbag2 folder (it has a metadata.yaml)."""
    return path.suffix.lower() in BAG_SUFFIXES if path.is_file() else (path / "metadata.yaml").exists()


def audio_typestore(base: Typestore | None = None) -> Typestore:
    """A type store that also knows audio_common's messages; the latest ROS 2 store unless ``base`` is given.

    Bags recorded by ROS carry their message definitions and are read with
    those; this store serves bags written without them, and writers (tests).
    """
    try:
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    except ImportError:
        raise ImportError(INSTALL_HINT) from None
    store = base if base is not None else get_typestore(Stores.LATEST)
    types = {}
    for name, definition in AUDIO_MESSAGE_DEFINITIONS.items():
        types.update(get_types_from_msg(definition, name))
    store.register(types)
    return store


class BagReplay:
    """An open bag and its mapping: ``scenes()`` reads and checks one scene at a time."""

    def __init__(self, path: Path, mapping: Mapping) -> None:
        self.path = path
        self.mapping = mapping
        self._opened = _open(path)
        self._reader: AnyReader | TruncatedBag = self._opened
        self._plans: list[ScenePlan] | None = None
        #: Where a truncated bag ends ("the file ends inside a chunk ..."); None for a whole bag.
        self.cut: str | None = None

    def __enter__(self) -> Self:
        try:
            self._opened.open()
        except Exception as error:  # noqa: BLE001 - rosbags, apsw, lz4 and zstd each raise their own errors
            self._reader = self._salvage(error)
        self.start, self.stop = self._reader.start_time, self._reader.end_time
        self._connections = self._check_topics()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self._reader.close()

    def _salvage(self, error: Exception) -> TruncatedBag:
        """A bag rosbags cannot open, read from its start up to its cut (:mod:`bridge.tools.truncated`)."""
        from bridge.tools.truncated import salvage_bag

        refused = InvalidRecordingError(str(self.path), f"cannot be opened as a ROS bag: {_describe(error)}")
        try:
            bag = salvage_bag(self.path, set(self.mapping.streams.values()), _default_typestore)
        except Exception as salvage_error:  # noqa: BLE001 - a file that is no bag at all fails in many ways
            raise InvalidRecordingError(
                refused.field, f"{refused.problem}; read from its start: {salvage_error}"
            ) from None
        if bag.salvage.last is None:
            problem = bag.salvage.problem or "it holds no message"
            raise InvalidRecordingError(refused.field, f"{refused.problem}; read from its start: {problem}") from None
        self.cut = bag.salvage.problem
        return bag

    @property
    def identity(self) -> str:
        """A digest of what every readable copy of the bag begins with: its first message time, its topics
        with their types, and the messages of that first instant.

        The same bag copied, moved, opened as its bare storage file, or cut short (a truncated copy and
        the same bag repaired) keeps its keys; two bags that start at the same instant on the same topics
        (simulated clocks) differ by their first messages.
        """
        topics = sorted({(c.topic, c.msgtype) for c in self._reader.connections})
        every: list[Any] = list(self._reader.connections)
        messages = self._reader.messages(every, self.start, self.start + 1)
        first = sorted((topic.topic, hashlib.sha256(raw).hexdigest()) for topic, _, raw in messages)
        return hashlib.sha256(json.dumps([self.start, topics, first]).encode()).hexdigest()[:24]

    def plans(self) -> list[ScenePlan]:
        """The bag's scenes, from its markers or the mapping's schedule (a truncated bag's up to its cut)."""
        if self._plans is None:
            self._plans = self._segment()
        return self._plans

    def _segment(self) -> list[ScenePlan]:
        if self.mapping.windows is not None:
            return plan_from_windows(self.mapping.windows, self.start, self.stop)
        topic = self.mapping.markers
        if topic is None:
            raise InvalidRecordingError("mapping.segmentation", "needs exactly one of markers (a stream) or windows")
        markers = [(m.time, str(self._decode(m).data)) for m in self._messages([topic], Window(self.start, self.stop))]
        return plan_from_markers(markers, self.start, self.stop, f"{self.path} {topic}", cut=self.cut is not None)

    def scenes(
        self, plans: Sequence[ScenePlan] | None = None, *, seed: int = 0, max_points: int = DEFAULT_MAX_POINTS
    ) -> Iterator[SegmentedScene]:
        """Each scene read whole, checked and encoded (nothing of a bad scene is returned).

        Clouds are subsampled to ``max_points`` by a generator seeded by ``seed`` and the scene's key
        (:func:`scene_rng`), so a scene's body does not depend on the scenes replayed before it.
        """
        identity = self.identity
        topics = sorted({stream for role, stream in self.mapping.streams.items() if role != "segmentation.markers"})
        chosen = self.plans() if plans is None else plans
        for plan in chosen:
            if self.cut is not None and plan.window.stop >= self.stop:  # the scene reaches the last message read
                raise self._cut_error(plan)
            by_topic: dict[str, list[Message]] = {topic: [] for topic in topics}
            for message in self._messages(topics, plan.window, plan):
                by_topic[message.topic].append(message)
            key = f"bag-{identity}-{plan.window.start}"
            rng = scene_rng(seed, key)
            recordings = [self._recording(obj, by_topic, rng, max_points) for obj in plan.objects]
            yield SegmentedScene(plan, recordings, key)
        if self.cut is not None and (not self.plans() or chosen[-1:] == self.plans()[-1:]):
            raise self._cut_error(None)  # a schedule keeps only whole objects: the cut one was never planned

    def _check_topics(self) -> dict[str, list[Connection | Channel]]:
        mapping = self.mapping
        expected = {
            "clouds.look": CLOUD_TYPES,
            "clouds.before": CLOUD_TYPES,
            "clouds.after": CLOUD_TYPES,
            "audio": AUDIO_TYPES,
            "proprioception": JOINT_TYPES,
            "haptics": HAPTIC_TYPES,
            "segmentation.markers": MARKER_TYPES,
        }
        connections: dict[str, list[Connection | Channel]] = {}
        for role, topic in mapping.streams.items():
            found = [c for c in self._reader.connections if c.topic == topic]
            if not found:
                present = ", ".join(sorted({c.topic for c in self._reader.connections}))
                raise InvalidRecordingError(
                    f"{self.path} {topic}", f"topic missing from the bag (mapping {role}); the bag has: {present}"
                )
            wrong = sorted({c.msgtype for c in found} - set(expected[role]))
            if wrong:
                raise InvalidRecordingError(
                    f"{self.path} {topic}",
                    f"carries {', '.join(wrong)}, but mapping {role} needs {' or '.join(expected[role])}",
                )
            connections[topic] = found
        return connections

    def _messages(self, topics: Sequence[str], window: Window, plan: ScenePlan | None = None) -> Iterator[Message]:
        """Messages of ``topics`` in ``window``; a read failure names the last message read well."""
        connections = [c for topic in topics for c in self._connections[topic]]
        last: tuple[str, int] | None = None
        # Each reader is given back the connections it listed (_check_topics): rosbags' or a salvage's.
        messages = self._reader.messages(connections, window.start, window.stop + 1)  # type: ignore[arg-type]
        try:
            for connection, time, raw in messages:
                yield Message(connection.topic, time, connection, raw)
                last = (connection.topic, time)
        except Exception as error:  # noqa: BLE001 - a damaged file fails inside rosbags, apsw, lz4 or zstd
            problem = f"the file ends or is damaged after it ({_describe(error)})"
            if last is None:
                start = format_time(window.start, self.start)
                raise InvalidRecordingError(
                    str(self.path), f"nothing can be read from {start} on: {problem}; {self._lost(plan)}"
                ) from None
            raise self._refusal(*last, problem, plan) from None

    def _cut_error(self, plan: ScenePlan | None) -> InvalidRecordingError:
        """The refusal of the scene a truncated bag's cut falls in, naming the last message read."""
        assert isinstance(self._reader, TruncatedBag) and self._reader.salvage.last is not None
        channel, time = self._reader.salvage.last
        return self._refusal(channel.topic, time, str(self.cut), plan)

    def _refusal(self, topic: str, time: int, problem: str, plan: ScenePlan | None) -> InvalidRecordingError:
        return InvalidRecordingError(
            f"{self.path} {topic}",
            f"message at {format_time(time, self.start)} is the last one read: {problem}; {self._lost(plan)}",
        )

    def _lost(self, plan: ScenePlan | None) -> str:
        if plan is None:
            return "the recording after it is cut and not posted"
        return f"scene {plan.index} (from {format_time(plan.window.start, self.start)}) is cut and not posted"

    def _decode(self, message: Message) -> Any:
        try:
            return self._reader.deserialize(message.raw, message.connection.msgtype)
        except Exception as error:  # noqa: BLE001 - rosbags' deserialisers raise several kinds
            raise self._problem(message, f"cannot be decoded as {message.connection.msgtype}: {_describe(error)}")

    def _problem(self, message: Message, what: str) -> InvalidRecordingError:
        return InvalidRecordingError(
            f"{self.path} {message.topic}", f"message at {format_time(message.time, self.start)}: {what}"
        )

    def _missing(self, topic: str, window: Window, what: str) -> InvalidRecordingError:
        span = f"{format_time(window.start, self.start)} to {format_time(window.stop, self.start)}"
        return InvalidRecordingError(f"{self.path} {topic}", f"no message in {what} ({span})")

    def _recording(
        self, obj: ObjectPlan, by_topic: dict[str, list[Message]], rng: np.random.Generator, max_points: int
    ) -> RawObject:
        clouds = self.mapping.clouds
        looks = _within(by_topic[clouds.look], obj.look)
        if not looks:
            raise self._missing(clouds.look, obj.look, f"the look window of object {obj.name!r}")
        look = self._cloud(looks[-1], rng, max_points)  # drawn first: the order of the subsampling draws
        interactions = [
            self._interaction(obj, interaction, by_topic, rng, max_points) for interaction in obj.interactions
        ]
        return RawObject(look=look, interactions=interactions)

    def _interaction(
        self,
        obj: ObjectPlan,
        plan: InteractionPlan,
        by_topic: dict[str, list[Message]],
        rng: np.random.Generator,
        max_points: int,
    ) -> Interaction:
        clouds = self.mapping.clouds
        what = f"the {plan.behaviour!r} window of object {obj.name!r}"
        befores = _within(by_topic[clouds.before], plan.window)
        afters = _within(by_topic[clouds.after], plan.window)
        if not befores:
            raise self._missing(clouds.before, plan.window, what)
        if not afters or (clouds.before == clouds.after and len(afters) < 2):
            raise self._missing(clouds.after, plan.window, f"{what} after its before cloud")
        return Interaction(
            behaviour=plan.behaviour,
            before=self._cloud(befores[0], rng, max_points),
            after=self._cloud(afters[-1], rng, max_points),
            audio=self._audio(self.mapping.audio, plan, by_topic),
            finger=self._finger(plan, by_topic, what),
        )

    def _cloud(self, message: Message, rng: np.random.Generator, max_points: int) -> PointCloud:
        points = point_cloud_points(self._decode(message), lambda what: self._problem(message, what))
        scaled = points * self.mapping.clouds.scale
        return _payload(lambda: payloads.cloud(scaled, rng, max_points), self._problem, message)

    def _audio(
        self, stream: AudioStream | None, plan: InteractionPlan, by_topic: dict[str, list[Message]]
    ) -> Audio | None:
        if stream is None or not applies(stream.behaviours, plan.behaviour):
            return None
        messages = _within(by_topic[stream.source], plan.window)
        if not messages:
            return None
        chunks = [audio_samples(self._decode(m), stream, functools.partial(self._problem, m)) for m in messages]
        return _payload(lambda: payloads.audio(np.concatenate(chunks), stream.sample_rate), self._problem, messages[0])

    def _finger(self, plan: InteractionPlan, by_topic: dict[str, list[Message]], what: str) -> Finger | None:
        joint, haptics = self.mapping.proprioception, self.mapping.haptics
        if (
            joint is None
            or haptics is None
            or not (applies(joint.behaviours, plan.behaviour) and applies(haptics.behaviours, plan.behaviour))
        ):
            return None
        joints = _within(by_topic[joint.source], plan.window)
        touches = _within(by_topic[haptics.source], plan.window)
        if not joints and not touches:
            return None
        for topic, messages in ((joint.source, joints), (haptics.source, touches)):
            if not messages:
                raise self._missing(topic, plan.window, f"{what}, though its other finger topic has messages")
        angles = [joint_angle(self._decode(m), joint, functools.partial(self._problem, m)) for m in joints]
        pressures = [haptic_value(self._decode(m), haptics, functools.partial(self._problem, m)) for m in touches]
        series = finger_series([m.time for m in joints], angles, [m.time for m in touches], pressures)
        return _payload(lambda: payloads.finger(*series), self._problem, joints[0])


def point_cloud_points(message: Any, problem: Callable[[str], Exception]) -> np.ndarray:
    """x, y, z of a sensor_msgs/msg/PointCloud2 as (n, 3) float64.

    Points with NaN are dropped only when the message says it may hold them
    (``is_dense`` false: an organised cloud marks missing depth so); in a cloud
    that claims to be dense they are an error.
    """
    fields = {field.name: field for field in message.fields}
    missing = [axis for axis in "xyz" if axis not in fields]
    if missing:
        raise problem(f"PointCloud2 has no field {missing} (fields: {sorted(fields)})")
    order = ">" if message.is_bigendian else "<"
    try:
        dtype = np.dtype(
            {
                "names": list("xyz"),
                "formats": [order + POINT_FIELD_TYPES[fields[axis].datatype] for axis in "xyz"],
                "offsets": [fields[axis].offset for axis in "xyz"],
                "itemsize": message.point_step,
            }
        )
        rows = np.asarray(message.data, dtype=np.uint8).reshape(message.height, message.row_step)
        packed = np.ascontiguousarray(rows[:, : message.width * message.point_step])
        table = packed.reshape(-1).view(dtype)
    except (KeyError, ValueError, TypeError) as error:
        raise problem(f"PointCloud2 layout does not match its data ({error})") from None
    points = np.column_stack([table[axis].astype(np.float64) for axis in "xyz"])
    finite = np.all(np.isfinite(points), axis=1)
    if message.is_dense and not finite.all():
        raise problem(
            f"cloud has {int((~finite).sum())} NaN or infinite points of {len(points)}, though is_dense is true"
        )
    if not finite.any():
        raise problem(f"cloud has no finite point (all {len(points)} are NaN or infinite)")
    return points[finite]


def audio_samples(message: Any, stream: AudioStream, problem: Callable[[str], Exception]) -> np.ndarray:
    """Mono samples in [-1, 1] of an AudioData(Stamped) (PCM bytes) or a Float32MultiArray message."""
    if hasattr(message, "audio"):
        message = message.audio
    data = np.asarray(message.data)
    if data.dtype == np.uint8:
        dtype, full_scale = SAMPLE_DTYPES[stream.sample_format]
        frame = np.dtype(dtype).itemsize * stream.channels
        if data.size % frame:
            raise problem(
                f"{data.size} bytes are not whole {stream.sample_format} frames of {stream.channels} channel(s)"
            )
        data = data.view(dtype).astype(np.float64) / full_scale
    if data.size % stream.channels:
        raise problem(f"{data.size} samples are not whole frames of {stream.channels} channels")
    return data.reshape(-1, stream.channels).mean(axis=1)


def joint_angle(message: Any, joint: Proprioception, problem: Callable[[str], Exception]) -> float:
    """The mapped joint's position (radians) in a sensor_msgs/msg/JointState."""
    names = list(message.name)
    if joint.joint not in names:
        raise problem(f"JointState has no joint {joint.joint!r} (joints: {names})")
    position = np.asarray(message.position, dtype=np.float64)
    index = names.index(joint.joint)
    if index >= position.size:
        raise problem(f"JointState lists joint {joint.joint!r} but has only {position.size} positions")
    return float(np.deg2rad(position[index]) if joint.unit == "deg" else position[index])


def haptic_value(message: Any, haptics: Haptics, problem: Callable[[str], Exception]) -> float:
    """One haptic reading: a WrenchStamped component, or the mapped elements of an array reduced."""
    if hasattr(message, "wrench"):
        part, axis = haptics.component.split(".")
        vector = getattr(message.wrench, part)
        values = np.array([vector.x, vector.y, vector.z])
        return float(np.linalg.norm(values) if axis == "norm" else values["xyz".index(axis)])
    return reduce_values(np.asarray(message.data, dtype=np.float64), haptics, problem)


def reduce_values(values: np.ndarray, haptics: Haptics, problem: Callable[[str], Exception]) -> float:
    """The mapped elements (all by default) reduced to one value; shared with yarp's skin ports."""
    if haptics.indices is not None:
        if max(haptics.indices) >= values.size:
            raise problem(f"has {values.size} values, the mapping reads index {max(haptics.indices)}")
        values = values[list(haptics.indices)]
    if values.size == 0:
        raise problem("has no values")
    return float(getattr(np, haptics.reduce)(values))


def replay_bag(
    client: Client,
    model_id: str,
    path: Path,
    mapping: Mapping,
    *,
    seed: int = 0,
    max_points: int = DEFAULT_MAX_POINTS,
    limit: int | None = None,
    on_answer: Callable[[SegmentedScene, SceneRead | QueuedScene], None] | None = None,
) -> list[SceneRead | QueuedScene]:
    """Post the bag's scenes in order (the first ``limit`` only, when given), each with its key."""
    with BagReplay(path, mapping) as bag:
        scenes = bag.scenes(bag.plans()[:limit], seed=seed, max_points=max_points)
        return post_scenes(client, model_id, scenes, on_answer=on_answer)


def post_scenes(
    client: Client,
    model_id: str,
    scenes: Iterable[SegmentedScene],
    *,
    on_answer: Callable[[SegmentedScene, SceneRead | QueuedScene], None] | None = None,
) -> list[SceneRead | QueuedScene]:
    """Post each scene under its key as soon as it is read and checked: a bad scene stops the replay
    before it is sent."""
    answers = []
    for scene in scenes:
        objects = [SceneObject(raw=raw) for raw in scene.recordings]
        answer = client.scenes.create(model_id, objects, idempotency_key=scene.key)
        answers.append(answer)
        if on_answer is not None:
            on_answer(scene, answer)
    return answers


def scene_rng(seed: int, key: str) -> np.random.Generator:
    """The subsampling generator of one scene, seeded by the replay's seed and the scene's key.

    A restarted replay sends the very same body under each key, so the service answers with the
    stored scene instead of refusing a reused key.
    """
    digest = int.from_bytes(hashlib.sha256(key.encode()).digest()[:8], "big")
    return np.random.default_rng([seed, digest])


def _default_typestore(ros1: bool) -> Typestore:
    """The store a salvaged bag starts from: ROS 1 Noetic's or the latest ROS 2 types, with the audio types."""
    from rosbags.typesys import Stores, get_typestore

    return audio_typestore(get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.LATEST))


def _open(path: Path) -> AnyReader:
    try:
        from rosbags.highlevel import AnyReader
    except ImportError:
        raise ImportError(INSTALL_HINT) from None
    if not path.exists():
        raise InvalidRecordingError(str(path), "does not exist")
    return AnyReader([path], default_typestore=audio_typestore())


def _within(messages: Sequence[Message], window: Window) -> list[Message]:
    return [message for message in messages if window.holds(message.time)]


def _payload(build: Callable[[], PayloadT], problem: Callable[[Message, str], Exception], message: Message) -> PayloadT:
    """Check and encode a payload (:mod:`bridge.tools.payloads`); its error is re-raised naming the topic and time."""
    try:
        return build()
    except InvalidRecordingError as error:
        raise problem(message, str(error)) from None


def _describe(error: Exception) -> str:
    return f"{type(error).__name__}: {error}" if str(error) else type(error).__name__
