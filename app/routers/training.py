"""Training: labelled objects in, prototypes and concept web fitted, the prototype table out."""

from __future__ import annotations

from fastapi import APIRouter, status

from app.deps import ModelDep, ReadAccess, StateDep, WriteAccess, WriteModelDep, model_write
from app.errors import (
    Forbidden,
    InvalidInput,
    ModelNotFitted,
    ModelNotFound,
    PayloadTooLarge,
    Unauthorized,
    error_responses,
)
from app.schemas.training import FitCreate, FitRead, PrototypeTableRead, TrainingBatchCreate, TrainingBatchRead
from app.services import training as training_service

router = APIRouter(prefix="/v1/models/{model_id}", tags=["training"])
_WRITE_ERRORS = (InvalidInput, ModelNotFound, Unauthorized, Forbidden)


@router.post(
    "/training-objects",
    status_code=status.HTTP_201_CREATED,
    summary="Add labelled training objects (entity/effect vectors or raw payloads)",
    dependencies=[WriteAccess],
    responses=error_responses(*_WRITE_ERRORS, PayloadTooLarge),
)
def add_training_objects(body: TrainingBatchCreate, model: WriteModelDep, state: StateDep) -> TrainingBatchRead:
    with model_write(state, model) as write:
        return training_service.add_training_objects(write.session, model, body)


@router.post(
    "/fit",
    summary="Fit prototypes, concept web and behaviour effects from the training objects",
    dependencies=[WriteAccess],
    responses=error_responses(*_WRITE_ERRORS, ModelNotFitted),
)
def fit(model: WriteModelDep, state: StateDep, body: FitCreate | None = None) -> FitRead:
    with model_write(state, model) as write:
        return training_service.fit(write.session, model, body or FitCreate())


@router.get(
    "/prototypes",
    summary="The prototype table (Table VIII)",
    dependencies=[ReadAccess],
    responses=error_responses(ModelNotFound, ModelNotFitted, Unauthorized),
)
async def get_prototypes(model: ModelDep) -> PrototypeTableRead:
    return training_service.prototype_table(model)
