"""Liveness and readiness probes (the Prometheus metrics are mounted by app/main.py)."""

from __future__ import annotations

import anyio
from fastapi import APIRouter

from app.deps import AdmissionDep, StateDep
from app.errors import NotReady, error_responses
from app.routing import JsonBodyRoute
from app.schemas.health import HealthRead, ReadinessRead
from app.services import health as health_service

router = APIRouter(tags=["health"], route_class=JsonBodyRoute)


@router.get("/healthz", summary="Liveness: the process answers")
async def healthz() -> HealthRead:
    return HealthRead(status="ok")


@router.get(
    "/readyz",
    summary="Readiness: models loaded, database reachable and taking writes",
    responses=error_responses(NotReady),
)
async def readyz(state: StateDep, admission: AdmissionDep) -> ReadinessRead:
    return await anyio.to_thread.run_sync(health_service.readiness, state, limiter=admission.probe_threads)
