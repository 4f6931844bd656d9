"""Real ``contextweb serve`` processes for the end-to-end tests (crash, faults, several processes).

:func:`start_server` migrates the database as ``contextweb migrate`` does (the
server only checks it), runs ``python -m app.cli serve`` on a free loopback port
with the given database URL (and extra arguments such as ``--workers 2``),
waits until ``/readyz`` answers 200, and returns a :class:`ServerProcess`
handle: base URL, pid, log file, ``stop()`` (SIGTERM, then SIGKILL after a
grace period) and ``kill()`` (SIGKILL, as a crash). :func:`running_server` is
the same as a context manager that always stops the process.

Each server gets its own process group (``start_new_session``), so that
stopping a ``--workers N`` supervisor also ends its worker processes: the
group is signalled by the id of the process this module started, nothing
else. The environment is the test process's own less every ``CONTEXTWEB_*``
variable (the developer's settings never leak in), so the numba cache the
session fixture of tests/conftest.py filled is the one the server loads.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path

import httpx
import pytest

from storage.database import create_database_engine
from storage.migrations import upgrade_to_head

PROJECT_ROOT = Path(__file__).resolve().parents[1]

#: Deadline of a start (loading every model, the numba warm-up from the disk cache).
STARTUP_SECONDS = 90.0
#: Grace period of a SIGTERM before the SIGKILL.
STOP_SECONDS = 15.0


def free_port() -> int:
    """A TCP port free on 127.0.0.1 right now."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


class ServerStartError(RuntimeError):
    """The server exited, or did not answer ``/readyz`` 200 before its deadline."""


class ServerProcess:
    """One ``contextweb serve`` process (and its workers) on ``127.0.0.1:port``."""

    def __init__(
        self,
        process: subprocess.Popen[bytes],
        port: int,
        log_path: Path,
        command: list[str],
        base_url: str | None = None,
    ) -> None:
        self.process = process
        self.port = port
        self.log_path = log_path
        self.command = command
        self.base_url = base_url or f"http://127.0.0.1:{port}"

    @property
    def pid(self) -> int:
        return self.process.pid

    @property
    def running(self) -> bool:
        return self.process.poll() is None

    def url(self, path: str) -> str:
        return f"{self.base_url}{path}"

    def client(self, **options: object) -> httpx.Client:
        """An ``httpx.Client`` on this server (10 s timeout unless given)."""
        options.setdefault("timeout", 10.0)
        return httpx.Client(base_url=self.base_url, **options)  # type: ignore[arg-type]

    def log(self, tail: int = 6000) -> str:
        """The last ``tail`` characters of the server's log (stdout and stderr)."""
        try:
            return self.log_path.read_text(errors="replace")[-tail:]
        except FileNotFoundError:
            return ""

    def wait_ready(self, deadline_seconds: float = STARTUP_SECONDS) -> None:
        """Until ``/readyz`` answers 200; :class:`ServerStartError` if the process exits or time runs out."""
        deadline = time.monotonic() + deadline_seconds
        last = "no answer"
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                raise ServerStartError(
                    f"server on port {self.port} exited with {self.process.returncode} before it was ready:\n"
                    f"{self.log()}"
                )
            try:
                response = httpx.get(self.url("/readyz"), timeout=2.0)
                if response.status_code == 200:
                    return
                last = f"{response.status_code} {response.text[:200]}"
            except httpx.TransportError as error:
                last = type(error).__name__
            time.sleep(0.1)
        raise ServerStartError(
            f"server on port {self.port} not ready after {deadline_seconds:.0f} s (last /readyz: {last}):\n{self.log()}"
        )

    def _signal_group(self, sig: int) -> None:
        try:
            os.killpg(self.process.pid, sig)  # the group this module created for the server (its own pid)
        except ProcessLookupError:
            pass

    def stop(self, timeout: float = STOP_SECONDS) -> int | None:
        """SIGTERM, wait up to ``timeout`` s, then SIGKILL; the group (worker processes) too. Idempotent."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self._signal_group(signal.SIGKILL)
                self.process.wait(timeout=10)
        self._signal_group(signal.SIGKILL)  # workers left behind by a supervisor that died
        return self.process.returncode

    def kill(self) -> None:
        """SIGKILL the server process (a crash); its workers too."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGKILL)
            self.process.wait(timeout=10)
        self._signal_group(signal.SIGKILL)

    def __repr__(self) -> str:
        return f"ServerProcess(pid={self.pid}, base_url={self.base_url!r}, log={str(self.log_path)!r})"


def server_environment(database_url: str, port: int, extra: Mapping[str, str] | None = None) -> dict[str, str]:
    """The test process's environment without ``CONTEXTWEB_*``, plus the server's database and port."""
    env = {key: value for key, value in os.environ.items() if not key.startswith("CONTEXTWEB_")}
    env |= {"CONTEXTWEB_DATABASE_URL": database_url, "CONTEXTWEB_PORT": str(port), "CONTEXTWEB_HOST": "127.0.0.1"}
    env |= dict(extra or {})
    return env


def migrate(database_url: str) -> None:
    """Bring the database to the latest schema with the function ``contextweb migrate`` runs,
    as ``make run`` and the container's entry point do before ``contextweb serve``."""
    engine = create_database_engine(database_url)
    try:
        upgrade_to_head(engine)
    finally:
        engine.dispose()


def start_server(
    database_url: str,
    log_dir: Path,
    *,
    port: int | None = None,
    args: Sequence[str] = (),
    env: Mapping[str, str] | None = None,
    log_level: str = "warning",
    ready_seconds: float = STARTUP_SECONDS,
    name: str = "server",
    command_prefix: Sequence[str] = (),
    base_url: str | None = None,
) -> ServerProcess:
    """Migrate, start ``python -m app.cli serve [args]`` on ``port`` (a free one by default) and wait for ``/readyz``.

    ``env`` adds or overrides variables (``CONTEXTWEB_HOST``…). ``command_prefix`` runs the
    command through another (``ip netns exec NAME``: tests/netns.py), and ``base_url`` is where
    the server is reached from here when that is not its own loopback port. The log goes to
    ``log_dir/<name>-<port>.log`` (appended: a restart on the same port adds to it).
    Raises :class:`ServerStartError` (with the log's tail) when the server exits or is
    not ready in time; the process is then stopped.
    """
    migrate(database_url)
    port = port or free_port()
    log_path = log_dir / f"{name}-{port}.log"
    command = [*command_prefix, sys.executable, "-m", "app.cli", "serve", "--log-level", log_level, *args]
    with log_path.open("ab") as log:
        process = subprocess.Popen(
            command,
            cwd=PROJECT_ROOT,
            env=server_environment(database_url, port, env),
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
    server = ServerProcess(process, port, log_path, command, base_url)
    try:
        server.wait_ready(ready_seconds)
    except BaseException:
        server.stop(timeout=5)
        raise
    return server


def start_server_or_fail(database_url: str, log_dir: Path, **options: object) -> ServerProcess:
    """:func:`start_server`, turning a failed start into ``pytest.fail`` with the log."""
    try:
        return start_server(database_url, log_dir, **options)  # type: ignore[arg-type]
    except ServerStartError as error:
        pytest.fail(str(error), pytrace=False)


@contextmanager
def running_server(database_url: str, log_dir: Path, **options: object) -> Iterator[ServerProcess]:
    """:func:`start_server_or_fail` as a context manager: the server is always stopped at the end."""
    server = start_server_or_fail(database_url, log_dir, **options)
    try:
        yield server
    finally:
        server.stop()


def start_servers(database_urls: Sequence[str], log_dir: Path, **options: object) -> list[ServerProcess]:
    """Start one server per URL at the same time (a start is mostly waiting on the warm-up);
    every one started is stopped again when any fails (``pytest.fail`` with its log)."""
    import threading

    results: list[ServerProcess | BaseException | None] = [None] * len(database_urls)

    def start(index: int, url: str) -> None:
        try:
            results[index] = start_server(url, log_dir, name=f"server{index}", **options)  # type: ignore[arg-type]
        except BaseException as error:  # noqa: BLE001 - reported below
            results[index] = error

    threads = [threading.Thread(target=start, args=(i, url)) for i, url in enumerate(database_urls)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(STARTUP_SECONDS + 30)
    servers = [result for result in results if isinstance(result, ServerProcess)]
    errors = [result for result in results if not isinstance(result, ServerProcess)]
    if errors:
        for server in servers:
            server.stop()
        pytest.fail("\n\n".join(str(error) for error in errors), pytrace=False)
    return servers


def stop_all(servers: Sequence[ServerProcess]) -> None:
    """Stop every server (SIGTERM, then SIGKILL), even when one stop fails."""
    for server in servers:
        try:
            server.stop()
        except Exception:  # noqa: BLE001 - the others must still be stopped
            server.kill()
