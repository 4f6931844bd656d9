"""Context labels: the name an operator gives a context ("kitchen").

Revision ID: 0004
Revises: 0003
Create Date: 2026-12-02

A context's index is stable for its whole life (a new context is appended as
K grows, never renumbered), so a label is keyed by (model, context index) and
stays on its context when K grows. Labels are read from the database where
they are shown, so every process sees a new label on its next request.
"""

from collections.abc import Sequence

import sqlalchemy as sa

from alembic import op

revision: str = "0004"
down_revision: str | None = "0003"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "context_label",
        sa.Column("model_id", sa.String(length=32), nullable=False),
        sa.Column("context", sa.Integer(), autoincrement=False, nullable=False),
        sa.Column("label", sa.String(length=80), nullable=False),
        sa.Column("updated_at", sa.DateTime(timezone=True), nullable=False),
        sa.ForeignKeyConstraint(
            ["model_id"], ["model.id"], name=op.f("fk_context_label_model_id_model"), ondelete="CASCADE"
        ),
        sa.PrimaryKeyConstraint("model_id", "context", name=op.f("pk_context_label")),
    )


def downgrade() -> None:
    op.drop_table("context_label")
