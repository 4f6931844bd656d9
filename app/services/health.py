"""Readiness: every model is in memory, the database answers and can take a write."""

from __future__ import annotations

from sqlalchemy.exc import SQLAlchemyError

from app.errors import NotReady, is_storage_failure, storage_failure_reason
from app.schemas.health import ReadinessRead
from app.state import AppState
from storage.repositories import health as health_repository
from storage.unit_of_work import unit_of_work


def readiness(state: AppState) -> ReadinessRead:
    if not state.models_loaded:
        raise NotReady("models are still loading")
    storage = state.storage
    try:
        with state.read_sessions() as session:
            health_repository.ping(session)
    except SQLAlchemyError as error:
        raise NotReady(f"database unreachable: {storage_failure_reason(error)}") from None
    if storage.probe_due():
        try:
            with unit_of_work(state.write_sessions) as session:
                health_repository.probe_write(session, storage.process_id)
        except SQLAlchemyError as error:
            if not is_storage_failure(error):
                raise
            storage.record_probe(storage_failure_reason(error))
        else:
            storage.record_probe(None)
    if storage.failure is not None:
        raise NotReady(f"the database cannot take a write: {storage.failure}")
    return ReadinessRead(status="ready", models_loaded=len(state.registry))
