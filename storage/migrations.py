"""Bring a database to the latest schema with Alembic (``alembic upgrade head``), or check it is there.

``contextweb migrate`` (which the container's entry point and ``make run`` call) and the
tests' database fixtures run :func:`upgrade_to_head`: the migrations are the only schema
source, and they run in one place. ``contextweb serve``, the app's lifespan and
``contextweb keys`` and ``contextweb models`` only check the schema (:func:`require_schema_at_head`) and refuse to
work on a database that is not at the head revision.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from alembic.config import Config
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory
from sqlalchemy import Engine, text
from sqlalchemy.orm import Session, sessionmaker

from alembic import command
from storage.database import PROJECT_ROOT, create_database_engine, create_session_makers

ALEMBIC_DIRECTORY = PROJECT_ROOT / "alembic"


def alembic_config() -> Config:
    config = Config()
    config.set_main_option("script_location", str(ALEMBIC_DIRECTORY))
    return config


#: The PostgreSQL advisory lock that serialises migrations of one database (any constant will do).
MIGRATION_LOCK_KEY = 0x636F6E74657874  # "context"


def upgrade_to_head(engine: Engine) -> None:
    """Apply every migration not yet applied to ``engine``'s database.

    Several processes may start at once on one database (replicas, ``--workers``): on
    PostgreSQL the migration holds a transaction-level advisory lock, so the second one waits
    for the first to commit and then finds nothing to do (without it, two concurrent upgrades
    raced on ``alembic_version``). SQLite's migration transaction takes the file's write lock.
    """
    config = alembic_config()
    with engine.begin() as connection:
        if connection.dialect.name == "postgresql":
            connection.execute(text("SELECT pg_advisory_xact_lock(:key)"), {"key": MIGRATION_LOCK_KEY})
        config.attributes["connection"] = connection
        command.upgrade(config, "head")


class SchemaNotAtHead(RuntimeError):
    """The database's schema is not at the migrations' head revision: ``contextweb migrate`` has not run."""

    def __init__(self, current: str | None, head: str) -> None:
        self.current = current
        self.head = head
        at = f"at revision {current}" if current else "empty (no revision)"
        super().__init__(f"the database schema is {at}, not at the head revision {head}: run `contextweb migrate`")


def schema_revisions(engine: Engine) -> tuple[str | None, str]:
    """(the revision ``engine``'s database is at, or None for an empty one; the migrations' head)."""
    head = ScriptDirectory.from_config(alembic_config()).get_current_head()
    assert head is not None, "alembic/versions holds the migrations"
    with engine.connect() as connection:
        return MigrationContext.configure(connection).get_current_revision(), head


def require_schema_at_head(engine: Engine) -> None:
    """Raise :class:`SchemaNotAtHead` unless ``engine``'s database is at the head revision."""
    current, head = schema_revisions(engine)
    if current != head:
        raise SchemaNotAtHead(current, head)


@contextmanager
def sessions_at_head(
    url: str, *, sqlite_synchronous: str = "FULL"
) -> Iterator[tuple[sessionmaker[Session], sessionmaker[Session]]]:
    """The read and write session makers of a one-off command (``contextweb keys``, ``contextweb
    models``) on the database at ``url``, which must be at the head revision (else
    :class:`SchemaNotAtHead`: one line and exit 75, app/cli.py); the engine is disposed after."""
    engine = create_database_engine(url, sqlite_synchronous=sqlite_synchronous)
    try:
        require_schema_at_head(engine)
        yield create_session_makers(engine)
    finally:
        engine.dispose()
