"""The bridge's own request and response types (pydantic v2), mirroring docs/api.md.

The bridge runs on the robot and must not import the service, so it keeps its
own copy of the shapes. Requests are strict (``extra="forbid"``, as the service
is), so a robot finds a malformed scene before it is queued; responses ignore
fields they do not know, so an older robot keeps working against a newer
service. Array payloads travel as base64 of little-endian float32
(:func:`float32_base64`), a quarter of the size of JSON numbers.

Sizes of Table III are repeated here (the bridge cannot import ``core``);
tests/test_bridge_client.py checks them against ``core.features.layout``.
"""

from __future__ import annotations

import base64
import sys
from array import array
from collections.abc import Iterable, Mapping, Sequence
from datetime import datetime
from typing import Annotated, Any, Generic, Literal, TypeVar

from pydantic import BaseModel, ConfigDict, Field, model_validator

ENTITY_SIZE = 91
EFFECT_SIZE = 66

ConceptKind = Literal["noun", "adjective", "verb"]
ObjectLevel = Literal["concepts", "features", "raw"]
OBJECT_LEVELS: tuple[ObjectLevel, ...] = ("concepts", "features", "raw")
T = TypeVar("T")


def float32_base64(values: Any) -> str:
    """Base64 of ``values`` as little-endian float32, flattened row by row.

    Takes a numpy array (without importing numpy: anything with ``astype``) or
    any iterable of numbers, or of rows of numbers.
    """
    if hasattr(values, "astype"):
        return base64.b64encode(values.astype("<f4").tobytes()).decode("ascii")
    flat = array("f", _flatten(values))
    if sys.byteorder == "big":
        flat.byteswap()
    return base64.b64encode(flat.tobytes()).decode("ascii")


def _flatten(values: Iterable[Any]) -> Iterable[float]:
    for value in values:
        if isinstance(value, Iterable):
            yield from (float(v) for v in value)
        else:
            yield float(value)


class RequestModel(BaseModel):
    model_config = ConfigDict(extra="forbid", protected_namespaces=())


class ResponseModel(BaseModel):
    model_config = ConfigDict(extra="ignore", protected_namespaces=())


class Vocabulary(RequestModel):
    """The concepts of a world (§III): nouns, dichotomic adjective pairs, verbs (the behaviours)."""

    nouns: list[str] = Field(min_length=1)
    adjective_pairs: list[tuple[str, str]]
    verbs: list[str]


class Priors(RequestModel):
    """α and ξ, the symmetric Dirichlet priors of Eq. 5; None: the service's default (0.1)."""

    alpha: float | None = Field(default=None, gt=0)
    xi: float | None = Field(default=None, gt=0)


class SamplerSettings(RequestModel):
    """Gibbs sweeps of each step (docs/api.md, "Hyperparameters"); None: the service's default."""

    sweeps: int | None = Field(default=None, ge=1)
    scene_sweeps: int | None = Field(default=None, ge=1)
    rejuvenation_tokens: int | None = Field(default=None, ge=0)
    inference_sweeps: int | None = Field(default=None, ge=1)
    inference_burn_in: int | None = Field(default=None, ge=0)


class _KRule(RequestModel):
    max_contexts: int | None = Field(default=None, ge=1)
    birth_window: int | None = Field(default=None, ge=1)
    birth_check_interval: int | None = Field(default=None, ge=1)
    novelty_window: int | None = Field(default=None, ge=1)
    scene_prior_strength: float | None = Field(default=None, gt=0)


class ScenesRule(_KRule):
    """The default K rule, scene-partition evidence; None: the service's default."""

    name: Literal["scenes"] = "scenes"
    partition_scans: int | None = Field(default=None, ge=1)
    online_partition_scans: int | None = Field(default=None, ge=1)
    partition_random_starts: int | None = Field(default=None, ge=0)
    birth_margin: float | None = Field(default=None, ge=0)
    online_birth_margin: float | None = Field(default=None, ge=0)
    birth_proposals: int | None = Field(default=None, ge=1)
    delta: float | None = Field(default=None, ge=0, le=1)
    split_scans: int | None = Field(default=None, ge=0)


class PaperRule(_KRule):
    """The paper's Algorithm 2 (C_low ≠ ∅ under τ); None: the service's default."""

    name: Literal["paper"]
    tau: float | None = Field(default=None, gt=0, lt=1)
    delta: float | None = Field(default=None, ge=0, le=1)


class Hyperparameters(RequestModel):
    """Incremental-LDA's settings, nested by concern as the service takes them (docs/api.md);
    what is left out takes the service's default."""

    priors: Priors = Field(default_factory=lambda: Priors())
    sampler: SamplerSettings = Field(default_factory=lambda: SamplerSettings())
    k_rule: Annotated[ScenesRule | PaperRule, Field(discriminator="name")] = Field(default_factory=lambda: ScenesRule())


class ModelCreate(RequestModel):
    """A new model; ``hyperparameters`` are Incremental-LDA's (α, ξ, τ, δ, ...: docs/api.md), the service's defaults otherwise."""

    name: str = Field(min_length=1, max_length=200)
    seed: int = Field(0, ge=0)
    sigma: float | None = Field(None, ge=0, le=1, description="σ of Eq. 6; the service's default (0.5) when None.")
    hyperparameters: Hyperparameters = Field(default_factory=lambda: Hyperparameters())
    vocabulary: Vocabulary | None = None


class Model(ResponseModel):
    """A model as the service describes it: K so far, counts, what is fitted."""

    id: str
    name: str
    seed: int
    sigma: float | None = None
    hyperparameters: dict[str, Any] | None = Field(
        description="Nested: priors, sampler, k_rule (docs/api.md); null for an unavailable model whose stored ones cannot be read."
    )
    vocabulary: dict[str, Any] | None = Field(
        description="null for an unavailable model whose stored vocabulary cannot be read."
    )
    context_count: int
    vocabulary_size: int
    scene_count: int
    training_object_count: int
    prototypes_fitted: bool
    concept_web_fitted: bool
    created_at: datetime


class ObjectFeatures(RequestModel):
    """Feature level: the entity vector e (91 values) and the effect f (66 values) of each behaviour."""

    entity: list[float] = Field(min_length=ENTITY_SIZE, max_length=ENTITY_SIZE)
    effects: dict[str, list[float]] = Field(default_factory=dict)

    @model_validator(mode="after")
    def _effect_sizes(self) -> ObjectFeatures:
        for behaviour, effect in self.effects.items():
            if len(effect) != EFFECT_SIZE:
                raise ValueError(f"effects[{behaviour!r}] has {len(effect)} values, not {EFFECT_SIZE}")
        return self


class PointCloud(RequestModel):
    """(n, 3) points in metres in the table frame, sent as base64 float32 x0 y0 z0 x1 ..."""

    points: str | list[list[float]]

    @classmethod
    def of(cls, points: Any) -> PointCloud:
        return cls(points=float32_base64(points))


class Audio(RequestModel):
    """Mono PCM in [-1, 1] at ``sample_rate`` Hz (recorded while shaking)."""

    samples: str | list[float]
    sample_rate: int

    @classmethod
    def of(cls, samples: Any, sample_rate: int) -> Audio:
        return cls(samples=float32_base64(samples), sample_rate=sample_rate)


class Finger(RequestModel):
    """Index-finger tactile pressure and joint angle (radians) at the same instants of a grasp."""

    haptic: str | list[float]
    proprioceptive: str | list[float]

    @classmethod
    def of(cls, haptic: Any, proprioceptive: Any) -> Finger:
        return cls(haptic=float32_base64(haptic), proprioceptive=float32_base64(proprioceptive))


class Interaction(RequestModel):
    """One behaviour applied to an object: clouds before and after, and the audio or finger series it recorded."""

    behaviour: str
    before: PointCloud
    after: PointCloud
    audio: Audio | None = None
    finger: Finger | None = None


class RawObject(RequestModel):
    """Raw level: the first look (e_v) and every interaction (§II-C)."""

    look: PointCloud
    interactions: list[Interaction] = Field(default_factory=list)


class SceneObject(RequestModel):
    """One object of a scene, at exactly one level: ``concepts``, ``features`` or ``raw``."""

    concepts: list[str] | dict[str, float] | None = None
    kinds: dict[str, ConceptKind] = Field(default_factory=dict)
    features: ObjectFeatures | None = None
    raw: RawObject | None = None

    @model_validator(mode="after")
    def _one_level(self) -> SceneObject:
        given = [level for level in OBJECT_LEVELS if getattr(self, level) is not None]
        if len(given) != 1:
            raise ValueError(f"give exactly one of concepts, features, raw (got {', '.join(given) or 'none'})")
        return self

    @property
    def level(self) -> ObjectLevel:
        return next(level for level in OBJECT_LEVELS if getattr(self, level) is not None)

    @classmethod
    def from_concepts(
        cls, concepts: Sequence[str] | Mapping[str, float], kinds: Mapping[str, ConceptKind] | None = None
    ) -> SceneObject:
        """Active concept names, or name -> probability, from the robot's own recognisers."""
        named = dict(concepts) if isinstance(concepts, Mapping) else list(concepts)
        return cls(concepts=named, kinds=dict(kinds or {}))

    @classmethod
    def from_features(
        cls, entity: Sequence[float], effects: Mapping[str, Sequence[float]] | None = None
    ) -> SceneObject:
        """Table III vectors computed on the robot."""
        return cls(
            features=ObjectFeatures(
                entity=[float(v) for v in entity],
                effects={behaviour: [float(v) for v in f] for behaviour, f in (effects or {}).items()},
            )
        )

    @classmethod
    def from_raw(cls, look: Any, interactions: Sequence[Interaction] = ()) -> SceneObject:
        """Raw sensor data: the first look's points and the interactions."""
        return cls(raw=RawObject(look=PointCloud.of(look), interactions=list(interactions)))


class TrainingObject(RequestModel):
    """A labelled training object: its noun, one adjective per pair, and its observations (features or raw).

    ``verbs`` labels each behaviour's interaction with a verb concept; a
    behaviour left out is labelled with its own name.
    """

    noun: str
    adjectives: list[str] = Field(min_length=1)
    features: ObjectFeatures | None = None
    raw: RawObject | None = None
    verbs: dict[str, str] = Field(default_factory=dict)

    @model_validator(mode="after")
    def _one_level(self) -> TrainingObject:
        if (self.features is None) == (self.raw is None):
            raise ValueError("give exactly one of features, raw")
        return self


class TrainingBatch(RequestModel):
    objects: list[TrainingObject] = Field(min_length=1)


class TrainingBatchRead(ResponseModel):
    added: int
    training_object_count: int


class FitRead(ResponseModel):
    """What a fit produced: it takes effect for the scenes posted after it."""

    model_id: str
    method: str
    training_object_count: int
    concept_web_edges: int
    behaviours: list[str]


class SceneCreate(RequestModel):
    """A scene: the objects the robot perceives together (one LDA document, §IV-B)."""

    objects: list[SceneObject] = Field(min_length=1)


class ObjectAnalysis(ResponseModel):
    """One object's concept web at each stage: perception (Eq. 1), web (LBP), in context (Eq. 6)."""

    level: ObjectLevel
    active_concepts: list[str]
    perception: dict[str, float]
    web: dict[str, float] | None = None
    in_context: dict[str, float] | None = None


class SceneRead(ResponseModel):
    """The service's answer to a scene: K, the context posterior θ and the objects' concept webs."""

    model_id: str
    scene_id: int | None = None
    learned: bool
    context_count: int
    previous_context_count: int
    context_posterior: list[float]
    map_context: int
    map_context_label: str | None = None
    """The map context's label, as an operator named it when the scene was answered."""
    objects: list[ObjectAnalysis] = Field(default_factory=list)
    created_at: datetime | None = None


class SceneSummary(ResponseModel):
    """One line of a model's scene history."""

    scene_id: int
    context_count: int
    map_context: int
    context_posterior: list[float]
    created_at: datetime


class PlanCreate(RequestModel):
    """Bring ``object`` from ``start`` to ``goal`` (Fig. 15(a) positions); the context is given
    (``context``), read from a learned scene (``scene_id``) or inferred from ``scene``; none means no pruning."""

    object: str
    start: int = Field(ge=1)
    goal: int = Field(ge=1)
    obstacles: dict[str, int] = Field(default_factory=dict)
    context: int | None = None
    scene_id: int | None = None
    scene: SceneCreate | None = None
    mode: Literal["paper", "bfs", "astar"] = "astar"
    node_budget: int | None = None
    depth_budget: int | None = None

    @model_validator(mode="after")
    def _one_context_source(self) -> PlanCreate:
        given = [name for name in ("context", "scene_id", "scene") if getattr(self, name) is not None]
        if len(given) > 1:
            raise ValueError(f"give at most one of context, scene_id, scene (got {', '.join(given)})")
        return self


class SearchCount(ResponseModel):
    status: str
    nodes_expanded: int
    nodes_generated: int


class Plan(ResponseModel):
    """A plan and its search: the behaviours kept and pruned by P(verb | χ), against the unpruned search (§V-E)."""

    status: Literal["solved", "unreachable", "budget_exceeded"]
    mode: str
    context: int | None = None
    context_source: str
    plan: list[str]
    positions: list[int]
    kept: list[str]
    pruned: list[str]
    verb_given_context: dict[str, float] | None = None
    nodes_expanded: int
    nodes_generated: int
    unpruned: SearchCount


class ConceptProbability(ResponseModel):
    name: str
    kind: ConceptKind | None = None
    probability: float


class DistinctiveConcept(ConceptProbability):
    relevance: float


class Context(ResponseModel):
    """A discovered context: its index and label, how many scenes it is the MAP context of, its top
    concepts P(c | χ) and its distinctive ones (LDAvis relevance)."""

    context: int
    label: str | None = None
    scene_count: int
    top_concepts: list[ConceptProbability]
    distinctive_concepts: list[DistinctiveConcept] = Field(default_factory=list)


class Contexts(ResponseModel):
    model_id: str
    context_count: int
    scene_count: int
    contexts: list[Context]


class Page(ResponseModel, Generic[T]):
    """One page of a listing, oldest first."""

    items: list[T]
    total: int
    offset: int
    limit: int


class HelloEvent(ResponseModel):
    """First message of a stream: where the model stands (fetch the history for what came before)."""

    type: Literal["hello"]
    model_id: str
    context_count: int
    scene_count: int


class SceneEvent(ResponseModel):
    """A scene was learned and committed."""

    type: Literal["scene"]
    model_id: str
    scene_id: int
    context_count: int
    context_posterior: list[float]
    map_context: int
    map_context_label: str | None = None
    active_concepts: list[list[str]]
    created_at: datetime


class SceneUnreadableEvent(ResponseModel):
    """Scene ``scene_id`` was learned, but its stored answer cannot be read back (damaged storage):
    sent in its place in the order."""

    type: Literal["scene_unreadable"]
    model_id: str
    scene_id: int
    detail: str


class ContextDiscoveredEvent(ResponseModel):
    """K grew while learning ``scene_id``."""

    type: Literal["context_discovered"]
    model_id: str
    scene_id: int
    context_count: int
    previous_context_count: int


class ModelFittedEvent(ResponseModel):
    """Prototypes and concept web were fitted again."""

    type: Literal["model_fitted"]
    model_id: str
    training_object_count: int


StreamEvent = Annotated[
    HelloEvent | SceneEvent | SceneUnreadableEvent | ContextDiscoveredEvent | ModelFittedEvent,
    Field(discriminator="type"),
]
