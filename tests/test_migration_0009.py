"""Migration 0009 gives the models of an older database the columns of keyed creation, on SQLite and
PostgreSQL, and its downgrade drops them in place: the ``model`` table is never rebuilt, so nothing
that references it (ON DELETE CASCADE) is lost either way."""

from __future__ import annotations

from datetime import UTC, datetime

import pytest
import sqlalchemy as sa
from sqlalchemy import Engine
from sqlalchemy.exc import IntegrityError

from tests.conftest import migrate

NOW = datetime(2026, 12, 6, tzinfo=UTC)


def _insert_model(engine: Engine, model_id: str, key: str | None = None) -> None:
    columns = "id, name, seed, sigma, hyperparameters, vocabulary, created_at, updated_at"
    values = ":id, 'm', 0, 0.5, '{}', '{}', :now, :now"
    if key is not None:
        columns, values = f"{columns}, idempotency_key", f"{values}, :key"
    with engine.begin() as connection:
        connection.execute(
            sa.text(f"INSERT INTO model ({columns}) VALUES ({values})"), {"id": model_id, "now": NOW, "key": key}
        )


def _counts(engine: Engine) -> tuple[int, int]:
    with engine.connect() as connection:
        return (
            connection.execute(sa.text("SELECT count(*) FROM model")).scalar_one(),
            connection.execute(sa.text("SELECT count(*) FROM word")).scalar_one(),
        )


def test_keyed_creation_columns_come_and_go_without_touching_what_references_models(engine: Engine) -> None:
    migrate(engine, "downgrade", "0008")
    _insert_model(engine, "old")
    with engine.begin() as connection:
        connection.execute(
            sa.text("INSERT INTO word (model_id, id, name, created_at) VALUES ('old', 0, 'cup', :now)"), {"now": NOW}
        )

    migrate(engine, "upgrade", "head")
    with engine.connect() as connection:
        assert connection.execute(sa.text("SELECT idempotency_key, request_hash FROM model")).one() == (None, None)
    _insert_model(engine, "keyless")  # keyless models are not indexed and never collide
    _insert_model(engine, "first", key="create-1")
    with pytest.raises(IntegrityError):
        _insert_model(engine, "second", key="create-1")
    assert _counts(engine) == (3, 1)

    migrate(engine, "downgrade", "0008")
    columns = {column["name"] for column in sa.inspect(engine).get_columns("model")}
    assert not columns & {"idempotency_key", "request_hash"}, columns
    assert _counts(engine) == (3, 1)  # the old model's word survived: the table was not rebuilt
    migrate(engine, "upgrade", "head")
    assert _counts(engine) == (3, 1)
