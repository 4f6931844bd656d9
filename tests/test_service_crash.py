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

import threading
import time
from pathlib import Path

import httpx

from storage.database import create_database_engine, create_session_makers
from storage.repositories import incremental_lda as lda_repository
from tests.conftest import FAST_HYPERPARAMETERS
from tests.servers import free_port, start_server_or_fail

SCENE = {"objects": [{"concepts": ["cup", "hard", "short"]}, {"concepts": ["ball", "soft", "noisy", "spoon"]}]}
#: Asked for 0.0.0.0 without an API key: the server must stay on loopback (and say so).
ALL_INTERFACES = {"CONTEXTWEB_HOST": "0.0.0.0"}


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
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    server = start_server_or_fail(database_url, tmp_path, port=port, env=ALL_INTERFACES)
    try:
        body = {"name": "robot", "seed": 1, "hyperparameters": FAST_HYPERPARAMETERS}
        model_id = httpx.post(f"{base}/v1/models", json=body).json()["id"]
        acknowledged: dict[str, dict] = {}
        in_flight: list[str] = []
        robot = threading.Thread(target=_post_until_killed, args=(base, model_id, acknowledged, in_flight))
        robot.start()
        while len(acknowledged) < 25 and robot.is_alive():
            time.sleep(0.005)
        server.kill()
        robot.join(timeout=30)
        assert not robot.is_alive() and len(acknowledged) >= 25

        server = start_server_or_fail(database_url, tmp_path, port=port, env=ALL_INTERFACES)
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
    log = server.log_path.read_text()
    assert "binds 127.0.0.1 only (not 0.0.0.0)" in log, "without keys the server stays on loopback"
    engine = create_database_engine(database_url)
    read, _ = create_session_makers(engine)
    with read() as session:
        assert lda_repository.stored_counts(session, model_id) == lda_repository.assignment_counts(session, model_id)
    engine.dispose()
