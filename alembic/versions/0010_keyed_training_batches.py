"""Keyed training batches: a batch of training objects posted with an Idempotency-Key is remembered.

Revision ID: 0010
Revises: 0009
Create Date: 2026-12-06

Posting training objects could not be retried safely: a batch whose answer was lost (or that was
answered 503 "may have stored") and that was posted again added its objects twice, which weighs
their labels double in every later fit. A keyed batch now leaves one row, (model, key) with the
body's digest and the answer it got; a retry with the same key and body is answered again and
adds nothing. Keyless batches leave no row, as before.
"""

from collections.abc import Sequence

import sqlalchemy as sa

from alembic import op

revision: str = "0010"
down_revision: str | None = "0009"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "training_batch",
        sa.Column("model_id", sa.String(length=32), nullable=False),
        sa.Column("idempotency_key", sa.String(length=200), nullable=False),
        sa.Column("request_hash", sa.LargeBinary(), nullable=False),
        sa.Column("added", sa.Integer(), nullable=False),
        sa.Column("training_object_count", sa.Integer(), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.ForeignKeyConstraint(
            ["model_id"], ["model.id"], name=op.f("fk_training_batch_model_id_model"), ondelete="CASCADE"
        ),
        sa.PrimaryKeyConstraint("model_id", "idempotency_key", name=op.f("pk_training_batch")),
    )


def downgrade() -> None:
    op.drop_table("training_batch")
