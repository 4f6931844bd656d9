"""Training: labelled objects (Appendix) from which prototypes and the concept web are fitted."""

from __future__ import annotations

from typing import Literal

from pydantic import ConfigDict, Field

from app.schemas.common import ReadSchema, RequestSchema
from app.schemas.observations import BehaviourName, Name, ObjectFeatures, OneLevel, RawObject
from app.schemas.scenes import ConceptKind

TRAINING_LEVELS = ("features", "raw")


class TrainingObjectCreate(OneLevel):
    """One labelled object: its noun, one adjective per pair, and its observations (features or raw)."""

    levels = TRAINING_LEVELS

    noun: Name = Field(examples=["cup"])
    adjectives: list[Name] = Field(
        min_length=1, max_length=1_000, examples=[["hard", "silent", "short", "thick", "round"]]
    )
    features: ObjectFeatures | None = None
    raw: RawObject | None = None
    verbs: dict[BehaviourName, Name] = Field(
        default_factory=dict,
        description="Verb label of each behaviour's interaction; a behaviour left out is labelled with its own name.",
    )


class TrainingBatchCreate(RequestSchema):
    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "objects": [
                        {
                            "noun": "cup",
                            "adjectives": ["hard", "silent", "short", "thick", "round"],
                            "features": {"entity": [0.0] * 91, "effects": {"grasp": [0.0] * 66}},
                            "verbs": {"grasp": "grasp"},
                        }
                    ]
                }
            ]
        }
    )

    objects: list[TrainingObjectCreate] = Field(min_length=1, max_length=500)


class TrainingBatchRead(ReadSchema):
    model_config = ConfigDict(json_schema_extra={"examples": [{"added": 1, "training_object_count": 45}]})

    added: int
    training_object_count: int


class FitCreate(RequestSchema):
    model_config = ConfigDict(json_schema_extra={"examples": [{"method": "rgng", "seed": 0}]})

    method: Literal["rgng", "kmeans"] = Field(
        "rgng", description="Clustering of the (mean, variance) plane: RGNG as in the paper, or k-means."
    )
    seed: int | None = Field(None, ge=0, le=2**63 - 1, description="Default: the model's seed.")


class FitRead(ReadSchema):
    """What a fit produced (it takes effect for the scenes posted after it)."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "model_id": "3f2c0b9e5d7a4e1f8a6b2c4d9e0f1a2b",
                    "method": "rgng",
                    "training_object_count": 45,
                    "concept_web_edges": 171,
                    "behaviours": ["grasp", "move_left"],
                }
            ]
        }
    )

    model_id: str
    method: str
    training_object_count: int
    concept_web_edges: int = Field(description="Pairs of concepts that co-occurred in training (Fig. 8).")
    behaviours: list[str] = Field(description="Behaviours whose effect on position the planner learned.")


class PrototypeRead(ReadSchema):
    name: str
    kind: ConceptKind
    relevance: str = Field(
        description="One symbol per feature of Table III: + positive, - negative, * irrelevant, 0 unaffected."
    )


class PrototypeTableRead(ReadSchema):
    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "method": "rgng",
                    "concepts": [{"name": "grasp", "kind": "verb", "relevance": "0" * 6 + "*" * 60}],
                    "table": "grasp  000 000 ****...",
                }
            ]
        }
    )

    method: str
    concepts: list[PrototypeRead]
    table: str = Field(description="Table VIII as printable text.")
