"""From the objects of a scene as posted (concepts, features or raw) to their concept webs.

The pipeline of Fig. 6(b):

1. **Perception** P(c) over the vocabulary's concepts. Concept level: a named
   concept is certain (1.0) and so is the absence of its rivals (the other
   nouns, the opposite adjective); a name → probability map is taken as given,
   the nouns or a pair completed so that they sum to 1; concepts not mentioned
   carry no evidence (0.5; a verb not mentioned is a behaviour not applied).
   Feature level: the prototypes (Eq. 1, ``core.prototypes.perceive``). Raw
   level: Table III features extracted from the payloads, then the prototypes.
2. **Concept web** (loopy BP, Eqs. 2–4) when the model has one fitted. Without
   a web, the perception is read directly: the most probable noun, the more
   probable adjective of each pair, the verbs at ≥ 0.5.
3. **Active concepts** (the object's words in the scene's LDA document, Table V):
   the MAP concepts *that carry evidence*: a noun or adjective pair the object
   was perceived or named with, and the verbs whose behaviour was applied. A
   verb the web only predicts from the noun (an affordance) is left out, as in
   ``core.context.feedback``: counting it would repeat the noun's vote once per
   predicted behaviour. Names outside the vocabulary (concept level) skip the
   web and are active when listed, or when their probability is ≥ 0.5.
4. **In context** (Eq. 6, :func:`in_context`): the context fed back into the
   webs by ``core.context.feedback.contextual_feedback``. The model learns the
   document of step 3, not the in-context one: it learns from what was
   perceived, so that its own expectations are never fed back as observations.
"""

from __future__ import annotations

import functools
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TypeVar

import numpy as np

from app.errors import InvalidInput, ModelNotFitted
from app.schemas.observations import InteractionIn, ObjectFeatures, RawObject, as_array
from app.schemas.scenes import ObjectLevel, SceneObject
from core.concept_web import ConceptWeb, WebInference
from core.context.feedback import contextual_feedback
from core.context.incremental import IncrementalLDA
from core.errors import InvalidInputError
from core.features.extract import recording_features
from core.payloads import Audio, FingerSeries, Interaction, ObjectRecording, PointCloud
from core.prototypes.perception import NO_EVIDENCE, perceive_many
from core.prototypes.prototypes import PrototypeSet
from core.vocabulary import Vocabulary

ACTIVE_PROBABILITY = 0.5
PayloadT = TypeVar("PayloadT")


class SettledWebs:
    """The concept webs of concept-level objects, by their evidence: a bounded LRU memo.

    Settling a web is a pure function of its evidence (the perception and which
    verbs were applied: loopy BP from uniform messages is deterministic), and the
    evidence of an object named at the concept level is a function of its names,
    which a robot's scenes repeat: a hit returns the very inference a cold run
    would. Feature- and raw-level perceptions are continuous and not memoised.
    Entries keep their max-product messages (Eq. 6's first MAP pass starts from them),
    ≈ 16 KB each on the paper's web, so ``SETTLED_WEBS_CACHED`` bounds the memory
    per model (≈ 8 MB).
    Thread-safe: ``/infer`` analyses without the model's lock.
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


#: Distinct concept-level objects whose settled webs a model keeps (see :class:`SettledWebs`).
SETTLED_WEBS_CACHED = 512


@dataclass(frozen=True)
class Perception:
    """What a model has fitted to perceive objects; replaced whole by a fit, never mutated
    (but for its memo of settled concept-level webs, which belongs to its ``concept_web``)."""

    vocabulary: Vocabulary
    prototypes: PrototypeSet | None = None
    concept_web: ConceptWeb | None = None
    settled_webs: SettledWebs = field(
        default_factory=lambda: SettledWebs(SETTLED_WEBS_CACHED), compare=False, repr=False
    )


@dataclass(frozen=True)
class ObjectResult:
    """One object's analysis: probabilities per stage and its active concepts (LDA words)."""

    level: ObjectLevel
    active_concepts: list[str]
    perception: dict[str, float]
    web: dict[str, float] | None
    in_context: dict[str, float] | None = None


@dataclass(frozen=True)
class SceneAnalysis:
    """The objects of a scene after perception and their concept webs, before context."""

    objects: list[ObjectResult]
    perceptions: np.ndarray = field(repr=False)
    """(n_objects, n_concepts) perception over the vocabulary, the webs' evidence."""
    applied: np.ndarray = field(repr=False)
    """(n_objects, n_verbs) behaviours applied to each object."""
    settled: tuple[WebInference, ...] | None = field(default=None, repr=False)
    """The concept webs settled on ``perceptions`` (None without a fitted web): step 1 of Eq. 6's loop."""
    settled_by: ConceptWeb | None = field(default=None, repr=False)
    """The web that settled them (a fit may replace the model's web before :func:`in_context`)."""

    @property
    def words(self) -> list[str]:
        return [word for obj in self.objects for word in obj.active_concepts]


@dataclass(frozen=True)
class _Evidence:
    """Perception over the vocabulary, which concepts carry evidence, and names outside it."""

    level: ObjectLevel
    probabilities: np.ndarray
    informed: np.ndarray
    applied: np.ndarray
    unseen: dict[str, float]


def analyse_objects(perception: Perception, objects: Sequence[SceneObject], model_id: str) -> SceneAnalysis:
    """Perception, concept web and active concepts of every object of a scene."""
    evidence = _scene_evidence(perception, objects, model_id)
    perceptions = np.stack([item.probabilities for item in evidence])
    applied = np.stack([item.applied for item in evidence])
    web = perception.concept_web
    settled: Sequence[WebInference | None] = (
        _settle(perception, web, evidence, perceptions, applied) if web is not None else [None] * len(evidence)
    )
    concepts = perception.vocabulary.concepts
    results = []
    for item, inference in zip(evidence, settled, strict=True):
        if inference is None:
            active_mask = _map_without_web(perception.vocabulary, item)
        else:
            active_mask = inference.map_configuration & item.informed
        active = [concepts[i] for i in np.flatnonzero(active_mask)]
        active += [name for name, p in item.unseen.items() if p >= ACTIVE_PROBABILITY]
        results.append(
            ObjectResult(
                level=item.level,
                active_concepts=active,
                perception={**_named(concepts, item.probabilities), **item.unseen},
                web=None if inference is None else _named(concepts, inference.probabilities),
            )
        )
    webs = None if web is None else tuple(item for item in settled if item is not None)
    return SceneAnalysis(results, perceptions, applied, webs, web)


def _settle(
    perception: Perception, web: ConceptWeb, evidence: Sequence[_Evidence], perceptions: np.ndarray, applied: np.ndarray
) -> list[WebInference]:
    """Every object's web settled on its perception: memoised ones for concept-level objects,
    the others in one ``infer_many`` call."""
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
    """A read-only copy that holds only its own object's arrays (not the whole batch's), with
    the max-product messages Eq. 6's warm MAP passes start from (the sum-product ones are
    not needed: the in-context settlings skip that pass, see :func:`in_context`)."""

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


def in_context(
    perception: Perception, incremental_lda: IncrementalLDA, analysis: SceneAnalysis, *, sigma: float, seed: int
) -> SceneAnalysis:
    """The analysis with each object's P*(c) of Eq. 6 (unchanged when no web is fitted).

    Reads the context model: call it holding the model's lock.
    """
    web = perception.concept_web
    if web is None:
        return analysis
    feedback = contextual_feedback(
        web,
        incremental_lda,
        analysis.perceptions,
        perception.vocabulary,
        applied=analysis.applied,
        sigma=sigma,
        seed=seed,
        perceived=analysis.settled if analysis.settled_by is web else None,
        marginals=False,  # the answer shows P* (Eq. 6), not the in-context webs' marginals
        warm_map=True,  # agreement with the cold path measured in docs/feedback.md
    )
    concepts = perception.vocabulary.concepts
    objects = [
        ObjectResult(obj.level, obj.active_concepts, obj.perception, obj.web, _named(concepts, row))
        for obj, row in zip(analysis.objects, feedback.in_context, strict=True)
    ]
    return SceneAnalysis(objects, analysis.perceptions, analysis.applied, analysis.settled, analysis.settled_by)


def _named(concepts: Sequence[str], values: np.ndarray) -> dict[str, float]:
    return dict(zip(concepts, values.tolist(), strict=True))


@dataclass(frozen=True)
class _Measured:
    """A feature- or raw-level object's vectors, checked, waiting for the scene's one perception call."""

    level: ObjectLevel
    entity: np.ndarray
    effects: dict[str, np.ndarray]


def _scene_evidence(perception: Perception, objects: Sequence[SceneObject], model_id: str) -> list[_Evidence]:
    """Every object's evidence: concept-level ones from their names, the measured ones (features,
    raw) from the prototypes in one ``perceive_many`` call for the scene (Eq. 1 batched).
    Every object is checked before any is perceived."""
    items = [_observed(perception, obj, f"objects[{i}]", model_id) for i, obj in enumerate(objects)]
    measured = {i: item for i, item in enumerate(items) if isinstance(item, _Measured)}
    perceived: dict[int, _Evidence] = {}
    if measured and perception.prototypes is not None:  # _observed refused measured objects without prototypes
        with np.errstate(over="ignore", invalid="ignore"):  # extreme inputs are refused in _perceived
            rows = perceive_many(
                perception.prototypes,
                [item.entity for item in measured.values()],
                [item.effects for item in measured.values()],
            )
        for (i, item), row in zip(measured.items(), rows, strict=True):
            perceived[i] = _perceived(perception.vocabulary, item, row, f"objects[{i}]")
    return [perceived[i] if isinstance(item, _Measured) else item for i, item in enumerate(items)]


def _observed(perception: Perception, obj: SceneObject, field: str, model_id: str) -> _Evidence | _Measured:
    """A concept-level object's evidence, or a measured object's checked vectors."""
    vocabulary = perception.vocabulary
    if obj.concepts is not None:
        return _concept_evidence(vocabulary, obj.concepts)
    level: ObjectLevel
    if obj.features is not None:
        level, behaviours = "features", list(obj.features.effects)
    else:
        assert obj.raw is not None
        level, behaviours = "raw", [interaction.behaviour for interaction in obj.raw.interactions]
    check_behaviours(vocabulary, behaviours, f"{field}.{level}")
    if perception.prototypes is None:
        raise ModelNotFitted(model_id, "prototypes (needed for objects at the features or raw level)")
    if obj.features is not None:
        entity, effects = feature_vectors(obj.features)
    else:
        entity, effects = raw_feature_vectors(obj.raw, f"{field}.raw")
    return _Measured(level, entity, effects)


def _perceived(vocabulary: Vocabulary, measured: _Measured, probabilities: np.ndarray, field: str) -> _Evidence:
    if not np.isfinite(probabilities).all():
        raise InvalidInput(
            f"{field}.{measured.level}", "values too far from every prototype: the perception is not finite"
        )
    applied = np.array([verb in measured.effects for verb in vocabulary.verbs], dtype=bool)
    informed = np.concatenate([np.ones(len(vocabulary.nouns) + len(vocabulary.adjectives), dtype=bool), applied])
    return _Evidence(measured.level, probabilities, informed, applied, {})


@dataclass(frozen=True)
class _Layout:
    """Where each concept sits: its column, and its group (the nouns, one adjective pair; -1 for a verb)."""

    column: dict[str, int]
    group: np.ndarray
    group_size: np.ndarray
    verbs: slice


@functools.lru_cache(maxsize=64)
def _layout(vocabulary: Vocabulary) -> _Layout:
    n_nouns, n_pairs = len(vocabulary.nouns), len(vocabulary.adjective_pairs)
    group = np.concatenate(
        [np.zeros(n_nouns, int), np.repeat(np.arange(1, n_pairs + 1), 2), np.full(len(vocabulary.verbs), -1)]
    )
    return _Layout(
        column={name: i for i, name in enumerate(vocabulary.concepts)},
        group=group,
        group_size=np.bincount(group[group >= 0], minlength=n_pairs + 1),
        verbs=slice(n_nouns + 2 * n_pairs, len(vocabulary)),
    )


def _concept_evidence(vocabulary: Vocabulary, concepts: Sequence[str] | Mapping[str, float]) -> _Evidence:
    """Perception of a named object: the nouns and each pair named in completed to a distribution.

    In a group (the nouns, or one pair) with a name given, the unnamed members
    share what the named ones leave, and a total above 1 is rescaled. A pure
    function of the names (and probabilities) given, which a robot's scenes
    repeat: it is memoised, its arrays read-only.
    """
    if isinstance(concepts, Mapping):
        return _named_evidence(vocabulary, tuple(concepts.items()))
    return _named_evidence(vocabulary, tuple((name, 1.0) for name in concepts))


@functools.lru_cache(maxsize=4096)
def _named_evidence(vocabulary: Vocabulary, named_probabilities: tuple[tuple[str, float], ...]) -> _Evidence:
    given = dict(named_probabilities)
    layout = _layout(vocabulary)
    probabilities = np.full(len(vocabulary), NO_EVIDENCE)
    named = np.zeros(len(vocabulary), dtype=bool)
    unseen: dict[str, float] = {}
    for name, value in given.items():
        column = layout.column.get(name)
        if column is None:
            unseen[name] = float(value)
        else:
            probabilities[column], named[column] = value, True
    group, n_groups = layout.group, len(layout.group_size)
    grouped = group >= 0
    group_named = np.bincount(group[grouped & named], minlength=n_groups) > 0
    informed = np.where(grouped, group_named[np.maximum(group, 0)], named)
    if group_named.any():
        named_mass = np.bincount(group[grouped & named], weights=probabilities[grouped & named], minlength=n_groups)
        unnamed = np.bincount(group[grouped & ~named], minlength=n_groups)
        share = np.maximum(0.0, 1.0 - named_mass) / np.maximum(unnamed, 1)
        filled = grouped & informed & ~named
        probabilities[filled] = share[group[filled]]
        members = grouped & informed
        totals = np.bincount(group[members], weights=probabilities[members], minlength=n_groups)[group[members]]
        uniform = 1.0 / layout.group_size[group[members]]
        probabilities[members] = np.where(
            totals > 0, probabilities[members] / np.where(totals > 0, totals, 1.0), uniform
        )
    evidence = _Evidence("concepts", probabilities, informed, named[layout.verbs].copy(), unseen)
    for array in (evidence.probabilities, evidence.informed, evidence.applied):
        array.flags.writeable = False
    return evidence


def _map_without_web(vocabulary: Vocabulary, item: _Evidence) -> np.ndarray:
    """Active concepts read off the perception: argmax noun, argmax of each pair, verbs ≥ 0.5."""
    active = np.zeros(len(vocabulary), dtype=bool)
    p, informed = item.probabilities, item.informed
    n_nouns = len(vocabulary.nouns)
    if informed[:n_nouns].any():
        active[int(np.argmax(p[:n_nouns]))] = True
    for pair in range(len(vocabulary.adjective_pairs)):
        first = n_nouns + 2 * pair
        if informed[first]:
            active[first if p[first] >= p[first + 1] else first + 1] = True
    verbs = slice(n_nouns + len(vocabulary.adjectives), len(vocabulary))
    active[verbs] = informed[verbs] & (p[verbs] >= ACTIVE_PROBABILITY)
    return active


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
    recording = _recording(raw, field)
    try:
        return recording_features(recording)
    except InvalidInputError as error:
        raise InvalidInput(f"{field}.{error.field.removeprefix('recording.')}", error.problem) from None


def _recording(raw: RawObject, field: str) -> ObjectRecording:
    """The core payloads (validated there); a problem is reported at its place in the request."""
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
