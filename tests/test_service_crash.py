"""Nothing acknowledged is ever lost: SIGKILL the server while a robot posts scenes, restart, check.

A real ``contextweb serve`` process on a free port; a client thread posts
scenes with Idempotency-Keys and records every 201 it gets. The server is
killed mid-stream; after a restart every acknowledged scene is stored with the
answer it was acknowledged with, n_kw equals the counts of the stored
assignments, and the robot's retry of its interrupted request is safe. The
server is asked for 0.0.0.0 without an API key, so it must say it stays on
loopback.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import httpx
import pytest

from storage.database import create_database_engine, create_session_makers
from storage.repositories import incremental_lda as lda_repository
from tests.conftest import FAST_HYPERPARAMETERS

PROJECT_ROOT = Path(__file__).resolve().parents[1]
SCENE = {"objects": [{"concepts": ["cup", "hard", "short"]}, {"concepts": ["ball", "soft", "noisy", "spoon"]}]}


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _start_server(database_url: str, port: int, log: Path) -> subprocess.Popen[bytes]:
    env = {key: value for key, value in os.environ.items() if not key.startswith("CONTEXTWEB_")}
    env |= {"CONTEXTWEB_DATABASE_URL": database_url, "CONTEXTWEB_PORT": str(port), "CONTEXTWEB_HOST": "0.0.0.0"}
    process = subprocess.Popen(
        [sys.executable, "-m", "app.cli", "serve", "--log-level", "warning"],
        cwd=PROJECT_ROOT,
        env=env,
        stdout=log.open("ab"),
        stderr=subprocess.STDOUT,
    )
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        try:
            if httpx.get(f"http://127.0.0.1:{port}/readyz", timeout=1).status_code == 200:
                return process
        except httpx.TransportError:
            pass
        if process.poll() is not None:
            break
        time.sleep(0.1)
    process.kill()
    pytest.fail(f"the server did not become ready:\n{log.read_text()}")


def _post_until_killed(base: str, model_id: str, acknowledged: dict[str, dict], in_flight: list[str]) -> None:
    with httpx.Client(base_url=base, timeout=10) as client:
        for n in range(10_000):
            key = f"scene-{n}"
            in_flight[:] = [key]
            try:
                response = client.post(f"/v1/models/{model_id}/scenes", json=SCENE, headers={"Idempotency-Key": key})
            except httpx.TransportError:
                return
            assert response.status_code == 201, response.text
            acknowledged[key] = response.json()


def test_sigkill_while_posting_loses_no_acknowledged_scene(database_url: str, tmp_path: Path) -> None:
    port, log = _free_port(), tmp_path / "server.log"
    base = f"http://127.0.0.1:{port}"
    server = _start_server(database_url, port, log)
    try:
        body = {"name": "robot", "seed": 1, "hyperparameters": FAST_HYPERPARAMETERS}
        model_id = httpx.post(f"{base}/v1/models", json=body).json()["id"]
        acknowledged: dict[str, dict] = {}
        in_flight: list[str] = []
        robot = threading.Thread(target=_post_until_killed, args=(base, model_id, acknowledged, in_flight))
        robot.start()
        while len(acknowledged) < 25 and robot.is_alive():
            time.sleep(0.005)
        server.send_signal(signal.SIGKILL)
        server.wait()
        robot.join(timeout=30)
        assert not robot.is_alive() and len(acknowledged) >= 25

        server = _start_server(database_url, port, log)
        stored = httpx.get(f"{base}/v1/models/{model_id}/scenes", params={"limit": 500}).json()
        assert stored["total"] in (len(acknowledged), len(acknowledged) + 1)
        for answer in acknowledged.values():
            assert httpx.get(f"{base}/v1/models/{model_id}/scenes/{answer['scene_id']}").json() == answer

        retry = httpx.post(f"{base}/v1/models/{model_id}/scenes", json=SCENE, headers={"Idempotency-Key": in_flight[0]})
        assert retry.status_code == 201
        assert retry.json()["scene_id"] == len(acknowledged)
        after = httpx.get(f"{base}/v1/models/{model_id}").json()
        assert after["scene_count"] == len(acknowledged) + 1
    finally:
        server.kill()
        server.wait()
    assert "binds 127.0.0.1 only (not 0.0.0.0)" in log.read_text(), "without keys the server stays on loopback"
    engine = create_database_engine(database_url)
    read, _ = create_session_makers(engine)
    with read() as session:
        assert lda_repository.stored_counts(session, model_id) == lda_repository.assignment_counts(session, model_id)
    engine.dispose()
