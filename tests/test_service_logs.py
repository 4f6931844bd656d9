"""No API key appears in the server's log: the websocket's ``api_key`` query value is redacted; and
every worker's own lines reach the log, with their level.

A real ``contextweb serve --workers 2`` at log level info (uvicorn logs each
websocket's path with its query string); a dashboard opens the stream with its
key in the query, as browsers must.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import httpx
from websockets.sync.client import connect

from app.logs import REDACTED, RedactKeys, redact_keys
from tests.conftest import migrated_database
from tests.servers import running_server

WRITE_KEY, READ_KEY = "robot-secret-4f1c", "dashboard-secret-9e2a"


def test_redaction_keeps_the_rest_of_the_line() -> None:
    line = '127.0.0.1:5 - "WebSocket /v1/models/ab/stream?x=1&api_key=s3cr%C3%A9t&y=2" [accepted]'
    assert redact_keys(line) == f'127.0.0.1:5 - "WebSocket /v1/models/ab/stream?x=1&api_key={REDACTED}&y=2" [accepted]'
    record = logging.LogRecord("uvicorn.error", logging.INFO, "", 0, '%s - "WebSocket %s"', ("c", "/s?api_key=k"), None)
    assert RedactKeys().filter(record) and record.getMessage() == f'c - "WebSocket /s?api_key={REDACTED}"'


def test_the_streams_key_never_reaches_the_log(request, tmp_path: Path) -> None:
    url = migrated_database("sqlite", request, tmp_path)
    keys = {"CONTEXTWEB_WRITE_KEY": WRITE_KEY, "CONTEXTWEB_READ_KEY": READ_KEY}
    with running_server(url, tmp_path, args=["--workers", "2"], env=keys, log_level="info") as server:
        model = httpx.post(f"{server.base_url}/v1/models", json={"name": "m"}, headers={"X-API-Key": WRITE_KEY})
        assert model.status_code == 201, model.text
        stream = f"ws://127.0.0.1:{server.port}/v1/models/{model.json()['id']}/stream?api_key={READ_KEY}"
        with connect(stream, open_timeout=20) as websocket:
            assert '"hello"' in websocket.recv(timeout=20)
        deadline = time.monotonic() + 60  # the other worker may still be warming up
        while server.log(tail=100_000).count("model(s) loaded from") < 2 and time.monotonic() < deadline:
            time.sleep(0.2)
        log = server.log(tail=100_000)
    assert "WebSocket /v1/models/" in log and f"api_key={REDACTED}" in log, log[-2000:]
    assert READ_KEY not in log and WRITE_KEY not in log
    # Each worker writes the service's own lines, with their level: a worker is a new interpreter,
    # and before log_config configured the root logger its start-up lines were lost (a drill).
    loaded = [line for line in log.splitlines() if "model(s) loaded from" in line]
    assert len(loaded) == 2 and all(line.startswith("INFO:     contextweb: ") for line in loaded), log[-3000:]
