"""The offline queue: requests the service could not take, kept on the robot's disk.

A robot keeps sensing while the network or the service is down. Writes that
can wait (scenes, training interactions) go into a SQLite file (stdlib
``sqlite3``) together with the ``Idempotency-Key`` they were first sent with,
and are sent again, oldest first, when the service answers. Because the key is
the one of the first attempt, a request that did reach the service before the
connection dropped is recognised there and not counted twice.

SQLite rather than a JSON file: one insert is atomic and durable
(``synchronous=FULL``), so a robot that loses power mid-write keeps a
consistent queue. Requests the service refuses for good (a 4xx other than 429)
move to a ``rejected`` table with the service's answer, so one bad request
never blocks the ones behind it and nothing is lost silently.
"""

from __future__ import annotations

import json
import sqlite3
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

_SCHEMA = """
CREATE TABLE IF NOT EXISTS pending_request (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    method TEXT NOT NULL,
    path TEXT NOT NULL,
    body TEXT NOT NULL,
    idempotency_key TEXT NOT NULL UNIQUE,
    created_at REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS rejected_request (
    id INTEGER PRIMARY KEY,
    method TEXT NOT NULL,
    path TEXT NOT NULL,
    body TEXT NOT NULL,
    idempotency_key TEXT NOT NULL,
    created_at REAL NOT NULL,
    status_code INTEGER NOT NULL,
    answer TEXT NOT NULL,
    rejected_at REAL NOT NULL
);
"""
_COLUMNS = "id, method, path, body, idempotency_key, created_at"


@dataclass(frozen=True)
class QueuedRequest:
    """One request waiting on disk; ``id`` orders the queue (first in, first out)."""

    id: int
    method: str
    path: str
    body: Any
    idempotency_key: str
    created_at: float

    @classmethod
    def _from_row(cls, row: tuple[Any, ...]) -> QueuedRequest:
        id_, method, path, body, key, created_at = row
        return cls(id_, method, path, json.loads(body), key, created_at)


class OfflineQueue:
    """A first-in-first-out queue of JSON requests in a SQLite file at ``path``."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._lock = threading.Lock()
        self._db = sqlite3.connect(self.path, check_same_thread=False, isolation_level=None)
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute("PRAGMA synchronous=FULL")
        self._db.executescript(_SCHEMA)

    def put(self, method: str, path: str, body: Any, idempotency_key: str) -> QueuedRequest:
        """Append a request; a key already queued is kept once (its first body wins)."""
        now = time.time()
        with self._lock:
            self._db.execute(
                "INSERT OR IGNORE INTO pending_request (method, path, body, idempotency_key, created_at) "
                "VALUES (?, ?, ?, ?, ?)",
                (method, path, json.dumps(body), idempotency_key, now),
            )
            row = self._db.execute(
                f"SELECT {_COLUMNS} FROM pending_request WHERE idempotency_key = ?", (idempotency_key,)
            ).fetchone()
        return QueuedRequest._from_row(row)

    def oldest(self) -> QueuedRequest | None:
        with self._lock:
            row = self._db.execute(f"SELECT {_COLUMNS} FROM pending_request ORDER BY id LIMIT 1").fetchone()
        return None if row is None else QueuedRequest._from_row(row)

    def pending(self) -> list[QueuedRequest]:
        """Every waiting request, oldest first."""
        with self._lock:
            rows = self._db.execute(f"SELECT {_COLUMNS} FROM pending_request ORDER BY id").fetchall()
        return [QueuedRequest._from_row(row) for row in rows]

    def remove(self, request_id: int) -> None:
        """Forget a request the service has taken."""
        with self._lock:
            self._db.execute("DELETE FROM pending_request WHERE id = ?", (request_id,))

    def reject(self, request_id: int, status_code: int, answer: Any) -> None:
        """Move a request the service refused for good to the ``rejected`` table."""
        with self._lock:
            self._db.execute("BEGIN IMMEDIATE")
            self._db.execute(
                f"INSERT INTO rejected_request ({_COLUMNS}, status_code, answer, rejected_at) "
                f"SELECT {_COLUMNS}, ?, ?, ? FROM pending_request WHERE id = ?",
                (status_code, json.dumps(answer), time.time(), request_id),
            )
            self._db.execute("DELETE FROM pending_request WHERE id = ?", (request_id,))
            self._db.execute("COMMIT")

    def rejected(self) -> list[tuple[QueuedRequest, int, Any]]:
        """Refused requests with the status and body the service answered."""
        with self._lock:
            rows = self._db.execute(
                f"SELECT {_COLUMNS}, status_code, answer FROM rejected_request ORDER BY id"
            ).fetchall()
        return [(QueuedRequest._from_row(row[:6]), row[6], json.loads(row[7])) for row in rows]

    def __len__(self) -> int:
        with self._lock:
            return int(self._db.execute("SELECT COUNT(*) FROM pending_request").fetchone()[0])

    def close(self) -> None:
        with self._lock:
            self._db.close()
