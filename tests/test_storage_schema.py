"""The schema comes from the migrations, matches the ORM models, and follows the naming convention."""

from __future__ import annotations

import threading

import pytest
from alembic.autogenerate import compare_metadata
from alembic.migration import MigrationContext
from sqlalchemy import Engine, create_engine, inspect, text

from storage.database import create_database_engine
from storage.migrations import upgrade_to_head
from storage.models import Base


def test_migrations_create_exactly_the_orm_schema(engine: Engine) -> None:
    with engine.connect() as connection:
        differences = compare_metadata(MigrationContext.configure(connection), Base.metadata)
    assert differences == []


def test_upgrading_twice_is_a_no_op_and_names_follow_the_convention(engine: Engine) -> None:
    upgrade_to_head(engine)
    inspector = inspect(engine)
    tables = set(inspector.get_table_names())
    assert {
        "model",
        "incremental_lda_state",
        "word",
        "scene",
        "token_batch",
        "context_word_count",
        "training_object",
    } <= tables
    assert "token" not in tables  # alembic 0007: one token_batch row per write
    assert inspector.get_pk_constraint("token_batch")["name"] == "pk_token_batch"
    foreign_keys = {fk["name"] for fk in inspector.get_foreign_keys("scene")}
    assert foreign_keys == {"fk_scene_model_id_model"}
    unique = {index["name"] for index in inspector.get_indexes("scene") if index["unique"]}
    assert unique == {"ix_scene_model_id_idempotency_key"}


@pytest.mark.postgres
def test_processes_that_start_together_migrate_one_database_once(postgres_url: str) -> None:
    """Replicas start at once: concurrent upgrades of a fresh database all succeed (advisory lock)."""
    name = f"{postgres_url.rsplit('/', 1)[1]}_race"
    server = postgres_url.rsplit("/", 1)[0]
    admin = create_engine(f"{server}/postgres", isolation_level="AUTOCOMMIT")
    errors: list[str] = []

    def upgrade() -> None:
        engine = create_database_engine(f"{server}/{name}")
        try:
            upgrade_to_head(engine)
        except Exception as error:  # noqa: BLE001 - collected and asserted below
            errors.append(repr(error)[:300])
        finally:
            engine.dispose()

    try:
        for _ in range(3):
            with admin.connect() as connection:
                connection.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
                connection.execute(text(f'CREATE DATABASE "{name}"'))
            threads = [threading.Thread(target=upgrade) for _ in range(3)]
            for thread in threads:
                thread.start()
            for thread in threads:
                thread.join(timeout=120)
        assert errors == []
    finally:
        with admin.connect() as connection:
            connection.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
        admin.dispose()
