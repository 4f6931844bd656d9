"""Model tombstones: a deleted model is marked, then purged in short transactions.

Revision ID: 0012
Revises: 0011
Create Date: 2026-12-08

``DELETE /v1/models/{id}`` deleted the model row, and ON DELETE CASCADE every row of the model, in
one transaction. On SQLite that transaction holds the database's one write lock: 0.56 s for a model
of 100,000 scenes and 5.6 s for a million (docs/scaling.md), past the 5 s busy timeout of every
other model's writes. Now the delete only marks the model (``deleted_at``) and drops its version
row, which every process reads to find its models; app/purge.py then deletes its rows a few
thousand at a time. One nullable column: the ``model`` table is not rebuilt, so nothing that
references it is touched; existing models are live.
"""

from collections.abc import Sequence

import sqlalchemy as sa

from alembic import op

revision: str = "0012"
down_revision: str | None = "0011"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.add_column("model", sa.Column("deleted_at", sa.DateTime(timezone=True), nullable=True))


def downgrade() -> None:
    """Models still being purged are deleted outright first (their cascade, in this transaction):
    without the column nothing would tell them from live models."""
    op.execute(sa.text("DELETE FROM model WHERE deleted_at IS NOT NULL"))
    op.drop_column("model", "deleted_at")
