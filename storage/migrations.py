"""Bring a database to the latest schema with Alembic (``alembic upgrade head``).

The server runs this on start, ``contextweb migrate`` runs it on demand, and the
tests build their databases with it: the migrations are the only schema source.
"""

from __future__ import annotations

from alembic.config import Config
from sqlalchemy import Engine

from alembic import command
from storage.database import PROJECT_ROOT

ALEMBIC_DIRECTORY = PROJECT_ROOT / "alembic"


def alembic_config() -> Config:
    config = Config()
    config.set_main_option("script_location", str(ALEMBIC_DIRECTORY))
    return config


def upgrade_to_head(engine: Engine) -> None:
    """Apply every migration not yet applied to ``engine``'s database."""
    config = alembic_config()
    with engine.begin() as connection:
        config.attributes["connection"] = connection
        command.upgrade(config, "head")
