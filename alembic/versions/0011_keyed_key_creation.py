"""Keyed API-key creation: a key remembers the Idempotency-Key and body digest it was created with.

Revision ID: 0011
Revises: 0010
Create Date: 2026-12-07

``POST /v1/keys`` ignored an Idempotency-Key: a creation whose answer was lost and that was
posted again made a second key, and nobody held the first one's secret. The secret is shown
once and only its hash is stored, so a retry cannot be answered again; it is answered 409
``key_already_created`` naming the key made under that Idempotency-Key (to revoke, then create
another). Two nullable columns on ``api_key`` and a unique index on the keyed rows, as for models
(0009); existing keys have no Idempotency-Key.
"""

from collections.abc import Sequence

import sqlalchemy as sa

from alembic import op

revision: str = "0011"
down_revision: str | None = "0010"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

_KEYED = sa.text("idempotency_key IS NOT NULL")


def upgrade() -> None:
    op.add_column("api_key", sa.Column("idempotency_key", sa.String(length=200), nullable=True))
    op.add_column("api_key", sa.Column("request_hash", sa.LargeBinary(), nullable=True))
    op.create_index(
        "ix_api_key_idempotency_key",
        "api_key",
        ["idempotency_key"],
        unique=True,
        sqlite_where=_KEYED,
        postgresql_where=_KEYED,
    )


def downgrade() -> None:
    op.drop_index("ix_api_key_idempotency_key", table_name="api_key")
    op.drop_column("api_key", "request_hash")
    op.drop_column("api_key", "idempotency_key")
