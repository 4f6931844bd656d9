"""The LDA documents of the experiments (Table V): what each object of a scene contributes.

The paper's protocol (the default, ``--documents perceived``): an object's words are the active
concepts of its *perceived* concept web. The object is recorded by the simulator's sensors
(``World.recordings`` at the experiment's seed), its features extracted, perceived by the prototypes
of Eq. 1 fitted on the training objects' features, its web (fitted on the training objects'
configurations) settled, and Table V's rule picks its active concepts
(``core.scene.perceive_scene``, the service's pipeline). Verbs are among them: an applied
behaviour is evidence and the web activates its verb when the MAP keeps it.

The ablation (``--documents labels``): the object's true noun, adjectives and applicable verbs
(``Scene.tokens``), the documents every experiment used before issue 15.

Choices the paper leaves open, written down:

- **One recording per object.** Training objects are perceived from the same recording their
  features were fitted on (the robot has one recording of each object); test objects are unseen
  by the prototypes and the web. The world's scenes draw from every object, as §V's do.
- **The world is fixed per experiment seed** (``World.paper(seed, world)``), and test sets draw
  their scenes from its objects with their own seeds: perceiving the 60 objects of a new world
  per test set would cost a minute each.
- **Quick runs** (``--quick``) perceive recognition's quick objects only, and scenes draw from them
  (label documents cost nothing: they keep every object).

Perceived documents are memoised per (world, seed, quick) in the process; the features behind
them are also cached on disk when ``context_scenes.FEATURE_CACHE`` is set (the report sets it), so
every experiment of a report run shares one extraction per (world, seed).
"""

from __future__ import annotations

import argparse
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from core.concept_web import ConceptWeb
from core.prototypes import fit_prototypes
from core.scene import MeasuredObject, Perception, perceive_scene
from experiments import context_scenes
from sim.world import DEFAULT_WORLD, WORLDS, Scene, World, WorldObject, generate_scenes, scene_from_nouns

PERCEIVED = "perceived"
LABELS = "labels"
SOURCES: tuple[str, ...] = (PERCEIVED, LABELS)
DEFAULT_SOURCE = PERCEIVED


def add_world_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--world", choices=WORLDS, default=DEFAULT_WORLD, help="difficulty of the paper world (docs/world.md)"
    )


def add_documents_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--documents",
        choices=SOURCES,
        default=DEFAULT_SOURCE,
        help="LDA documents: active concepts of perceived webs (the paper's) or the objects' true labels",
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``--world`` and ``--documents``, the protocol options of every LDA experiment."""
    add_world_argument(parser)
    add_documents_argument(parser)


@dataclass(frozen=True)
class Documents:
    """A world's objects and the LDA words of each (by object id), from ``source``."""

    world: World
    objects: tuple[WorldObject, ...]
    words: Mapping[str, tuple[str, ...]]
    source: str

    def scene(self, scene: Scene) -> list[str]:
        """The scene's document: its objects' words, object by object."""
        return [word for obj in scene.objects for word in self.words[obj.object_id]]

    def scenes(self, n_scenes: int, seed: Any, **options: Any) -> tuple[Scene, ...]:
        """Pure (or ``mixture``) scenes of this world's objects (``sim.world.generate_scenes``)."""
        return generate_scenes(self.world, n_scenes, seed, objects=self.objects, **options)

    def scene_from_nouns(self, spec: Any, seed: Any) -> Scene:
        return scene_from_nouns(self.world, spec, seed, objects=self.objects)


_MEMO: dict[tuple[str, int, bool], dict[str, tuple[str, ...]]] = {}


def experiment_documents(world_name: str, seed: int, source: str, quick: bool = False) -> Documents:
    """The documents of ``World.paper(seed, world_name)`` from ``source`` (module docstring)."""
    # Imported here: recognition imports context_scenes, which this module's users import first.
    from experiments.recognition import experiment_objects

    world = World.paper(seed=seed, difficulty=world_name)
    if source == LABELS:
        words = {obj.object_id: (*obj.concepts, *obj.behaviours) for obj in world.objects}
        return Documents(world, world.objects, words, source)
    train, test = experiment_objects(world, quick)
    objects = world.objects if not quick else tuple(obj for obj in world.objects if obj in (*train, *test))
    if source != PERCEIVED:
        raise ValueError(f"unknown document source {source!r}; known: {SOURCES}")
    key = (world_name, int(seed), quick)
    if key not in _MEMO:
        features = context_scenes.object_features(world, objects, seed)
        perception = fitted_perception(world, train, features, seed)
        _MEMO[key] = perceived_words(perception, objects, features)
    return Documents(world, objects, _MEMO[key], source)


def fitted_perception(
    world: World, train: Sequence[WorldObject], features: Mapping[str, context_scenes.Features], seed: int
) -> Perception:
    """The prototypes (Eq. 1) fitted on the training objects' features and the concept web on their
    configurations, as Fig. 13's setup fits them (``recognition.make_setup``)."""
    from experiments.recognition import training_data

    prototypes = fit_prototypes(world.vocabulary, *training_data(tuple(train), dict(features)), seed=seed)
    web = ConceptWeb.fit(world.vocabulary, [[*obj.concepts, *obj.behaviours] for obj in train])
    return Perception(world.vocabulary, prototypes, web)


def perceived_words(
    perception: Perception, objects: Sequence[WorldObject], features: Mapping[str, context_scenes.Features]
) -> dict[str, tuple[str, ...]]:
    """Each object's active concepts (Table V) after perception and its settled web, in one scene call
    (``core.scene.perceive_scene``: the same words ``perceived_concepts`` gives one object)."""
    measured = [MeasuredObject(*features[obj.object_id]) for obj in objects]
    scene = perceive_scene(perception, measured)
    return {obj.object_id: item.active_concepts for obj, item in zip(objects, scene.objects, strict=True)}
