"""A network partition between one server process and PostgreSQL while both processes take writes.

Two real server processes on one database and one model: A is cut from PostgreSQL, B reaches it
directly. Robots post scenes to both (Idempotency-Keys, 503s retried). A's link is cut for a
while, then restored, in two ways:

- **a proxy** (:class:`~tests.faults.TcpProxy`) between A and PostgreSQL closes A's open
  connections and blackholes its new ones (TCP connects, nothing ever answers);
- **a real link**: A runs in a network namespace of its own and reaches PostgreSQL over a veth
  pair whose end is taken down (tests/netns.py): packets vanish both ways, nothing is closed or
  refused. A connection of A's caught mid-transaction is then left to PostgreSQL's side to end
  (its keepalives, ``tcp_user_timeout``): until it does, the model's row lock it held stops B's
  writes too (docs/scaling.md, "Failure cases").

What must hold (issue 13):

- A answers within its deadline: a 503 JSON error with ``Retry-After`` for the writes it cannot
  commit and on ``/readyz``; it never hangs, never acknowledges a scene that is not stored;
- B keeps serving: 201s while A is cut off (on the real link, also in the cut's last seconds,
  once PostgreSQL has ended A's sessions);
- after the restore A is ready again, catches up, and both report the same
  ``scene_count``/``context_count``/``/contexts``; every acknowledged answer is
  stored as sent; scene and token ids have no gaps; n_kw equals the stored
  assignments.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from pathlib import Path

import httpx
import pytest
from sqlalchemy.engine import make_url

from tests.conftest import FAST_HYPERPARAMETERS, concept_scenes
from tests.faults import (
    FAULT_PACE,
    KeyedClient,
    TcpProxy,
    all_posts,
    contract_problems,
    create_model,
    fresh_postgres_database,
    model_invariants,
    model_summary,
    readiness_problem,
    status_summary,
    stop_clients,
    unfinished,
    wait_ready,
)
from tests.netns import namespace_host, relay_in
from tests.servers import ServerProcess, free_port, start_server_or_fail, start_servers, stop_all

pytestmark = [pytest.mark.postgres, pytest.mark.slow]

#: The longest a request to the cut-off process may take to answer (issue 13: a 503 within its deadline).
ANSWER_DEADLINE = 10.0
#: On a real link: the write deadline (CONTEXTWEB_WRITE_DEADLINE_SECONDS' default), since a write in
#: flight is answered when its connection's ``tcp_user_timeout`` (5 s) fires or, failing that, at
#: the deadline; by hand the longest attempts were 8.1 and 8.4 s (docs/scaling.md).
REAL_LINK_ANSWER_DEADLINE = 15.0
#: Longer than the deadline: a process that only waits for the network to come back fails the test.
CUT_SECONDS = ANSWER_DEADLINE + 2.0
#: On a real link: long enough for B to serve again after PostgreSQL ended A's stranded sessions
#: (≈ 9 s at most by their keepalives, 5 s by ``tcp_user_timeout``; the lock wait is 10 s).
REAL_LINK_CUT_SECONDS = 20.0
#: B must acknowledge scenes sent this long after the cut began, before the restore.
REAL_LINK_SERVED_AFTER = 12.0
CLIENTS_PER_PROCESS = 2
RECOVERY_SECONDS = 20.0
CATCH_UP_SECONDS = 10.0


def _probe_readiness(base_url: str, findings: list[str], deadline: float) -> None:
    """/readyz of the cut-off process: a 503 with the reason, within the deadline."""
    started = time.monotonic()
    try:
        response = httpx.get(f"{base_url}/readyz", timeout=deadline + 5)
    except httpx.TransportError as error:
        findings.append(f"cut-off process: /readyz {type(error).__name__} after {time.monotonic() - started:.1f} s")
        return
    took = time.monotonic() - started
    problem = readiness_problem(response)
    if problem:
        findings.append(f"cut-off process: {problem} (after {took:.1f} s)")
    if took > deadline:
        findings.append(f"cut-off process: /readyz took {took:.1f} s (deadline {deadline:.0f} s)")


def test_partitioned_process_answers_503_and_catches_up(tmp_path: Path) -> None:
    with fresh_postgres_database("contextweb_partition") as url:
        target = make_url(url)
        proxy = TcpProxy(target_port=target.port or 5432, target_host=target.host or "127.0.0.1")
        servers = []
        try:
            servers = start_servers([proxy.url_for(url), url], tmp_path)
            _partition(url, servers[0], servers[1], proxy.cut, proxy.restore, CUT_SECONDS, ANSWER_DEADLINE)
        finally:
            stop_all(servers)
            proxy.close()


def test_a_process_cut_from_postgresql_by_a_real_link_answers_503_and_catches_up(tmp_path: Path) -> None:
    """The same on a real link (module docstring): A in a network namespace, its database link's
    end taken down for :data:`REAL_LINK_CUT_SECONDS`, and B serving again in the cut's last part."""
    with fresh_postgres_database("contextweb_real_link") as url, namespace_host() as host:
        target = make_url(url)
        database_relay = TcpProxy(
            target_port=target.port or 5432,
            target_host=target.host or "127.0.0.1",
            listen_host=host.database_link.host_address,
            like_postgres=True,
        )
        servers: list[ServerProcess] = []
        port = free_port()
        try:
            with relay_in(host, port, port) as cut_off_url:
                servers.append(
                    start_server_or_fail(
                        database_relay.url_for(url),
                        tmp_path,
                        port=port,
                        command_prefix=host.exec_prefix,
                        base_url=cut_off_url,
                        name="namespaced",
                    )
                )
                servers.append(start_server_or_fail(url, tmp_path, name="direct"))
                _partition(
                    url,
                    servers[0],
                    servers[1],
                    lambda: host.cut(host.database_link),
                    lambda: host.restore(host.database_link),
                    REAL_LINK_CUT_SECONDS,
                    REAL_LINK_ANSWER_DEADLINE,
                    served_after=REAL_LINK_SERVED_AFTER,
                )
        finally:
            stop_all(servers)
            database_relay.close()


def _partition(
    url: str,
    cut_off: ServerProcess,
    direct: ServerProcess,
    cut: Callable[[], object],
    restore: Callable[[], object],
    cut_seconds: float,
    answer_deadline: float,
    *,
    served_after: float = 1.0,
) -> None:
    """Post to both processes, ``cut`` A from the database for ``cut_seconds``, ``restore``, and check
    the module docstring's contract. B must acknowledge a scene sent ``served_after`` s or more
    after the cut began and answered before the restore."""
    servers = [cut_off, direct]
    model_id = create_model(direct.base_url, FAST_HYPERPARAMETERS, name="partition")
    deadline = time.monotonic() + cut_seconds + 38
    clients = [
        KeyedClient(
            server.base_url,
            model_id,
            concept_scenes(2000, seed=30 + 10 * p + i),
            f"{label}-robot{i}",
            deadline,
            request_timeout=answer_deadline + 5,
            pace=FAULT_PACE,
        )
        for p, (label, server) in enumerate((("cut", cut_off), ("direct", direct)))
        for i in range(CLIENTS_PER_PROCESS)
    ]
    for client in clients:
        client.start()
    findings: list[str] = []
    try:
        time.sleep(2.0)
        cut_at = time.monotonic()
        cut()
        time.sleep(0.5)
        # In a thread: the cut ends on time even when the probe hangs.
        probe = threading.Thread(
            target=_probe_readiness, args=(cut_off.base_url, findings, answer_deadline), daemon=True
        )
        probe.start()
        time.sleep(max(0.0, cut_seconds - (time.monotonic() - cut_at)))
        restored_at = time.monotonic()
        restore()
        probe.join(answer_deadline + 10)
        status, body = wait_ready(cut_off.base_url, RECOVERY_SECONDS)
        if status != 200:
            findings.append(
                f"cut-off process not ready {RECOVERY_SECONDS:.0f} s after the restore: {status} {body[:200]}"
            )
        time.sleep(3.0)
    finally:
        stop_clients(clients, join_seconds=40)

    posts = all_posts(clients)
    summary = status_summary(posts)
    print(f"statuses of {len(posts)} scenes: {summary}")
    problems = findings + contract_problems(clients)
    problems += [
        f"{server.base_url} exited ({server.process.returncode}):\n{server.log(2000)}"
        for server in servers
        if not server.running
    ]
    cut_posts = [post for post in posts if post.server == cut_off.base_url]
    longest = max((d for post in cut_posts for d in post.durations), default=0.0)
    print(f"cut-off process: {status_summary(cut_posts)}, longest attempt {longest:.1f} s")
    problems += [
        f"the cut-off process answered {post.key} with {status} after {duration:.1f} s "
        f"(deadline {answer_deadline:.0f} s)"
        for post in cut_posts
        for status, duration in zip(post.statuses, post.durations, strict=True)
        if duration > answer_deadline
    ]
    if not any(503 in post.statuses for post in cut_posts):
        problems.append("the cut-off process never answered a 503")
    served_meanwhile = [
        post.key
        for post in posts
        if post.server == direct.base_url
        for status, start, duration in zip(post.statuses, post.started, post.durations, strict=True)
        if status == 201 and start >= cut_at + served_after and start + duration <= restored_at
    ]
    direct_longest = max((d for post in posts if post.server == direct.base_url for d in post.durations), default=0.0)
    print(
        f"direct process: {len(served_meanwhile)} scenes acknowledged during the cut, longest attempt {direct_longest:.1f} s"
    )
    if not served_meanwhile:
        problems.append(
            f"the process still connected acknowledged nothing sent {served_after:.0f} s or more into the cut "
            "and answered before the restore"
        )
    problems += [f"never acknowledged: {entry}" for entry in unfinished(clients)]
    assert not problems, f"statuses {summary}; {len(problems)} problems:\n" + "\n".join(problems[:20])

    base_urls = [direct.base_url, cut_off.base_url]
    catch_up = time.monotonic() + CATCH_UP_SECONDS
    while True:
        summaries = [model_summary(base_url, model_id) for base_url in base_urls]
        views = [
            (model["scene_count"], model["context_count"], contexts) if model is not None else status
            for status, model, contexts in summaries
        ]
        if views[0] == views[1] or time.monotonic() > catch_up:
            break
        time.sleep(0.5)
    assert views[0] == views[1], f"the processes disagree after the restore: {summaries}"
    invariants = model_invariants(url, base_urls, model_id, posts)
    assert not invariants, "\n".join(invariants)
