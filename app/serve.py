"""``contextweb serve`` and ``contextweb migrate``: run the service, or bring its database up to date.

The two are separate steps: ``migrate`` is the only command that changes the schema (the
container's entry point and ``make run`` call it before ``serve``), and ``serve`` refuses a
database that is not at the head revision (exit 75, app/cli.py) instead of migrating it.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from typing import TYPE_CHECKING, Any

from sqlalchemy.exc import OperationalError

from app.connections import WorkerListener, create_counts, set_header_read_timeout
from app.logs import LOG_FORMAT, log_config
from app.settings import LOOPBACK_HOSTS, Settings
from storage.database import create_database_engine
from storage.migrations import require_schema_at_head, upgrade_to_head

if TYPE_CHECKING:
    from fastapi import FastAPI

logger = logging.getLogger("contextweb")


def add_serve_arguments(serve: argparse.ArgumentParser) -> None:
    serve.add_argument("--host", help="interface to bind (default CONTEXTWEB_HOST or 127.0.0.1)")
    serve.add_argument("--port", type=int, help="port to listen on (default CONTEXTWEB_PORT or 8000)")
    serve.add_argument("--log-level", default="info", choices=["critical", "error", "warning", "info", "debug"])
    serve.add_argument(
        "--workers",
        type=int,
        default=1,
        help="worker processes sharing the port; they coordinate through the database (docs/scaling.md)",
    )


#: sysexits' EX_UNAVAILABLE: the database cannot be reached; a restart policy may try again.
EXIT_DATABASE_UNAVAILABLE = 69


def run_migrate(_args: argparse.Namespace) -> int:
    # Only the database settings matter to a migration: a one-shot migrating container (compose's
    # `migrate`, an init container) runs the production image without the keys it never uses.
    settings = Settings(environment="development")
    engine = create_database_engine(settings.resolved_database_url, sqlite_synchronous=settings.sqlite_synchronous)
    try:
        upgrade_to_head(engine)
    except OperationalError as error:
        return _database_unavailable("migrate", engine.url.render_as_string(), error)
    finally:
        engine.dispose()
    print(f"{engine.url.render_as_string()} is at the latest schema")
    return 0


def _database_unavailable(command: str, url: str, error: OperationalError) -> int:
    """One line, not a traceback: a container restarting while its database is down would
    otherwise log a hundred lines a try (docs/deployment.md)."""
    reason = str(error.orig or error).strip().splitlines()[0]
    print(f"contextweb {command}: the database {url} cannot be reached: {reason}", file=sys.stderr)
    return EXIT_DATABASE_UNAVAILABLE


def _check_database(settings: Settings) -> int | None:
    """Before any worker starts: the exit status if the database cannot be reached, else None;
    :class:`~storage.migrations.SchemaNotAtHead` (one line and exit 75, app/cli.py) if it is not
    migrated. ``serve`` never migrates: ``contextweb migrate`` does, once, before it."""
    engine = create_database_engine(settings.resolved_database_url, sqlite_synchronous=settings.sqlite_synchronous)
    try:
        require_schema_at_head(engine)
        return None
    except OperationalError as error:
        return _database_unavailable("serve", engine.url.render_as_string(), error)
    finally:
        engine.dispose()


def serving_app(settings: Settings | None = None) -> FastAPI:
    """The app a serving process runs: this process's numba kernels warmed up and its start-up
    objects frozen out of the garbage collector (app/services/warmup.py), then
    :func:`app.main.create_app`. uvicorn calls it in every worker process (``--workers N``), so
    each worker is warm before it accepts a connection; ``create_app`` itself stays a plain factory.

    FastAPI builds a route's parameter and body fields on the route's first request (≈ 30 ms of
    that request, docs/benchmarks.md); building the OpenAPI document builds every route's here.
    It also keeps that building off the request threads, where FastAPI's
    ``warnings.catch_warnings()`` around it (not thread-safe) could meet another thread's.

    The freeze comes before the app's lifespan loads the stored models: they are made after it,
    like the models a serving process creates later, and their cyclic garbage stays collectable.
    """
    from app.main import create_app
    from app.services.warmup import freeze_start_up_objects, warm_up_kernels

    settings = settings or Settings()
    set_header_read_timeout(settings.header_read_timeout_seconds)  # before the process accepts a connection
    warm_up_kernels()  # before /readyz says ready: a first request must not wait for numba to compile
    app = create_app(settings)
    app.openapi()  # nor for FastAPI to build its route's fields
    freeze_start_up_objects()  # and must not stall on a full collection of start-up's objects
    return app


def run_serve(args: argparse.Namespace) -> int:
    """Check the database, then serve on uvicorn; without API keys, only on loopback (and say so)."""
    import uvicorn
    from uvicorn.supervisors import Multiprocess

    overrides: dict[str, Any] = {name: value for name in ("host", "port") if (value := getattr(args, name)) is not None}
    settings = Settings(**overrides)
    logging.basicConfig(level=args.log_level.upper(), format=LOG_FORMAT)  # until uvicorn applies log_config
    host = settings.bind_host()
    if not settings.auth_enabled:
        moved = f" (not {settings.host})" if settings.host not in LOOPBACK_HOSTS else ""
        logger.warning(
            "no CONTEXTWEB_WRITE_KEY configured: every route is open, so the server binds %s only%s",
            host,
            moved,
        )
    if args.workers < 1:
        raise SystemExit("contextweb serve: --workers must be at least 1")
    if (status := _check_database(settings)) is not None:
        return status
    options: dict[str, Any] = {
        "host": host,
        "port": settings.port,
        "log_level": args.log_level,
        "log_config": log_config(args.log_level),
        "access_log": False,
        "ws": "app.websocket_protocol:ResettableWebSocketProtocol",  # slow stream clients can be dropped (docs/stream.md)
        "http": "app.connections:HeaderDeadlineProtocol",  # stalled headers are cut (app/connections.py)
    }
    if args.workers == 1:
        uvicorn.run(serving_app(settings), **options)
        return 0
    # Each worker builds its own app from the environment (uvicorn imports the factory by name).
    os.environ.update({f"CONTEXTWEB_{name.upper()}": str(value) for name, value in overrides.items()})
    # Each worker on its own socket of the port, its keep-alive connections evened out (app/connections.py).
    worker_options = options | {"http": "app.connections:BalancedHttpToolsProtocol"}
    config = uvicorn.Config("app.serve:serving_app", factory=True, workers=args.workers, **worker_options)
    try:
        listener = WorkerListener.bind_to(host, settings.port)
    except OSError as error:
        print(f"contextweb serve: cannot listen on {host}:{settings.port}: {error.strerror}", file=sys.stderr)
        return 1
    counts = create_counts(os.getpid(), args.workers)
    try:
        logger.info("serving on http://%s:%d with %d workers", host, listener.getsockname()[1], args.workers)
        Multiprocess(config, sockets=[listener]).run()
    finally:
        counts.unlink(missing_ok=True)
        listener.close()
    return 0
