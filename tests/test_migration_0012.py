"""Migration 0012 gives the models of an older database a ``deleted_at`` column, all of them live, on
SQLite and PostgreSQL; its downgrade first deletes outright the models still being purged (nothing
would tell them from live ones without the column), with what references them."""

from __future__ import annotations

from datetime import UTC, datetime

import sqlalchemy as sa
from sqlalchemy import Engine

from tests.conftest import migrate

NOW = datetime(2026, 12, 8, tzinfo=UTC)


def _insert_model_with_a_word(engine: Engine, model_id: str) -> None:
    with engine.begin() as connection:
        connection.execute(
            sa.text(
                "INSERT INTO model (id, name, seed, sigma, hyperparameters, vocabulary, created_at, updated_at) "
                "VALUES (:id, 'm', 0, 0.5, '{}', '{}', :now, :now)"
            ),
            {"id": model_id, "now": NOW},
        )
        connection.execute(
            sa.text("INSERT INTO word (model_id, id, name, created_at) VALUES (:id, 0, 'cup', :now)"),
            {"id": model_id, "now": NOW},
        )


def _words(engine: Engine) -> dict[str, int]:
    with engine.connect() as connection:
        return dict(connection.execute(sa.text("SELECT model_id, count(*) FROM word GROUP BY model_id")).all())


def test_models_are_live_after_the_upgrade_and_marked_ones_go_with_the_downgrade(engine: Engine) -> None:
    migrate(engine, "downgrade", "0011")
    _insert_model_with_a_word(engine, "old")

    migrate(engine, "upgrade", "head")
    with engine.connect() as connection:
        assert connection.execute(sa.text("SELECT id, deleted_at FROM model")).all() == [("old", None)]
    _insert_model_with_a_word(engine, "doomed")
    with engine.begin() as connection:
        connection.execute(sa.text("UPDATE model SET deleted_at = :now WHERE id = 'doomed'"), {"now": NOW})
    assert _words(engine) == {"old": 1, "doomed": 1}

    migrate(engine, "downgrade", "0011")
    assert "deleted_at" not in {column["name"] for column in sa.inspect(engine).get_columns("model")}
    assert _words(engine) == {"old": 1}  # the marked model and its word are gone; the live one's stays
    migrate(engine, "upgrade", "head")
    assert _words(engine) == {"old": 1}
