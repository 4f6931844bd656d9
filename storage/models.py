"""The tables, SQLAlchemy 2 style: one row per model, word, scene, token batch and n_kw count.

A model's Incremental-LDA state is stored incrementally: every learned scene
adds its ``scene`` row and one ``token_batch`` row (its new tokens' words and
contexts, and the earlier tokens its sweeps reassigned, packed), rewrites the
``context_word_count`` entries (n_kw of Eq. 5) that moved, and replaces the
small ``incremental_lda_state`` row (K, scene count, random state) — all in the
scene's transaction; after the commit of every ``checkpoint_interval``-th scene,
a transaction of its own replaces the model's ``incremental_lda_checkpoint`` (the
whole corpus at that scene's version, as packed arrays) and deletes the batches at
or below the previous checkpoint's version. The
invariants: for every model, the checkpoint with the batches above its version
applied in order gives every token's word and context, and ``context_word_count``
equals their counts grouped by (context, word).
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any, ClassVar

from sqlalchemy import (
    JSON,
    BigInteger,
    CheckConstraint,
    DateTime,
    Float,
    ForeignKey,
    Index,
    Integer,
    LargeBinary,
    MetaData,
    String,
    Table,
    UniqueConstraint,
    text,
)
from sqlalchemy.dialects.postgresql import JSONB
from sqlalchemy.engine import Dialect
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column
from sqlalchemy.types import TypeDecorator

from storage.compression import compress_answer, decompress_answer

NAMING_CONVENTION = {
    "ix": "ix_%(column_0_label)s",
    "uq": "uq_%(table_name)s_%(column_0_N_name)s",
    "ck": "ck_%(table_name)s_%(constraint_name)s",
    "fk": "fk_%(table_name)s_%(column_0_N_name)s_%(referred_table_name)s",
    "pk": "pk_%(table_name)s",
}

#: The form of a model's stored hyperparameters that this code writes (alembic 0006).
HYPERPARAMETERS_VERSION = 2

#: JSON everywhere, stored as JSONB on PostgreSQL.
JSONType = JSON().with_variant(JSONB(), "postgresql")


def utc_now() -> datetime:
    return datetime.now(UTC)


class UtcDateTime(TypeDecorator[datetime]):
    """A timezone-aware UTC timestamp on every backend (SQLite stores no zone; it is UTC here)."""

    impl = DateTime(timezone=True)
    cache_ok = True

    def process_bind_param(self, value: datetime | None, dialect: Dialect) -> datetime | None:
        return None if value is None else value.astimezone(UTC)

    def process_result_value(self, value: datetime | None, dialect: Dialect) -> datetime | None:
        if value is None or value.tzinfo is not None:
            return value
        return value.replace(tzinfo=UTC)


class CompressedText(TypeDecorator[str]):
    """Text stored deflated with a preset dictionary (storage/compression.py), read back byte for byte."""

    impl = LargeBinary
    cache_ok = True

    def process_bind_param(self, value: str | None, dialect: Dialect) -> bytes | None:
        return None if value is None else compress_answer(value)

    def process_result_value(self, value: bytes | None, dialect: Dialect) -> str | None:
        return None if value is None else decompress_answer(bytes(value))


class Base(DeclarativeBase):
    metadata = MetaData(naming_convention=NAMING_CONVENTION)
    if TYPE_CHECKING:
        # Every class here is mapped to a declarative Table (DeclarativeBase types it as any FromClause),
        # so ``Model.__table__.c`` and ``.create()`` type-check; declared as SQLAlchemy declares it.
        __table__: ClassVar[Table]
    type_annotation_map: ClassVar[dict[Any, Any]] = {
        dict[str, Any]: JSONType,
        list[Any]: JSONType,
        datetime: UtcDateTime,
    }


def _model_fk() -> Any:
    return ForeignKey("model.id", ondelete="CASCADE")


#: Only rows written with an Idempotency-Key are indexed by it (models: alembic 0009; scenes: 0008).
_KEYED = text("idempotency_key IS NOT NULL")


class Model(Base):
    """One independent context model (one robot or environment) and its fitted perception."""

    __tablename__ = "model"
    __table_args__ = (
        Index("ix_model_idempotency_key", "idempotency_key", unique=True, sqlite_where=_KEYED, postgresql_where=_KEYED),
    )

    id: Mapped[str] = mapped_column(String(32), primary_key=True)
    name: Mapped[str] = mapped_column(String(200))
    idempotency_key: Mapped[str | None] = mapped_column(String(200))
    """The Idempotency-Key the model was created with (one namespace for every client: a UUID), or null."""
    request_hash: Mapped[bytes | None] = mapped_column(LargeBinary)
    """The SHA-256 digest of the creation's body, which a retry under ``idempotency_key`` must match."""
    seed: Mapped[int] = mapped_column(BigInteger)
    sigma: Mapped[float] = mapped_column(Float)
    hyperparameters: Mapped[dict[str, Any]]
    hyperparameters_version: Mapped[int] = mapped_column(Integer, default=HYPERPARAMETERS_VERSION, server_default="1")
    """The form of ``hyperparameters``: 1 flat (before migration 0006; what a process of an
    earlier version writes), 2 nested by concern (priors, sampler, k_rule)."""
    vocabulary: Mapped[dict[str, Any]]
    prototypes: Mapped[dict[str, Any] | None]
    concept_web: Mapped[dict[str, Any] | None]
    fitted_at: Mapped[datetime | None] = mapped_column()
    created_at: Mapped[datetime] = mapped_column(default=utc_now)
    updated_at: Mapped[datetime] = mapped_column(default=utc_now, onupdate=utc_now)
    deleted_at: Mapped[datetime | None] = mapped_column()
    """When the model was deleted (alembic 0012), or null while it lives. A deleted model's row stays
    until its scenes and tokens are purged in short transactions (app/purge.py); every query that
    lists or loads models skips it (``storage.repositories.models.LIVE``)."""


class IncrementalLdaState(Base):
    """The scalar part of a model's Incremental-LDA state (K, scene count, random state)."""

    __tablename__ = "incremental_lda_state"

    model_id: Mapped[str] = mapped_column(_model_fk(), primary_key=True)
    scene_count: Mapped[int] = mapped_column(Integer, default=0)
    context_count: Mapped[int] = mapped_column(Integer)
    state: Mapped[dict[str, Any]]
    version: Mapped[int] = mapped_column(BigInteger, default=0, server_default="0")
    """How many writes the model has committed (scenes, training objects, fits, repairs)."""
    updated_at: Mapped[datetime] = mapped_column(default=utc_now, onupdate=utc_now)


class Word(Base):
    """A word of the LDA vocabulary (an active concept name); ``id`` is its column in n_kw."""

    __tablename__ = "word"
    __table_args__ = (UniqueConstraint("model_id", "name"),)

    model_id: Mapped[str] = mapped_column(_model_fk(), primary_key=True)
    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=False)
    name: Mapped[str] = mapped_column(String(200))
    kind: Mapped[str | None] = mapped_column(String(20))
    created_at: Mapped[datetime] = mapped_column(default=utc_now)


class Scene(Base):
    """One learned scene (an LDA document) and the answer it was acknowledged with."""

    __tablename__ = "scene"
    __table_args__ = (
        Index(
            "ix_scene_model_id_idempotency_key",
            "model_id",
            "idempotency_key",
            unique=True,
            sqlite_where=_KEYED,
            postgresql_where=_KEYED,
        ),
    )

    model_id: Mapped[str] = mapped_column(_model_fk(), primary_key=True)
    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=False)
    idempotency_key: Mapped[str | None] = mapped_column(String(200))
    request_hash: Mapped[bytes | None] = mapped_column(LargeBinary)
    """The SHA-256 digest (32 bytes) of the request body, which a retry under the same
    ``idempotency_key`` must match; null for a scene posted without a key (nothing compares it)."""
    context_count: Mapped[int] = mapped_column(Integer)
    map_context: Mapped[int] = mapped_column(Integer)
    context_posterior: Mapped[list[Any]]
    answer: Mapped[str] = mapped_column("answer_zlib", CompressedText)
    """The JSON body the scene was acknowledged with, byte for byte (replayed as is); stored
    compressed (alembic 0005: 4.1 KB of JSON a scene took more than half of the database)."""
    created_at: Mapped[datetime] = mapped_column(default=utc_now)


class TokenBatch(Base):
    """The tokens one write added and the tokens it reassigned, packed in one row (alembic 0007).

    A learned scene's new tokens are ``first_token`` .. ``first_token + token_count - 1``
    (the indices Incremental-LDA uses: scenes in order, words in scene order), all of scene
    ``scene_id``; ``packed`` holds their word ids and contexts, and the ids and new contexts of
    the earlier tokens the write's sweeps reassigned (a reassigned token keeps its scene and
    word, so they are not stored again). A model's corpus is its checkpoint's arrays with the
    batches above the checkpoint's version applied in version order (docs/scaling.md, "Token
    batches"). Keyed by (model, version): a catch-up reads a primary-key range, no other index.
    """

    __tablename__ = "token_batch"
    __table_args__ = ({"sqlite_with_rowid": False},)  # clustered on its key: no second copy of it

    model_id: Mapped[str] = mapped_column(_model_fk(), primary_key=True)
    version: Mapped[int] = mapped_column(BigInteger, primary_key=True, autoincrement=False)
    """The model version of the write."""
    scene_id: Mapped[int | None] = mapped_column(Integer)
    """The scene whose tokens the batch adds (None: a write that only reassigns)."""
    first_token: Mapped[int] = mapped_column(Integer)
    token_count: Mapped[int] = mapped_column(Integer)
    packed: Mapped[bytes] = mapped_column(LargeBinary)
    """``words``, ``contexts`` (new tokens), ``moved``, ``moved_contexts`` (reassigned ones), packed
    (storage/compression.py :func:`pack_token_batch`)."""


class IncrementalLdaCheckpoint(Base):
    """The latest checkpoint of a model's corpus: every token's word and context at one version.

    Written after the commit of every ``checkpoint_interval``-th scene, at that scene's version,
    in a transaction of its own (app/services/scenes.py ``store_checkpoint``), so that a start
    loads it and only the batches written since (``token_batch.version`` > its version), not the
    whole history (docs/scaling.md, "Checkpoints"). Once batches below it are deleted (alembic 0007)
    it is part of the model's truth; while every batch since version 0 is kept, ``contextweb models
    repair`` can rebuild it from them.
    """

    __tablename__ = "incremental_lda_checkpoint"

    model_id: Mapped[str] = mapped_column(_model_fk(), primary_key=True)
    version: Mapped[int] = mapped_column(BigInteger)
    """The model's version the arrays equal."""
    scene_count: Mapped[int] = mapped_column(Integer)
    token_count: Mapped[int] = mapped_column(Integer)
    context_count: Mapped[int] = mapped_column(Integer)
    word_count: Mapped[int] = mapped_column(Integer)
    arrays: Mapped[bytes] = mapped_column(LargeBinary)
    """``words``, ``contexts`` (per token) and ``scene_lengths``, packed (storage/compression.py)."""
    compacted_version: Mapped[int] = mapped_column(BigInteger, default=0, server_default="0")
    """Every ``token_batch`` of the model at or below this version was deleted (folded into
    checkpoints, alembic 0007); a process behind it cannot catch up from the batches and reloads."""
    created_at: Mapped[datetime] = mapped_column(default=utc_now)


class ContextWordCount(Base):
    """n_kw of Eq. 5: how many tokens of word w are assigned to context k."""

    __tablename__ = "context_word_count"

    model_id: Mapped[str] = mapped_column(_model_fk(), primary_key=True)
    context: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=False)
    word_id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=False)
    count: Mapped[int] = mapped_column(Integer)
    version: Mapped[int] = mapped_column(BigInteger, default=0, server_default="0")
    """The model version of the write that last changed the count."""


class TrainingObject(Base):
    """A labelled training object (Appendix): its features and noun/adjective/verb labels."""

    __tablename__ = "training_object"

    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    model_id: Mapped[str] = mapped_column(_model_fk(), index=True)
    noun: Mapped[str] = mapped_column(String(200))
    adjectives: Mapped[list[Any]]
    entity: Mapped[list[Any]]
    effects: Mapped[dict[str, Any]]
    verbs: Mapped[dict[str, Any]]
    created_at: Mapped[datetime] = mapped_column(default=utc_now)


class TrainingBatch(Base):
    """A batch of training objects posted with an Idempotency-Key (alembic 0010): its key, its
    body's digest and the answer it got, so that a retry is answered again instead of adding the
    objects twice. Batches posted without a key leave no row."""

    __tablename__ = "training_batch"

    model_id: Mapped[str] = mapped_column(_model_fk(), primary_key=True)
    idempotency_key: Mapped[str] = mapped_column(String(200), primary_key=True)
    request_hash: Mapped[bytes] = mapped_column(LargeBinary)
    added: Mapped[int] = mapped_column(Integer)
    training_object_count: Mapped[int] = mapped_column(Integer)
    """The model's training objects once the batch was added: the answer as it was given."""
    created_at: Mapped[datetime] = mapped_column(default=utc_now)


class ContextLabel(Base):
    """The name an operator gave a context; contexts keep their index as K grows (alembic 0004)."""

    __tablename__ = "context_label"

    model_id: Mapped[str] = mapped_column(_model_fk(), primary_key=True)
    context: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=False)
    label: Mapped[str] = mapped_column(String(80))
    updated_at: Mapped[datetime] = mapped_column(default=utc_now, onupdate=utc_now)


class StorageProbe(Base):
    """One row per serving process, rewritten by the readiness probe to test that writes succeed."""

    __tablename__ = "storage_probe"

    id: Mapped[str] = mapped_column(String(64), primary_key=True)
    probed_at: Mapped[datetime] = mapped_column()


class ApiKey(Base):
    """An API key of one robot or dashboard: its role, its models, and only the SHA-256 of its secret.

    The model scope is a JSON list of model ids, NULL meaning every model (app/auth.py). A list
    rather than an association table: the request's one primary-key read returns the key with
    its scope, and deleting a model cannot silently turn a scoped key into one with no models
    (or, with a NULL-for-all convention, into an all-models key); an id left over from a deleted
    model matches nothing, since model ids are random and never reused.
    """

    __tablename__ = "api_key"
    __table_args__ = (
        CheckConstraint("role IN ('read', 'write', 'admin')", name="role"),
        Index(
            "ix_api_key_idempotency_key", "idempotency_key", unique=True, sqlite_where=_KEYED, postgresql_where=_KEYED
        ),
    )

    id: Mapped[str] = mapped_column(String(32), primary_key=True)
    """The lookup id, the public middle part of the key (``cw_<id>_<secret>``)."""
    name: Mapped[str] = mapped_column(String(200))
    role: Mapped[str] = mapped_column(String(10))
    model_ids: Mapped[list[Any] | None]
    prefix: Mapped[str] = mapped_column(String(40))
    """The key's first characters, shown in listings so an operator can recognise a key."""
    secret_hash: Mapped[str] = mapped_column(String(64))
    """Hex SHA-256 of the whole key (app/auth.py says why not a slow KDF)."""
    created_at: Mapped[datetime] = mapped_column(default=utc_now)
    revoked_at: Mapped[datetime | None] = mapped_column()
    idempotency_key: Mapped[str | None] = mapped_column(String(200))
    """The Idempotency-Key the key was created under (alembic 0011); null without one."""
    request_hash: Mapped[bytes | None] = mapped_column(LargeBinary)
    """The SHA-256 digest of the creation's body, which a retry under ``idempotency_key`` must match."""
