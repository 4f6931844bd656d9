"""Replay an iCub session recorded with YARP's ``yarpdatadumper`` (one dump folder per port).

A dump folder holds ``info.log`` (``Type: Bottle;`` then one line per
connection) and ``data.log``, one line per message::

    <counter> <time stamp> [<second stamp>] <bottle values ...>

(yarpdatadumper writes the sender's stamp when the envelope has one, else
the receiver's; with ``--txTime --rxTime`` both, the sender's first: set
``[yarp] timestamps = 2`` and the first is used.) Stamps are seconds; every
port must be stamped by the same clock, as the dumpers of one machine are.

What is read (the mapping file names the dump folders, relative to the
session folder given on the command line):

* ``[segmentation] markers``: a port of marker bottles in the grammar of
  :mod:`bridge.tools.segments` (``look cup``, ``begin cup grasp``, ``end``; quoted
  strings are unquoted with :mod:`shlex`, as Bottle text quotes them);
* ``[proprioception] column``: one joint of a ``state:o`` port, e.g. column 11
  of ``/icub/right_arm/state:o`` (16 values, degrees: 11 is the index finger's
  proximal joint), converted to radians;
* ``[haptics] columns``: taxels of a skin port, e.g. columns 0–11 of
  ``/icub/skin/right_hand_comp`` (the index fingertip), reduced per line;
* ``[clouds] folder``: the clouds (and audio) are not on YARP ports here: they
  are the folder layout of ``bridge.tools.replay``, one object folder per object name
  in the markers. The finger series of an interaction comes from the logs
  (replacing any finger.csv), segmented by the same markers.
"""

from __future__ import annotations

import hashlib
import shlex
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bridge.client import Client, QueuedScene
from bridge.errors import InvalidRecordingError
from bridge.models import Finger, RawObject, SceneRead
from bridge.tools import payloads
from bridge.tools.bags import post_scenes, reduce_values, scene_rng
from bridge.tools.mapping import Mapping, Proprioception
from bridge.tools.payloads import DEFAULT_MAX_POINTS
from bridge.tools.replay import read_object
from bridge.tools.segments import (
    NANOSECONDS,
    InteractionPlan,
    ObjectPlan,
    ScenePlan,
    SegmentedScene,
    applies,
    finger_series,
    format_time,
    plan_from_markers,
    plan_from_windows,
)

DUMP_FILES = ("data.log", "info.log")


@dataclass(frozen=True)
class PortLog:
    """One dump folder read: stamps in nanoseconds and each line's bottle values as text."""

    folder: Path
    times: np.ndarray
    values: list[list[str]]
    line_numbers: list[int]

    def numbers(self, line: int, first: int, count: int | None = None) -> np.ndarray:
        """The line's values from column ``first`` on (``count`` of them, or all) as floats."""
        words = self.values[line][first:] if count is None else self.values[line][first : first + count]
        try:
            return np.array([float(word) for word in words], dtype=np.float64)
        except ValueError as error:
            raise self.problem(line, f"a value is not a number ({error})") from None

    def problem(self, line: int, what: str) -> InvalidRecordingError:
        seconds = self.times[line] / NANOSECONDS
        return InvalidRecordingError(
            f"{self.folder / 'data.log'}", f"line {self.line_numbers[line]} (stamp {seconds:.6f} s): {what}"
        )


def is_yarp_session(path: Path) -> bool:
    """A dump folder, or a folder whose subfolders include dump folders."""
    if not path.is_dir():
        return False
    return _is_dump(path) or any(_is_dump(child) for child in path.iterdir() if child.is_dir())


def _is_dump(folder: Path) -> bool:
    return all((folder / name).is_file() for name in DUMP_FILES)


def read_port_log(folder: Path, timestamps: int = 1) -> PortLog:
    """A yarpdatadumper folder's ``data.log`` (its ``info.log`` must say ``Type: Bottle``)."""
    for name in DUMP_FILES:
        if not (folder / name).is_file():
            raise InvalidRecordingError(str(folder), f"is not a yarpdatadumper folder: it has no {name}")
    info = (folder / "info.log").read_text(encoding="utf-8", errors="replace")
    if "Type: Bottle" not in info:
        raise InvalidRecordingError(str(folder / "info.log"), "does not say 'Type: Bottle': only bottle dumps are read")
    times, values, line_numbers = [], [], []
    lines = (folder / "data.log").read_text(encoding="utf-8", errors="replace").splitlines()
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            words = shlex.split(line)
            stamp = float(words[1])
        except (ValueError, IndexError) as error:
            raise InvalidRecordingError(
                str(folder / "data.log"), f"line {number} is not '<counter> <stamp> <values>': {error}"
            ) from None
        if any("(" in word for word in words[1 + timestamps :]):
            raise InvalidRecordingError(str(folder / "data.log"), f"line {number} holds a nested bottle: not supported")
        times.append(round(stamp * NANOSECONDS))
        values.append(words[1 + timestamps :])
        line_numbers.append(number)
    stamps = np.asarray(times, dtype=np.int64)
    if stamps.size and np.any(np.diff(stamps) < 0):
        back = line_numbers[int(np.argmax(np.diff(stamps) < 0)) + 1]
        raise InvalidRecordingError(str(folder / "data.log"), f"line {back} goes back in time")
    return PortLog(folder, stamps, values, line_numbers)


class YarpSession:
    """A folder of dump folders and its mapping; ``scenes()`` reads and checks one scene at a time."""

    def __init__(self, path: Path, mapping: Mapping) -> None:
        if mapping.markers is None and mapping.windows is None:
            raise InvalidRecordingError("mapping.segmentation", "is missing")
        if len({mapping.clouds.look, mapping.clouds.before, mapping.clouds.after}) != 1:
            raise InvalidRecordingError(
                "mapping.clouds", "of a yarp session is one folder of object folders: give folder"
            )
        if mapping.proprioception is not None and not isinstance(mapping.proprioception.joint, int):
            raise InvalidRecordingError("mapping.proprioception", "a yarp port is read by column, not by joint name")
        self.path = path
        self.mapping = mapping
        self.clouds = path / mapping.clouds.look
        self.logs = {
            role: read_port_log(path / stream, mapping.yarp_timestamps)
            for role, stream in mapping.streams.items()
            if role in ("proprioception", "haptics", "segmentation.markers")
        }
        if not self.logs or all(log.times.size == 0 for log in self.logs.values()):
            raise InvalidRecordingError(str(path), "holds no stamped line in the mapped dump folders")
        stamped = [log.times for log in self.logs.values() if log.times.size]
        self.start = int(min(times[0] for times in stamped))
        self.stop = int(max(times[-1] for times in stamped))

    @property
    def identity(self) -> str:
        """A digest of the logs' content: the same session copied or moved keeps its keys."""
        digest = hashlib.sha256()
        for role in sorted(self.logs):
            digest.update((self.logs[role].folder / "data.log").read_bytes())
        return digest.hexdigest()[:24]

    def plans(self) -> list[ScenePlan]:
        if self.mapping.windows is not None:
            return plan_from_windows(self.mapping.windows, self.start, self.stop)
        log = self.logs["segmentation.markers"]
        markers = [(int(time), " ".join(words)) for time, words in zip(log.times, log.values, strict=True)]
        return plan_from_markers(markers, self.start, self.stop, str(log.folder / "data.log"))

    def scenes(
        self, plans: Sequence[ScenePlan] | None = None, *, seed: int = 0, max_points: int = DEFAULT_MAX_POINTS
    ) -> Iterator[SegmentedScene]:
        """Each scene read whole, checked and encoded (nothing of a bad scene is returned); clouds are
        subsampled as a bag's are (:func:`bridge.tools.bags.scene_rng`)."""
        identity = self.identity
        for plan in self.plans() if plans is None else plans:
            key = f"yarp-{identity}-{plan.window.start}"
            rng = scene_rng(seed, key)
            recordings = [self._recording(obj, rng, max_points) for obj in plan.objects]
            yield SegmentedScene(plan, recordings, key)

    def _recording(self, obj: ObjectPlan, rng: np.random.Generator, max_points: int) -> RawObject:
        folder = self.clouds / obj.name
        if not folder.is_dir():
            raise InvalidRecordingError(str(folder), f"is missing: the markers name object {obj.name!r}")
        behaviours = [plan.behaviour for plan in obj.interactions]
        raw = read_object(folder, self.mapping.clouds.scale, rng=rng, max_points=max_points, behaviours=behaviours).raw
        if self.mapping.proprioception is None:
            return raw
        interactions = [  # the logs' finger series replaces a finger.csv
            interaction.model_copy(update={"finger": self._finger(plan)})
            for interaction, plan in zip(raw.interactions, obj.interactions, strict=True)
        ]
        return raw.model_copy(update={"interactions": interactions})

    def _finger(self, plan: InteractionPlan) -> Finger | None:
        joint, haptics = self.mapping.proprioception, self.mapping.haptics
        if (
            joint is None
            or haptics is None
            or not (applies(joint.behaviours, plan.behaviour) and applies(haptics.behaviours, plan.behaviour))
        ):
            return None
        joints, skin = self.logs["proprioception"], self.logs["haptics"]
        joint_lines = _lines_within(joints, plan.window.start, plan.window.stop)
        skin_lines = _lines_within(skin, plan.window.start, plan.window.stop)
        if joint_lines.size == 0 and skin_lines.size == 0:
            return None
        for log, lines in ((joints, joint_lines), (skin, skin_lines)):
            if lines.size == 0:
                raise InvalidRecordingError(
                    str(log.folder / "data.log"),
                    f"has no line in the {plan.behaviour!r} window from {format_time(plan.window.start, self.start)}"
                    f" to {format_time(plan.window.stop, self.start)}, though the other finger port has",
                )
        angles = [self._angle(joints, int(line), joint) for line in joint_lines]
        pressures = [
            reduce_values(skin.numbers(int(line), 0), haptics, _problem_at(skin, int(line))) for line in skin_lines
        ]
        series = finger_series(joints.times[joint_lines], angles, skin.times[skin_lines], pressures)
        try:
            return payloads.finger(*series)
        except InvalidRecordingError as error:
            raise joints.problem(int(joint_lines[0]), str(error)) from None

    def _angle(self, log: PortLog, line: int, joint: Proprioception) -> float:
        column = int(joint.joint)
        if column >= len(log.values[line]):
            raise log.problem(line, f"has {len(log.values[line])} values, the mapping reads column {column}")
        value = float(log.numbers(line, column, 1)[0])
        return float(np.deg2rad(value)) if joint.unit == "deg" else value


def _lines_within(log: PortLog, start: int, stop: int) -> np.ndarray:
    return np.flatnonzero((log.times >= start) & (log.times <= stop))


def _problem_at(log: PortLog, line: int) -> Callable[[str], Exception]:
    return lambda what: log.problem(line, what)


def replay_yarp(
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
    """Post the session's scenes in order, each with its key (as :func:`bridge.tools.bags.replay_bag`)."""
    session = YarpSession(path, mapping)
    scenes = session.scenes(session.plans()[:limit], seed=seed, max_points=max_points)
    return post_scenes(client, model_id, scenes, on_answer=on_answer)
