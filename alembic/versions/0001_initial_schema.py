"""Initial schema: models, their training objects, words, scenes, tokens and n_kw counts.

Revision ID: 0001
Revises:
Create Date: 2026-11-21

Self-contained (no import of storage.models), so that later changes to the
models never change what this revision creates.
"""

from collections.abc import Sequence

import sqlalchemy as sa
from sqlalchemy.dialects import postgresql

from alembic import op

revision: str = "0001"
down_revision: str | None = None
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

JSON = sa.JSON().with_variant(postgresql.JSONB(), "postgresql")
TIMESTAMP = sa.DateTime(timezone=True)


def upgrade() -> None:
    op.create_table(
        "model",
        sa.Column("id", sa.String(length=32), nullable=False),
        sa.Column("name", sa.String(length=200), nullable=False),
        sa.Column("seed", sa.BigInteger(), nullable=False),
        sa.Column("sigma", sa.Float(), nullable=False),
        sa.Column("hyperparameters", JSON, nullable=False),
        sa.Column("vocabulary", JSON, nullable=False),
        sa.Column("prototypes", JSON, nullable=True),
        sa.Column("concept_web", JSON, nullable=True),
        sa.Column("fitted_at", TIMESTAMP, nullable=True),
        sa.Column("created_at", TIMESTAMP, nullable=False),
        sa.Column("updated_at", TIMESTAMP, nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_model")),
    )
    op.create_table(
        "context_word_count",
        sa.Column("model_id", sa.String(length=32), nullable=False),
        sa.Column("context", sa.Integer(), autoincrement=False, nullable=False),
        sa.Column("word_id", sa.Integer(), autoincrement=False, nullable=False),
        sa.Column("count", sa.Integer(), nullable=False),
        sa.ForeignKeyConstraint(
            ["model_id"], ["model.id"], name=op.f("fk_context_word_count_model_id_model"), ondelete="CASCADE"
        ),
        sa.PrimaryKeyConstraint("model_id", "context", "word_id", name=op.f("pk_context_word_count")),
    )
    op.create_table(
        "incremental_lda_state",
        sa.Column("model_id", sa.String(length=32), nullable=False),
        sa.Column("scene_count", sa.Integer(), nullable=False),
        sa.Column("context_count", sa.Integer(), nullable=False),
        sa.Column("state", JSON, nullable=False),
        sa.Column("updated_at", TIMESTAMP, nullable=False),
        sa.ForeignKeyConstraint(
            ["model_id"], ["model.id"], name=op.f("fk_incremental_lda_state_model_id_model"), ondelete="CASCADE"
        ),
        sa.PrimaryKeyConstraint("model_id", name=op.f("pk_incremental_lda_state")),
    )
    op.create_table(
        "scene",
        sa.Column("model_id", sa.String(length=32), nullable=False),
        sa.Column("id", sa.Integer(), autoincrement=False, nullable=False),
        sa.Column("idempotency_key", sa.String(length=200), nullable=True),
        sa.Column("request_hash", sa.String(length=64), nullable=False),
        sa.Column("context_count", sa.Integer(), nullable=False),
        sa.Column("map_context", sa.Integer(), nullable=False),
        sa.Column("context_posterior", JSON, nullable=False),
        sa.Column("answer", sa.Text(), nullable=False),
        sa.Column("created_at", TIMESTAMP, nullable=False),
        sa.ForeignKeyConstraint(["model_id"], ["model.id"], name=op.f("fk_scene_model_id_model"), ondelete="CASCADE"),
        sa.PrimaryKeyConstraint("model_id", "id", name=op.f("pk_scene")),
        sa.UniqueConstraint("model_id", "idempotency_key", name=op.f("uq_scene_model_id_idempotency_key")),
    )
    op.create_table(
        "token",
        sa.Column("model_id", sa.String(length=32), nullable=False),
        sa.Column("id", sa.Integer(), autoincrement=False, nullable=False),
        sa.Column("scene_id", sa.Integer(), nullable=False),
        sa.Column("word_id", sa.Integer(), nullable=False),
        sa.Column("context", sa.Integer(), nullable=False),
        sa.ForeignKeyConstraint(["model_id"], ["model.id"], name=op.f("fk_token_model_id_model"), ondelete="CASCADE"),
        sa.PrimaryKeyConstraint("model_id", "id", name=op.f("pk_token")),
    )
    op.create_table(
        "training_object",
        sa.Column("id", sa.Integer(), autoincrement=True, nullable=False),
        sa.Column("model_id", sa.String(length=32), nullable=False),
        sa.Column("noun", sa.String(length=200), nullable=False),
        sa.Column("adjectives", JSON, nullable=False),
        sa.Column("entity", JSON, nullable=False),
        sa.Column("effects", JSON, nullable=False),
        sa.Column("verbs", JSON, nullable=False),
        sa.Column("created_at", TIMESTAMP, nullable=False),
        sa.ForeignKeyConstraint(
            ["model_id"], ["model.id"], name=op.f("fk_training_object_model_id_model"), ondelete="CASCADE"
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_training_object")),
    )
    with op.batch_alter_table("training_object", schema=None) as batch_op:
        batch_op.create_index(batch_op.f("ix_training_object_model_id"), ["model_id"], unique=False)

    op.create_table(
        "word",
        sa.Column("model_id", sa.String(length=32), nullable=False),
        sa.Column("id", sa.Integer(), autoincrement=False, nullable=False),
        sa.Column("name", sa.String(length=200), nullable=False),
        sa.Column("kind", sa.String(length=20), nullable=True),
        sa.Column("created_at", TIMESTAMP, nullable=False),
        sa.ForeignKeyConstraint(["model_id"], ["model.id"], name=op.f("fk_word_model_id_model"), ondelete="CASCADE"),
        sa.PrimaryKeyConstraint("model_id", "id", name=op.f("pk_word")),
        sa.UniqueConstraint("model_id", "name", name=op.f("uq_word_model_id_name")),
    )


def downgrade() -> None:
    op.drop_table("word")
    with op.batch_alter_table("training_object", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_training_object_model_id"))

    op.drop_table("training_object")
    op.drop_table("token")
    op.drop_table("scene")
    op.drop_table("incremental_lda_state")
    op.drop_table("context_word_count")
    op.drop_table("model")
