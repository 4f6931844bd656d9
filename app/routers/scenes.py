"""Scenes: learn one online, analyse one without learning, read the history."""

from __future__ import annotations

from functools import partial
from typing import Annotated

from fastapi import APIRouter, Path, Query, Response, status

from app.deps import (
    AdmissionDep,
    BodySizeDep,
    IdempotencyKey,
    ModelDep,
    ReadAccess,
    ReadSessionDep,
    StateDep,
    WriteAccess,
    WriteModelDep,
    WriteRate,
    model_write,
    write_or_postpone,
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
    SceneNotFound,
    StorageBusy,
    Unauthorized,
    error_responses,
)
from app.registry import ModelRuntime
from app.routing import JsonBodyRoute
from app.schemas.common import Page
from app.schemas.scenes import SceneCreate, SceneRead, SceneSummary
from app.services import scenes as scene_service
from app.state import AppState

router = APIRouter(prefix="/v1/models/{model_id}", tags=["scenes"], route_class=JsonBodyRoute)

_ANALYSIS_ERRORS = (InvalidInput, ModelNotFound, ModelNotFitted, PayloadTooLarge, Unauthorized)


@router.post(
    "/scenes",
    status_code=status.HTTP_201_CREATED,
    response_model=SceneRead,
    summary="Learn a scene online and answer its analysis",
    dependencies=[WriteAccess, WriteRate],
    responses=error_responses(*_ANALYSIS_ERRORS, IdempotencyKeyReused, Forbidden, ModelBusy, RateLimited, StorageBusy),
)
async def post_scene(
    body: SceneCreate,
    model: WriteModelDep,
    state: StateDep,
    admission: AdmissionDep,
    body_bytes: BodySizeDep,
    idempotency_key: IdempotencyKey = None,
) -> Response:
    answer, replayed, checkpoint = await admission.run_scene(
        model.id,
        partial(scene_service.read_scene, model, body, idempotency_key),
        partial(_learn_scene, state, model, idempotency_key),
        heavy=any(obj.raw is not None for obj in body.objects),
        body_bytes=body_bytes,
    )
    if checkpoint is not None:  # stored before the answer, so that the scene's 201 says it was tried
        await admission.run_follow_up(scene_service.store_checkpoint, state.write_sessions, model.id, checkpoint)
    headers = {"Idempotent-Replayed": "true"} if replayed else None
    return Response(answer, status.HTTP_201_CREATED, headers, media_type="application/json")


def _learn_scene(
    state: AppState, model: ModelRuntime, idempotency_key: str | None, read: scene_service.ReadScene
) -> scene_service.LearnedScene:
    """On the admitted scene thread: perception before the model's lock, the learning under it. If
    another process holds the model's lock (PostgreSQL), the wait for it and the learning are
    postponed to a write thread, so this process's scenes of other models need not wait for them."""
    prepared = scene_service.prepare_scene(model, read)
    return write_or_postpone(partial(_write_scene, state, model, idempotency_key, prepared))


def _write_scene(
    state: AppState,
    model: ModelRuntime,
    idempotency_key: str | None,
    prepared: scene_service.PreparedScene,
    wait: bool,
) -> scene_service.LearnedScene:
    """The prepared scene learned in one unit of work of its model (``wait``: app/deps.py ``model_write``);
    a checkpoint it took is for the route to store after the commit, outside the locks and on a
    write thread (``Admission.run_follow_up``): packing it takes seconds at a million scenes, and
    this scene thread is the one the process's other models wait for."""
    with model_write(state, model, wait=wait, idempotency_key=idempotency_key) as write:
        learned = scene_service.learn_scene(
            write.session, model, write.version, prepared, idempotency_key, write.locked, state.metrics
        )
        write.version_saved = write.notified = write.keeps_labels = not learned.replayed
        write.unchanged = learned.replayed
    return learned


@router.post(
    "/infer",
    summary="Analyse a scene without learning it",
    dependencies=[ReadAccess],
    responses=error_responses(*_ANALYSIS_ERRORS),
)
def infer_scene(body: SceneCreate, model: ModelDep, session: ReadSessionDep) -> SceneRead:
    return scene_service.infer_scene(model, body, session)


@router.get(
    "/scenes",
    summary="Scene history, in learning order",
    dependencies=[ReadAccess],
    responses=error_responses(ModelNotFound, Unauthorized),
)
def list_scenes(
    model: ModelDep,
    session: ReadSessionDep,
    offset: Annotated[int, Query(ge=0, le=2**31 - 1)] = 0,
    limit: Annotated[int, Query(ge=1, le=500)] = 50,
) -> Page[SceneSummary]:
    return scene_service.scene_history(session, model, offset=offset, limit=limit)


@router.get(
    "/scenes/{scene_id}",
    response_model=SceneRead,
    summary="One scene's stored analysis and context posterior",
    dependencies=[ReadAccess],
    responses=error_responses(ModelNotFound, SceneNotFound, Unauthorized),
)
def get_scene(model: ModelDep, session: ReadSessionDep, scene_id: Annotated[int, Path(ge=0, le=2**31 - 1)]) -> Response:
    return Response(scene_service.get_scene(session, model, scene_id), media_type="application/json")
