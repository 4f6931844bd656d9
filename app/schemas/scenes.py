"""Scenes: what a robot posts (objects at three levels, mixed freely) and the analysis it gets back."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Literal

from pydantic import ConfigDict, Field
from pydantic.json_schema import JsonDict

from app.schemas.common import ListOrMap, Probability, ReadSchema, RequestSchema
from app.schemas.observations import Name, ObjectFeatures, OneLevel, RawObject, only_one_level

#: The kinds of concept of §III (``core.vocabulary.CONCEPT_KINDS``).
ConceptKind = Literal["noun", "adjective", "verb"]
ObjectLevel = Literal["concepts", "features", "raw"]
OBJECT_LEVELS: tuple[ObjectLevel, ...] = ("concepts", "features", "raw")
MAX_OBJECTS_PER_SCENE = 64
MAX_CONCEPTS_PER_OBJECT = 256
#: Decimal places of every probability an answer reports (``context_posterior`` and the objects' stages):
#: far below the sampler's and loopy BP's own accuracy, and most of a stored answer's bytes otherwise
#: (docs/api.md, "Precision of answers").
ANSWER_DECIMALS = 6

ConceptNames = Annotated[list[Name], Field(min_length=1, max_length=MAX_CONCEPTS_PER_OBJECT)]
ConceptProbabilities = Annotated[dict[Name, Probability], Field(min_length=1, max_length=MAX_CONCEPTS_PER_OBJECT)]


class SceneObject(OneLevel):
    """One object of a scene, at exactly one of three levels."""

    levels = OBJECT_LEVELS

    concepts: ListOrMap[ConceptNames, ConceptProbabilities] | None = Field(
        None,
        description=(
            "Concept level, for robots with their own recognisers: the names of the object's active concepts, "
            "or a map name -> probability of being active. Names the model has not seen grow its vocabulary."
        ),
    )
    kinds: dict[Name, ConceptKind] = Field(
        default_factory=dict,
        description="Kind of concept names the model's vocabulary does not have (shown in context listings).",
    )
    features: ObjectFeatures | None = Field(None, description="Feature level: Table III vectors.")
    raw: RawObject | None = Field(None, description="Raw level: point clouds, audio and finger series.")

    @property
    def level(self) -> ObjectLevel:
        return only_one_level({"concepts": self.concepts, "features": self.features, "raw": self.raw}, OBJECT_LEVELS)


SCENE_EXAMPLE: JsonDict = {
    "objects": [
        {"concepts": ["cup", "hard", "silent", "short", "thick", "round", "grasp", "move_left"]},
        {"concepts": {"plate": 0.9, "cup": 0.1, "hard": 0.8, "soft": 0.2}},
        {"features": {"entity": [0.0] * 91, "effects": {"move_left": [0.0] * 66}}},
    ]
}


class SceneCreate(RequestSchema):
    """A scene: the objects the robot perceives together (an LDA document, §IV-B)."""

    model_config = ConfigDict(json_schema_extra={"examples": [SCENE_EXAMPLE]})

    objects: list[SceneObject] = Field(min_length=1, max_length=MAX_OBJECTS_PER_SCENE)


class ObjectAnalysis(ReadSchema):
    """One object's concept web: the probability of each concept at each stage of Fig. 6(b), rounded to
    ``ANSWER_DECIMALS`` places."""

    level: ObjectLevel
    active_concepts: list[str] = Field(description="The MAP concepts: the words this object adds to the scene.")
    perception: dict[str, float] = Field(
        description="P(c) from the recogniser (concept level) or the prototypes (Eq. 1)."
    )
    web: dict[str, float] | None = Field(
        description="P(c) after loopy BP on the concept web; null when none is fitted."
    )
    in_context: dict[str, float] | None = Field(
        description="P(c)* of Eq. 6 (context fed back into the web); null until context feedback is available."
    )


class SceneRead(ReadSchema):
    """The analysis of a scene: per-object concept webs and the context posterior P(χ | scene).

    Every probability is rounded to ``ANSWER_DECIMALS`` places; ``map_context`` and the active
    concepts are decided on the full-precision values."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "model_id": "3f2c0b9e5d7a4e1f8a6b2c4d9e0f1a2b",
                    "scene_id": 41,
                    "learned": True,
                    "context_count": 3,
                    "previous_context_count": 3,
                    "context_posterior": [0.91, 0.05, 0.04],
                    "map_context": 0,
                    "objects": [
                        {
                            "level": "concepts",
                            "active_concepts": ["cup", "hard"],
                            "perception": {"cup": 1.0, "hard": 1.0},
                            "web": None,
                            "in_context": None,
                        }
                    ],
                    "created_at": "2025-01-01T12:00:00Z",
                }
            ]
        }
    )

    model_id: str
    scene_id: int | None = Field(description="Index of the scene in the model (null for inference).")
    learned: bool = Field(description="True when the model learned the scene, false for /infer.")
    context_count: int = Field(description="K after this scene.")
    previous_context_count: int = Field(description="K before this scene; larger K means a context was discovered.")
    context_posterior: list[float] = Field(
        description="θ = P(χ | scene) over the K contexts, rounded to 6 decimal places (may not sum to 1 exactly)."
    )
    map_context: int = Field(description="The most probable context (decided before rounding).")
    map_context_label: str | None = Field(
        None, description="The most probable context's label as it stood when the scene was answered, or null."
    )
    objects: list[ObjectAnalysis]
    created_at: datetime | None = None


class SceneSummary(ReadSchema):
    """One line of the scene history."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "scene_id": 41,
                    "context_count": 3,
                    "map_context": 0,
                    "context_posterior": [0.91, 0.05, 0.04],
                    "created_at": "2025-01-01T12:00:00Z",
                }
            ]
        }
    )

    scene_id: int = Field(validation_alias="id")
    context_count: int
    map_context: int
    context_posterior: list[float]
    created_at: datetime
