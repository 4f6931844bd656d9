"""Post interactions recorded on disk, as scenes or training objects (``contextweb bridge replay``).

One object is one folder (docs/bridge.md has the full layout)::

    cup_03/
        object.json            optional labels {"noun": "cup", "adjectives": [...]} (needed for training)
        look.ply               first snapshot: PLY or PCD, metres, table frame
        grasp/                 one folder per behaviour applied
            before.pcd
            after.pcd
            finger.csv         optional: columns haptic, proprioceptive (or finger.npy, shape (n, 2))
        shake/
            before.ply
            after.ply
            audio.wav          optional: any sample rate, mixed down to mono

A scene is a folder of object folders (or one object folder alone). ROS bags
(:mod:`bridge.tools.bags`) and yarpdatadumper sessions (:mod:`bridge.tools.yarp`) are
replayed too, with a mapping file (``--mapping``, :mod:`bridge.tools.mapping`). Files are
read with maintained readers: ``plyfile`` for PLY, ``pypcd4`` for PCD (ASCII,
binary and binary_compressed), ``soundfile`` for WAV, ``numpy`` for CSV/NPY;
each array is checked and encoded by :mod:`bridge.tools.payloads` (the one encoder of raw
objects), so a bad file fails with an error naming the file and the problem before anything is sent.
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import soundfile
from plyfile import PlyData, PlyElement, PlyParseError
from pypcd4 import PointCloud as PcdCloud

from bridge.client import DEFAULT_BASE_URL, Client, QueuedScene
from bridge.errors import InvalidRecordingError
from bridge.models import Audio, Finger, Interaction, RawObject, SceneObject, TrainingObject
from bridge.tools import payloads
from bridge.tools.payloads import DEFAULT_MAX_POINTS, RecordingLike

if TYPE_CHECKING:
    from bridge.models import SceneRead
    from bridge.tools.segments import SegmentedScene

CLOUD_SUFFIXES = (".ply", ".pcd")
FORMATS = ("auto", "folder", "bag", "yarp")
LABELS_FILE = "object.json"


@dataclass(frozen=True)
class RecordedObject:
    """One object folder read back: its raw payload (clouds subsampled) and, when present, its labels."""

    path: Path
    raw: RawObject
    noun: str | None = None
    adjectives: tuple[str, ...] = ()


def read_point_cloud(path: Path, scale: float = 1.0) -> np.ndarray:
    """x, y, z of a PLY (``vertex`` element) or PCD file as (n, 3) float64, times ``scale`` (0.001 for millimetres).

    Points with NaN are dropped (PCD marks missing depth so); a file with no finite point is an error.
    """
    suffix = path.suffix.lower()
    if suffix not in CLOUD_SUFFIXES:
        raise InvalidRecordingError(str(path), f"is not a point cloud file ({', '.join(CLOUD_SUFFIXES)})")
    try:
        if suffix == ".ply":
            vertex = PlyData.read(str(path))["vertex"]
            points = np.column_stack([np.asarray(vertex[axis], dtype=np.float64) for axis in ("x", "y", "z")])
        else:
            points = PcdCloud.from_path(path).numpy(("x", "y", "z")).astype(np.float64)
    except (KeyError, ValueError, OSError, PlyParseError) as error:
        raise InvalidRecordingError(str(path), f"cannot be read as a point cloud: {error}") from None
    points = points[np.all(np.isfinite(points), axis=1)] * scale
    if len(points) == 0:
        raise InvalidRecordingError(str(path), "holds no finite point")
    return points


def read_audio(path: Path) -> tuple[np.ndarray, int]:
    """A WAV (or any libsndfile format) as mono float PCM in [-1, 1], and its sample rate."""
    try:
        samples, sample_rate = soundfile.read(str(path), dtype="float32", always_2d=True)
    except (RuntimeError, soundfile.LibsndfileError) as error:
        raise InvalidRecordingError(str(path), f"cannot be read as audio: {error}") from None
    return samples.mean(axis=1), int(sample_rate)


def read_finger(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Haptic and proprioceptive series: a CSV with those two named columns, or an (n, 2) NPY."""
    if path.suffix.lower() == ".npy":
        table = np.load(path, allow_pickle=False)
        if table.ndim != 2 or table.shape[1] != 2:
            raise InvalidRecordingError(
                str(path), f"must be an (n, 2) array of haptic, proprioceptive; got {table.shape}"
            )
        return table[:, 0], table[:, 1]
    table = np.genfromtxt(path, delimiter=",", names=True, dtype=np.float64)
    names = table.dtype.names or ()
    if not {"haptic", "proprioceptive"} <= set(names):
        raise InvalidRecordingError(str(path), f"needs the columns haptic and proprioceptive, has {list(names)}")
    return np.atleast_1d(table["haptic"]), np.atleast_1d(table["proprioceptive"])


def read_object(
    folder: Path,
    scale: float = 1.0,
    *,
    rng: np.random.Generator | None = None,
    max_points: int = DEFAULT_MAX_POINTS,
    behaviours: Sequence[str] | None = None,
) -> RecordedObject:
    """An object folder (layout in the module docstring) as a raw payload with its labels.

    ``behaviours`` picks the interaction folders, in that order (a yarp session's markers); None:
    every one, sorted by name. Clouds are subsampled with ``rng`` (seed 0 when None) in the order
    look, then each interaction's before and after.
    """
    rng = np.random.default_rng(0) if rng is None else rng
    if behaviours is None:
        folders = sorted(child for child in folder.iterdir() if child.is_dir())
    else:
        folders = [folder / name for name in behaviours]
        missing = [path.name for path in folders if not path.is_dir()]
        if missing:
            raise InvalidRecordingError(str(folder), f"has no folder {missing[0]!r} for the markers")
    look_path = _cloud(folder, "look")
    look = payloads.cloud(read_point_cloud(look_path, scale), rng, max_points, str(look_path))
    interactions = [_read_interaction(behaviour, scale, rng, max_points) for behaviour in folders]
    raw = RawObject(look=look, interactions=interactions)
    labels_path = folder / LABELS_FILE
    if not labels_path.exists():
        return RecordedObject(folder, raw)
    labels = json.loads(labels_path.read_text(encoding="utf-8"))
    return RecordedObject(folder, raw, labels.get("noun"), tuple(labels.get("adjectives", ())))


def _read_interaction(behaviour: Path, scale: float, rng: np.random.Generator, max_points: int) -> Interaction:
    clouds = {stem: _cloud(behaviour, stem) for stem in ("before", "after")}
    audio_path = _first(behaviour, ("audio.wav", "audio.flac"))
    finger_path = _first(behaviour, ("finger.csv", "finger.npy"))
    audio: Audio | None = None
    finger: Finger | None = None
    if audio_path is not None:
        audio = payloads.audio(*read_audio(audio_path), field=str(audio_path))
    if finger_path is not None:
        finger = payloads.finger(*read_finger(finger_path), field=str(finger_path))
    before, after = (
        payloads.cloud(read_point_cloud(path, scale), rng, max_points, str(path)) for path in clouds.values()
    )
    return Interaction(behaviour=behaviour.name, before=before, after=after, audio=audio, finger=finger)


def read_scene(
    folder: Path,
    scale: float = 1.0,
    *,
    rng: np.random.Generator | None = None,
    max_points: int = DEFAULT_MAX_POINTS,
) -> list[RecordedObject]:
    """A scene folder (its subfolders are objects) or a single object folder."""
    rng = np.random.default_rng(0) if rng is None else rng
    if _has_cloud(folder, "look"):
        return [read_object(folder, scale, rng=rng, max_points=max_points)]
    objects = [
        read_object(child, scale, rng=rng, max_points=max_points)
        for child in sorted(folder.iterdir())
        if child.is_dir()
    ]
    if not objects:
        raise InvalidRecordingError(str(folder), "holds neither a look.ply/look.pcd nor object folders")
    return objects


def write_object(
    folder: Path,
    recording: RecordingLike,
    *,
    noun: str | None = None,
    adjectives: Sequence[str] = (),
    cloud_format: str = "ply",
    finger_format: str = "csv",
) -> Path:
    """Write a recording (the simulator's ``core.payloads.ObjectRecording``) in the replay layout: the
    inverse of :func:`read_object`, for tests and for turning simulated runs into files."""
    folder.mkdir(parents=True, exist_ok=True)
    _write_cloud(folder / f"look.{cloud_format}", recording.look.points)
    for interaction in recording.interactions:
        behaviour = folder / interaction.behaviour
        behaviour.mkdir(exist_ok=True)
        _write_cloud(behaviour / f"before.{cloud_format}", interaction.before.points)
        _write_cloud(behaviour / f"after.{cloud_format}", interaction.after.points)
        if interaction.audio is not None:
            soundfile.write(
                str(behaviour / "audio.wav"), interaction.audio.samples, interaction.audio.sample_rate, subtype="FLOAT"
            )
        if interaction.finger is not None:
            table = np.column_stack([interaction.finger.haptic, interaction.finger.proprioceptive])
            if finger_format == "npy":
                np.save(behaviour / "finger.npy", table)
            else:
                np.savetxt(behaviour / "finger.csv", table, delimiter=",", header="haptic,proprioceptive", comments="")
    if noun is not None:
        labels = {"noun": noun, "adjectives": list(adjectives)}
        (folder / LABELS_FILE).write_text(json.dumps(labels, indent=2) + "\n", encoding="utf-8")
    return folder


def _write_cloud(path: Path, points: np.ndarray) -> None:
    if path.suffix == ".pcd":
        PcdCloud.from_xyz_points(points.astype(np.float32)).save(path)
        return
    vertex = np.empty(len(points), dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    vertex["x"], vertex["y"], vertex["z"] = points.T
    PlyData([PlyElement.describe(vertex, "vertex")], byte_order="<").write(str(path))


def _has_cloud(folder: Path, stem: str) -> bool:
    return any((folder / f"{stem}{suffix}").exists() for suffix in CLOUD_SUFFIXES)


def _cloud(folder: Path, stem: str) -> Path:
    found = _first(folder, tuple(f"{stem}{suffix}" for suffix in CLOUD_SUFFIXES))
    if found is None:
        raise InvalidRecordingError(str(folder), f"has no {stem}.ply or {stem}.pcd")
    return found


def _first(folder: Path, names: Sequence[str]) -> Path | None:
    return next((folder / name for name in names if (folder / name).exists()), None)


def add_service_arguments(parser: argparse.ArgumentParser) -> None:
    """``--url``, ``--api-key``, ``--queue``: where a tool sends, as a robot's :class:`Client` would."""
    parser.add_argument("--url", help=f"the service (default: $CONTEXTWEB_URL, else {DEFAULT_BASE_URL})")
    parser.add_argument("--api-key", help="the write key (default: $CONTEXTWEB_API_KEY)")
    parser.add_argument("--queue", help="offline queue file (scenes wait there while the service is away)")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "paths",
        nargs="+",
        type=Path,
        help="scene folders (or object folders; labelled ones with --training), ROS bags, yarpdatadumper sessions",
    )
    parser.add_argument(
        "--format",
        choices=FORMATS,
        default="auto",
        help="auto: a .bag/.mcap/.db3 file or a folder with metadata.yaml is a bag, a folder of data.log+info.log "
        "dumps is a yarp session, anything else a folder of recordings",
    )
    parser.add_argument("--mapping", type=Path, help="the TOML mapping file of a bag or yarp session (docs/bridge.md)")
    add_service_arguments(parser)
    parser.add_argument("--model-id", required=True, help="the model to post to")
    parser.add_argument("--training", action="store_true", help="post labelled objects as training objects, then fit")
    parser.add_argument(
        "--scale", type=float, default=1.0, help="multiply point coordinates (0.001: files in millimetres)"
    )
    parser.add_argument("--max-points", type=int, default=DEFAULT_MAX_POINTS, help="points kept per cloud")
    parser.add_argument("--seed", type=int, default=0, help="seed of the cloud subsampling")


def run(args: argparse.Namespace) -> int:
    formats = {path: recording_format(path) if args.format == "auto" else args.format for path in args.paths}
    if any(kind != "folder" for kind in formats.values()):
        return _run_recordings(args, formats)
    rng = np.random.default_rng(args.seed)
    with Client(args.url, args.api_key, offline_queue=args.queue) as client:
        if args.training:
            fit = replay_training(
                client, args.model_id, args.paths, rng=rng, scale=args.scale, max_points=args.max_points
            )
            print(
                f"model {args.model_id}: {fit.training_object_count} training objects, {fit.concept_web_edges} web edges"
            )
            return 0
        for path in args.paths:
            answer = replay_scene(client, args.model_id, path, rng=rng, scale=args.scale, max_points=args.max_points)
            print(f"{path}: {_describe(answer)}")
    return 0


def recording_format(path: Path) -> str:
    """``bag``, ``yarp`` or ``folder``: what ``--format auto`` takes a path for."""
    from bridge.tools.bags import is_bag
    from bridge.tools.yarp import is_yarp_session

    if is_bag(path):
        return "bag"
    return "yarp" if is_yarp_session(path) else "folder"


def _run_recordings(args: argparse.Namespace, formats: dict[Path, str]) -> int:
    """Replay bags and yarp sessions (mixed with folders, if given). Imported here: ``bridge.tools.yarp`` reads
    object folders with this module, and only a bag replay needs ``rosbags``."""
    from bridge.tools.bags import replay_bag
    from bridge.tools.mapping import read_mapping
    from bridge.tools.yarp import replay_yarp

    if args.training:
        print("contextweb bridge replay: --training takes object folders only", file=sys.stderr)
        return 2
    replayers = {"bag": replay_bag, "yarp": replay_yarp}
    try:
        if args.mapping is None:
            raise InvalidRecordingError("--mapping", "is needed to replay a bag or a yarp session")
        mapping = read_mapping(args.mapping)
        with Client(args.url, args.api_key, offline_queue=args.queue) as client:
            for path, kind in formats.items():
                if kind == "folder":
                    answer = replay_scene(
                        client, args.model_id, path, rng=np.random.default_rng(args.seed), scale=args.scale,
                        max_points=args.max_points,
                    )  # fmt: skip
                    print(f"{path}: {_describe(answer)}")
                    continue
                replayers[kind](
                    client, args.model_id, path, mapping, seed=args.seed, max_points=args.max_points,
                    on_answer=functools.partial(_print_scene_answer, path),
                )  # fmt: skip
    except (InvalidRecordingError, ImportError) as error:
        print(f"contextweb bridge replay: {error}", file=sys.stderr)
        return 2
    return 0


def replay_scene(
    client: Client,
    model_id: str,
    folder: Path,
    *,
    rng: np.random.Generator,
    scale: float = 1.0,
    max_points: int = DEFAULT_MAX_POINTS,
) -> Any:
    """Post one recorded scene at the raw level; the service's analysis (or a QueuedScene)."""
    objects = [SceneObject(raw=obj.raw) for obj in read_scene(folder, scale, rng=rng, max_points=max_points)]
    return client.scenes.create(model_id, objects)


def replay_training(
    client: Client,
    model_id: str,
    folders: Sequence[Path],
    *,
    rng: np.random.Generator,
    scale: float = 1.0,
    max_points: int = DEFAULT_MAX_POINTS,
) -> Any:
    """Post labelled object folders as training objects (one request each: raw objects are large), then fit."""
    for folder in folders:
        obj = read_object(folder, scale, rng=rng, max_points=max_points)
        if obj.noun is None:
            raise InvalidRecordingError(
                str(folder / LABELS_FILE), "is missing: a training object needs its noun and adjectives"
            )
        labelled = TrainingObject(noun=obj.noun, adjectives=list(obj.adjectives), raw=obj.raw)
        client.training.add_objects(model_id, [labelled])
    return client.training.fit(model_id)


def _print_scene_answer(path: Path, scene: SegmentedScene, answer: SceneRead | QueuedScene) -> None:
    print(f"{path} scene {scene.plan.index} ({len(scene.recordings)} objects): {_describe(answer)}")


def _describe(answer: Any) -> str:
    if isinstance(answer, QueuedScene):
        return f"queued offline ({answer.queued} waiting)"
    posterior = " ".join(f"{p:.2f}" for p in answer.context_posterior)
    return f"scene {answer.scene_id}, K = {answer.context_count}, posterior [{posterior}]"
