"""A test host in a network namespace of its own, with real links that a test cuts.

:func:`namespace_host` makes a namespace (``ip netns add``) joined to this machine by two veth
pairs, each a /30 link of its own:

- the **database link**: a process in the namespace reaches PostgreSQL at the host's end of it,
  where a relay (:class:`tests.faults.TcpProxy` with ``like_postgres``) forwards to PostgreSQL on
  loopback. PostgreSQL here listens on loopback only, which a namespace cannot reach; the relay
  carries PostgreSQL's own keepalive and ``TCP_USER_TIMEOUT`` settings on the link's side, so it
  notices a vanished client as PostgreSQL would and closes the session's connection;
- the **client link**: the test reaches a server in the namespace at the namespace's end of it,
  through a relay process inside the namespace (``python -m tests.netns relay``) to the server's
  loopback port, so that the server keeps its loopback-only default (no API key needed).

:meth:`NamespaceHost.cut` takes the host's end of a link down: packets vanish both ways, nothing
is closed or refused, nothing sent is acknowledged (a pulled cable, a dead switch), unlike a proxy
that closes or swallows connections. :meth:`NamespaceHost.restore` brings it up again.

Needs root and iproute2's ``ip`` (both on this machine and its CI); the test is skipped, saying
why, where either is missing or the namespace cannot be made. Addresses are in 10.231.0.0/16,
which only these links use, and only on this machine (docs/scaling.md, "Failure cases", has the
drill by hand this automates).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import pytest


@dataclass(frozen=True)
class Link:
    """One veth pair: ``host_interface`` (this machine's end) and the namespace's end, with their addresses."""

    host_interface: str
    namespace_interface: str
    host_address: str
    namespace_address: str


@dataclass(frozen=True)
class NamespaceHost:
    name: str
    database_link: Link
    client_link: Link

    @property
    def exec_prefix(self) -> list[str]:
        """What runs a command inside the namespace."""
        return ["ip", "netns", "exec", self.name]

    def cut(self, link: Link) -> None:
        _ip("link", "set", link.host_interface, "down")

    def restore(self, link: Link) -> None:
        _ip("link", "set", link.host_interface, "up")


def _ip(*arguments: str) -> None:
    subprocess.run(["ip", *arguments], check=True, capture_output=True, timeout=10)


def _free_subnets(count: int) -> list[int]:
    """``count`` third octets x of 10.231.x.0/30 that no interface here uses, from this process's id."""
    used = subprocess.run(["ip", "-4", "-o", "addr"], check=True, capture_output=True, text=True, timeout=10).stdout
    start = os.getpid() % 250
    free = [x % 250 for x in range(start, start + 250) if f"10.231.{x % 250}." not in used]
    return free[:count]


@contextmanager
def namespace_host() -> Iterator[NamespaceHost]:
    """A namespace with a database link and a client link (module docstring); removed at the end."""
    if os.geteuid() != 0 or shutil.which("ip") is None:
        pytest.skip("a network namespace needs root and iproute2's ip")
    tag = f"cw{os.getpid()}"
    name = f"contextweb-{tag}"
    links = [
        Link(f"{tag}{kind}h", f"{tag}{kind}n", f"10.231.{subnet}.1", f"10.231.{subnet}.2")
        for kind, subnet in zip("dc", _free_subnets(2), strict=True)
    ]
    try:
        _ip("netns", "add", name)
    except subprocess.CalledProcessError as error:
        pytest.skip(f"no network namespace could be made: {error.stderr.decode(errors='replace').strip()}")
    try:
        _ip("-n", name, "link", "set", "lo", "up")
        for link in links:
            _ip("link", "add", link.host_interface, "type", "veth", "peer", "name", link.namespace_interface)
            _ip("link", "set", link.namespace_interface, "netns", name)
            _ip("addr", "add", f"{link.host_address}/30", "dev", link.host_interface)
            _ip("-n", name, "addr", "add", f"{link.namespace_address}/30", "dev", link.namespace_interface)
            _ip("link", "set", link.host_interface, "up")
            _ip("-n", name, "link", "set", link.namespace_interface, "up")
        yield NamespaceHost(name, *links)
    finally:
        for link in links:  # the pair goes with either end; the namespace's ends go with it
            subprocess.run(["ip", "link", "del", link.host_interface], check=False, capture_output=True, timeout=10)
        subprocess.run(["ip", "netns", "del", name], check=False, capture_output=True, timeout=10)


@contextmanager
def relay_in(host: NamespaceHost, listen_port: int, target_port: int) -> Iterator[str]:
    """A relay process inside ``host``'s namespace from its client link's address to its loopback
    ``target_port``; yields the base URL the test reaches it at."""
    command = [*host.exec_prefix, sys.executable, "-m", "tests.netns", "relay"]
    command += [host.client_link.namespace_address, str(listen_port), str(target_port)]
    project_root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    process = subprocess.Popen(command, cwd=project_root, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        line = process.stderr.readline() if process.stderr else b""  # "ready" once it listens
        if b"ready" not in line:
            raise RuntimeError(f"the relay in {host.name} did not start: {line!r}")
        yield f"http://{host.client_link.namespace_address}:{listen_port}"
    finally:
        process.terminate()
        process.wait(10)


def _relay_main(listen_host: str, listen_port: int, target_port: int) -> None:
    from tests.faults import TcpProxy

    with TcpProxy(target_port, listen_host=listen_host, listen_port=listen_port):
        print("ready", file=sys.stderr, flush=True)
        while True:
            time.sleep(3600)


if __name__ == "__main__":
    if len(sys.argv) == 5 and sys.argv[1] == "relay":
        _relay_main(sys.argv[2], int(sys.argv[3]), int(sys.argv[4]))
    else:
        sys.exit("usage: python -m tests.netns relay LISTEN_HOST LISTEN_PORT TARGET_PORT")
