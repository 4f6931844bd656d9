"""Contexts discovered by a model."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path, Query

from app.deps import (
    AdmissionDep,
    ModelDep,
    ReadAccess,
    ReadSessionDep,
    StateDep,
    WriteAccess,
    WriteModelDep,
    WriteRate,
    write_model,
)
from app.errors import (
    ContextNotFound,
    Forbidden,
    InvalidInput,
    ModelBusy,
    ModelNotFound,
    RateLimited,
    StorageBusy,
    Unauthorized,
    error_responses,
)
from app.routing import JsonBodyRoute
from app.schemas.contexts import ContextLabelRead, ContextLabelUpdate, ContextsRead
from app.services import contexts as context_service
from core.context.metrics import RELEVANCE_WEIGHT

router = APIRouter(prefix="/v1/models/{model_id}", tags=["contexts"], route_class=JsonBodyRoute)


@router.get(
    "/contexts",
    summary="The contexts with their top and distinctive concepts, and scene counts",
    dependencies=[ReadAccess],
    responses=error_responses(ModelNotFound, Unauthorized),
)
def list_contexts(
    model: ModelDep,
    session: ReadSessionDep,
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
    return context_service.list_contexts(session, model, top, relevance_weight)


@router.patch(
    "/contexts/{context}",
    summary="Name a context (the label stays on it as K grows)",
    dependencies=[WriteAccess, WriteRate],
    responses=error_responses(
        ModelNotFound, ContextNotFound, InvalidInput, Unauthorized, Forbidden, ModelBusy, RateLimited, StorageBusy
    ),
)
async def label_context(
    body: ContextLabelUpdate,
    model: WriteModelDep,
    state: StateDep,
    admission: AdmissionDep,
    context: Annotated[int, Path(ge=0, le=10_000, description="The context's index.")],
) -> ContextLabelRead:
    """A write of the model like any other (its lock, its version): K is current when the context is
    checked, and a label cannot race the model's deletion on another process into a server error."""
    return await admission.run_write(
        model.id,
        write_model,
        state,
        model,
        lambda session: context_service.label_context(session, model, context, body.label),
    )
