"""Stream the synthetic iCub world into a running service (``contextweb bridge simulate``).

It plays the robot of §II–§V through the same :class:`bridge.Client` a real
robot uses: it trains a model on the world's 45 training objects (labelled
entity and effect vectors, or raw recordings), fits it, then posts scenes of a
chosen mix of contexts at a chosen rate and input level, showing a progress
bar and a live line with K and the last context posterior.

Input levels of a scene object:

* ``concepts``: the object's noun, adjectives and applicable verbs (the words a
  concept web would activate, ``sim.world.Scene.tokens``);
* ``features``: its Table III vectors, extracted here from a fresh recording;
* ``raw``: the fresh recording itself (point clouds, audio, finger series),
  each cloud subsampled to ``--max-points`` so that a scene of five objects
  (27 clouds each) stays within the service's body limit (docs/bridge.md).

This is a development tool of the server's distribution (it imports ``sim`` and ``core``: the
world, the feature extraction); it encodes raw objects with the robot's own encoder
(:mod:`bridge.tools.payloads`), and the client imports none of it.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from bridge.client import Client, QueuedScene
from bridge.models import (
    FitRead,
    SceneObject,
    SceneRead,
    TrainingObject,
)
from bridge.tools.payloads import DEFAULT_MAX_POINTS, raw_object
from bridge.tools.replay import add_service_arguments
from core.features.extract import recording_features
from core.payloads import ObjectRecording
from sim.world import Scene, World, WorldConfig, WorldObject, generate_scenes

LEVELS = ("concepts", "features", "raw")
#: Largest body per training request; the service's default limit is 8 MiB.
TRAINING_BATCH_BYTES = 4 * 1024 * 1024


@dataclass
class SimulationSummary:
    """What a simulation sent and what the service answered last."""

    model_id: str
    scenes_sent: int = 0
    scenes_queued: int = 0
    context_count: int | None = None
    last_posterior: list[float] = field(default_factory=list)
    map_contexts: list[int] = field(default_factory=list)
    fit: FitRead | None = None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_service_arguments(parser)
    parser.add_argument("--model", default="simulated-icub", help="name of the model to use, created when missing")
    parser.add_argument("--model-id", help="use this existing model instead of --model")
    parser.add_argument(
        "--contexts",
        action="append",
        metavar="NAMES",
        help="comma-separated contexts of one phase of pure scenes; repeat for phases (e.g. kitchen,playroom then "
        "kitchen,playroom,workshop to watch a context appear). Default: all contexts",
    )
    parser.add_argument("--mixture", help="mixed scenes instead: e.g. playroom=0.67,workshop=0.33 (Table VI)")
    parser.add_argument("--scenes", type=int, default=60, help="scenes per phase")
    parser.add_argument("--rate", type=float, default=2.0, help="scenes per second (0: as fast as the service answers)")
    parser.add_argument("--level", choices=LEVELS, default="concepts", help="input level of the scene objects")
    parser.add_argument(
        "--train-level", choices=("features", "raw"), default="features", help="level of the training objects"
    )
    parser.add_argument("--skip-training", action="store_true", help="do not post training objects nor fit")
    parser.add_argument("--max-points", type=int, default=DEFAULT_MAX_POINTS, help="points kept per raw cloud")
    parser.add_argument("--seed", type=int, default=0, help="seed of the world, the scenes and the recordings")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar (logs, CI)")


def run(args: argparse.Namespace) -> int:
    world = World(WorldConfig.paper(), args.seed)
    phases = _phases(world, args)
    with Client(args.url, args.api_key, offline_queue=args.queue) as client:
        model = client.models.get(args.model_id) if args.model_id else client.models.select(args.model, seed=args.seed)
        if model.concept_web_fitted and not args.skip_training:
            print(f"model {model.id} is already fitted: training skipped")
        summary = simulate(
            client,
            model.id,
            world,
            phases,
            level=args.level,
            rate=args.rate,
            seed=args.seed,
            train_level=None if args.skip_training or model.concept_web_fitted else args.train_level,
            max_points=args.max_points,
            progress=not args.no_progress,
        )
    print(
        f"model {summary.model_id}: {summary.scenes_sent} scenes sent ({summary.scenes_queued} queued), "
        f"K = {summary.context_count}, last posterior {_format_posterior(summary.last_posterior)}"
    )
    return 0


def _phases(world: World, args: argparse.Namespace) -> list[tuple[Scene, ...]]:
    if args.mixture:
        mixture = {name.strip(): float(share) for name, share in (part.split("=") for part in args.mixture.split(","))}
        return [generate_scenes(world, args.scenes, args.seed, mixture=mixture)]
    groups = args.contexts or [",".join(context.name for context in world.config.contexts)]
    return [
        generate_scenes(world, args.scenes, args.seed + phase, contexts=[name.strip() for name in group.split(",")])
        for phase, group in enumerate(groups)
    ]


def simulate(
    client: Client,
    model_id: str,
    world: World,
    phases: Sequence[Sequence[Scene]],
    *,
    level: str = "concepts",
    rate: float = 0.0,
    seed: int = 0,
    train_level: str | None = "features",
    max_points: int = DEFAULT_MAX_POINTS,
    progress: bool = True,
) -> SimulationSummary:
    """Train (unless ``train_level`` is None), then post every scene of every phase in order."""
    summary = SimulationSummary(model_id)
    rng = np.random.default_rng(seed)
    if train_level is not None:
        summary.fit = train(
            client, model_id, world, level=train_level, rng=rng, max_points=max_points, progress=progress
        )
    scenes = [scene for phase in phases for scene in phase]
    interval = 1.0 / rate if rate > 0 else 0.0
    bar = tqdm(scenes, desc="scenes", unit="scene", disable=not progress, file=sys.stderr)
    next_at = time.monotonic()
    for scene in bar:
        answer = client.scenes.create(model_id, scene_objects(world, scene, level, rng, max_points))
        summary.scenes_sent += 1
        if isinstance(answer, QueuedScene):
            summary.scenes_queued += 1
            bar.set_postfix_str(f"service away: {answer.queued} scene(s) queued")
        else:
            _record(summary, answer)
            truth = "+".join(sorted(scene.mixture))
            bar.set_postfix_str(
                f"K={answer.context_count} θ={_format_posterior(answer.context_posterior)} true={truth}"
            )
        next_at += interval
        time.sleep(max(0.0, next_at - time.monotonic()))
    return summary


def _record(summary: SimulationSummary, answer: SceneRead) -> None:
    summary.context_count = answer.context_count
    summary.last_posterior = answer.context_posterior
    summary.map_contexts.append(answer.map_context)


def train(
    client: Client,
    model_id: str,
    world: World,
    *,
    level: str,
    rng: np.random.Generator,
    objects: Sequence[WorldObject] | None = None,
    max_points: int = DEFAULT_MAX_POINTS,
    progress: bool = True,
) -> FitRead:
    """Post labelled objects (default: the world's 45 training objects, §II-A) in batches under the
    body limit, then fit."""
    objects = world.train_objects if objects is None else objects
    labelled = (
        training_object(obj, world.record(obj, rng), level, rng, max_points)
        for obj in tqdm(objects, desc="training objects", unit="object", disable=not progress, file=sys.stderr)
    )
    for batch in _batches(labelled, TRAINING_BATCH_BYTES):
        client.training.add_objects(model_id, batch)
    return client.training.fit(model_id)


def _batches(objects: Iterator[TrainingObject], max_bytes: int) -> Iterator[list[TrainingObject]]:
    batch: list[TrainingObject] = []
    size = 0
    for obj in objects:
        obj_size = len(obj.model_dump_json())
        if batch and size + obj_size > max_bytes:
            yield batch
            batch, size = [], 0
        batch.append(obj)
        size += obj_size
    if batch:
        yield batch


def training_object(
    obj: WorldObject, recording: ObjectRecording, level: str, rng: np.random.Generator, max_points: int
) -> TrainingObject:
    """A labelled training object from one recording: its noun and adjectives, features or raw data."""
    if level == "raw":
        return TrainingObject(
            noun=obj.noun, adjectives=list(obj.adjectives), raw=raw_object(recording, rng, max_points)
        )
    entity, effects = recording_features(recording)
    features = _feature_object(entity, effects).features
    return TrainingObject(noun=obj.noun, adjectives=list(obj.adjectives), features=features)


def _feature_object(entity: np.ndarray, effects: dict[str, np.ndarray]) -> SceneObject:
    """A feature-level scene object: the bridge's models take plain lists (a robot's install has no numpy)."""
    return SceneObject.from_features(entity.tolist(), {behaviour: f.tolist() for behaviour, f in effects.items()})


def scene_objects(
    world: World, scene: Scene, level: str, rng: np.random.Generator, max_points: int
) -> list[SceneObject]:
    """The scene's objects at ``level``; features and raw come from a fresh recording of each object."""
    if level == "concepts":
        return [SceneObject.from_concepts([*obj.concepts, *obj.behaviours]) for obj in scene.objects]
    recordings = [world.record(obj, rng) for obj in scene.objects]
    if level == "features":
        return [_feature_object(*recording_features(recording)) for recording in recordings]
    return [SceneObject(raw=raw_object(recording, rng, max_points)) for recording in recordings]


def _format_posterior(posterior: Sequence[float]) -> str:
    return "[" + " ".join(f"{p:.2f}" for p in posterior) + "]"
