"""SQLite write turns across real processes (storage/write_turns.py).

- Mutual exclusion: processes that each read, bump and rewrite a counter file under the turn
  lose no bump (without the turn they do).
- The deadline: while another process holds the turn, ``held()`` fails with SQLite's busy
  error after about the busy timeout; the waiter thread gives back the lock it takes for that
  abandoned wait, so the holder's release makes the turn free again for every process.
- A ``flock`` that fails (the turn file's descriptor turned into an ``O_PATH`` one, on which the
  kernel refuses ``flock`` with EBADF, as a filesystem without locks refuses it with ENOLCK)
  makes the turn the mutex alone, with a warning: writes go on, in the writer's try and in the
  waiter thread's.
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import textwrap
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from sqlalchemy.exc import OperationalError

from storage.write_turns import WriteTurn

PROJECT = Path(__file__).resolve().parents[1]
PROCESSES = 3
BUMPS = 150

_BUMPER = textwrap.dedent(
    """
    import contextlib, os, sys, time
    from pathlib import Path
    from storage.write_turns import WriteTurn
    database, counter, bumps, use_turn = sys.argv[1], Path(sys.argv[2]), int(sys.argv[3]), sys.argv[4] == "1"
    turn = WriteTurn(database, timeout_seconds=60)
    scratch = counter.with_name(f"{counter.name}.{os.getpid()}")
    print("ready", flush=True)
    sys.stdin.readline()  # every process starts bumping at once, or a slow start-up runs them one by one
    for _ in range(bumps):
        with turn.held() if use_turn else contextlib.nullcontext():
            value = int(counter.read_text())
            time.sleep(0.0005)
            scratch.write_text(str(value + 1))
            os.replace(scratch, counter)  # whole: a reader sees the old value or the new one
    """
)

_HOLDER = textwrap.dedent(
    """
    import fcntl, os, sys
    descriptor = os.open(sys.argv[1], os.O_RDWR | os.O_CREAT, 0o644)
    fcntl.flock(descriptor, fcntl.LOCK_EX)
    print("held", flush=True)
    sys.stdin.readline()  # until the test says so
    """
)


@contextmanager
def _held_by_another_process(turn_path: str) -> Iterator[None]:
    """The turn file locked by another process (:data:`_HOLDER`) until the block ends."""
    holder = subprocess.Popen(
        [sys.executable, "-c", _HOLDER, turn_path], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        assert holder.stdout is not None and holder.stdout.readline() == "held\n"
        yield
    finally:
        assert holder.stdin is not None
        holder.stdin.write("\n")
        holder.stdin.flush()
        assert holder.wait(timeout=30) == 0


def _bump_in_processes(database: Path, counter: Path, use_turn: bool) -> int:
    counter.write_text("0")
    command = [sys.executable, "-c", _BUMPER, str(database), str(counter), str(BUMPS), "1" if use_turn else "0"]
    processes = [
        subprocess.Popen(command, cwd=PROJECT, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        for _ in range(PROCESSES)
    ]
    for process in processes:
        assert process.stdout is not None and process.stdout.readline() == "ready\n"
    for process in processes:
        assert process.stdin is not None
        process.stdin.write("go\n")
        process.stdin.flush()
    for process in processes:
        assert process.wait(timeout=120) == 0
    return int(counter.read_text())


def test_the_turn_excludes_other_processes(tmp_path: Path) -> None:
    database = tmp_path / "turns.sqlite3"
    assert _bump_in_processes(database, tmp_path / "counter", use_turn=True) == PROCESSES * BUMPS
    # The check can fail: without the turn the same processes lose bumps.
    assert _bump_in_processes(database, tmp_path / "counter", use_turn=False) < PROCESSES * BUMPS


def test_a_turn_held_elsewhere_is_a_busy_error_after_the_timeout_and_free_after_its_release(tmp_path: Path) -> None:
    database = tmp_path / "turns.sqlite3"
    turn = WriteTurn(str(database), timeout_seconds=0.5)
    with _held_by_another_process(f"{database}-turn"):
        for _ in range(2):  # the second wait queues behind the first, abandoned, one
            started = time.monotonic()
            with pytest.raises(OperationalError, match="database is locked"), turn.held():
                pass
            assert 0.5 <= time.monotonic() - started < 5.0
    with turn.held():  # the waiter gave the abandoned turns back: it is free again, here ...
        pass
    # ... and for another process, which gets it while this turn is idle.
    assert _bump_in_processes(database, tmp_path / "counter", use_turn=True) == PROCESSES * BUMPS


def _break_flock(turn: WriteTurn) -> None:
    """From now on the kernel refuses ``flock`` on the turn file's descriptor (EBADF): it is made a
    copy of an ``O_PATH`` descriptor of the same file, which can be closed but not locked."""
    assert turn.path is not None and turn._file is not None
    path_only = os.open(turn.path, os.O_PATH)
    try:
        os.dup2(path_only, turn._file.descriptor)
    finally:
        os.close(path_only)


def test_a_failing_flock_leaves_the_mutex_alone_and_writes_go_on(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    database = tmp_path / "turns.sqlite3"
    turn = WriteTurn(str(database), timeout_seconds=0.5)
    with turn.held():  # opens the turn file
        pass
    _break_flock(turn)
    with caplog.at_level(logging.WARNING, logger="contextweb"):
        started = time.monotonic()
        with turn.held():
            pass
        assert time.monotonic() - started < 0.5  # no wait for a lock that cannot be taken
    assert turn.path is None
    assert any("flock on" in record.message and "Bad file descriptor" in record.message for record in caplog.records)
    with turn.held():  # and from then on the mutex alone, without a further warning
        pass
    assert sum("flock on" in record.message for record in caplog.records) == 1


def test_a_failing_flock_in_the_waiter_thread_does_not_stall_later_turns(tmp_path: Path) -> None:
    database = tmp_path / "turns.sqlite3"
    turn = WriteTurn(str(database), timeout_seconds=0.5)
    with _held_by_another_process(f"{database}-turn"):
        with pytest.raises(OperationalError, match="database is locked"), turn.held():
            pass  # abandoned: the waiter thread still waits in flock, for a turn it must give back
        _break_flock(turn)  # ... on a descriptor that no longer takes flock
    for _ in range(3):  # before the fix, the waiter died on EBADF, and every later turn timed out
        started = time.monotonic()
        with turn.held():
            pass
        assert time.monotonic() - started < 0.5
