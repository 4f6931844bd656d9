"""The service's settings: one pydantic-settings class, read from ``CONTEXTWEB_*`` variables.

Every field is documented in docs/operations.md. A ``Settings`` is created once
by the CLI (or by a test) and handed to :func:`app.main.create_app`; nothing
else reads the environment.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, SecretStr, field_validator, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict
from sqlalchemy.engine import make_url
from sqlalchemy.exc import ArgumentError

from storage.database import DEFAULT_DATABASE_URL, is_sqlite

LOOPBACK_HOSTS = frozenset({"127.0.0.1", "::1", "localhost"})


def normalise_origin(origin: str) -> str:
    """An ``Origin`` value in the form it is compared in: trimmed, lower case, no trailing slash."""
    return origin.strip().rstrip("/").lower()


#: The databases the models can be stored in (SQLAlchemy backend names; ``postgres`` is ``postgresql``'s alias).
DATABASE_BACKENDS = ("postgresql", "postgres", "sqlite")

#: Scenes between two checkpoints of a model (docs/scaling.md, "Checkpoints", says why this many).
DEFAULT_CHECKPOINT_INTERVAL = 10_000


class Settings(BaseSettings):
    """Deployment settings; ``CONTEXTWEB_DATABASE_URL`` etc. override the defaults."""

    model_config = SettingsConfigDict(env_prefix="CONTEXTWEB_", env_file=None, extra="ignore")

    environment: Literal["development", "production"] = Field(
        "development", description="`production` refuses to start without a write key."
    )
    database_url: str | None = Field(
        None, description="SQLAlchemy URL; unset means SQLite (WAL) at var/contextweb.sqlite3 under the project."
    )
    host: str = Field("127.0.0.1", description="Interface `contextweb serve` binds to.")
    port: int = Field(8000, ge=1, le=65535, description="Port `contextweb serve` listens on.")
    write_key: SecretStr | None = Field(
        None, description="Bootstrap admin key (every route and model, the key routes); setting it turns keys on."
    )
    read_key: SecretStr | None = Field(None, description="Bootstrap read key (the read routes of every model).")
    max_body_bytes: int = Field(8 * 1024 * 1024, ge=1024, description="Largest request body accepted; more is a 413.")
    body_read_timeout_seconds: float = Field(
        10.0, gt=0, le=600, description="Time a request's whole body may take to arrive; then a 408 and the close."
    )
    header_read_timeout_seconds: float = Field(
        10.0,
        gt=0,
        le=600,
        description="Time a request's line and headers may take to arrive (from the connection's opening or the "
        "request's first byte); then a 408 and the close.",
    )
    max_vocabulary: int = Field(
        10_000, ge=1, le=1_000_000, description="Concepts (|W|) a model may hold; a scene that would pass it is a 422."
    )
    max_new_concepts_per_scene: int = Field(
        64, ge=1, le=16_384, description="New concept names one scene may add to a model's vocabulary; more is a 422."
    )
    sqlite_synchronous: Literal["FULL", "NORMAL"] = Field(
        "FULL", description="SQLite `synchronous` pragma: FULL makes every acknowledged commit survive a power loss."
    )
    database_pool_size: int = Field(8, ge=1, description="Connections kept open per process.")
    stream_queue_size: int = Field(256, ge=1, description="Events buffered per websocket client before it is dropped.")
    stream_send_timeout_seconds: float = Field(
        5.0, gt=0, le=300, description="How long one websocket send may wait on a client that does not read; then 1013."
    )
    allowed_origins: list[str] = Field(
        default_factory=list,
        description="Browser origins (JSON list) that may open the stream; others are closed with 4403. Empty: any.",
    )
    metrics_max_models: int = Field(
        100, ge=1, description="Models with their own `model` label in /metrics; later ones share `_other`."
    )
    write_threads: int = Field(
        4,
        ge=1,
        description="Threads the admitted model writes share, apart from `worker_threads` (docs/operations.md).",
    )
    scene_threads: int = Field(
        0,
        ge=0,
        description="Threads that learn scenes at once, apart from the write threads (which extract a raw scene's "
        "features first, and wait for a model's lock held by another process); 0: the database's default, "
        "1 on SQLite and 2 on PostgreSQL (docs/scaling.md says why).",
    )
    worker_threads: int = Field(16, ge=1, description="Threads running the blocking routes (numba, database).")
    model_write_queue: int = Field(
        32, ge=0, le=10_000, description="Writes a model keeps waiting behind the one in progress; more is a 429."
    )
    model_write_queue_bytes: int = Field(
        32 * 1024 * 1024,
        ge=0,
        description="Total body bytes of a model's waiting writes (one always may wait); more is a 429; 0 is no bound.",
    )
    rate_limit_per_second: float = Field(
        0.0, ge=0.0, le=1e6, description="Writes a second each client (API key, else address) may make; 0 is off."
    )
    rate_limit_burst: int = Field(
        50, ge=1, le=1_000_000, description="Writes a client may make at once before the rate applies."
    )
    checkpoint_interval: int = Field(
        DEFAULT_CHECKPOINT_INTERVAL,
        ge=1,
        description="Every this-many scenes a model's checkpoint is rewritten: a start reads it and at most "
        'this many scenes\' rows (docs/scaling.md, "Checkpoints", has the trade-off).',
    )
    sqlite_busy_timeout_ms: int = Field(
        5_000,
        ge=0,
        le=60_000,
        description="How long an SQLite write waits for the database's write lock; then a 503 `storage_busy`.",
    )
    write_deadline_seconds: float = Field(
        15.0,
        ge=1.0,
        le=600.0,
        description="PostgreSQL: how long a write transaction may run before its connection is cut and the write "
        "answered 503 `storage_unavailable` (a database that stopped answering). Longer than `lock_timeout` (10 s), "
        "shorter than the clients' own time-outs (the bridge's is 30 s; 20 s is common).",
    )
    load_deadline_seconds: float = Field(
        120.0,
        ge=1.0,
        le=3_600.0,
        description="PostgreSQL: how long a model's load, reload or catch-up may read before its connection is cut "
        "and the request answered 503 (a database that stopped answering, which would otherwise hold the model's "
        "lock, and for a first load every other first load, until it answers). A model of 1,000,000 scenes loads "
        "in about 3 s here (docs/benchmarks.md); a load's reads wait for no write's lock.",
    )

    @field_validator("write_key", "read_key", mode="before")
    @classmethod
    def _empty_key_is_unset(cls, value: object) -> object:
        """``CONTEXTWEB_READ_KEY=`` (compose's ``${CONTEXTWEB_READ_KEY:-}``) means no key, not the empty key."""
        if value is None or (isinstance(value, str) and not value.strip()):
            return None
        if isinstance(value, SecretStr) and not value.get_secret_value().strip():
            return None
        return value

    @field_validator("allowed_origins")
    @classmethod
    def _normalise_origins(cls, origins: list[str]) -> list[str]:
        """As browsers send them (RFC 6454 serialisation): lower case, no trailing slash."""
        return [normalise_origin(origin) for origin in origins]

    @field_validator("database_url")
    @classmethod
    def _check_database_url(cls, url: str | None) -> str | None:
        """A URL of one of the two databases the models are stored in (the URL is not repeated: it
        may hold a password)."""
        if not url:  # unset, or set empty (as a compose file's ${VAR:-} gives): the default
            return None
        try:
            backend = make_url(url).get_backend_name()
        except ArgumentError:
            raise ValueError(
                "cannot be read as a database URL; expected postgresql://USER@HOST:PORT/NAME or sqlite:///PATH"
            ) from None
        if backend not in DATABASE_BACKENDS:
            raise ValueError(f"models are stored in PostgreSQL or SQLite, not {backend!r}")
        return url

    @model_validator(mode="after")
    def _default_scene_threads(self) -> Settings:
        """0 scene threads: 2 on PostgreSQL, where a second thread learns a scene while the first
        waits for its commit; 1 on SQLite, where the process's writes take turns on one write lock
        anyway, so a second thread only takes the GIL from the first (docs/scaling.md)."""
        if self.scene_threads == 0:
            self.scene_threads = 1 if is_sqlite(self.resolved_database_url) else 2
        return self

    @model_validator(mode="after")
    def _refuse_unsafe_keys(self) -> Settings:
        if self.read_key is not None and self.write_key is None:
            raise ValueError("CONTEXTWEB_READ_KEY is set without CONTEXTWEB_WRITE_KEY: every write route would be open")
        if self.environment == "production" and self.write_key is None:
            raise ValueError("CONTEXTWEB_ENVIRONMENT=production needs CONTEXTWEB_WRITE_KEY")
        return self

    @property
    def resolved_database_url(self) -> str:
        return self.database_url or DEFAULT_DATABASE_URL

    @property
    def auth_enabled(self) -> bool:
        """Keys are checked as soon as a write key is configured; without one the server stays on loopback."""
        return self.write_key is not None

    def bind_host(self) -> str:
        """The host to bind: the configured one, or loopback when no key protects the routes."""
        return self.host if self.auth_enabled else "127.0.0.1"
