"""Model versions: every write to a model bumps its version, and the rows it wrote carry it.

Revision ID: 0002
Revises: 0001
Create Date: 2026-12-01

Several processes serve one database (docs/scaling.md). A process that is
behind a model's stored version catches up by reading only the rows written
since its own version: the token rows (new or reassigned) and the n_kw entries
carry the version of the write that last changed them, and the state row holds
the model's current version. ``storage_probe`` is the row the readiness probe
writes to find out whether the database can take a write.
"""

from collections.abc import Sequence

import sqlalchemy as sa

from alembic import op

revision: str = "0002"
down_revision: str | None = "0001"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("incremental_lda_state") as batch_op:
        batch_op.add_column(sa.Column("version", sa.BigInteger(), nullable=False, server_default="0"))
    with op.batch_alter_table("token") as batch_op:
        batch_op.add_column(sa.Column("version", sa.BigInteger(), nullable=False, server_default="0"))
        batch_op.create_index("ix_token_model_id_version", ["model_id", "version"], unique=False)
    with op.batch_alter_table("context_word_count") as batch_op:
        batch_op.add_column(sa.Column("version", sa.BigInteger(), nullable=False, server_default="0"))
    op.create_table(
        "storage_probe",
        sa.Column("id", sa.String(length=64), nullable=False),
        sa.Column("probed_at", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_storage_probe")),
    )


def downgrade() -> None:
    op.drop_table("storage_probe")
    with op.batch_alter_table("context_word_count") as batch_op:
        batch_op.drop_column("version")
    with op.batch_alter_table("token") as batch_op:
        batch_op.drop_index("ix_token_model_id_version")
        batch_op.drop_column("version")
    with op.batch_alter_table("incremental_lda_state") as batch_op:
        batch_op.drop_column("version")
