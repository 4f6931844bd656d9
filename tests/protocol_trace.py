"""libpq's own trace of what a test's connections send to PostgreSQL."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from psycopg import pq
from sqlalchemy import Engine, event


class ProtocolTrace:
    """libpq's trace of every message on the connections ``engine`` checks out (psycopg's
    ``PGconn.trace``): what was sent, not what a mock says was sent."""

    def __init__(self, engine: Engine, folder: Path) -> None:
        self._file = (folder / "libpq-trace.txt").open("w+")
        event.listen(engine, "checkout", self._trace)

    def _trace(self, dbapi_connection: Any, _record: Any, _proxy: Any) -> None:
        dbapi_connection.pgconn.trace(self._file.fileno())
        dbapi_connection.pgconn.set_trace_flags(pq.Trace.SUPPRESS_TIMESTAMPS | pq.Trace.REGRESS_MODE)

    def sent(self) -> list[str]:
        """The messages the client sent, as "Sync", 'Parse "" "BEGIN"' and so on."""
        self._file.flush()
        self._file.seek(0)
        return [
            " ".join(part.strip() for part in line.split("\t")[2:])
            for line in self._file.read().splitlines()
            if line.startswith("F\t")
        ]
