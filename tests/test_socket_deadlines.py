"""The watchdog of storage/deadlines.py on real sockets: a socket past its deadline is shut down
(its blocked reader wakes with end-of-stream), one disarmed in time never is."""

from __future__ import annotations

import os
import socket
import threading
import time

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
        deadlines.arm(ours.fileno(), 0.3, lambda: expired.append(time.monotonic()))
        data, seconds = _blocked_read_seconds(ours)
        assert data == b"" and expired  # end-of-stream: the read ended by the cut, after the callback
        assert 0.3 - 0.01 <= seconds < 2.0, seconds


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
