"""API keys: one per robot or dashboard, with a role and a set of models (docs/api.md, "Keys")."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Literal

from pydantic import Field, StringConstraints

from app.schemas.common import ReadSchema, RequestSchema
from app.schemas.observations import Name

Role = Literal["read", "write", "admin"]
#: A model id as the paths take it (app/deps.py ``ModelId``).
ScopedModelId = Annotated[str, StringConstraints(min_length=1, max_length=64)]
#: More models than one key needs; bounds the work of checking them.
MAX_MODELS_PER_KEY = 1000


class ApiKeyCreate(RequestSchema):
    name: Name = Field(description="Who holds the key (a robot, a dashboard).", examples=["icub-7"])
    role: Role = Field(
        description="read < write < admin; admin also manages keys and is never scoped to models.", examples=["write"]
    )
    models: list[ScopedModelId] | None = Field(
        None,
        min_length=1,
        max_length=MAX_MODELS_PER_KEY,
        description="The ids of the models the key may use (they must exist); null: every model, present and future.",
        examples=[["3f2c0b9e5d7a4e1f8a6b2c4d9e0f1a2b"]],
    )


class ApiKeyRead(ReadSchema):
    id: str = Field(description="The key's lookup id (the part after `cw_`); used to revoke it.")
    name: str
    role: Role
    models: list[str] | None = Field(description="null: every model.")
    prefix: str = Field(description="The key's first characters, to recognise it; never the whole secret.")
    created_at: datetime
    revoked_at: datetime | None


class ApiKeyCreated(ApiKeyRead):
    key: str = Field(description="The key to send in X-API-Key. Shown once: only its SHA-256 is stored.")
