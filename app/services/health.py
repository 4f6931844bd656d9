"""Readiness: every model is in memory, the database answers and can take a write.

The probe's write waits at most :data:`PROBE_LOCK_WAIT_MS` for SQLite's write lock. When
another connection holds it longer (an outside ``sqlite3`` shell, a backup, a long
transaction of another process), the service stays **ready** and the lock is logged:
the database is up, reads are served from WAL snapshots, and writes answer a prompt
503 ``storage_busy`` that clients retry; reporting not ready would take every process
sharing the database out of its load balancer at once for a transient lock. A failed
probe for any other reason (full disk, I/O error, read-only file) is not ready.
"""

from __future__ import annotations

import logging

from sqlalchemy.exc import SQLAlchemyError

from app.errors import NotReady, is_storage_busy, is_storage_failure, storage_failure_reason
from app.schemas.health import ReadinessRead
from app.state import AppState
from storage.database import with_lock_wait
from storage.repositories import health as health_repository
from storage.unit_of_work import unit_of_work

logger = logging.getLogger("contextweb")

#: Milliseconds the probe's write waits for SQLite's write lock (``/readyz`` must answer promptly).
PROBE_LOCK_WAIT_MS = 100


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
            with unit_of_work(with_lock_wait(state.write_sessions, PROBE_LOCK_WAIT_MS)) as session:
                health_repository.probe_write(session, storage.process_id)
        except SQLAlchemyError as error:
            if not is_storage_failure(error):
                raise
            if is_storage_busy(error):
                logger.warning("readiness probe: the database's write lock is held elsewhere; writes wait for it")
            else:
                storage.record_probe(storage_failure_reason(error))
        else:
            storage.record_probe(None)
    if storage.failure is not None:
        raise NotReady(f"the database cannot take a write: {storage.failure}")
    return ReadinessRead(status="ready", models_loaded=len(state.registry))
