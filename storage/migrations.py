"""Bring a database to the latest schema with Alembic (``alembic upgrade head``).

The server runs this on start, ``contextweb migrate`` runs it on demand, and the
tests build their databases with it: the migrations are the only schema source.
"""

from __future__ import annotations

from alembic.config import Config
from sqlalchemy import Engine, text

from alembic import command
from storage.database import PROJECT_ROOT

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
