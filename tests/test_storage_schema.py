"""The schema comes from the migrations, matches the ORM models, and follows the naming convention."""

from __future__ import annotations

from alembic.autogenerate import compare_metadata
from alembic.migration import MigrationContext
from sqlalchemy import Engine, inspect

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
        "token",
        "context_word_count",
        "training_object",
    } <= tables
    assert inspector.get_pk_constraint("token")["name"] == "pk_token"
    foreign_keys = {fk["name"] for fk in inspector.get_foreign_keys("scene")}
    assert foreign_keys == {"fk_scene_model_id_model"}
    unique = {constraint["name"] for constraint in inspector.get_unique_constraints("scene")}
    assert unique == {"uq_scene_model_id_idempotency_key"}
