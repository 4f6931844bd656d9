"""The app factory: ``create_app(settings)`` builds the FastAPI app; its lifespan owns the state.

On start the lifespan creates the engine and the session makers, checks that the
database is at the latest schema (``contextweb migrate`` brings it there; the app never
migrates), reloads every model into memory, binds the websocket hub to the event
loop and starts the scene feed (app/feed.py) and the check that closes revoked keys' streams
(app/auth.py); on stop it stops them, closes the dashboards' sockets and disposes of the engine.

The process-wide preparation of a server (the numba warm-up and ``gc.freeze()``) is not the
factory's: ``contextweb serve`` does it before it builds the app (app/serve.py, ``serving_app``).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import TypedDict

import anyio
from fastapi import FastAPI
from fastapi.staticfiles import StaticFiles
from prometheus_client import CollectorRegistry
from prometheus_fastapi_instrumentator import Instrumentator

from app.admission import Admission, RefuseBusyWrites, admission_of
from app.auth import close_revoked_streams
from app.errors import InvalidInput, ModelUnavailable, StorageUnavailable, add_exception_handlers, error_responses
from app.feed import SceneFeed
from app.metrics import ModelMetrics
from app.middleware import RequestBodyLimits, UnexpectedErrors
from app.purge import ModelPurger
from app.registry import ModelRegistry
from app.routers import contexts, health, keys, models, plans, scenes, stream, training
from app.services.limits import VocabularyLimits
from app.settings import Settings
from app.state import AppState
from app.stream import StreamHub
from storage.database import create_database_engine, create_session_makers
from storage.migrations import require_schema_at_head

logger = logging.getLogger("contextweb")

#: The dashboard's built files (sources in frontend/, built with ``npm run build``).
DASHBOARD_DIRECTORY = Path(__file__).resolve().parent / "static"

API_DESCRIPTION = """\
Context for robots, as a service: concept webs (MRF + loopy BP) and Incremental-LDA
(Çelikkanat et al.). Each model learns the contexts of the scenes one robot posts,
online, and answers every scene with its concept webs and context posterior.
See docs/api.md for the request and response shapes, docs/stream.md for the websocket.
"""


class LifespanState(TypedDict):
    contextweb: AppState
    admission: Admission


def create_app(settings: Settings | None = None) -> FastAPI:
    """A new app for ``settings`` (read from the environment when omitted)."""
    settings = settings or Settings()

    @asynccontextmanager
    async def lifespan(_app: FastAPI) -> AsyncIterator[LifespanState]:
        anyio.to_thread.current_default_thread_limiter().total_tokens = settings.worker_threads
        state = await anyio.to_thread.run_sync(_start, settings)
        state.metrics = model_metrics.events
        admission = admission_of(settings)
        model_metrics.state.bind(state, admission)
        state.hub.bind(asyncio.get_running_loop())
        state.feed.start()
        await anyio.to_thread.run_sync(state.purger.start, state.read_sessions)
        revocations = asyncio.create_task(close_revoked_streams(state.hub, state.read_sessions))
        try:
            yield {"contextweb": state, "admission": admission}
        finally:
            revocations.cancel()
            await anyio.to_thread.run_sync(state.feed.stop)
            await anyio.to_thread.run_sync(state.purger.stop)
            state.hub.close_everyone("server shutting down")
            state.engine.dispose()

    app = FastAPI(
        title="Contextweb",
        version="1.0.0",
        description=API_DESCRIPTION,
        lifespan=lifespan,
    )
    add_exception_handlers(app)
    app.add_middleware(UnexpectedErrors)  # innermost: the others see an ordinary 500
    app.add_middleware(RefuseBusyWrites)  # inside the body limits: the body it drops is counted and timed by them
    app.add_middleware(
        RequestBodyLimits,
        max_bytes=settings.max_body_bytes,
        read_timeout_seconds=settings.body_read_timeout_seconds,
    )
    app.include_router(health.router)
    for router in (models.router, training.router, scenes.router, contexts.router, plans.router):
        app.include_router(router, responses=error_responses(InvalidInput, StorageUnavailable, ModelUnavailable))
    app.include_router(keys.router, responses=error_responses(InvalidInput, StorageUnavailable))
    app.include_router(stream.router)
    metrics_registry = CollectorRegistry()
    model_metrics = ModelMetrics(metrics_registry, settings.metrics_max_models)
    Instrumentator(registry=metrics_registry, excluded_handlers=["/metrics"]).instrument(app).expose(
        app, endpoint="/metrics", tags=["health"], summary="Prometheus metrics"
    )
    # Last: the dashboard at / must not shadow any API route.
    app.mount("/", StaticFiles(directory=DASHBOARD_DIRECTORY, html=True), name="dashboard")
    return app


def _start(settings: Settings) -> AppState:
    """Blocking start-up work, run off the event loop."""
    engine = create_database_engine(
        settings.resolved_database_url,
        sqlite_synchronous=settings.sqlite_synchronous,
        pool_size=settings.database_pool_size,
        sqlite_busy_timeout_ms=settings.sqlite_busy_timeout_ms,
        write_deadline_seconds=settings.write_deadline_seconds,
    )
    try:
        require_schema_at_head(engine)
    except BaseException:
        engine.dispose()
        raise
    read_sessions, write_sessions = create_session_makers(engine)
    hub = StreamHub(settings.stream_queue_size)
    state = AppState(
        settings=settings,
        engine=engine,
        read_sessions=read_sessions,
        write_sessions=write_sessions,
        registry=ModelRegistry(
            read_sessions,
            VocabularyLimits.from_settings(settings),
            checkpoint_interval=settings.checkpoint_interval,
            load_deadline_seconds=settings.load_deadline_seconds,
        ),
        hub=hub,
        feed=SceneFeed(hub, engine, read_sessions),
        purger=ModelPurger(write_sessions),
    )
    state.registry.load_all()
    logger.info("%d model(s) loaded from %s", len(state.registry), engine.url.render_as_string())
    state.models_loaded = True
    return state
