"""Liveness and readiness probes (the Prometheus metrics are mounted by app/main.py)."""

from __future__ import annotations

from fastapi import APIRouter

from app.deps import StateDep
from app.errors import NotReady, error_responses
from app.schemas.health import HealthRead, ReadinessRead
from app.services import health as health_service

router = APIRouter(tags=["health"])


@router.get("/healthz", summary="Liveness: the process answers")
async def healthz() -> HealthRead:
    return HealthRead(status="ok")


@router.get(
    "/readyz",
    summary="Readiness: models loaded, database reachable and taking writes",
    responses=error_responses(NotReady),
)
def readyz(state: StateDep) -> ReadinessRead:
    return health_service.readiness(state)
