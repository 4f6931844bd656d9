"""What a robot observed of one object, at the feature or the raw level (shared by scenes and training).

Features are the vectors of Table III: an entity vector e (91 values) and, per
behaviour applied, an effect vector f (66 values). Raw payloads follow
:mod:`core.payloads` (metres in the table frame, mono PCM in [-1, 1], finger
series); every array is either a JSON array or a base64 string of little-endian
float32 values (point clouds: x, y, z of each point in turn).
"""

from __future__ import annotations

import base64
import binascii
from typing import Annotated, Any, ClassVar, TypeVar

import numpy as np
from pydantic import AfterValidator, Field, StringConstraints, field_validator, model_validator

from app.schemas.common import NO_CONTROL_CHARACTERS, ArrayOrBase64, FiniteFloat, RequestSchema
from core.features.layout import EFFECT_SIZE, ENTITY_SIZE
from core.payloads import MAX_SAMPLE_RATE, MIN_SAMPLE_RATE

#: A name stored in the database: no control characters (PostgreSQL text refuses NUL).
Name = Annotated[str, StringConstraints(min_length=1, max_length=200, pattern=NO_CONTROL_CHARACTERS)]
#: A behaviour of the model's repertoire (one of its verbs, e.g. ``push_left``).
BehaviourName = Annotated[Name, Field(examples=["push_left"])]


def _decodable_float32(text: str) -> str:
    """Check (not convert) a base64 float32 array, so the body stays hashable as sent."""
    decode_float32(text)
    return text


def decode_float32(text: str) -> np.ndarray:
    """The float64 values of a base64 string of little-endian float32; ValueError names the problem."""
    try:
        raw = base64.b64decode(text, validate=True)
    except (binascii.Error, ValueError):
        raise ValueError("is not valid base64") from None
    if len(raw) % 4:
        raise ValueError(f"decodes to {len(raw)} bytes, not a whole number of float32 values")
    values = np.frombuffer(raw, dtype="<f4").astype(np.float64)
    if not np.isfinite(values).all():
        raise ValueError("contains NaN or infinite values")
    return values


#: A base64 string of little-endian float32 values.
Base64Floats = Annotated[
    str,
    StringConstraints(min_length=1),
    AfterValidator(_decodable_float32),
    Field(description="Base64 of little-endian float32 values.", examples=["AACAPwAAAEA="]),
]
FloatSeries = ArrayOrBase64[Annotated[list[FiniteFloat], Field(min_length=1)], Base64Floats]
Point = Annotated[list[FiniteFloat], Field(min_length=3, max_length=3)]
Points = ArrayOrBase64[Annotated[list[Point], Field(min_length=1)], Base64Floats]

EntityVector = Annotated[
    list[FiniteFloat],
    Field(min_length=ENTITY_SIZE, max_length=ENTITY_SIZE, description="Entity vector e of Table III (91 values)."),
]
EffectVector = Annotated[
    list[FiniteFloat],
    Field(min_length=EFFECT_SIZE, max_length=EFFECT_SIZE, description="Effect vector f = e'_v - e_v (66 values)."),
]


def as_array(values: list[float] | list[list[float]] | str) -> np.ndarray:
    """A JSON array or a base64 float32 string as a float64 array."""
    if isinstance(values, str):
        return decode_float32(values)
    return np.asarray(values, dtype=np.float64)


class ObjectFeatures(RequestSchema):
    """An object at the feature level: its entity vector and the effect of each behaviour applied."""

    entity: EntityVector
    effects: dict[BehaviourName, EffectVector] = Field(
        default_factory=dict, description="Effect vector of each behaviour applied, keyed by behaviour."
    )


class PointCloudIn(RequestSchema):
    points: Points = Field(description="(n, 3) xyz rows in metres, or base64 float32 x0 y0 z0 x1 …")

    @field_validator("points")
    @classmethod
    def _whole_points(cls, points: list[list[float]] | str) -> list[list[float]] | str:
        if isinstance(points, str) and decode_float32(points).size % 3:
            raise ValueError("base64 points must hold a multiple of 3 values (x, y, z per point)")
        return points

    def array(self) -> np.ndarray:
        return as_array(self.points).reshape(-1, 3)


class AudioIn(RequestSchema):
    samples: FloatSeries = Field(description="Mono PCM in [-1, 1].")
    sample_rate: int = Field(ge=MIN_SAMPLE_RATE, le=MAX_SAMPLE_RATE, description="Hz.")


class FingerIn(RequestSchema):
    haptic: FloatSeries = Field(description="Index-finger tactile pressure during the grasp.")
    proprioceptive: FloatSeries = Field(description="Index-finger joint angle (radians), same instants.")


class InteractionIn(RequestSchema):
    behaviour: BehaviourName
    before: PointCloudIn
    after: PointCloudIn
    audio: AudioIn | None = Field(None, description="Recorded while shaking.")
    finger: FingerIn | None = Field(None, description="Recorded while grasping.")


class RawObject(RequestSchema):
    """An object at the raw level: the first look and every interaction (§II-C)."""

    look: PointCloudIn
    interactions: list[InteractionIn] = Field(default_factory=list, max_length=64)


Level = TypeVar("Level", bound=str)


def only_one_level(values: dict[str, Any], levels: tuple[Level, ...]) -> Level:
    """The one level given in ``values`` (a ValueError when none or several are)."""
    given = [level for level in levels if values.get(level) is not None]
    if len(given) != 1:
        raise ValueError(f"give exactly one of {', '.join(levels)} (got {', '.join(given) or 'none'})")
    return given[0]


class OneLevel(RequestSchema):
    """An object observed at exactly one of the levels named in ``levels``."""

    levels: ClassVar[tuple[str, ...]]

    @model_validator(mode="before")
    @classmethod
    def _one_level(cls, values: Any) -> Any:
        if isinstance(values, dict):
            only_one_level(values, cls.levels)
        return values
