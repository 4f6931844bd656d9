"""Contexts: what Incremental-LDA discovered, each with its most probable concepts."""

from __future__ import annotations

from typing import Annotated

from pydantic import ConfigDict, Field, StringConstraints

from app.schemas.common import NO_CONTROL_CHARACTERS, ReadSchema, RequestSchema
from app.schemas.scenes import ConceptKind


class ConceptProbability(ReadSchema):
    name: str
    kind: ConceptKind | None = Field(description="Null for a concept outside the vocabulary posted without a kind.")
    probability: float = Field(description="P(c | χ) (φ of the context).")


class DistinctiveConcept(ConceptProbability):
    relevance: float = Field(
        description="LDAvis relevance λ log P(c | χ) + (1 − λ) log(P(c | χ) / P(c)) (Sievert & Shirley 2014)."
    )


ContextLabel = Annotated[
    str,
    StringConstraints(strip_whitespace=True, min_length=1, max_length=80, pattern=NO_CONTROL_CHARACTERS),
]


class ContextLabelUpdate(RequestSchema):
    label: ContextLabel | None = Field(
        description="The context's name, 1-80 printable characters; null removes it.", examples=["kitchen"]
    )


class ContextLabelRead(ReadSchema):
    model_id: str
    context: int
    label: str | None


class ContextRead(ReadSchema):
    context: int = Field(description="Index of the context, 0 … K-1; stable: a context keeps its index as K grows.")
    label: str | None = Field(description="The name an operator gave it (PATCH …/contexts/{context}), or null.")
    scene_count: int = Field(description="Learned scenes whose most probable context this is (current assignments).")
    top_concepts: list[ConceptProbability] = Field(description="The most probable concepts, by P(c | χ).")
    distinctive_concepts: list[DistinctiveConcept] = Field(
        description="The concepts that set this context apart, by relevance at the request's λ."
    )


class ContextsRead(ReadSchema):
    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "model_id": "3f2c0b9e5d7a4e1f8a6b2c4d9e0f1a2b",
                    "context_count": 1,
                    "scene_count": 4,
                    "relevance_weight": 0.6,
                    "contexts": [
                        {
                            "context": 0,
                            "label": "kitchen",
                            "scene_count": 4,
                            "top_concepts": [{"name": "cup", "kind": "noun", "probability": 0.21}],
                            "distinctive_concepts": [
                                {"name": "pour", "kind": "verb", "probability": 0.08, "relevance": -1.9}
                            ],
                        }
                    ],
                }
            ]
        }
    )

    model_id: str
    context_count: int
    scene_count: int
    relevance_weight: float = Field(description="The λ the distinctive concepts were ranked with.")
    contexts: list[ContextRead]
