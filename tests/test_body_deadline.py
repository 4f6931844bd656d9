"""The read deadlines against a real ``contextweb serve``: stalled bodies and stalled headers get a 408 and a close.

Raw sockets send a request's headers and only part of its body (or a chunked body
that trickles on past the deadline), or part of the headers, or nothing; each must be
answered 408 in the documented shape and closed within the deadline plus a margin,
while a normal request on another connection is served meanwhile. Both deadlines are 1 s here.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.conftest import migrated_database
from tests.servers import ServerProcess, running_server

DEADLINE_SECONDS = 1.0
#: Generous: the machine is shared and slow; the point is "closed", not "closed fast".
MARGIN_SECONDS = 4.0
STALLED_CONNECTIONS = 50


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    directory = Path(tmp_path_factory.mktemp("deadline"))
    url = migrated_database("sqlite", None, directory)  # type: ignore[arg-type]
    env = {
        "CONTEXTWEB_BODY_READ_TIMEOUT_SECONDS": str(DEADLINE_SECONDS),
        "CONTEXTWEB_HEADER_READ_TIMEOUT_SECONDS": str(DEADLINE_SECONDS),
        "CONTEXTWEB_MAX_BODY_BYTES": "65536",
    }
    with running_server(url, directory, env=env) as server:
        yield server


def _connect(server: ServerProcess) -> socket.socket:
    sock = socket.create_connection(("127.0.0.1", server.port), timeout=DEADLINE_SECONDS + MARGIN_SECONDS)
    return sock


def _headers(path: str, extra: str) -> bytes:
    return f"POST {path} HTTP/1.1\r\nHost: test\r\nContent-Type: application/json\r\n{extra}\r\n".encode()


def _read_until_closed(sock: socket.socket) -> bytes:
    """Everything the server sends until it closes the connection (a timeout fails the test).

    A client that is still sending when the server closes gets a reset instead of an
    orderly end: the server's kernel answers bytes that arrive after its close with RST
    (TCP, RFC 1122 4.2.2.13). That is accepted only once the whole response, as long as
    its Content-Length says, has arrived before the reset.
    """
    received = b""
    while True:
        try:
            chunk = sock.recv(65536)
        except ConnectionResetError:
            if not _is_complete_response(received):
                raise
            return received
        if not chunk:
            return received
        received += chunk


def _is_complete_response(received: bytes) -> bool:
    head, separator, body = received.partition(b"\r\n\r\n")
    if not separator:
        return False
    for line in head.lower().split(b"\r\n")[1:]:
        name, _, value = line.partition(b":")
        if name.strip() == b"content-length":
            return len(body) >= int(value)
    return False


def _error_of(response: bytes) -> tuple[int, dict[str, object], bytes]:
    head, _, body = response.partition(b"\r\n\r\n")
    status = int(head.split(b" ", 2)[1])
    return status, json.loads(body), head.lower()


def test_stalled_bodies_get_a_408_and_are_closed_while_others_are_served(server: ServerProcess) -> None:
    with server.client() as client:
        model_id = client.post("/v1/models", json={"name": "deadline"}).json()["id"]
    path = f"/v1/models/{model_id}/scenes"
    stalled = []
    started = time.monotonic()
    for _ in range(STALLED_CONNECTIONS):
        sock = _connect(server)
        sock.sendall(_headers(path, "Content-Length: 1000\r\n") + b'{"objects": [')
        stalled.append(sock)
    # Meanwhile, a normal request on its own connection is served at once.
    with server.client() as client:
        scene = client.post(path, json={"objects": [{"concepts": ["cup", "hard"]}]})
        assert scene.status_code == 201, scene.text
        served_after = time.monotonic() - started
    for sock in stalled:
        with sock:
            status, error, head = _error_of(_read_until_closed(sock))
            assert status == 408 and b"connection: close" in head
            assert error == {
                "error": "request_timeout",
                "detail": f"the request body did not arrive within {DEADLINE_SECONDS:g} s "
                "(CONTEXTWEB_BODY_READ_TIMEOUT_SECONDS)",
                "field": "body",
            }
    elapsed = time.monotonic() - started
    assert served_after < DEADLINE_SECONDS + MARGIN_SECONDS
    assert DEADLINE_SECONDS <= elapsed < DEADLINE_SECONDS + MARGIN_SECONDS, elapsed
    with server.client() as client:
        assert client.get(f"/v1/models/{model_id}").json()["scene_count"] == 1


def test_a_trickling_chunked_body_meets_the_same_deadline(server: ServerProcess) -> None:
    """The deadline is for the whole body, not between two chunks: a chunk every 0.2 s does not keep it open."""
    stop = threading.Event()
    with _connect(server) as sock:
        started = time.monotonic()  # before the headers leave: the server's clock cannot start earlier
        sock.sendall(_headers("/v1/models", "Transfer-Encoding: chunked\r\n"))

        def trickle() -> None:
            while not stop.is_set():
                try:
                    sock.sendall(b"1\r\n \r\n")
                except OSError:
                    return
                stop.wait(0.2)

        sender = threading.Thread(target=trickle)
        sender.start()
        try:
            status, error, _ = _error_of(_read_until_closed(sock))
        finally:
            stop.set()
            sender.join()
        assert status == 408 and error["field"] == "body"
        assert DEADLINE_SECONDS <= time.monotonic() - started < DEADLINE_SECONDS + MARGIN_SECONDS


def test_a_slow_body_that_arrives_in_time_is_served(server: ServerProcess) -> None:
    body = json.dumps({"name": "slow but in time"}).encode()
    with _connect(server) as sock:
        sock.sendall(_headers("/v1/models", f"Content-Length: {len(body)}\r\nConnection: close\r\n"))
        for start in range(0, len(body), 8):
            sock.sendall(body[start : start + 8])
            time.sleep(0.05)
        status, created, _ = _error_of(_read_until_closed(sock))
    assert status == 201 and created["name"] == "slow but in time"


def test_a_chunked_body_over_the_limit_is_a_413_on_the_body_from_the_real_server(server: ServerProcess) -> None:
    """Exactly one byte over in the last chunk: the server has read everything it closes on (closing
    on unread bytes would reset the connection, and the client could lose the answer)."""
    with _connect(server) as sock:
        sock.sendall(_headers("/v1/models", "Transfer-Encoding: chunked\r\n"))
        chunk = b"[" + b"0," * 4095 + b"0"
        for _ in range(8):
            sock.sendall(b"%x\r\n%s\r\n" % (len(chunk), chunk))
        sock.sendall(b"1\r\n \r\n")
        status, error, head = _error_of(_read_until_closed(sock))
    assert status == 413 and error["error"] == "payload_too_large" and error["field"] == "body"
    assert b"connection: close" in head


HEADER_TIMEOUT = {
    "error": "request_timeout",
    "detail": f"the request line and headers did not arrive within {DEADLINE_SECONDS:g} s "
    "(CONTEXTWEB_HEADER_READ_TIMEOUT_SECONDS)",
    "field": None,
}


def test_stalled_headers_and_silent_connections_get_a_408_and_are_closed_while_others_are_served(
    server: ServerProcess,
) -> None:
    """uvicorn times out neither (a "slowloris" client held 31 connections for good, app/connections.py)."""
    started = time.monotonic()
    silent = [_connect(server) for _ in range(10)]
    partial = [_connect(server) for _ in range(10)]
    for sock in partial:
        sock.sendall(b"GET /healthz HTTP/1.1\r\nHost: test\r\nX-Slow: ")
    with server.client() as client:
        assert client.get("/healthz").status_code == 200
        served_after = time.monotonic() - started
    for sock in silent + partial:
        with sock:
            status, error, head = _error_of(_read_until_closed(sock))
            assert status == 408 and b"connection: close" in head and error == HEADER_TIMEOUT
    elapsed = time.monotonic() - started
    assert served_after < DEADLINE_SECONDS
    assert DEADLINE_SECONDS <= elapsed < DEADLINE_SECONDS + MARGIN_SECONDS, elapsed


def test_each_request_of_a_keep_alive_connection_has_the_header_deadline(server: ServerProcess) -> None:
    with _connect(server) as sock:
        sock.sendall(b"GET /healthz HTTP/1.1\r\nHost: test\r\n\r\n")
        received = b""
        while not _is_complete_response(received):
            received += sock.recv(65536)
        assert received.startswith(b"HTTP/1.1 200")
        time.sleep(DEADLINE_SECONDS / 2)  # within uvicorn's keep-alive time-out (5 s): the connection stays
        started = time.monotonic()
        sock.sendall(b"GET /healthz HTTP/1.1\r\n")
        status, error, _ = _error_of(_read_until_closed(sock))
    assert status == 408 and error == HEADER_TIMEOUT
    assert DEADLINE_SECONDS <= time.monotonic() - started + 0.05 < DEADLINE_SECONDS + MARGIN_SECONDS


def test_headers_that_trickle_in_within_the_deadline_are_served(server: ServerProcess) -> None:
    request = b"GET /healthz HTTP/1.1\r\nHost: test\r\nConnection: close\r\n\r\n"
    with _connect(server) as sock:
        for start in range(0, len(request), 6):
            sock.sendall(request[start : start + 6])
            time.sleep(DEADLINE_SECONDS / 20)
        assert _read_until_closed(sock).startswith(b"HTTP/1.1 200")


@pytest.mark.parametrize(
    ("request_bytes", "what"),
    [
        (b"FOO /healthz HTTP/1.1\r\nHost: test\r\n\r\n", "method"),
        (b"GET /healthz HTTP/1.1\r\nHost: test\r\nIdempotency-Key: \x7f\r\n\r\n", "header"),
        (b"POST /v1/models HTTP/1.1\r\nHost: test\r\nContent-Length: -1\r\n\r\n", "Content-Length"),
        (b"POST /v1/models HTTP/1.1\r\nHost: test\r\nTransfer-Encoding: chunked\r\n\r\nZZ\r\n", "chunk size"),
    ],
)
def test_bytes_the_http_parser_refuses_get_a_400_in_the_error_shape_and_are_closed(
    server: ServerProcess, request_bytes: bytes, what: str
) -> None:
    """uvicorn answered these with a plain-text line; the detail quotes httptools' parser, whose
    wording may change between its versions: only the part it names is checked."""
    with _connect(server) as sock:
        sock.sendall(request_bytes)
        status, error, head = _error_of(_read_until_closed(sock))
    assert status == 400 and b"connection: close" in head and b"content-type: application/json" in head
    assert error["error"] == "bad_request" and error["field"] is None
    detail = str(error["detail"])
    assert detail.startswith("not a valid HTTP/1.1 request: ") and detail.endswith("; the connection is closed")
    assert what.lower() in detail.lower(), detail
    with server.client() as client:
        assert client.get("/healthz").status_code == 200


#: uvicorn's keep-alive time-out (``timeout_keep_alive``, app/serve.py keeps its 5 s).
KEEP_ALIVE_SECONDS = 5.0


def test_a_request_sent_while_the_server_was_stopped_is_served_not_reset(server: ServerProcess) -> None:
    """A server process stopped (SIGSTOP; a paused VM alike) past its keep-alive time-out, while a
    client sends its next request on the kept-alive connection, serves that request when it runs
    again. Its event loop finds the keep-alive timer and the request due together and ran the timer
    first (libuv's order after an interrupted poll), closing a connection with a request in it: the
    client got a reset for a request it had sent (a drill of two replicas, one stopped 15 s, 2026-12-07)."""
    with _connect(server) as sock:
        sock.settimeout(KEEP_ALIVE_SECONDS + MARGIN_SECONDS + 10)
        request = b"GET /healthz HTTP/1.1\r\nHost: test\r\n\r\n"
        sock.sendall(request)
        received = b""
        while not _is_complete_response(received):
            received += sock.recv(65536)
        assert received.startswith(b"HTTP/1.1 200"), received
        time.sleep(0.2)  # the server idles in its event loop's poll, the keep-alive timer armed
        os.kill(server.pid, signal.SIGSTOP)
        try:
            sock.sendall(request)
            time.sleep(KEEP_ALIVE_SECONDS + 1.5)
        finally:
            os.kill(server.pid, signal.SIGCONT)
        received = b""
        while not _is_complete_response(received):
            chunk = sock.recv(65536)
            assert chunk, f"the server closed the connection with the request unanswered: {received!r}"
            received += chunk
    assert received.startswith(b"HTTP/1.1 200"), received
