"""Sensor payloads to the feature vectors of Table III."""

from core.features.layout import EFFECT_LAYOUT, EFFECT_SIZE, ENTITY_LAYOUT, ENTITY_SIZE, VISUAL

__all__ = ["EFFECT_LAYOUT", "EFFECT_SIZE", "ENTITY_LAYOUT", "ENTITY_SIZE", "VISUAL"]
