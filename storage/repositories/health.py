"""The database round trips of the readiness probe: a read, and a small write."""

from __future__ import annotations

from sqlalchemy import text
from sqlalchemy.orm import Session

from storage.database import DriverStatements
from storage.models import StorageProbe, utc_now


def ping(session: Session) -> None:
    session.execute(text("SELECT 1"))


def probe_write(session: Session, process_id: str) -> None:
    """Rewrite this process's probe row in the caller's transaction (commit it to test the write)."""
    driver = DriverStatements(session)
    driver.execute(_UPSERT_PROBE, (process_id, driver.bind(StorageProbe.__table__.c.probed_at)(utc_now())))


_UPSERT_PROBE = "INSERT INTO storage_probe (id, probed_at) VALUES (?, ?) ON CONFLICT (id) DO UPDATE SET probed_at = excluded.probed_at"
