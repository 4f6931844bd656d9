"""``contextweb serve --workers 2`` evens out long-lived keep-alive connections (app/connections.py).

The kernel hands each new connection to whichever worker accepts it first, so 8 keep-alive
clients could stay 1/7 for hours. Here 8 real clients, opened one after another on a real
2-worker server, each make a few requests; afterwards each worker holds exactly 4 of them (read
from ``/proc``, as bench_scaling counts them), every request was answered, and the closes stopped:
a round of requests in which no worker asked for a new connection.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

from app.connections import ConnectionCounts, create_counts
from bench.bench_scaling import socket_owners
from tests.conftest import migrated_database
from tests.servers import running_server, server_environment

CLIENTS = 8
MAX_ROUNDS = 40
"""Rounds of one request per client allowed to settle (each close moves one connection; 2–4 rounds idle)."""


def _worker_pids(supervisor: int) -> list[int]:
    children = Path(f"/proc/{supervisor}/task/{supervisor}/children").read_text().split()
    return [int(pid) for pid in children]


def _listening_sockets(port: int, pids: list[int]) -> dict[int, int]:
    """How many sockets listening on ``port`` each process holds (from /proc)."""
    inodes = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for row in Path(table).read_text().splitlines()[1:]:
            fields = row.split()
            if int(fields[1].rsplit(":", 1)[1], 16) == port and fields[3] == "0A":  # TCP_LISTEN
                inodes.add(f"socket:[{fields[9]}]")
    held = {}
    for pid in pids:
        links = []
        for fd in os.listdir(f"/proc/{pid}/fd"):
            try:
                links.append(os.readlink(f"/proc/{pid}/fd/{fd}"))
            except OSError:  # closed meanwhile
                continue
        held[pid] = sum(link in inodes for link in links)
    return held


def test_each_worker_listens_on_its_own_socket_and_the_port_stays_one_servers(
    request: pytest.FixtureRequest, tmp_path: Path
) -> None:
    """Two listening sockets, one in each worker and none in the supervisor, so the kernel's choice
    between them does not depend on which worker is awake; and a second server cannot join the port
    (``SO_REUSEPORT`` would let it) but says why it stopped."""
    url = migrated_database("sqlite", request, tmp_path)
    with running_server(url, tmp_path, args=["--workers", "2"], log_level="info") as server:
        deadline = time.monotonic() + 60
        while len(workers := re.findall(r"Started server process \[(\d+)\]", server.log(1_000_000))) < 2:
            assert time.monotonic() < deadline, server.log(4000)
            time.sleep(0.2)
        children = _worker_pids(server.pid)  # the workers and multiprocessing's resource tracker
        assert {int(pid) for pid in workers} <= set(children)
        expected = {server.pid: 0} | {pid: int(str(pid) in workers) for pid in children}
        # A worker logs "Started server process" before its startup calls listen(), so poll.
        while (listening := _listening_sockets(server.port, [server.pid, *children])) != expected:
            assert time.monotonic() < deadline, listening
            time.sleep(0.2)
        second = subprocess.run(
            [sys.executable, "-m", "app.cli", "serve", "--workers", "2"],
            env=server_environment(url, server.port, None),
            capture_output=True,
            text=True,
            timeout=120,
            check=False,
        )
        assert second.returncode == 1, second.stderr[-2000:]
        assert f"cannot listen on 127.0.0.1:{server.port}: Address already in use" in second.stderr
        assert server.process.poll() is None


def test_two_workers_end_with_four_connections_each(request: pytest.FixtureRequest, tmp_path: Path) -> None:
    url = migrated_database("sqlite", request, tmp_path)
    with running_server(url, tmp_path, args=["--workers", "2"], log_level="info") as server:
        deadline = time.monotonic() + 60
        while server.log(1_000_000).count("Application startup complete") < 2 and time.monotonic() < deadline:
            time.sleep(0.2)
        clients = [httpx.Client(base_url=server.base_url, timeout=10) for _ in range(CLIENTS)]
        try:
            for client in clients:  # opened one after another, as robots coming online
                assert client.get("/healthz").status_code == 200
            closes_by_round: list[int] = []
            responses: list[httpx.Response] = []
            while len(closes_by_round) < MAX_ROUNDS and (not closes_by_round or closes_by_round[-1]):
                responses = [client.get("/healthz") for client in clients]
                assert all(response.status_code == 200 for response in responses)
                closes_by_round.append(sum(response.headers.get("connection") == "close" for response in responses))
            assert closes_by_round[-1] == 0, f"still reconnecting after {MAX_ROUNDS} rounds: {closes_by_round}"
            ports = [response.extensions["network_stream"].get_extra_info("client_addr")[1] for response in responses]
            owners = socket_owners(server.port, ports, _worker_pids(server.pid))
        finally:
            for client in clients:
                client.close()
    held = sorted(count for count in owners.values() if count)
    assert held == [4, 4], (owners, closes_by_round)


def test_a_worker_over_its_share_is_told_so(tmp_path: Path) -> None:
    """The share rule on one counts file: ⌈open connections / workers⌉ per worker."""
    path = create_counts(999_999_001, 2)
    try:
        first, second = ConnectionCounts(path), ConnectionCounts(path)
        assert first.opened() is False  # 1 open in all: share 1
        assert first.opened() is True  # 2 in all: share 1, and the first holds 2
        first.closed()
        assert second.opened() is False  # 1 and 1
        assert second.opened() is False  # 3 in all: share 2
        assert second.opened() is True  # 4 in all: share 2, and the second holds 3
    finally:
        path.unlink()
