"""The service's settings: one pydantic-settings class, read from ``CONTEXTWEB_*`` variables.

Every field is documented in docs/operations.md. A ``Settings`` is created once
by the CLI (or by a test) and handed to :func:`app.main.create_app`; nothing
else reads the environment.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, SecretStr, field_validator, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from storage.database import DEFAULT_DATABASE_URL

LOOPBACK_HOSTS = frozenset({"127.0.0.1", "::1", "localhost"})


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
    write_key: SecretStr | None = Field(None, description="API key of the robots (write and read routes).")
    read_key: SecretStr | None = Field(None, description="API key of the dashboards (read routes only).")
    max_body_bytes: int = Field(8 * 1024 * 1024, ge=1024, description="Largest request body accepted; more is a 413.")
    sqlite_synchronous: Literal["FULL", "NORMAL"] = Field(
        "FULL", description="SQLite `synchronous` pragma: FULL makes every acknowledged commit survive a power loss."
    )
    database_pool_size: int = Field(8, ge=1, description="Connections kept open per process.")
    stream_queue_size: int = Field(256, ge=1, description="Events buffered per websocket client before it is dropped.")
    worker_threads: int = Field(16, ge=1, description="Threads running the blocking routes (numba, database).")

    @field_validator("write_key", "read_key", mode="before")
    @classmethod
    def _empty_key_is_unset(cls, value: object) -> object:
        """``CONTEXTWEB_READ_KEY=`` (compose's ``${CONTEXTWEB_READ_KEY:-}``) means no key, not the empty key."""
        if value is None or (isinstance(value, str) and not value.strip()):
            return None
        if isinstance(value, SecretStr) and not value.get_secret_value().strip():
            return None
        return value

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
