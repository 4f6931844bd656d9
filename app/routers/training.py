"""Training: labelled objects in, prototypes and concept web fitted, the prototype table out."""

from __future__ import annotations

from fastapi import APIRouter, Response, status

from app.deps import (
    AdmissionDep,
    BodySizeDep,
    IdempotencyKey,
    ModelDep,
    ReadAccess,
    StateDep,
    WriteAccess,
    WriteModelDep,
    WriteRate,
    model_write,
    write_model,
)
from app.errors import (
    Forbidden,
    IdempotencyKeyReused,
    InvalidInput,
    ModelBusy,
    ModelNotFitted,
    ModelNotFound,
    PayloadTooLarge,
    RateLimited,
    StorageBusy,
    Unauthorized,
    error_responses,
)
from app.registry import ModelRuntime
from app.routing import JsonBodyRoute
from app.schemas.training import FitCreate, FitRead, PrototypeTableRead, TrainingBatchCreate, TrainingBatchRead
from app.services import training as training_service
from app.state import AppState
from storage.database import autocommit_reads

router = APIRouter(prefix="/v1/models/{model_id}", tags=["training"], route_class=JsonBodyRoute)
_WRITE_ERRORS = (InvalidInput, ModelNotFound, Unauthorized, Forbidden, ModelBusy, RateLimited, StorageBusy)


@router.post(
    "/training-objects",
    status_code=status.HTTP_201_CREATED,
    summary="Add labelled training objects (entity/effect vectors or raw payloads)",
    dependencies=[WriteAccess, WriteRate],
    responses=error_responses(*_WRITE_ERRORS, PayloadTooLarge, IdempotencyKeyReused),
)
async def add_training_objects(
    body: TrainingBatchCreate,
    model: WriteModelDep,
    state: StateDep,
    admission: AdmissionDep,
    body_bytes: BodySizeDep,
    response: Response,
    idempotency_key: IdempotencyKey = None,
) -> TrainingBatchRead:
    """With an Idempotency-Key, a retry with the same body is answered as the batch first was, with
    `Idempotent-Replayed: true`, and adds nothing (keys are per model, as for scenes)."""
    added = await admission.run_write(
        model.id, _add_training_objects, state, model, body, idempotency_key, body_bytes=body_bytes
    )
    if added.replayed:
        response.headers["Idempotent-Replayed"] = "true"
    return added.answer


def _add_training_objects(
    state: AppState, model: ModelRuntime, body: TrainingBatchCreate, idempotency_key: str | None
) -> training_service.AddedBatch:
    """The batch's rows computed first (raw payloads' features: seconds), then stored in one unit
    of work of its model; a replay changes nothing (no new version)."""
    prepared = training_service.prepare_training_objects(model, body)
    with model_write(state, model) as write:
        added = training_service.add_training_objects(write.session, model, body, idempotency_key, prepared)
        write.unchanged = added.replayed
        return added


@router.post(
    "/fit",
    summary="Fit prototypes, concept web and behaviour effects from the training objects",
    dependencies=[WriteAccess, WriteRate],
    responses=error_responses(*_WRITE_ERRORS, ModelNotFitted),
)
async def fit(model: WriteModelDep, state: StateDep, admission: AdmissionDep, body: FitCreate | None = None) -> FitRead:
    return await admission.run_write(model.id, _fit, state, model, body or FitCreate())


def _fit(state: AppState, model: ModelRuntime, options: FitCreate) -> FitRead:
    """The fit computed from one read of the training objects, outside the model's write (seconds,
    which on SQLite would hold every model's writes), then stored in one unit of work of its model
    (recomputed there only if objects were added meanwhile: ``training_service.fit``)."""
    with autocommit_reads(state.read_sessions) as session:
        prepared = training_service.prepare_fit(session, model, options)
    return write_model(state, model, lambda session: training_service.fit(session, model, options, prepared))


@router.get(
    "/prototypes",
    summary="The prototype table (Table VIII)",
    dependencies=[ReadAccess],
    responses=error_responses(ModelNotFound, ModelNotFitted, Unauthorized),
)
async def get_prototypes(model: ModelDep) -> PrototypeTableRead:
    return training_service.prototype_table(model)
