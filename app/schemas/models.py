"""Models: one per robot or environment, each with its own hyperparameters and state."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal

from pydantic import ConfigDict, Discriminator, Field, Tag, model_validator

from app.schemas.common import PAPER_RULE, SCENES_RULE, ReadSchema, RequestSchema
from app.schemas.observations import Name
from core.context.feedback import PAPER_SIGMA
from core.context.hyperparameters import nest_flat_settings
from core.context.k_selection import PAPER_TAU

MAX_CONCEPTS_PER_KIND = 256
#: Upper bound on integer settings, so that one request's work stays bounded (far above useful values).
MAX_INTEGER_SETTING = 10_000
#: K at most 100; rejuvenation may touch up to 100,000 earlier tokens per sweep.
MAX_CONTEXTS_BOUND, MAX_REJUVENATION_TOKENS = 100, 100_000
#: Dirichlet concentrations (α, ξ, the scene prior's pseudo-counts): 1e-6 to 1e3. Above 1e3 the
#: prior outweighs the counts of any scene (a scene is at most 16,384 tokens, typically ~30), so
#: every posterior is uniform: a larger value means nothing more. Below 1e-6 the products of
#: Eq. 5 (n + α)(n + ξ) for unseen words fall towards float64's underflow and the sampler's
#: probabilities lose their precision; the paper uses 0.1. ``alpha: 1e308`` made every posterior 0.
Concentration = Annotated[float, Field(ge=1e-6, le=1e3, allow_inf_nan=False)]
#: A margin above 10,000 nats can never be met (growth simply stops, which ``max_contexts`` says more plainly).
Margin = Annotated[float, Field(ge=0.0, le=1e4, allow_inf_nan=False)]
#: δ is a probability.
Delta = Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)]


def _count(default: int, description: str, *, lowest: int = 1, highest: int = MAX_INTEGER_SETTING) -> Any:
    return Field(default, ge=lowest, le=highest, description=description)


class Priors(RequestSchema):
    """The symmetric Dirichlet priors of Eq. 5."""

    alpha: Concentration = Field(default=0.1, description="α: prior on a scene's contexts (Eq. 5; §V-B uses 0.1).")
    xi: Concentration = Field(default=0.1, description="ξ: prior on a context's concepts (Eq. 5; §V-B uses 0.1).")


class SamplerSettings(RequestSchema):
    """How much collapsed Gibbs sampling (Eq. 5) each step gets."""

    sweeps: int = _count(200, "Gibbs sweeps after each K-incremental start (batch, or over the growth window).")
    scene_sweeps: int = _count(5, "Online: sweeps over a new scene's tokens.")
    rejuvenation_tokens: int = _count(
        64, "Online: earlier tokens resampled with each of those sweeps.", lowest=0, highest=MAX_REJUVENATION_TOKENS
    )
    inference_sweeps: int = _count(30, "Fold-in sweeps when a scene's context posterior is inferred.")
    inference_burn_in: int = _count(
        10, "Of those, the first ones not averaged (fewer than inference_sweeps).", lowest=0
    )


class _KRuleBase(RequestSchema):
    max_contexts: int = _count(
        10, "K never exceeds this; at the cap growth is simply not proposed any more.", highest=MAX_CONTEXTS_BOUND
    )
    birth_window: int = _count(100, "Online: scheduled growth checks decide on the last this-many scenes.")
    birth_check_interval: int = _count(
        25,
        "Online: growth is checked after each of the first this-many scenes, then after scenes 2, 4, 8, ... "
        "times this many; besides, novelty triggers checks (docs/context.md, 'When growth is checked online').",
    )
    novelty_window: int = _count(
        20,
        "Online: a scene that a fresh context explains better than every context held before the last "
        "this-many scenes triggers a growth check on those scenes from the earliest that was novel in the "
        "same sense (at least the last 5), itself included.",
    )
    scene_prior_strength: Concentration = Field(
        default=1.0,
        description="Pseudo-counts per concept of the corpus-centred Dirichlet on a context's concepts, "
        "with which the novelty trigger (and the scenes rule's evidence) scores a scene's blocks.",
    )


class ScenesRule(_KRuleBase):
    """The default K rule: K + 1 is kept when the best partition of the scenes into K + 1 contexts
    has more evidence than the best into K (docs/context.md, "Choosing K")."""

    name: Literal["scenes"] = "scenes"
    partition_scans: int = _count(25, "Sampled scans of each partition search in a batch fit.")
    online_partition_scans: int = _count(10, "The same online, where searches start from the model's own partition.")
    partition_random_starts: int = _count(
        4, "In a batch fit: searches from random partitions, besides those from the model's own.", lowest=0
    )
    birth_margin: Margin = Field(
        default=0.0,
        description="A batch fit keeps K + 1 if its evidence exceeds K's by more than this many nats.",
    )
    online_birth_margin: Margin = Field(
        default=3.0,
        description="The same margin online (3 nats: a Bayes factor of 20, 'strong' on Kass & Raftery's scale).",
    )
    birth_proposals: int = _count(
        2, "Searches for K + 1 also start with each of this many worst-explained scenes in the new context."
    )
    delta: Delta = Field(
        default=0.05, description="δ of a forced start: probability that a confident token moves (Algorithm 3)."
    )
    split_scans: int = _count(3, "Scene-level split passes after a forced start.", lowest=0)


class PaperRule(_KRuleBase):
    """The paper's Algorithm 2: K grows while C_low ≠ ∅, the concepts whose confidence max_χ φ_χc is below τ."""

    name: Literal["paper"]
    tau: float = Field(
        default=PAPER_TAU,
        gt=0.0,
        lt=1.0,
        allow_inf_nan=False,
        description="τ: a concept is in C_low when its confidence max_χ φ_χc is below τ (docs/context.md has the τ scan).",
    )
    delta: Delta = Field(
        default=0.05,
        description="δ: probability that a confident token moves to the new context (Algorithm 3).",
    )


def _k_rule_tag(value: Any) -> str | None:
    name = value.get("name", "scenes") if isinstance(value, dict) else getattr(value, "name", None)
    return {"scenes": SCENES_RULE, "paper": PAPER_RULE}.get(name) if isinstance(name, str) else None


#: The K rule, told apart by its ``name``; ``likelihood`` is refused (an experiments' baseline now).
KRuleSettings = Annotated[
    Annotated[ScenesRule, Tag(SCENES_RULE)] | Annotated[PaperRule, Tag(PAPER_RULE)],
    Discriminator(
        _k_rule_tag,
        custom_error_type="invalid_k_rule",
        custom_error_message="name must be 'scenes' or 'paper' ('likelihood' is no longer a rule of the service: "
        "it is a baseline of the experiments, experiments/baselines/likelihood_rule.py)",
    ),
]


class Hyperparameters(RequestSchema):
    """Incremental-LDA's settings, nested by concern (``core.context.Hyperparameters``).

    The flat form of earlier versions (every setting at the top level, the rule named by
    ``k_selection``) is still accepted and is deprecated (docs/api.md): its settings go to their
    group, and those the chosen rule does not have (another rule's, or the retired
    ``likelihood`` rule's) are dropped, as they had no effect. Answers are nested.
    """

    model_config = ConfigDict(
        json_schema_extra={"examples": [{"priors": {"alpha": 0.1}, "k_rule": {"name": "scenes"}}]}
    )

    priors: Priors = Field(default_factory=lambda: Priors())
    sampler: SamplerSettings = Field(default_factory=lambda: SamplerSettings())
    k_rule: KRuleSettings = Field(
        default_factory=lambda: ScenesRule(), description="The rule for K and its own settings."
    )

    @model_validator(mode="before")
    @classmethod
    def _nest_flat_settings(cls, data: Any) -> Any:
        """The deprecated flat form: a mapping with none of the groups' names."""
        if isinstance(data, dict) and data and not set(data) & {"priors", "sampler", "k_rule"}:
            return nest_flat_settings(data)[0]
        return data


class VocabularySchema(RequestSchema):
    """The concepts of a world (§III): nouns, dichotomic adjective pairs, verbs (= behaviours)."""

    nouns: list[Name] = Field(min_length=1, max_length=MAX_CONCEPTS_PER_KIND)
    adjective_pairs: list[Annotated[tuple[Name, Name], Field(strict=False)]] = Field(max_length=MAX_CONCEPTS_PER_KIND)
    verbs: list[Name] = Field(max_length=MAX_CONCEPTS_PER_KIND)


class ModelCreate(RequestSchema):
    model_config = ConfigDict(
        json_schema_extra={
            "examples": [{"name": "icub-kitchen", "seed": 7, "hyperparameters": {"priors": {"alpha": 0.1}}}]
        }
    )

    name: Name
    seed: int = Field(0, ge=0, le=2**63 - 1, description="Seed of the model's random generator.")
    sigma: float = Field(
        PAPER_SIGMA,
        ge=0,
        le=1,
        allow_inf_nan=False,
        description="σ of Eq. 6: weight of the concept web against the context (1 = web only).",
    )
    hyperparameters: Hyperparameters = Field(default_factory=lambda: Hyperparameters())
    vocabulary: VocabularySchema | None = Field(None, description="Default: the paper's 29 concepts.")


class ModelRead(ReadSchema):
    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "id": "3f2c0b9e5d7a4e1f8a6b2c4d9e0f1a2b",
                    "name": "icub-kitchen",
                    "seed": 7,
                    "sigma": 0.5,
                    "hyperparameters": {"priors": {"alpha": 0.1, "xi": 0.1}, "k_rule": {"name": "scenes"}},
                    "vocabulary": {"nouns": ["cup"], "adjective_pairs": [["hard", "soft"]], "verbs": ["grasp"]},
                    "context_count": 3,
                    "vocabulary_size": 29,
                    "scene_count": 120,
                    "training_object_count": 45,
                    "prototypes_fitted": True,
                    "concept_web_fitted": True,
                    "created_at": "2025-01-01T12:00:00Z",
                }
            ]
        }
    )

    id: str
    name: str
    seed: int
    sigma: float
    hyperparameters: Hyperparameters | None = Field(
        description="null only for an unavailable model whose stored hyperparameters cannot be read."
    )
    vocabulary: VocabularySchema | None = Field(
        description="null only for an unavailable model whose stored vocabulary cannot be read."
    )
    context_count: int = Field(description="K, the number of contexts discovered so far.")
    vocabulary_size: int = Field(description="|W|: distinct concepts seen in scenes.")
    scene_count: int
    training_object_count: int
    status: Literal["available", "unavailable"] = Field(
        "available", description="`unavailable`: the stored state failed its check or is being reloaded (503s)."
    )
    unavailable_reason: str | None = Field(None, description="Why the model is unavailable, and what to run.")
    prototypes_fitted: bool
    concept_web_fitted: bool
    created_at: datetime
