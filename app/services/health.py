"""Readiness: the database answers and every model is in memory."""

from __future__ import annotations

from sqlalchemy.exc import SQLAlchemyError
from sqlalchemy.orm import Session

from app.errors import NotReady
from app.schemas.health import ReadinessRead
from app.state import AppState
from storage.repositories import health as health_repository


def readiness(session: Session, state: AppState) -> ReadinessRead:
    if not state.models_loaded:
        raise NotReady("models are still loading")
    try:
        health_repository.ping(session)
    except SQLAlchemyError as error:
        raise NotReady(f"database unreachable: {type(error).__name__}") from None
    return ReadinessRead(status="ready", models_loaded=len(state.registry))
