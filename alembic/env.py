"""Alembic environment: the URL comes from the caller, else from ``CONTEXTWEB_DATABASE_URL``.

``storage.migrations.upgrade_to_head`` hands over an open connection (so SQLite
gets the engine's pragmas); the ``alembic`` command line falls back to
``CONTEXTWEB_DATABASE_URL`` or the default SQLite file. Batch mode is on so that
later ``ALTER``s work on SQLite.
"""

from __future__ import annotations

import os
from logging.config import fileConfig
from typing import Any

from alembic import context
from storage.database import DEFAULT_DATABASE_URL, create_database_engine, normalise_url
from storage.models import Base

config = context.config
if config.config_file_name is not None and "connection" not in config.attributes:
    fileConfig(config.config_file_name)


def _database_url() -> str:
    return os.environ.get("CONTEXTWEB_DATABASE_URL") or DEFAULT_DATABASE_URL


def _run(connection: Any) -> None:
    context.configure(connection=connection, target_metadata=Base.metadata, render_as_batch=True, compare_type=True)
    with context.begin_transaction():
        context.run_migrations()


def run_migrations_online() -> None:
    connection = config.attributes.get("connection")
    if connection is not None:
        _run(connection)
        return
    engine = create_database_engine(_database_url())
    with engine.connect() as connection:
        _run(connection)
    engine.dispose()


def run_migrations_offline() -> None:
    context.configure(url=normalise_url(_database_url()), target_metadata=Base.metadata, render_as_batch=True)
    with context.begin_transaction():
        context.run_migrations()


if context.is_offline_mode():
    run_migrations_offline()
else:
    run_migrations_online()
