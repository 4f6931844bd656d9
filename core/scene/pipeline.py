"""One scene from its objects to their active concepts and P*(c) in context (Fig. 6(b)).

The pipeline the service and the experiments share:

1. **Perception** P(c) over the vocabulary's concepts (``core.scene.evidence``):
   a named object's names, or a measured object's features (Table III; raw
   payloads are turned into features by :meth:`MeasuredObject.from_recording`)
   through the prototypes (Eq. 1), one ``perceive_many`` call for the scene.
2. **Concept web** (loopy BP, Eqs. 2–4) when one is fitted. Without a web the
   perception is read directly (``core.concept_web.active.perception_map``).
3. **Active concepts** (the object's words in the scene's LDA document, Table V):
   the MAP concepts that carry evidence (``core.concept_web.active``). Names
   outside the vocabulary (concept level) skip the web and are active when their
   probability is ≥ 0.5.
4. **In context** (Eq. 6, :func:`scene_in_context`): the context fed back into the
   webs by ``core.context.feedback.contextual_feedback``. An Incremental-LDA model
   learns the document of step 3 (:attr:`PerceivedScene.words`), not the in-context
   one: it learns from what was perceived, so that its own expectations are never
   fed back as observations.

The experiments' document of one recorded object (the paper's protocol, Table V):

>>> from core.concept_web import ConceptWeb
>>> from core.features import recording_features
>>> from core.prototypes import fit_prototypes
>>> from sim.world import World
>>> world = World.paper(seed=7)
>>> train = world.train_objects[::3]  # a third of them: every concept still has examples
>>> features = [recording_features(world.record(obj, 7)) for obj in train]
>>> prototypes = fit_prototypes(
...     world.vocabulary,
...     np.array([entity for entity, _ in features]),
...     [list(obj.concepts) for obj in train],
...     np.array([effect for _, effects in features for effect in effects.values()]),
...     [verb for _, effects in features for verb in effects],
...     seed=7,
... )
>>> web = ConceptWeb.fit(world.vocabulary, [[*obj.concepts, *obj.behaviours] for obj in train])
>>> perception = Perception(world.vocabulary, prototypes, web)
>>> cup = next(obj for obj in world.test_objects if obj.noun == "cup")
>>> words = perceived_concepts(perception, world.record(cup, 7))
>>> words[0] in world.vocabulary.nouns and set(words) <= set(world.vocabulary.concepts)
True
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from core.concept_web import ConceptWeb, WebInference
from core.concept_web.active import ACTIVE_PROBABILITY, active_concepts, perception_map
from core.context.feedback import contextual_feedback
from core.context.incremental import IncrementalLDA
from core.errors import InvalidInputError
from core.features.extract import recording_features
from core.payloads import ObjectRecording
from core.prototypes.perception import perceive_many
from core.prototypes.prototypes import PrototypeSet
from core.scene.evidence import ObjectEvidence, ObjectLevel, measured_evidence, named_evidence
from core.vocabulary import Vocabulary


class SettledWebs:
    """The concept webs of named objects, by their evidence: a bounded LRU memo.

    Settling a web is a pure function of its evidence (the perception and which
    verbs were applied: loopy BP from uniform messages is deterministic), and the
    evidence of an object named at the concept level is a function of its names,
    which a robot's scenes repeat: a hit returns the very inference a cold run
    would. Measured perceptions are continuous and not memoised.
    Entries keep their max-product messages (Eq. 6's first MAP pass starts from them),
    ≈ 16 KB each on the paper's web, so ``SETTLED_WEBS_CACHED`` bounds the memory
    per model (≈ 8 MB). Thread-safe: a service analyses scenes without the model's lock.
    """

    def __init__(self, capacity: int) -> None:
        self._capacity = capacity
        self._entries: OrderedDict[bytes, WebInference] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key: bytes) -> WebInference | None:
        with self._lock:
            found = self._entries.get(key)
            if found is not None:
                self._entries.move_to_end(key)
            return found

    def put(self, key: bytes, inference: WebInference) -> None:
        with self._lock:
            self._entries[key] = inference
            self._entries.move_to_end(key)
            while len(self._entries) > self._capacity:
                self._entries.popitem(last=False)


#: Distinct named objects whose settled webs a :class:`Perception` keeps (see :class:`SettledWebs`).
SETTLED_WEBS_CACHED = 512


@dataclass(frozen=True)
class Perception:
    """What a model has fitted to perceive objects (§III): its vocabulary, the prototypes of Eq. 1
    and the concept web. Replaced whole by a fit, never mutated (but for its memo of settled
    named webs, which belongs to its ``concept_web``)."""

    vocabulary: Vocabulary
    prototypes: PrototypeSet | None = None
    concept_web: ConceptWeb | None = None
    settled_webs: SettledWebs = field(
        default_factory=lambda: SettledWebs(SETTLED_WEBS_CACHED), compare=False, repr=False
    )


@dataclass(frozen=True)
class NamedObject:
    """An object given at the concept level: (name, probability) pairs, 1.0 for a name listed."""

    concepts: tuple[tuple[str, float], ...]

    @classmethod
    def of(cls, concepts: Sequence[str] | Mapping[str, float]) -> NamedObject:
        """From a list of names (each certain) or a name → probability map."""
        if isinstance(concepts, Mapping):
            return cls(tuple(concepts.items()))
        return cls(tuple((name, 1.0) for name in concepts))


@dataclass(frozen=True)
class MeasuredObject:
    """An object the robot measured: Table III's entity vector and the effect vector of each
    behaviour applied (``core.features``), given as features or extracted from raw payloads."""

    entity: np.ndarray
    effects: Mapping[str, np.ndarray]
    level: ObjectLevel = "features"

    @classmethod
    def from_recording(cls, recording: ObjectRecording) -> MeasuredObject:
        """Step 0 of the pipeline: the features of a recording's payloads (``core.features.recording_features``)."""
        entity, effects = recording_features(recording)
        return cls(entity, effects, "raw")


SceneObject = NamedObject | MeasuredObject


@dataclass(frozen=True)
class PerceivedObject:
    """One object after the pipeline: its evidence (perception P(c) over the vocabulary), its
    settled concept web (None without a fitted web), its active concepts (Table V) and, after
    :func:`scene_in_context`, P*(c) of Eq. 6 (``in_context``)."""

    evidence: ObjectEvidence
    web: WebInference | None
    active_concepts: tuple[str, ...]
    in_context: np.ndarray | None = None

    @property
    def level(self) -> ObjectLevel:
        return self.evidence.level


@dataclass(frozen=True)
class PerceivedScene:
    """The objects of a scene after perception and their concept webs (and in context, once
    :func:`scene_in_context` has run)."""

    objects: tuple[PerceivedObject, ...]
    perceptions: np.ndarray = field(repr=False)
    """(n_objects, n_concepts) perception over the vocabulary, the webs' evidence."""
    applied: np.ndarray = field(repr=False)
    """(n_objects, n_verbs) behaviours applied to each object."""
    settled_by: ConceptWeb | None = field(default=None, repr=False)
    """The web that settled the objects' webs (a fit may replace a service model's web before
    :func:`scene_in_context`)."""

    @property
    def words(self) -> list[str]:
        """The scene's LDA document (Table V): every object's active concepts, object by object."""
        return [word for obj in self.objects for word in obj.active_concepts]


def perceive_scene(perception: Perception, objects: Sequence[SceneObject]) -> PerceivedScene:
    """Steps 1–3: perception, concept web and active concepts of every object of a scene.

    Measured objects need fitted ``perception.prototypes``; an object whose
    perception is not finite (features too far from every prototype) is refused,
    its field ``objects[i].<level>``.
    """
    evidence = _scene_evidence(perception, objects)
    perceptions = np.stack([item.probabilities for item in evidence])
    applied = np.stack([item.applied for item in evidence])
    web = perception.concept_web
    settled: Sequence[WebInference | None] = (
        [None] * len(evidence) if web is None else _settle(perception, web, evidence, perceptions, applied)
    )
    vocabulary = perception.vocabulary
    perceived = tuple(
        PerceivedObject(item, inference, _active_names(vocabulary, item, inference))
        for item, inference in zip(evidence, settled, strict=True)
    )
    return PerceivedScene(perceived, perceptions, applied, web)


def perceived_concepts(perception: Perception, recorded: ObjectRecording | MeasuredObject) -> tuple[str, ...]:
    """The LDA words of one recorded object: the active concepts of its perceived concept web
    (Table V), exactly what :func:`perceive_scene` gives the object in a scene."""
    measured = recorded if isinstance(recorded, MeasuredObject) else MeasuredObject.from_recording(recorded)
    return perceive_scene(perception, [measured]).objects[0].active_concepts


def scene_in_context(
    perception: Perception,
    incremental_lda: IncrementalLDA,
    scene: PerceivedScene,
    *,
    sigma: float,
    seed: int,
    warm_map: bool = False,
) -> PerceivedScene:
    """Step 4: each object's P*(c) of Eq. 6 against the context model (the scene unchanged when no
    web is fitted). ``warm_map`` is ``contextual_feedback``'s speed option (docs/feedback.md).
    Reads ``incremental_lda``: a service calls it holding the model's lock."""
    web = perception.concept_web
    if web is None:
        return scene
    settled = [obj.web for obj in scene.objects] if scene.settled_by is web else None
    feedback = contextual_feedback(
        web,
        incremental_lda,
        scene.perceptions,
        perception.vocabulary,
        applied=scene.applied,
        sigma=sigma,
        seed=seed,
        perceived=settled,  # type: ignore[arg-type]  # every object has its web when settled_by is set
        marginals=False,  # P* (Eq. 6) is the answer, not the in-context webs' marginals
        warm_map=warm_map,
    )
    objects = tuple(replace(obj, in_context=row) for obj, row in zip(scene.objects, feedback.in_context, strict=True))
    return replace(scene, objects=objects)


def _active_names(vocabulary: Vocabulary, evidence: ObjectEvidence, inference: WebInference | None) -> tuple[str, ...]:
    """Table V's rule (``core.concept_web.active``) as names, then the unseen names at ≥ 0.5."""
    configuration = (
        perception_map(vocabulary, evidence.probabilities) if inference is None else inference.map_configuration
    )
    concepts = vocabulary.concepts
    active = [concepts[i] for i in np.flatnonzero(active_concepts(configuration, evidence.informed))]
    return (*active, *(name for name, p in evidence.unseen.items() if p >= ACTIVE_PROBABILITY))


def _settle(
    perception: Perception,
    web: ConceptWeb,
    evidence: Sequence[ObjectEvidence],
    perceptions: np.ndarray,
    applied: np.ndarray,
) -> list[WebInference]:
    """Every object's web settled on its perception: memoised ones for named objects, the others
    in one ``infer_many`` call."""
    keys = [
        item.probabilities.tobytes() + item.applied.tobytes() if item.level == "concepts" else None for item in evidence
    ]
    found = [None if key is None else perception.settled_webs.get(key) for key in keys]
    missing = [i for i, inference in enumerate(found) if inference is None]
    if missing:
        fresh = web.infer_many(perceptions[missing], applied=applied[missing])
        for i, inference in zip(missing, fresh, strict=True):
            found[i] = inference
            key = keys[i]
            if key is not None:
                perception.settled_webs.put(key, _frozen(inference))
    return found  # type: ignore[return-value]


def _frozen(inference: WebInference) -> WebInference:
    """A read-only copy that holds only its own object's arrays (not the whole batch's), with the
    max-product messages Eq. 6's warm MAP passes start from (the sum-product ones are not
    needed: :func:`scene_in_context` skips that pass)."""

    def own(array: np.ndarray | None) -> np.ndarray | None:
        if array is None:
            return None
        copy = array.copy()
        copy.flags.writeable = False
        return copy

    return WebInference(
        own(inference.probabilities),  # type: ignore[arg-type]
        own(inference.map_configuration),  # type: ignore[arg-type]
        inference.iterations,
        inference.converged,
        None,
        own(inference.max_messages),
    )


def _scene_evidence(perception: Perception, objects: Sequence[SceneObject]) -> list[ObjectEvidence]:
    """Every object's evidence: named ones from their names, the measured ones from the prototypes
    in one ``perceive_many`` call for the scene (Eq. 1 batched)."""
    vocabulary = perception.vocabulary
    measured = {i: obj for i, obj in enumerate(objects) if isinstance(obj, MeasuredObject)}
    perceived: dict[int, ObjectEvidence] = {}
    if measured:
        if perception.prototypes is None:
            raise InvalidInputError("perception.prototypes", "not fitted: needed for measured objects")
        with np.errstate(over="ignore", invalid="ignore"):  # extreme inputs are refused below
            rows = perceive_many(
                perception.prototypes,
                [obj.entity for obj in measured.values()],
                [obj.effects for obj in measured.values()],
            )
        for (i, obj), row in zip(measured.items(), rows, strict=True):
            if not np.isfinite(row).all():
                raise InvalidInputError(
                    f"objects[{i}].{obj.level}", "values too far from every prototype: the perception is not finite"
                )
            perceived[i] = measured_evidence(vocabulary, obj.level, row, obj.effects)
    return [
        perceived[i] if isinstance(obj, MeasuredObject) else named_evidence(vocabulary, obj.concepts)
        for i, obj in enumerate(objects)
    ]
