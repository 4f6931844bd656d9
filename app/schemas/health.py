"""Probe answers."""

from __future__ import annotations

from typing import Literal

from pydantic import ConfigDict

from app.schemas.common import ReadSchema


class HealthRead(ReadSchema):
    model_config = ConfigDict(json_schema_extra={"examples": [{"status": "ok"}]})

    status: Literal["ok"]


class ReadinessRead(ReadSchema):
    model_config = ConfigDict(json_schema_extra={"examples": [{"status": "ready", "models_loaded": 2}]})

    status: Literal["ready"]
    models_loaded: int
