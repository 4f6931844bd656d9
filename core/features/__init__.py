"""Sensor payloads to the feature vectors of Table III."""

from core.features.extract import (
    SurfaceEstimate,
    audio_features,
    effect_features,
    entity_features,
    finger_statistics,
    recording_features,
    surface_estimate,
    visual_features,
)
from core.features.layout import (
    EFFECT_LAYOUT,
    EFFECT_SIZE,
    ENTITY_LAYOUT,
    ENTITY_SIZE,
    FINGER_STATISTICS,
    HISTOGRAM_BINS,
    MFCC_COEFFICIENTS,
    VISUAL,
)

__all__ = [
    "EFFECT_LAYOUT",
    "EFFECT_SIZE",
    "ENTITY_LAYOUT",
    "ENTITY_SIZE",
    "FINGER_STATISTICS",
    "HISTOGRAM_BINS",
    "MFCC_COEFFICIENTS",
    "VISUAL",
    "SurfaceEstimate",
    "audio_features",
    "effect_features",
    "entity_features",
    "finger_statistics",
    "recording_features",
    "surface_estimate",
    "visual_features",
]
