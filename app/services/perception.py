"""The service's side of the scene pipeline (``core.scene``): requests in, answers out.

A scene's objects arrive as concepts, features or raw payloads (app.schemas);
here they are checked against the model (known behaviours, fitted prototypes),
turned into core's objects (raw payloads into ``core.payloads``, their problems
reported at their place in the request) and sent through ``core.scene``:
perception, concept webs, active concepts (:func:`analyse_objects`), then Eq. 6
in context (:func:`in_context`). The answers' named probabilities are built here,
rounded once to ``ANSWER_DECIMALS`` places (:func:`reported`; docs/api.md, "Precision of
answers"): the core's arrays, and every decision taken from them, keep full precision.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import TypeVar

import numpy as np

from app.errors import InvalidInput, ModelNotFitted
from app.schemas.observations import InteractionIn, ObjectFeatures, RawObject, as_array
from app.schemas.scenes import ANSWER_DECIMALS, ObjectLevel, SceneObject
from core.context.incremental import IncrementalLDA
from core.errors import InvalidInputError
from core.features.extract import recording_features
from core.payloads import Audio, FingerSeries, Interaction, ObjectRecording, PointCloud
from core.scene import (
    SETTLED_WEBS_CACHED,
    MeasuredObject,
    NamedObject,
    PerceivedScene,
    Perception,
    SettledWebs,
    perceive_scene,
    scene_in_context,
)
from core.scene import SceneObject as CoreObject
from core.vocabulary import Vocabulary

__all__ = [
    "SETTLED_WEBS_CACHED",
    "ObjectResult",
    "Perception",
    "SceneAnalysis",
    "SettledWebs",
    "analyse_objects",
    "check_behaviours",
    "feature_vectors",
    "in_context",
    "perceive_objects",
    "raw_feature_vectors",
    "reported",
    "scene_objects",
]

PayloadT = TypeVar("PayloadT")


@dataclass(frozen=True)
class ObjectResult:
    """One object's answer: probabilities per stage, by concept name, and its active concepts (LDA words)."""

    level: ObjectLevel
    active_concepts: list[str]
    perception: dict[str, float]
    web: dict[str, float] | None
    in_context: dict[str, float] | None = None


@dataclass(frozen=True)
class SceneAnalysis:
    """A scene's objects as answered, and the core scene they were read from (``in_context`` goes on from it)."""

    objects: list[ObjectResult]
    scene: PerceivedScene = field(repr=False)

    @property
    def words(self) -> list[str]:
        return self.scene.words


def analyse_objects(perception: Perception, objects: Sequence[SceneObject], model_id: str) -> SceneAnalysis:
    """Perception, concept web and active concepts of every object of a scene (``core.scene.perceive_scene``).
    Every object is checked (and a raw one's features extracted) before any is perceived."""
    return perceive_objects(perception, scene_objects(perception, objects, model_id))


def scene_objects(perception: Perception, objects: Sequence[SceneObject], model_id: str) -> list[CoreObject]:
    """Every object of a scene checked against ``perception`` and made core's: a raw one's features
    extracted (Table III; the GIL-free kernels of ``core.features``, the heavy part of a raw scene)."""
    return [_core_object(perception, obj, f"objects[{i}]", model_id) for i, obj in enumerate(objects)]


def perceive_objects(perception: Perception, objects: Sequence[CoreObject]) -> SceneAnalysis:
    """Perception, concept web and active concepts of the objects of :func:`scene_objects`."""
    return _answered(perception.vocabulary, perceive_scene(perception, objects))


def in_context(
    perception: Perception, incremental_lda: IncrementalLDA, analysis: SceneAnalysis, *, sigma: float, seed: int
) -> SceneAnalysis:
    """The analysis with each object's P*(c) of Eq. 6 (unchanged when no web is fitted).

    Reads the context model: call it holding the model's lock.
    """
    if perception.concept_web is None:
        return analysis
    scene = scene_in_context(
        perception,
        incremental_lda,
        analysis.scene,
        sigma=sigma,
        seed=seed,
        warm_map=True,  # agreement with the cold path measured in docs/feedback.md
    )
    concepts = perception.vocabulary.concepts
    objects = [
        replace(result, in_context=None if obj.in_context is None else _named(concepts, obj.in_context))
        for result, obj in zip(analysis.objects, scene.objects, strict=True)
    ]
    return SceneAnalysis(objects, scene)


def _answered(vocabulary: Vocabulary, scene: PerceivedScene) -> SceneAnalysis:
    """The objects' answers before context: perception (with the names outside the vocabulary) and web by name."""
    concepts = vocabulary.concepts
    objects = [
        ObjectResult(
            level=obj.level,
            active_concepts=list(obj.active_concepts),
            perception=_named(concepts, obj.evidence.probabilities) | _unseen(obj.evidence.unseen),
            web=None if obj.web is None else _named(concepts, obj.web.probabilities),
        )
        for obj in scene.objects
    ]
    return SceneAnalysis(objects, scene)


_SCALE = 10.0**ANSWER_DECIMALS


def reported(probabilities: np.ndarray | Sequence[float]) -> list[float]:
    """Probabilities as an answer reports them: rounded to ``ANSWER_DECIMALS`` places, as
    ``np.round`` rounds (the scaled value to the nearest integer, halves to even), without its
    per-call cost (an answer rounds ~15 short vectors); each prints with at most that many decimals."""
    scaled = np.multiply(probabilities, _SCALE, dtype=np.float64)
    return np.divide(np.rint(scaled, out=scaled), _SCALE, out=scaled).tolist()


def _named(concepts: Sequence[str], values: np.ndarray) -> dict[str, float]:
    """Probabilities by concept name, as reported (:func:`reported`)."""
    return dict(zip(concepts, reported(values), strict=True))


def _unseen(unseen: Mapping[str, float]) -> dict[str, float]:
    """The given probabilities of names outside the vocabulary, as reported (:func:`reported`)."""
    return dict(zip(unseen, reported(list(unseen.values())), strict=True)) if unseen else {}


def _core_object(perception: Perception, obj: SceneObject, field: str, model_id: str) -> CoreObject:
    """A concept-level object's names, or a measured object's checked vectors."""
    if obj.concepts is not None:
        return NamedObject.of(obj.concepts)
    features, raw = obj.features, obj.raw
    level: ObjectLevel
    if features is not None:
        level, behaviours = "features", list(features.effects)
    else:
        assert raw is not None
        level, behaviours = "raw", [interaction.behaviour for interaction in raw.interactions]
    check_behaviours(perception.vocabulary, behaviours, f"{field}.{level}")
    if perception.prototypes is None:
        raise ModelNotFitted(model_id, "prototypes (needed for objects at the features or raw level)")
    if features is not None:
        entity, effects = feature_vectors(features)
    else:
        assert raw is not None
        entity, effects = raw_feature_vectors(raw, f"{field}.raw")
    return MeasuredObject(entity, effects, level)


def check_behaviours(vocabulary: Vocabulary, behaviours: Iterable[str], field: str) -> None:
    """Every behaviour must be one of the vocabulary's verbs (the field names the first one that is not)."""
    for position, behaviour in enumerate(behaviours):
        if behaviour not in vocabulary.verbs:
            where = (
                f"{field}.effects.{behaviour}"
                if field.endswith("features")
                else f"{field}.interactions[{position}].behaviour"
            )
            raise InvalidInput(
                where, f"unknown behaviour {behaviour!r}; the model's behaviours are {list(vocabulary.verbs)}"
            )


def feature_vectors(features: ObjectFeatures) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The entity vector and the effect vector of each behaviour, as arrays."""
    effects = {behaviour: np.asarray(values, dtype=np.float64) for behaviour, values in features.effects.items()}
    return np.asarray(features.entity, dtype=np.float64), effects


def raw_feature_vectors(raw: RawObject, field: str) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Table III features extracted from the raw payloads (``core.features.extract``)."""
    recording = raw_recording(raw, field)
    try:
        return recording_features(recording)
    except InvalidInputError as error:
        raise InvalidInput(f"{field}.{error.field.removeprefix('recording.')}", error.problem) from None


def raw_recording(raw: RawObject, field: str) -> ObjectRecording:
    """A raw object decoded into the core payloads (validated there); a problem is reported at its place in the
    request (``field``)."""
    return ObjectRecording(
        look=_payload(PointCloud, f"{field}.look", raw.look.array()),
        interactions=tuple(
            _interaction(interaction, f"{field}.interactions[{i}]") for i, interaction in enumerate(raw.interactions)
        ),
    )


def _interaction(interaction: InteractionIn, field: str) -> Interaction:
    audio, finger = interaction.audio, interaction.finger
    return Interaction(
        behaviour=interaction.behaviour,
        before=_payload(PointCloud, f"{field}.before", interaction.before.array()),
        after=_payload(PointCloud, f"{field}.after", interaction.after.array()),
        audio=None if audio is None else _payload(Audio, f"{field}.audio", as_array(audio.samples), audio.sample_rate),
        finger=None
        if finger is None
        else _payload(FingerSeries, f"{field}.finger", as_array(finger.haptic), as_array(finger.proprioceptive)),
    )


def _payload(kind: Callable[..., PayloadT], field: str, *values: object) -> PayloadT:
    """``kind(*values)``; core's field (e.g. ``point_cloud.points``) becomes ``<field>.points``."""
    try:
        return kind(*values)
    except InvalidInputError as error:
        raise InvalidInput(f"{field}.{error.field.split('.', 1)[-1]}", error.problem) from None
