"""Messages of the websocket ``/v1/models/{id}/stream`` (docs/stream.md), server to client only."""

from __future__ import annotations

from datetime import datetime
from typing import Literal

from pydantic import Field

from app.schemas.common import ReadSchema


class HelloEvent(ReadSchema):
    """First message after connecting: where the model stands."""

    type: Literal["hello"] = "hello"
    model_id: str
    context_count: int
    scene_count: int


class SceneEvent(ReadSchema):
    """A scene was learned (and committed)."""

    type: Literal["scene"] = "scene"
    model_id: str
    scene_id: int
    context_count: int
    context_posterior: list[float]
    map_context: int
    map_context_label: str | None = Field(None, description="The label of the map context, as in the scene's answer.")
    active_concepts: list[list[str]] = Field(description="Active concepts of each object, in the scene's order.")
    created_at: datetime


class SceneUnreadableEvent(ReadSchema):
    """Scene ``scene_id`` was learned, but its stored answer cannot be read back (it was damaged after
    it was written): in its place in the order, so that the scenes after it follow."""

    type: Literal["scene_unreadable"] = "scene_unreadable"
    model_id: str
    scene_id: int
    detail: str


class ContextDiscoveredEvent(ReadSchema):
    """K grew: Incremental-LDA added a context while learning ``scene_id``."""

    type: Literal["context_discovered"] = "context_discovered"
    model_id: str
    scene_id: int
    context_count: int
    previous_context_count: int


class ModelFittedEvent(ReadSchema):
    """New prototypes and concept web were fitted from the training objects."""

    type: Literal["model_fitted"] = "model_fitted"
    model_id: str
    training_object_count: int
