"""Compact scene rows: the request's digest as 32 bytes, kept and indexed only for keyed scenes.

Revision ID: 0008
Revises: 0007
Create Date: 2026-12-02

``scene.request_hash`` was the 64-character hex SHA-256 of the request body on every scene;
it is only ever compared when a retry brings the same Idempotency-Key. It becomes the raw
32-byte digest, and null for a scene posted without a key. The unique constraint on
(model_id, idempotency_key) indexed every scene, keyless ones included (about 55 bytes each
on SQLite); it becomes a unique index on the keyed scenes only (``WHERE idempotency_key IS
NOT NULL``), which refuses the same duplicates (NULL keys never collided). Measured in
docs/benchmarks.md (``answers``, the scene row's columns and pages).

The downgrade writes the hex digests back and gives keyless scenes an empty
``request_hash`` (their body is not stored; no code reads a keyless scene's hash).

SQLite cannot drop a table's UNIQUE constraint in place: the scene table is rebuilt (batch
mode). Nothing references it, so the copy cascades nothing.
"""

from collections.abc import Callable, Sequence
from typing import Any

import sqlalchemy as sa

from alembic import op

revision: str = "0008"
down_revision: str | None = "0007"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

#: Scene rows converted per statement.
_BATCH = 5_000
_KEYED = sa.text("idempotency_key IS NOT NULL")
_INDEX = "ix_scene_model_id_idempotency_key"
_CONSTRAINT = "uq_scene_model_id_idempotency_key"


def upgrade() -> None:
    op.add_column("scene", sa.Column("request_digest", sa.LargeBinary(), nullable=True))
    _convert("request_hash", "request_digest", bytes.fromhex, keyed_only=True)
    with op.batch_alter_table("scene") as batch_op:
        batch_op.drop_constraint(_CONSTRAINT, type_="unique")
        batch_op.drop_column("request_hash")
        batch_op.alter_column("request_digest", new_column_name="request_hash", existing_type=sa.LargeBinary())
    op.create_index(
        _INDEX, "scene", ["model_id", "idempotency_key"], unique=True, sqlite_where=_KEYED, postgresql_where=_KEYED
    )


def downgrade() -> None:
    op.drop_index(_INDEX, table_name="scene")
    op.add_column("scene", sa.Column("request_hex", sa.String(length=64), nullable=True))
    _convert("request_hash", "request_hex", lambda digest: bytes(digest).hex(), keyed_only=False)
    with op.batch_alter_table("scene") as batch_op:
        batch_op.drop_column("request_hash")
        batch_op.alter_column(
            "request_hex", new_column_name="request_hash", existing_type=sa.String(length=64), nullable=False
        )
        batch_op.create_unique_constraint(_CONSTRAINT, ["model_id", "idempotency_key"])


def _convert(source: str, target: str, convert: Callable[[Any], Any], *, keyed_only: bool) -> None:
    """Fill ``scene.<target>`` with ``convert(scene.<source>)`` (an empty string where the source is
    null), on the keyed scenes only if ``keyed_only``, batch by batch in (model_id, id) order."""
    connection = op.get_bind()
    scene = sa.table(
        "scene",
        sa.column("model_id"),
        sa.column("id"),
        sa.column("idempotency_key"),
        sa.column(source),
        sa.column(target),
    )
    update = (
        sa.update(scene)
        .where(scene.c.model_id == sa.bindparam("key_model"), scene.c.id == sa.bindparam("key_id"))
        .values({target: sa.bindparam("value")})
    )
    after: tuple[str, int] | None = None
    while True:
        query = sa.select(scene.c.model_id, scene.c.id, scene.c[source]).order_by(scene.c.model_id, scene.c.id)
        if keyed_only:
            query = query.where(scene.c.idempotency_key.is_not(None))
        if after is not None:
            query = query.where(sa.tuple_(scene.c.model_id, scene.c.id) > sa.tuple_(*after))
        rows = connection.execute(query.limit(_BATCH)).all()
        if not rows:
            return
        connection.execute(
            update,
            [
                {"key_model": model_id, "key_id": id_, "value": "" if value is None else convert(value)}
                for model_id, id_, value in rows
            ],
        )
        after = (rows[-1][0], rows[-1][1])
