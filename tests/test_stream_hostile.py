"""Websockets under hostile clients (docs/stream.md): one that stops reading, SIGTERM's close code, the origin check.

The slow-client and SIGTERM tests run real ``contextweb serve`` processes (tests/servers.py)
and a client that genuinely stops reading from its TCP socket (:class:`StalledClient`). Whether
the server reset that socket is read from the client's own TCP state, without reading from it.
"""

from __future__ import annotations

import base64
import json
import os
import queue
import signal
import socket
import threading
import time
from collections.abc import Iterator
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import httpx
import pytest
import uvicorn
from fastapi.testclient import TestClient
from starlette.websockets import WebSocketDisconnect
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect

from app.main import create_app
from app.settings import Settings
from app.stream import CLOSE_FORBIDDEN, CLOSE_SERVICE_RESTART
from app.websocket_protocol import CLOSE_HANDSHAKE_SECONDS, RESET_EXTENSION, ResettableWebSocketProtocol
from tests.conftest import FAST_HYPERPARAMETERS, make_settings, migrated_database
from tests.servers import ServerProcess, free_port, running_server, start_server_or_fail

pytestmark = [
    pytest.mark.timeout(240),
    pytest.mark.skipif(not hasattr(socket, "TCP_INFO"), reason="reads the client's TCP state (Linux)"),
]

#: The send deadline of the slow-client server (CONTEXTWEB_STREAM_SEND_TIMEOUT_SECONDS).
SEND_SECONDS = 1.0
#: Added to the documented bound (send deadline + close handshake) for the feed's 50 ms polls and a busy machine.
SLACK_SECONDS = 3.0
#: Scenes posted at once; each event is ~39 kB, about 4 times what the buffers between server and client hold.
BURST_SCENES = 20
DASHBOARD_ORIGIN = "https://dash.example.com"
#: ``tcpi_state`` (the first byte of ``TCP_INFO``) of a connection that is over; after an RST, not a FIN.
TCP_CLOSE = 7
TCP_ESTABLISHED = 1


def big_scene() -> dict[str, Any]:
    """A scene of 32 objects of 8 long words (40 distinct words): its stream event is ~39 kB."""
    names = [f"concept-with-a-rather-long-name-{n:03d}" for n in range(48)]
    return {"objects": [{"concepts": names[(n * 7) % 40 : (n * 7) % 40 + 8]} for n in range(32)]}


class StalledClient:
    """A websocket client that does the handshake by hand and then never reads from its socket again.

    It asks for a small receive buffer and advertises a small MSS (``TCP_MAXSEG``): the server's
    kernel sizes its send buffer from the MSS, ~135 kB instead of ~4 MB on loopback, so a few
    scenes fill the buffers between the two (measured: ~6 kB client, ~135 kB server kernel,
    64 kB in uvicorn's transport before it stops writing).
    """

    def __init__(self, port: int, path: str) -> None:
        self.sock = socket.socket()
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_MAXSEG, 1000)
        self.sock.settimeout(10)
        self.sock.connect(("127.0.0.1", port))
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall(
            f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
            f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n".encode()
        )
        response = b""
        while not response.endswith(b"\r\n\r\n"):  # byte by byte: nothing past the headers is read
            response += self.sock.recv(1)
        assert response.startswith(b"HTTP/1.1 101"), response
        self.port = self.sock.getsockname()[1]

    def tcp_state(self) -> int:
        return self.sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_INFO, 1)[0]

    def wait_until_reset(self, seconds: float) -> float:
        """Seconds until the server reset the connection (polled without reading); fails after ``seconds``."""
        start = time.monotonic()
        while self.tcp_state() == TCP_ESTABLISHED:
            if time.monotonic() - start > seconds:
                raise AssertionError(f"the server did not drop the stalled client within {seconds} s")
            time.sleep(0.02)
        return time.monotonic() - start

    def read_to_end(self) -> bool:
        """Read what the socket holds; True when it ends in a reset, False on a clean end of stream."""
        try:
            while self.sock.recv(65536):
                pass
        except ConnectionResetError:
            return True
        return False

    def close(self) -> None:
        self.sock.close()


class EventReader:
    """A healthy dashboard: its messages read on a thread as they come, the close code kept."""

    def __init__(self, ws: ClientConnection) -> None:
        self.messages: list[dict[str, Any]] = []
        self.close_code: int | None = None
        self._thread = threading.Thread(target=self._read, args=(ws,), daemon=True)
        self._thread.start()

    def _read(self, ws: ClientConnection) -> None:
        try:
            while True:
                self.messages.append(json.loads(ws.recv()))
        except ConnectionClosed as closed:
            self.close_code = closed.rcvd.code if closed.rcvd else None

    def scene_ids(self) -> list[int]:
        return [message["scene_id"] for message in self.messages if message["type"] == "scene"]

    def wait_for_scenes(self, count: int, seconds: float = 30.0) -> None:
        deadline = time.monotonic() + seconds
        while len(self.scene_ids()) < count:
            assert time.monotonic() < deadline, f"{len(self.scene_ids())} of {count} scene events in {seconds} s"
            time.sleep(0.02)

    def wait_closed(self, seconds: float = 15.0) -> int | None:
        self._thread.join(seconds)
        assert not self._thread.is_alive(), f"the stream was not closed within {seconds} s"
        return self.close_code


def create_model(http: httpx.Client) -> str:
    response = http.post("/v1/models", json={"name": "watched", "hyperparameters": FAST_HYPERPARAMETERS})
    assert response.status_code == 201, response.text
    return response.json()["id"]


def post_scenes(http: httpx.Client, model_id: str, count: int) -> None:
    for _ in range(count):
        response = http.post(f"/v1/models/{model_id}/scenes", json=big_scene())
        assert response.status_code == 201, response.text


def stream_url(server: ServerProcess, model_id: str) -> str:
    return f"ws://127.0.0.1:{server.port}/v1/models/{model_id}/stream"


def assert_clean_log(server: ServerProcess) -> None:
    """No traceback, no error line: cancelled sends and resets left uvicorn's protocol consistent."""
    log = server.log(tail=200_000)
    assert "Traceback" not in log and "ERROR" not in log, log[-8000:]


@pytest.fixture(scope="module")
def slow_client_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    """A server with a 1 s send deadline and a queue too large to fill: only the deadline drops a client."""
    directory = tmp_path_factory.mktemp("slow-client")
    env = {
        "CONTEXTWEB_STREAM_SEND_TIMEOUT_SECONDS": str(SEND_SECONDS),
        "CONTEXTWEB_STREAM_QUEUE_SIZE": "100000",
        "CONTEXTWEB_ALLOWED_ORIGINS": json.dumps([DASHBOARD_ORIGIN]),
        "CONTEXTWEB_SQLITE_SYNCHRONOUS": "NORMAL",
    }
    database_url = f"sqlite:///{directory / 'contextweb.sqlite3'}"
    with running_server(database_url, directory, env=env, log_level="info") as server:
        yield server


def test_a_client_that_stops_reading_is_reset_within_the_bound(slow_client_server: ServerProcess) -> None:
    server = slow_client_server
    with server.client() as http:
        model_id = create_model(http)
        with connect(stream_url(server, model_id), max_queue=None, open_timeout=10) as ws:
            healthy = EventReader(ws)
            stalled = StalledClient(server.port, f"/v1/models/{model_id}/stream")
            try:
                post_scenes(http, model_id, BURST_SCENES)
                # By now the forwarder of the stalled client is blocked on a send that cannot complete.
                bound = SEND_SECONDS + CLOSE_HANDSHAKE_SECONDS + SLACK_SECONDS
                waited = stalled.wait_until_reset(bound)
                post_scenes(http, model_id, 2)  # the robot's posts still succeed
                assert stalled.tcp_state() == TCP_CLOSE
                assert stalled.read_to_end(), "the connection should end in a reset: the close frame cannot get through"
            finally:
                stalled.close()
            healthy.wait_for_scenes(BURST_SCENES + 2)
            assert healthy.scene_ids() == list(range(BURST_SCENES + 2)), "the healthy dashboard missed nothing"
    print(f"stalled client reset {waited:.2f} s after the burst (bound {bound:.0f} s)")
    assert f"dropping 127.0.0.1:{stalled.port} (client too slow: a send waited 1 s)" in server.log(tail=200_000)
    assert_clean_log(server)


def test_an_origin_outside_the_allowed_list_is_closed_with_4403(slow_client_server: ServerProcess) -> None:
    with slow_client_server.client() as http:
        url = stream_url(slow_client_server, create_model(http))
    with connect(url, origin="https://evil.example", open_timeout=10) as ws, pytest.raises(ConnectionClosed) as closed:
        ws.recv(timeout=10)
    assert closed.value.rcvd is not None and closed.value.rcvd.code == CLOSE_FORBIDDEN
    for origin in (DASHBOARD_ORIGIN, None):  # the dashboard's origin, and a robot that sends none
        with connect(url, origin=origin, open_timeout=10) as ws:  # type: ignore[arg-type]
            assert json.loads(ws.recv(timeout=10))["type"] == "hello"


@pytest.mark.parametrize("allowed", [[DASHBOARD_ORIGIN], []], ids=["checked", "unchecked"])
def test_the_origin_check_in_process(database_url: str, model_id: str, allowed: list[str]) -> None:
    settings = make_settings(database_url, allowed_origins=allowed)
    path = f"/v1/models/{model_id}/stream"
    with TestClient(create_app(settings)) as client:
        for origin in ("HTTPS://Dash.Example.com/", None):
            headers = {"origin": origin} if origin else {}
            with client.websocket_connect(path, headers=headers) as ws:
                assert ws.receive_json()["type"] == "hello"
        with client.websocket_connect(path, headers={"origin": "null"}) as ws:
            if allowed:
                with pytest.raises(WebSocketDisconnect) as closed:
                    ws.receive_json()
                assert closed.value.code == CLOSE_FORBIDDEN
            else:
                assert ws.receive_json()["type"] == "hello"


def test_allowed_origins_are_read_as_browsers_send_them(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CONTEXTWEB_ALLOWED_ORIGINS", '["https://Dash.Example.com/", "http://127.0.0.1:8000"]')
    assert Settings().allowed_origins == ["https://dash.example.com", "http://127.0.0.1:8000"]


def test_sigterm_closes_streams_with_1012_even_behind_a_stalled_client(tmp_path: Path) -> None:
    """uvicorn closes every websocket with 1012 on SIGTERM; a client whose socket is full cannot hold the exit."""
    database_url = f"sqlite:///{tmp_path / 'contextweb.sqlite3'}"
    env = {"CONTEXTWEB_STREAM_SEND_TIMEOUT_SECONDS": "120", "CONTEXTWEB_SQLITE_SYNCHRONOUS": "NORMAL"}
    with ExitStack() as closing:
        server = start_server_or_fail(database_url, tmp_path, env=env, log_level="info")
        closing.callback(server.stop)  # idempotent: a no-op after the stop under test
        with server.client() as http:
            model_id = create_model(http)
            ws = closing.enter_context(connect(stream_url(server, model_id), max_queue=None, open_timeout=10))
            healthy = EventReader(ws)
            stalled = StalledClient(server.port, f"/v1/models/{model_id}/stream")
            closing.callback(stalled.close)
            post_scenes(http, model_id, BURST_SCENES)
            healthy.wait_for_scenes(BURST_SCENES)  # every event is published: the stalled one's send is blocked
        assert stalled.tcp_state() == TCP_ESTABLISHED, "the 120 s send deadline should not have dropped it yet"
        started = time.monotonic()
        returncode = server.stop()
        stopped_in = time.monotonic() - started
        assert healthy.wait_closed() == CLOSE_SERVICE_RESTART
        assert stalled.tcp_state() == TCP_CLOSE
    # uvicorn re-raises the SIGTERM once it has shut down; a SIGKILL (after 15 s) would mean the stalled client held it.
    assert returncode in (0, -signal.SIGTERM), server.log()
    print(f"SIGTERM to exit: {stopped_in:.2f} s")
    assert stopped_in < CLOSE_HANDSHAKE_SECONDS + 2 * SLACK_SECONDS
    assert_clean_log(server)


@pytest.mark.slow
def test_sigterm_with_two_workers_closes_every_stream_with_1012(request: pytest.FixtureRequest, tmp_path: Path) -> None:
    # Migrated first: two workers that start on an empty database both create alembic_version, and one fails.
    database_url = migrated_database("sqlite", request, tmp_path)
    with running_server(database_url, tmp_path, args=["--workers", "2"], log_level="info") as server:
        with server.client() as http:
            url = stream_url(server, create_model(http))
        with ExitStack() as streams:
            readers = []
            for _ in range(6):  # spread over both workers by the kernel's accept
                ws = streams.enter_context(connect(url, open_timeout=10))
                assert json.loads(ws.recv(timeout=10))["type"] == "hello"
                readers.append(EventReader(ws))
            returncode = server.stop()
    assert returncode in (0, -signal.SIGTERM), server.log()
    assert [reader.wait_closed() for reader in readers] == [CLOSE_SERVICE_RESTART] * len(readers)
    assert_clean_log(server)


@pytest.mark.parametrize(
    "payload_bytes",
    [
        pytest.param(400_000, id="transport-buffer-full"),
        pytest.param(60_000, id="kernel-buffer-only"),
    ],
)
def test_a_keepalive_timeout_behind_a_full_buffer_reaches_the_app(payload_bytes: int) -> None:
    """uvicorn fails a connection whose pings go unanswered but does not tell the app; the protocol does.

    A real uvicorn server with short pings runs a bare ASGI app on this protocol: the app fills
    the stalled client's socket, waits for its next message, and resets the connection when told.
    With 400 kB some data is still in uvicorn's transport, which does not close before it drains:
    the app's reset ends it. With 60 kB it all fits in the server kernel's send buffer (~135 kB here)
    but not in the client's: the transport closes the socket at once, and before the fix the kernel
    kept an orphaned socket in FIN-WAIT-1, its unsent data and FIN stuck behind the client's closed
    window, for over a minute (a drill of 50 non-reading subscribers, 2026-12-07); the keepalive's
    close is now a reset when the kernel still holds unsent data.
    """
    told: queue.Queue[dict[str, Any]] = queue.Queue()

    async def app(scope: dict[str, Any], receive: Any, send: Any) -> None:
        await receive()  # websocket.connect
        await send({"type": "websocket.accept"})
        await send({"type": "websocket.send", "bytes": b"x" * payload_bytes})
        told.put(await receive())
        scope["extensions"][RESET_EXTENSION]["reset"]()

    port = free_port()
    config = uvicorn.Config(
        app,
        host="127.0.0.1",
        port=port,
        ws=ResettableWebSocketProtocol,
        ws_ping_interval=0.3,
        ws_ping_timeout=0.3,
        lifespan="off",
        log_level="warning",
    )
    server = uvicorn.Server(config)
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        deadline = time.monotonic() + 10
        while not server.started:
            assert time.monotonic() < deadline and thread.is_alive(), "uvicorn did not start"
            time.sleep(0.02)
        stalled = StalledClient(port, "/")
        try:
            message = told.get(timeout=10)
            assert message["type"] == "websocket.disconnect" and message["code"] == 1011
            stalled.wait_until_reset(CLOSE_HANDSHAKE_SECONDS + SLACK_SECONDS)
            assert stalled.read_to_end()
        finally:
            stalled.close()
    finally:
        server.should_exit = True
        thread.join(10)
