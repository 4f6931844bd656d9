"""The watchdog of storage/deadlines.py on real sockets: a socket past its deadline is shut down
(its blocked reader wakes with end-of-stream), one disarmed in time never is."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

from storage.deadlines import SocketDeadlines


def _blocked_read_seconds(reader: socket.socket) -> tuple[bytes, float]:
    started = time.monotonic()
    data = reader.recv(16)
    return data, time.monotonic() - started


def test_a_socket_past_its_deadline_is_cut_and_its_callback_runs_first() -> None:
    deadlines = SocketDeadlines()
    expired: list[float] = []
    ours, peer = socket.socketpair()
    with ours, peer:
        armed_at = time.monotonic()  # the deadline counts from the arming, not from the read's start
        deadlines.arm(ours.fileno(), 0.3, lambda: expired.append(time.monotonic()))
        data, _ = _blocked_read_seconds(ours)
        ended = time.monotonic() - armed_at
        assert data == b"" and expired  # end-of-stream: the read ended by the cut, after the callback
        assert 0.3 <= expired[0] - armed_at and 0.3 <= ended < 2.0, (expired[0] - armed_at, ended)


def test_a_disarmed_socket_is_never_cut_and_a_shorter_later_deadline_is_not_held_up() -> None:
    deadlines = SocketDeadlines()
    kept, kept_peer = socket.socketpair()
    cut, cut_peer = socket.socketpair()
    with kept, kept_peer, cut, cut_peer:
        long_token = deadlines.arm(kept.fileno(), 30.0, lambda: None)  # the watchdog now sleeps 30 s
        deadlines.arm(cut.fileno(), 0.2, lambda: None)  # must wake it
        data, seconds = _blocked_read_seconds(cut)
        assert data == b"" and seconds < 2.0, (data, seconds)
        deadlines.disarm(long_token)
        short_token = deadlines.arm(kept.fileno(), 0.2, lambda: None)
        deadlines.disarm(short_token)
        time.sleep(0.5)  # past that deadline: the socket still works both ways
        kept_peer.sendall(b"ping")
        assert kept.recv(16) == b"ping"
        kept.sendall(b"pong")
        assert kept_peer.recv(16) == b"pong"


def test_many_writes_arm_and_disarm_from_threads_without_a_cut() -> None:
    deadlines = SocketDeadlines()
    ours, peer = socket.socketpair()
    errors: list[BaseException] = []

    def writes() -> None:
        try:
            for _ in range(500):
                deadlines.disarm(deadlines.arm(ours.fileno(), 5.0, lambda: None))
        except BaseException as error:  # noqa: BLE001 - reported below
            errors.append(error)

    with ours, peer:
        descriptors = len(os.listdir("/proc/self/fd"))
        threads = [threading.Thread(target=writes) for _ in range(4)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join(30)
        assert not errors, errors
        assert len(os.listdir("/proc/self/fd")) == descriptors  # each disarm closed its socket's copy
        peer.sendall(b"still open")
        assert ours.recv(16) == b"still open"


_STALLED_CHILD = """
import json, socket, time
from storage.deadlines import SocketDeadlines

deadlines = SocketDeadlines()
ours, peer = socket.socketpair()
deadlines.arm(ours.fileno(), {deadline}, lambda: None)
print("armed", flush=True)
before = time.monotonic()
stall = 0.0
while stall < 1.0:  # busy until it has been stopped: a gap between two looks at the clock
    now = time.monotonic()
    stall, before = max(stall, now - before), now
resumed = time.monotonic()
while time.monotonic() - resumed < 0.3:  # running again, well within the deadline's own time
    pass
ours.setblocking(False)
try:
    cut_after_stall = ours.recv(16) == b""
except BlockingIOError:
    cut_after_stall = False
ours.setblocking(True)
ours.settimeout(10)
waited = time.monotonic()
try:
    cut_later = ours.recv(16) == b""
except TimeoutError:
    cut_later = False
print(json.dumps({{"stall": stall, "cut_after_stall": cut_after_stall, "cut_later": cut_later,
                  "cut_after_seconds": time.monotonic() - resumed}}), flush=True)
"""


def test_a_stall_of_the_process_itself_does_not_count_against_a_deadline() -> None:
    """A process stopped for longer than a deadline (SIGSTOP here; a paused VM alike) does not cut its
    sockets the moment it runs again: the stall is added to every armed deadline, which is there to
    measure the database, not this process. Cutting then answered 503 "the database did not answer
    within the write deadline" for writes whose own process had been frozen (a drill, 2026-12-07).
    The deadline still holds afterwards, for the time the process ran."""
    deadline = 1.0
    child = subprocess.Popen(
        [sys.executable, "-c", _STALLED_CHILD.format(deadline=deadline)],
        stdout=subprocess.PIPE,
        text=True,
        cwd=Path(__file__).resolve().parents[1],
    )
    try:
        assert child.stdout is not None
        assert child.stdout.readline().strip() == "armed"
        time.sleep(0.1)
        os.kill(child.pid, signal.SIGSTOP)
        time.sleep(deadline + 1.5)
        os.kill(child.pid, signal.SIGCONT)
        report = json.loads(child.stdout.readline())
    finally:
        child.kill()
        child.wait(10)
    assert report["stall"] >= deadline + 1.0, report
    assert not report["cut_after_stall"], report
    # Cut once the process itself has run past its deadline: ≈ 0.9 s after it resumed, not 10.
    assert report["cut_later"] and report["cut_after_seconds"] < deadline + 1.0, report
