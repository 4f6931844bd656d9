"""Checkpoints of the Incremental-LDA corpus, and scene answers stored compressed.

Revision ID: 0005
Revises: 0004
Create Date: 2026-12-02

A start used to read every token row of a model (≈ 0.27 ms a scene); it now
reads the model's latest checkpoint (``incremental_lda_checkpoint``: every
token's word and context at one version, packed) and only the token rows
written since (docs/scaling.md, "Checkpoints"). Models stored before this
migration have no checkpoint: they load from their token rows, as before,
until their next ``checkpoint_interval``-th scene writes one.

``scene.answer`` (the acknowledged JSON, ~4 KB a concept-level scene, more
than half of the database) becomes ``scene.answer_zlib``: the same bytes
deflated with a preset dictionary (storage/compression.py, whose dictionary is
frozen for exactly this reason: the rows converted here decode with it).
Existing answers are converted in batches, in key order; the downgrade
converts them back.

On SQLite the ``token`` table becomes a ``WITHOUT ROWID`` table, clustered on
its primary key (model_id, id): a rowid table kept the key a second time in
its primary-key index, a third of the token bytes (measured on 300 concept
scenes of 78 tokens: 3.59 MB of token table and indexes before, 2.30 MB after).
PostgreSQL has no such choice (heap tables); its tokens are left as they are.
"""

from collections.abc import Callable, Sequence
from typing import Any

import sqlalchemy as sa

from alembic import op
from storage.compression import compress_answer, decompress_answer

revision: str = "0005"
down_revision: str | None = "0004"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

#: Scene rows converted per statement (a batch of ~4 KB answers stays a few MB in memory).
_BATCH = 2_000


def upgrade() -> None:
    op.create_table(
        "incremental_lda_checkpoint",
        sa.Column("model_id", sa.String(length=32), nullable=False),
        sa.Column("version", sa.BigInteger(), nullable=False),
        sa.Column("scene_count", sa.Integer(), nullable=False),
        sa.Column("token_count", sa.Integer(), nullable=False),
        sa.Column("context_count", sa.Integer(), nullable=False),
        sa.Column("word_count", sa.Integer(), nullable=False),
        sa.Column("arrays", sa.LargeBinary(), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.ForeignKeyConstraint(
            ["model_id"], ["model.id"], name=op.f("fk_incremental_lda_checkpoint_model_id_model"), ondelete="CASCADE"
        ),
        sa.PrimaryKeyConstraint("model_id", name=op.f("pk_incremental_lda_checkpoint")),
    )
    op.add_column("scene", sa.Column("answer_zlib", sa.LargeBinary(), nullable=True))
    _convert("answer", "answer_zlib", compress_answer)
    with op.batch_alter_table("scene") as batch_op:
        batch_op.alter_column("answer_zlib", existing_type=sa.LargeBinary(), nullable=False)
        batch_op.drop_column("answer")
    if op.get_bind().dialect.name == "sqlite":
        _rebuild_sqlite_token_table(" WITHOUT ROWID")


def downgrade() -> None:
    if op.get_bind().dialect.name == "sqlite":
        _rebuild_sqlite_token_table("")
    op.add_column("scene", sa.Column("answer", sa.Text(), nullable=True))
    _convert("answer_zlib", "answer", lambda stored: decompress_answer(bytes(stored)))  # bytea reads as memoryview
    with op.batch_alter_table("scene") as batch_op:
        batch_op.alter_column("answer", existing_type=sa.Text(), nullable=False)
        batch_op.drop_column("answer_zlib")
    op.drop_table("incremental_lda_checkpoint")


def _rebuild_sqlite_token_table(options: str) -> None:
    """The token table recreated with ``options`` after its closing parenthesis, rows and index kept."""
    op.execute(
        "CREATE TABLE token_rebuilt (model_id VARCHAR(32) NOT NULL, id INTEGER NOT NULL, "
        "scene_id INTEGER NOT NULL, word_id INTEGER NOT NULL, context INTEGER NOT NULL, "
        "version BIGINT DEFAULT '0' NOT NULL, CONSTRAINT pk_token PRIMARY KEY (model_id, id), "
        "CONSTRAINT fk_token_model_id_model FOREIGN KEY(model_id) REFERENCES model (id) ON DELETE CASCADE)" + options
    )
    op.execute(
        "INSERT INTO token_rebuilt (model_id, id, scene_id, word_id, context, version) "
        "SELECT model_id, id, scene_id, word_id, context, version FROM token ORDER BY model_id, id"
    )
    op.execute("DROP TABLE token")
    op.execute("ALTER TABLE token_rebuilt RENAME TO token")
    op.execute("CREATE INDEX ix_token_model_id_version ON token (model_id, version)")


def _convert(source: str, target: str, convert: Callable[[Any], Any]) -> None:
    """Fill ``scene.<target>`` with ``convert(scene.<source>)``, batch by batch in (model_id, id) order."""
    connection = op.get_bind()
    scene = sa.table("scene", sa.column("model_id"), sa.column("id"), sa.column(source), sa.column(target))
    update = (
        sa.update(scene)
        .where(scene.c.model_id == sa.bindparam("key_model"), scene.c.id == sa.bindparam("key_id"))
        .values({target: sa.bindparam("value")})
    )
    after: tuple[str, int] | None = None
    while True:
        query = sa.select(scene.c.model_id, scene.c.id, scene.c[source]).order_by(scene.c.model_id, scene.c.id)
        if after is not None:
            query = query.where(sa.tuple_(scene.c.model_id, scene.c.id) > sa.tuple_(*after))
        rows = connection.execute(query.limit(_BATCH)).all()
        if not rows:
            return
        connection.execute(
            update, [{"key_model": model_id, "key_id": id_, "value": convert(value)} for model_id, id_, value in rows]
        )
        after = (rows[-1][0], rows[-1][1])
