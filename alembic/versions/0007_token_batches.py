"""Token batches: one packed row per write instead of one row per token.

Revision ID: 0007
Revises: 0006
Create Date: 2026-12-02

A learned scene wrote ~80 ``token`` rows (each repeating the 32-character model id, plus the
``ix_token_model_id_version`` index): 8.8 KB a scene of the 12.3 KB a concept-level scene took
at 10k scenes on SQLite. It now writes one ``token_batch`` row keyed by (model_id, version):
its new tokens' words and contexts and the ids and new contexts of the earlier tokens its sweeps
reassigned, packed (storage/compression.py ``pack_small_arrays``, a frozen format). A model's
corpus is its checkpoint with the batches above the checkpoint's version applied in order; a
scheduled checkpoint deletes the batches at or below the checkpoint it replaces, and
``incremental_lda_checkpoint.compacted_version`` records that version (docs/scaling.md, "Token
batches").

Upgrade: each model's token rows become one checkpoint at the model's current version (the
checkpoint packing of 0005, ``pack_arrays``), with ``compacted_version`` at that version (no batch
before it is kept); then ``token`` is dropped. Models without tokens get no checkpoint.

Downgrade: the token rows are rebuilt from each model's checkpoint and batches. A checkpointed
token carries the checkpoint's version, a token a batch added or moved the batch's version (the
last one), so the checkpoint still equals the rows not written since its version, as 0005 reads
them; then ``token_batch`` and ``compacted_version`` are dropped.

The packing is imported from storage/compression.py, whose formats are frozen for exactly this
reason (a format byte names each); the rest is written out here, so that later changes to the
repositories cannot change what this migration does.
"""

from collections.abc import Sequence

import numpy as np
import sqlalchemy as sa

from alembic import op
from storage.compression import pack_arrays, unpack_arrays, unpack_small_arrays

revision: str = "0007"
down_revision: str | None = "0006"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

_state = sa.table("incremental_lda_state", sa.column("model_id"), sa.column("version"), sa.column("context_count"))
_word = sa.table("word", sa.column("model_id"), sa.column("id"))
_checkpoint = sa.table(
    "incremental_lda_checkpoint",
    sa.column("model_id"),
    sa.column("version"),
    sa.column("scene_count"),
    sa.column("token_count"),
    sa.column("context_count"),
    sa.column("word_count"),
    sa.column("arrays"),
    sa.column("compacted_version"),
    sa.column("created_at"),
)
_batch = sa.table(
    "token_batch",
    sa.column("model_id"),
    sa.column("version"),
    sa.column("scene_id"),
    sa.column("first_token"),
    sa.column("token_count"),
    sa.column("packed"),
)
_token = sa.table(
    "token",
    sa.column("model_id"),
    sa.column("id"),
    sa.column("scene_id"),
    sa.column("word_id"),
    sa.column("context"),
    sa.column("version"),
)


def upgrade() -> None:
    op.create_table(
        "token_batch",
        sa.Column("model_id", sa.String(length=32), nullable=False),
        sa.Column("version", sa.BigInteger(), autoincrement=False, nullable=False),
        sa.Column("scene_id", sa.Integer(), nullable=True),
        sa.Column("first_token", sa.Integer(), nullable=False),
        sa.Column("token_count", sa.Integer(), nullable=False),
        sa.Column("packed", sa.LargeBinary(), nullable=False),
        sa.ForeignKeyConstraint(
            ["model_id"], ["model.id"], name=op.f("fk_token_batch_model_id_model"), ondelete="CASCADE"
        ),
        sa.PrimaryKeyConstraint("model_id", "version", name=op.f("pk_token_batch")),
        sqlite_with_rowid=False,
    )
    op.add_column(
        "incremental_lda_checkpoint",
        sa.Column("compacted_version", sa.BigInteger(), server_default="0", nullable=False),
    )
    connection = op.get_bind()
    models = connection.execute(sa.select(_token.c.model_id).distinct()).scalars().all()
    for model_id in models:
        _checkpoint_tokens(connection, model_id)
    op.drop_index("ix_token_model_id_version", table_name="token")
    op.drop_table("token")


def _checkpoint_tokens(connection: sa.Connection, model_id: str) -> None:
    """One checkpoint of the model's token rows at its current version, replacing any it had."""
    tokens = _token_columns(connection, model_id)
    state = connection.execute(
        sa.select(_state.c.version, _state.c.context_count).where(_state.c.model_id == model_id)
    ).first()
    version = 0 if state is None else int(state.version)
    context_count = max(int(tokens[:, 2].max()) + 1, 0 if state is None else int(state.context_count))
    word_count = max(
        int(tokens[:, 1].max()) + 1,
        connection.execute(sa.select(sa.func.count()).where(_word.c.model_id == model_id)).scalar_one(),
    )
    _, lengths = np.unique(tokens[:, 0], return_counts=True)
    arrays = pack_arrays({"words": tokens[:, 1], "contexts": tokens[:, 2], "scene_lengths": lengths})
    connection.execute(sa.delete(_checkpoint).where(_checkpoint.c.model_id == model_id))
    connection.execute(
        sa.insert(_checkpoint).values(
            model_id=model_id,
            version=version,
            scene_count=int(lengths.shape[0]),
            token_count=int(tokens.shape[0]),
            context_count=context_count,
            word_count=word_count,
            arrays=arrays,
            compacted_version=version,
            created_at=sa.func.now(),
        )
    )


#: Token rows read or written per round trip (bounded memory at millions of rows).
_CHUNK = 200_000


def _token_columns(connection: sa.Connection, model_id: str) -> np.ndarray:
    """(scene, word, context) of the model's token rows by id, read through the driver in chunks
    (numpy converts the driver's tuples ≈ 25× faster than SQLAlchemy's Rows: docs/benchmarks.md)."""
    placeholder = "?" if connection.dialect.paramstyle == "qmark" else "%s"
    cursor = connection.connection.dbapi_connection.cursor()
    try:
        cursor.execute(
            f"SELECT scene_id, word_id, context FROM token WHERE model_id = {placeholder} ORDER BY id", (model_id,)
        )
        chunks = []
        while rows := cursor.fetchmany(_CHUNK):
            chunks.append(np.array(rows, dtype=np.int64).reshape(-1, 3))
    finally:
        cursor.close()
    return np.concatenate(chunks) if chunks else np.zeros((0, 3), dtype=np.int64)


def downgrade() -> None:
    dialect = op.get_bind().dialect.name
    op.execute(
        "CREATE TABLE token (model_id VARCHAR(32) NOT NULL, id INTEGER NOT NULL, "
        "scene_id INTEGER NOT NULL, word_id INTEGER NOT NULL, context INTEGER NOT NULL, "
        "version BIGINT DEFAULT '0' NOT NULL, CONSTRAINT pk_token PRIMARY KEY (model_id, id), "
        "CONSTRAINT fk_token_model_id_model FOREIGN KEY(model_id) REFERENCES model (id) ON DELETE CASCADE)"
        + (" WITHOUT ROWID" if dialect == "sqlite" else "")
    )
    op.execute("CREATE INDEX ix_token_model_id_version ON token (model_id, version)")
    connection = op.get_bind()
    models = {
        *connection.execute(sa.select(_batch.c.model_id).distinct()).scalars(),
        *connection.execute(sa.select(_checkpoint.c.model_id)).scalars(),
    }
    for model_id in sorted(models):
        _token_rows(connection, model_id)
    if dialect == "sqlite":  # in place, as 0006 (SQLite 3.35+); batch mode would copy the table
        op.execute("ALTER TABLE incremental_lda_checkpoint DROP COLUMN compacted_version")
    else:
        op.drop_column("incremental_lda_checkpoint", "compacted_version")
    op.drop_table("token_batch")


def _token_rows(connection: sa.Connection, model_id: str) -> None:
    """The model's token rows, from its checkpoint and the batches above the checkpoint's version."""
    saved = connection.execute(
        sa.select(_checkpoint.c.version, _checkpoint.c.arrays).where(_checkpoint.c.model_id == model_id)
    ).first()
    words = contexts = scenes = versions = np.zeros(0, dtype=np.int64)
    since = 0
    if saved is not None:
        arrays = unpack_arrays(bytes(saved.arrays))
        words = arrays["words"].astype(np.int64)
        contexts = arrays["contexts"].astype(np.int64)
        scenes = np.repeat(np.arange(arrays["scene_lengths"].shape[0]), arrays["scene_lengths"]).astype(np.int64)
        since = int(saved.version)
        versions = np.full(words.shape[0], since, dtype=np.int64)
    batches = connection.execute(
        sa.select(_batch.c.version, _batch.c.scene_id, _batch.c.packed)
        .where(_batch.c.model_id == model_id, _batch.c.version > since)
        .order_by(_batch.c.version)
    ).all()
    for version, scene_id, packed in batches:
        new_words, new_contexts, moved_steps, moved_contexts = unpack_small_arrays(bytes(packed))
        moved = np.cumsum(moved_steps, dtype=np.int64)
        contexts[moved] = moved_contexts
        versions[moved] = version
        words = np.concatenate([words, new_words.astype(np.int64)])
        contexts = np.concatenate([contexts, new_contexts.astype(np.int64)])
        scenes = np.concatenate([scenes, np.full(new_words.shape[0], scene_id or 0, dtype=np.int64)])
        versions = np.concatenate([versions, np.full(new_words.shape[0], version, dtype=np.int64)])
    columns = np.stack([np.arange(words.shape[0]), scenes, words, contexts, versions], axis=1).tolist()
    for start in range(0, len(columns), _CHUNK):
        connection.execute(
            sa.insert(_token),
            [
                {"model_id": model_id, "id": i, "scene_id": s, "word_id": w, "context": k, "version": v}
                for i, s, w, k, v in columns[start : start + _CHUNK]
            ],
        )
