"""The bridge against a real service process: killed mid-stream, restarted, every scene exactly once.

:class:`ServiceProcess` (also used by the dashboard and docker tests) runs
``contextweb serve`` in a subprocess on a free loopback port with a temporary
SQLite database, and stops only the process it started.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

import httpx
import pytest

from bridge import Client, QueuedScene, RetryPolicy, SceneObject
from bridge.models import HelloEvent, SceneEvent, SceneRead
from tests.servers import migrate

PROJECT = Path(__file__).resolve().parents[1]
WRITE_KEY = "robot-write-key"
READ_KEY = "dashboard-read-key"
STARTUP_SECONDS = 90.0


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


class ServiceProcess:
    """One service process on ``127.0.0.1:port``; ``command`` defaults to ``contextweb serve``, on a
    database migrated first (as ``make run`` does); another command (the container's entry point)
    migrates for itself."""

    def __init__(self, tmp_path: Path, command: Sequence[str] | None = None, port: int | None = None) -> None:
        self.port = port or free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.command = list(command or [sys.executable, "-m", "app.cli", "serve"])
        self.migrate_first = command is None
        self.log_path = tmp_path / f"service-{self.port}.log"
        self.env = os.environ | {
            "CONTEXTWEB_DATABASE_URL": f"sqlite:///{tmp_path / 'contextweb.sqlite3'}",
            "CONTEXTWEB_HOST": "127.0.0.1",
            "CONTEXTWEB_PORT": str(self.port),
            "CONTEXTWEB_WRITE_KEY": WRITE_KEY,
            "CONTEXTWEB_READ_KEY": READ_KEY,
            "NUMBA_CACHE_DIR": os.environ.get("NUMBA_CACHE_DIR", str(PROJECT / ".cache" / "numba")),
            "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}",
        }
        self.process: subprocess.Popen[bytes] | None = None

    def start(self) -> ServiceProcess:
        if self.migrate_first:
            migrate(self.env["CONTEXTWEB_DATABASE_URL"])
        with self.log_path.open("ab") as log:
            self.process = subprocess.Popen(
                self.command, cwd=PROJECT, env=self.env, stdout=log, stderr=subprocess.STDOUT
            )
        deadline = time.monotonic() + STARTUP_SECONDS
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                raise RuntimeError(f"service exited with {self.process.returncode}:\n{self.log()}")
            try:
                if httpx.get(f"{self.url}/readyz", timeout=1.0).status_code == 200:
                    return self
            except httpx.TransportError:
                pass
            time.sleep(0.1)
        self.stop()
        raise RuntimeError(f"service not ready after {STARTUP_SECONDS} s:\n{self.log()}")

    def stop(self, sig: int = signal.SIGTERM) -> None:
        if self.process is None or self.process.poll() is not None:
            return
        self.process.send_signal(sig)
        try:
            self.process.wait(timeout=20)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait(timeout=10)

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")[-4000:]


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServiceProcess]:
    """One service for the module (starting one costs seconds); the crash test restarts it in place."""
    process = ServiceProcess(tmp_path_factory.mktemp("service")).start()
    try:
        yield process
    finally:
        process.stop()


CONTEXT_SCENES = (
    ["cup", "hard", "silent", "short", "round"],
    ["ball", "soft", "noisy", "round", "thick"],
    ["tool", "hard", "tall", "thin", "edgy"],
)


def _scene(i: int) -> list[SceneObject]:
    """Scene ``i``: two objects of one context, told apart by ``i`` so each body is unique."""
    concepts = CONTEXT_SCENES[i % 3]
    return [
        SceneObject.from_concepts(concepts),
        SceneObject.from_concepts({concepts[0]: 1.0, concepts[1]: round(0.5 + i / 1000, 3)}),
    ]


@pytest.mark.slow
def test_scenes_arrive_exactly_once_across_a_service_crash(service: ServiceProcess, tmp_path: Path) -> None:
    policy = RetryPolicy(max_retries=2, initial_delay=0.02, max_delay=0.2)
    robot = Client(service.url, WRITE_KEY, retry_policy=policy, offline_queue=tmp_path / "robot-queue.sqlite3", seed=3)
    model_id = robot.models.create("exactly-once").id
    dashboard = Client(service.url, READ_KEY, retry_policy=policy)
    events: list[HelloEvent | SceneEvent] = []
    watcher = threading.Thread(
        target=lambda: events.extend(e for e in dashboard.stream(model_id) if isinstance(e, (HelloEvent, SceneEvent))),
        daemon=True,  # a failing assertion must not leave pytest waiting for the stream at exit
    )
    watcher.start()

    answers: list[SceneRead | QueuedScene] = []
    keys: list[str] = []

    def post(i: int) -> None:
        key = f"scene-{i}-{model_id[:8]}"
        keys.append(key)
        answers.append(robot.scenes.create(model_id, _scene(i), idempotency_key=key))

    for i in range(8):
        post(i)
    # Crash the service while the robot keeps posting: whichever scene is in flight is either learned
    # with its answer lost, or never received; both must end up counted once.
    killer = threading.Timer(0.05, service.stop, kwargs={"sig": signal.SIGKILL})
    killer.start()
    for i in range(8, 14):
        post(i)
        time.sleep(0.02)
    killer.join()
    for i in range(14, 20):
        post(i)
    queued = [a for a in answers if isinstance(a, QueuedScene)]
    assert len(queued) >= 6 and len(robot.offline_queue) == len(queued)
    assert [a.idempotency_key for a in queued] == keys[20 - len(queued) :], "once offline, every later scene waits"

    service.start()
    _wait_for(lambda: sum(isinstance(e, HelloEvent) for e in events) >= 2, "the stream to reconnect")
    for i in range(20, 26):
        post(i)
    assert len(robot.offline_queue) == 0 and robot.offline_queue.rejected() == []
    assert all(isinstance(a, SceneRead) for a in answers[20:])

    history = list(robot.scenes.iterate(model_id, page_size=7))
    assert [s.scene_id for s in history] == list(range(26)), "26 scenes made, 26 learned"
    # Every key maps to its own stored scene, in the order the robot made them: replays change nothing.
    with httpx.Client(base_url=service.url, headers={"X-API-Key": WRITE_KEY}) as raw:
        for i, key in enumerate(keys):
            replay = raw.post(f"/v1/models/{model_id}/scenes", json=_body(i), headers={"Idempotency-Key": key})
            assert replay.status_code == 201 and replay.headers.get("Idempotent-Replayed") == "true"
            assert replay.json()["scene_id"] == i
    assert robot.models.get(model_id).scene_count == 26

    # The stream is a live view, not a log: a scene committed in the instant before the crash may never
    # be announced. Everything learned after the reconnection's hello must be, and nothing twice.
    rejoined = [e for e in events if isinstance(e, HelloEvent)][1].scene_count
    after = set(range(rejoined, 26))
    _wait_for(
        lambda: after <= {e.scene_id for e in events if isinstance(e, SceneEvent)}, "the stream to see new scenes"
    )
    dashboard.close()
    robot.close()
    watcher.join(timeout=5)
    seen = [e.scene_id for e in events if isinstance(e, SceneEvent)]
    assert len(seen) == len(set(seen)) and set(seen) <= set(range(26))
    print(f"exactly-once: 26 scenes, {len(queued)} through the offline queue, {len(seen)} seen on the stream")


def _body(i: int) -> dict:
    return {"objects": [obj.model_dump(mode="json", exclude_defaults=True) for obj in _scene(i)]}


def _wait_for(condition, what: str, timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.05)


def test_stream_refusals_raise_the_rest_error_classes(service: ServiceProcess) -> None:
    from bridge import AuthenticationError, ModelNotFoundError, PermissionDeniedError

    with Client(service.url, "wrong-key") as stranger, pytest.raises(AuthenticationError):
        next(stranger.stream("anything"))
    with Client(service.url, READ_KEY) as dashboard:
        with pytest.raises(ModelNotFoundError):
            next(dashboard.stream("no-such-model"))
        with pytest.raises(PermissionDeniedError):
            dashboard.models.create("not with the read key")
