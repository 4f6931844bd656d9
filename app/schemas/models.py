"""Models: one per robot or environment, each with its own hyperparameters and state."""

from __future__ import annotations

import ast
import dataclasses
import inspect
import textwrap
import typing
from datetime import datetime
from typing import Any, Literal

from pydantic import Field, create_model

from app.schemas.common import ReadSchema, RequestSchema
from app.schemas.observations import Name
from core.context.feedback import PAPER_SIGMA
from core.context.incremental import Hyperparameters as CoreHyperparameters

MAX_CONCEPTS_PER_KIND = 256
#: Upper bounds on integer settings, so that one request's work stays bounded (far above useful values).
MAX_INTEGER_SETTING = 10_000
INTEGER_SETTING_BOUNDS = {"max_contexts": 100, "rejuvenation_tokens": 100_000}
#: Dirichlet concentrations (α, ξ, the scene prior's pseudo-counts): 1e-6 to 1e3. Above 1e3 the
#: prior outweighs the counts of any scene (a scene is at most 16,384 tokens, typically ~30), so
#: every posterior is uniform: a larger value means nothing more. Below 1e-6 the products of
#: Eq. 5 (n + α)(n + ξ) for unseen words fall towards float64's underflow and the sampler's
#: probabilities lose their precision; the paper uses 0.1. ``alpha: 1e308`` made every posterior 0.
DIRICHLET_BOUNDS = {"ge": 1e-6, "le": 1e3}
#: Bounds of the real settings, with the reasons above and in each one's docstring: τ and δ are
#: probabilities; a z-score above 100 or a margin above 10,000 nats can never be met (growth
#: simply stops, which ``max_contexts`` says more plainly).
FLOAT_SETTING_BOUNDS: dict[str, dict[str, float]] = {
    "alpha": DIRICHLET_BOUNDS,
    "xi": DIRICHLET_BOUNDS,
    "scene_prior_strength": DIRICHLET_BOUNDS,
    "tau": {"gt": 0.0, "lt": 1.0},
    "delta": {"ge": 0.0, "le": 1.0},
    "growth_z": {"ge": 0.0, "le": 100.0},
    "online_growth_z": {"ge": 0.0, "le": 100.0},
    "birth_margin": {"ge": 0.0, "le": 1e4},
    "online_birth_margin": {"ge": 0.0, "le": 1e4},
}


def _attribute_docstrings(cls: type) -> dict[str, str]:
    """The docstring under each field of a dataclass (its source's convention), by field name."""
    body = ast.parse(textwrap.dedent(inspect.getsource(cls))).body[0].body  # type: ignore[attr-defined]
    docs = {}
    for node, following in zip(body, body[1:], strict=False):
        if (
            isinstance(node, ast.AnnAssign)
            and isinstance(node.target, ast.Name)
            and isinstance(following, ast.Expr)
            and isinstance(following.value, ast.Constant)
            and isinstance(following.value.value, str)
        ):
            docs[node.target.id] = " ".join(following.value.value.split())
    return docs


def _hyperparameter_fields(cls: type) -> dict[str, Any]:
    """Pydantic fields mirroring the core dataclass: same names, types, defaults and docstrings.

    The core's ``__post_init__`` stays the judge of valid values (the service
    calls it and reports its InvalidInputError with the field); here the types,
    finiteness, the work bounds of the integers and the ranges of the reals
    (:data:`FLOAT_SETTING_BOUNDS`) are checked. The core does not enforce these
    ranges, so a model stored before them still loads.
    """
    types, docs = typing.get_type_hints(cls), _attribute_docstrings(cls)
    fields: dict[str, Any] = {}
    for field in dataclasses.fields(cls):
        constraints: dict[str, Any] = {}
        if types[field.name] is int:
            constraints = {"ge": 0, "le": INTEGER_SETTING_BOUNDS.get(field.name, MAX_INTEGER_SETTING)}
        elif types[field.name] is float:
            constraints = {"allow_inf_nan": False, **FLOAT_SETTING_BOUNDS[field.name]}
        fields[field.name] = (types[field.name], Field(field.default, description=docs.get(field.name), **constraints))
    return fields


#: Incremental-LDA's settings, ``core.context.incremental.Hyperparameters`` as a request schema.
Hyperparameters = create_model(
    "Hyperparameters",
    __base__=RequestSchema,
    __doc__=CoreHyperparameters.__doc__,
    **_hyperparameter_fields(CoreHyperparameters),
)


class VocabularySchema(RequestSchema):
    """The concepts of a world (§III): nouns, dichotomic adjective pairs, verbs (= behaviours)."""

    nouns: list[Name] = Field(min_length=1, max_length=MAX_CONCEPTS_PER_KIND)
    adjective_pairs: list[tuple[Name, Name]] = Field(max_length=MAX_CONCEPTS_PER_KIND)
    verbs: list[Name] = Field(max_length=MAX_CONCEPTS_PER_KIND)


class ModelCreate(RequestSchema):
    model_config = {
        "json_schema_extra": {"examples": [{"name": "icub-kitchen", "seed": 7, "hyperparameters": {"alpha": 0.1}}]}
    }

    name: Name
    seed: int = Field(0, ge=0, le=2**63 - 1, description="Seed of the model's random generator.")
    sigma: float = Field(
        PAPER_SIGMA, ge=0, le=1, allow_inf_nan=False, description="σ of Eq. 6: weight of the concept web against the context (1 = web only)."
    )
    hyperparameters: Hyperparameters = Field(default_factory=Hyperparameters)
    vocabulary: VocabularySchema | None = Field(None, description="Default: the paper's 29 concepts.")


class ModelRead(ReadSchema):
    model_config = {
        "json_schema_extra": {
            "examples": [
                {
                    "id": "3f2c0b9e5d7a4e1f8a6b2c4d9e0f1a2b",
                    "name": "icub-kitchen",
                    "seed": 7,
                    "sigma": 0.5,
                    "hyperparameters": {"alpha": 0.1, "xi": 0.1},
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
    }

    id: str
    name: str
    seed: int
    sigma: float
    hyperparameters: dict[str, float | int | str]
    vocabulary: VocabularySchema
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
