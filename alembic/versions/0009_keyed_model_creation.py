"""Keyed model creation: a model remembers the Idempotency-Key and body digest it was created with.

Revision ID: 0009
Revises: 0008
Create Date: 2026-12-06

A creation answered 503 "may have stored the write" (the connection lost after its COMMIT was
sent, or cut by the write deadline) could only be repeated blind, making a second model. With a
key, the retry finds the stored model and gets its answer again. Two nullable columns on
``model``, and a unique index on the keyed rows only, as for scenes (0008); existing models have
no key.
"""

from collections.abc import Sequence

import sqlalchemy as sa

from alembic import op

revision: str = "0009"
down_revision: str | None = "0008"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

_KEYED = sa.text("idempotency_key IS NOT NULL")


def upgrade() -> None:
    op.add_column("model", sa.Column("idempotency_key", sa.String(length=200), nullable=True))
    op.add_column("model", sa.Column("request_hash", sa.LargeBinary(), nullable=True))
    op.create_index(
        "ix_model_idempotency_key",
        "model",
        ["idempotency_key"],
        unique=True,
        sqlite_where=_KEYED,
        postgresql_where=_KEYED,
    )


def downgrade() -> None:
    # In place, not in batch mode: rebuilding ``model`` would drop the table that every other one
    # references ON DELETE CASCADE. SQLite drops a column in place since 3.35 (2021).
    op.drop_index("ix_model_idempotency_key", table_name="model")
    op.drop_column("model", "request_hash")
    op.drop_column("model", "idempotency_key")
