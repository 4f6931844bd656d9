"""Planning in context."""

from __future__ import annotations

from fastapi import APIRouter

from app.deps import ModelDep, ReadAccess, ReadSessionDep
from app.errors import InvalidInput, ModelNotFitted, ModelNotFound, SceneNotFound, Unauthorized, error_responses
from app.routing import JsonBodyRoute
from app.schemas.plans import PlanCreate, PlanRead
from app.services import plans as plan_service

router = APIRouter(prefix="/v1/models/{model_id}", tags=["planning"], route_class=JsonBodyRoute)


@router.post(
    "/plans",
    summary="Plan a move over the table, behaviours pruned by the context",
    dependencies=[ReadAccess],
    responses=error_responses(InvalidInput, ModelNotFound, SceneNotFound, ModelNotFitted, Unauthorized),
)
def make_plan(body: PlanCreate, model: ModelDep, session: ReadSessionDep) -> PlanRead:
    return plan_service.make_plan(session, model, body)
