"""Contexts discovered by a model."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query

from app.deps import ModelDep, ReadAccess
from app.errors import ModelNotFound, Unauthorized, error_responses
from app.schemas.contexts import ContextsRead
from app.services import contexts as context_service
from core.context.metrics import RELEVANCE_WEIGHT

router = APIRouter(prefix="/v1/models/{model_id}", tags=["contexts"])


@router.get(
    "/contexts",
    summary="The contexts with their top and distinctive concepts, and scene counts",
    dependencies=[ReadAccess],
    responses=error_responses(ModelNotFound, Unauthorized),
)
def list_contexts(
    model: ModelDep,
    top: Annotated[int, Query(ge=1, le=1_000)] = 10,
    relevance_weight: Annotated[
        float,
        Query(
            alias="lambda",
            ge=0.0,
            le=1.0,
            description="λ of the relevance ranking: 1 ranks by P(c | χ), 0 by lift P(c | χ) / P(c).",
        ),
    ] = RELEVANCE_WEIGHT,
) -> ContextsRead:
    return context_service.list_contexts(model, top, relevance_weight)
