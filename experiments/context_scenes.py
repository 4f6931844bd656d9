"""What the context experiments share (Figs. 9, 12, 13, 14): features, a context model, test scenes.

- **Features** of an object are extracted once per process
  (:func:`object_features`): recording and extracting the 60 objects is the
  slowest step of every experiment, and several experiments (and their tests)
  use the same objects.
- **The context model** (:func:`train_context_model`) is Incremental-LDA learned
  in batch from pure-context scenes of the *training* objects (§V: a context
  drawn uniformly, 3–5 of its objects), each object adding the active concepts
  of its perceived web (the paper's protocol, ``experiments.documents``; with
  ``--documents labels`` its labelled noun, adjectives and applicable verbs,
  ``Scene.tokens``): the robot learns contexts from scenes of objects it was
  taught, and the test objects stay unseen. K is found by the model (its
  default birth-move rule).
- **Test scenes** (:func:`pure_context_scenes`): the test objects grouped by the
  context of their noun, shuffled, and cut into scenes of at most 5 objects of
  balanced sizes (7 objects give 4 + 3). Every test object is in exactly one
  scene, so each is evaluated once per draw; its companions are other *test*
  objects, perceived like it, so no label helps the context. A context with
  fewer than 3 test objects (``--quick``) gives a smaller scene.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from core.concept_web import ConceptWeb
from core.context import IncrementalLDA
from core.context.feedback import PAPER_POOLING, PAPER_SIGMA, contextual_feedback
from core.features import recording_features
from core.vocabulary import Vocabulary
from sim.world import World, WorldObject

#: Pure-context training scenes the context model learns from (the paper's experiments use up to 50).
TRAINING_SCENES = 50
MAX_OBJECTS_PER_SCENE = 5

Features = tuple[np.ndarray, dict[str, np.ndarray]]
_FEATURES: dict[tuple[str, str, int, int, str], Features] = {}
#: A folder where features are also kept on disk, one ``.npz`` per object (None: in memory only).
#: The report sets it so that its processes share one extraction per (world, seed); a file holds
#: the very float64 arrays extracted, so a cached run is bit for bit an uncached one.
FEATURE_CACHE: Path | None = None


def object_features(world: World, objects: Sequence[WorldObject], seed: int) -> dict[str, Features]:
    """Entity vector e and effect vectors f of each object's recording from ``seed``, by object id.

    Memoised per (world name, difficulty, world seed, recording seed, object): a recording
    depends on nothing else (``World.recordings`` gives every object its own stream).
    """
    prefix = (world.config.name, world.config.difficulty.name, world.seed, int(seed))
    for obj in objects:
        if (*prefix, obj.object_id) not in _FEATURES and (found := _cached(prefix, obj.object_id)) is not None:
            _FEATURES[(*prefix, obj.object_id)] = found
    missing = [obj for obj in objects if (*prefix, obj.object_id) not in _FEATURES]
    for object_id, recording in world.recordings(missing, seed=seed).items() if missing else ():
        _FEATURES[(*prefix, object_id)] = recording_features(recording)
        _store(prefix, object_id, _FEATURES[(*prefix, object_id)])
    return {obj.object_id: _FEATURES[(*prefix, obj.object_id)] for obj in objects}


def _cache_file(prefix: tuple[str, str, int, int], object_id: str) -> Path | None:
    if FEATURE_CACHE is None:
        return None
    name, difficulty, world_seed, seed = prefix
    return FEATURE_CACHE / f"{name}-{difficulty}-world{world_seed}-seed{seed}" / f"{object_id}.npz"


def _cached(prefix: tuple[str, str, int, int], object_id: str) -> Features | None:
    path = _cache_file(prefix, object_id)
    if path is None or not path.is_file():
        return None
    with np.load(path) as data:
        effects = {key.removeprefix("effect_"): data[key] for key in data.files if key.startswith("effect_")}
        return data["entity"], effects


def _store(prefix: tuple[str, str, int, int], object_id: str, features: Features) -> None:
    """Write atomically (a temporary file renamed): processes may extract the same object at once."""
    path = _cache_file(prefix, object_id)
    if path is None:
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    entity, effects = features
    partial = path.with_suffix(f".{os.getpid()}.tmp.npz")
    arrays: dict[str, Any] = {"entity": entity} | {f"effect_{verb}": effect for verb, effect in effects.items()}
    np.savez(partial, **arrays)
    partial.replace(path)


def train_context_model(
    world: World,
    train: Sequence[WorldObject],
    rng: np.random.Generator,
    n_scenes: int = TRAINING_SCENES,
    words: Mapping[str, Sequence[str]] | None = None,
) -> IncrementalLDA:
    """Incremental-LDA fitted on ``n_scenes`` pure-context scenes of the training objects, each object
    giving its ``words`` (the active concepts of its perceived web, ``experiments.documents``), or
    with ``words=None`` its labels (``Scene.tokens``)."""
    scenes = world.scenes(n_scenes, seed=rng, objects=train)
    documents = (
        [scene.tokens(with_verbs=True) for scene in scenes]
        if words is None
        else [[word for obj in scene.objects for word in words[obj.object_id]] for scene in scenes]
    )
    return IncrementalLDA(seed=int(rng.integers(2**31))).fit(documents)


def context_of(world: World, obj: WorldObject) -> str:
    """The context an object's noun occurs in (the first, for a noun of several contexts)."""
    return world.config.contexts_of(obj.noun)[0]


def pure_context_scenes(world: World, objects: Sequence[WorldObject], rng: np.random.Generator) -> list[np.ndarray]:
    """Indices into ``objects`` of each scene: every object once, with others of its context."""
    contexts = [context_of(world, obj) for obj in objects]
    scenes = []
    for name in dict.fromkeys(contexts):
        members = rng.permutation([i for i, context in enumerate(contexts) if context == name])
        scenes += np.array_split(members, -(-len(members) // MAX_OBJECTS_PER_SCENE))
    return scenes


def in_context_probabilities(
    web: ConceptWeb,
    context_model: IncrementalLDA,
    vocabulary: Vocabulary,
    perception: np.ndarray,
    applied: np.ndarray,
    scenes: Sequence[np.ndarray],
    *,
    sigma: float = PAPER_SIGMA,
    seed: int = 0,
    pooling: str = PAPER_POOLING,
) -> tuple[np.ndarray, np.ndarray]:
    """P*(c) of Eq. 6 and the in-context webs' P(c) of every object, each (n_objects, n_concepts),
    every object interpreted in its scene (``core.context.feedback``)."""
    eq_6, settled = np.empty_like(perception), np.empty_like(perception)
    for members in scenes:
        feedback = contextual_feedback(
            web,
            context_model,
            perception[members],
            vocabulary,
            applied=applied[members],
            sigma=sigma,
            seed=seed,
            pooling=pooling,
        )
        eq_6[members], settled[members] = feedback.in_context, feedback.in_context_web
    return eq_6, settled
