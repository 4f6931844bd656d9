"""Models: create, list, get, delete."""

from __future__ import annotations

from fastapi import APIRouter, Response, status

from app.deps import (
    AdmissionDep,
    IdempotencyKey,
    ModelDep,
    ReadAccess,
    ReadPrincipal,
    StateDep,
    WriteAccess,
    WriteModelDep,
    WriteRate,
    WriteSessionDep,
    write_model,
)
from app.errors import (
    Forbidden,
    IdempotencyKeyReused,
    InvalidInput,
    ModelBusy,
    ModelNotFound,
    RateLimited,
    StorageBusy,
    Unauthorized,
    error_responses,
)
from app.routing import JsonBodyRoute
from app.schemas.models import ModelCreate, ModelRead
from app.services import models as model_service

router = APIRouter(prefix="/v1/models", tags=["models"], route_class=JsonBodyRoute)
_AUTH = (Unauthorized, Forbidden)


@router.post(
    "",
    status_code=status.HTTP_201_CREATED,
    summary="Create a model",
    dependencies=[WriteAccess],
    responses=error_responses(InvalidInput, IdempotencyKeyReused, *_AUTH),
)
def create_model(
    body: ModelCreate,
    session: WriteSessionDep,
    state: StateDep,
    response: Response,
    idempotency_key: IdempotencyKey = None,
) -> ModelRead:
    """With an Idempotency-Key, a retry with the same body answers the model the first request created,
    as it is now, with `Idempotent-Replayed: true`; keys are one namespace for every client (use a UUID)."""
    created = model_service.create_model(session, state.registry, body, idempotency_key)
    if created.replayed:
        response.headers["Idempotent-Replayed"] = "true"
    return model_service.model_read(created.model)


@router.get("", summary="List the models (a scoped key's only)", responses=error_responses(Unauthorized))
def list_models(state: StateDep, principal: ReadPrincipal) -> list[ModelRead]:
    return [model_service.model_read(model) for model in state.registry.synchronise() if principal.covers(model.id)]


@router.get(
    "/{model_id}",
    summary="Get a model: hyperparameters, K, vocabulary size, scene count",
    dependencies=[ReadAccess],
    responses=error_responses(ModelNotFound, Unauthorized),
)
async def get_model(model: ModelDep) -> ModelRead:
    return model_service.model_read(model)


@router.delete(
    "/{model_id}",
    status_code=status.HTTP_204_NO_CONTENT,
    summary="Delete a model and everything it learned",
    dependencies=[WriteAccess, WriteRate],
    responses=error_responses(ModelNotFound, *_AUTH, ModelBusy, RateLimited, StorageBusy),
)
async def delete_model(model: WriteModelDep, state: StateDep, admission: AdmissionDep) -> None:
    await admission.run_write(
        model.id,
        write_model,
        state,
        model,
        lambda session: model_service.delete_model(session, state.registry, state.hub, state.purger, model),
    )
    if state.metrics is not None:
        state.metrics.model_deleted(model.id)  # its series go; its label is free for another model
