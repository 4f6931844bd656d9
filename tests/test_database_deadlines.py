"""A request to a database that stops answering ends at its deadline (PostgreSQL, a real server).

The server's backend is frozen (SIGSTOP, as in a stalled VM): its connection stays open and the
kernel acknowledges what the server sends, so without a deadline the write waits as long as the
freeze. With ``CONTEXTWEB_WRITE_DEADLINE_SECONDS`` the connection is cut at the deadline
(storage/deadlines.py) and the write answered 503, saying whether its ``COMMIT`` had been sent:

- frozen while it waits for the model's lock (before its commit): "nothing was changed", and the
  thawed backend finds its client gone and rolls back, so the keyed retry stores the scene anew;
- frozen in its ``COMMIT`` (a deferred trigger sleeps in it): "may have stored the write", and the
  thawed backend does commit, so the keyed retry gets the stored answer, not a second scene;
- a keyed model creation frozen in its ``COMMIT``: the same, and the retry answers the stored model;
- a process's catch-up of a model another process wrote to, frozen mid-read: cut at the load
  deadline, and the model reloads once the database answers again.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path

import httpx
import psycopg
import pytest

from app.registry import VERSION_CHECK_DEADLINE_SECONDS
from tests.conftest import FAST_HYPERPARAMETERS, concept_scenes
from tests.faults import (
    KeyedPost,
    TcpProxy,
    Timing,
    answer_while,
    at_once,
    backend_when,
    connections_refused,
    create_model,
    database_backends,
    database_name,
    end_backend,
    fresh_postgres_database,
    frozen_backends,
    holding_model_row,
    libpq_url,
    model_invariants,
    model_with_keyed_posts,
    post_keyed_once,
    slow_commits,
)
from tests.servers import running_server, start_servers, stop_all

pytestmark = pytest.mark.postgres

DEADLINE_SECONDS = 3.0
FREEZE_MARGIN_SECONDS = 3.0  # a freeze this much longer than the deadline: the answer must come before the thaw
COMMIT_SLEEP_SECONDS = 1.0  # a commit that would end well within the deadline, but for the freeze


def _assert_cut_at_the_deadline(
    answer: httpx.Response, timing: Timing, thawed_at: float, deadline: str, seconds: float, outcome: str = ""
) -> None:
    """A 503 naming ``deadline``, answered no sooner than ``seconds`` after the request (the deadline
    runs from the transaction's BEGIN, which follows the request's arrival) and before the thaw."""
    assert answer.status_code == 503 and answer.headers["retry-after"], answer.text
    body = answer.json()
    assert body["error"] == "storage_unavailable", body
    assert f"did not answer within {deadline} of {seconds:g} s" in body["detail"], body
    assert outcome in body["detail"], body
    assert timing.seconds >= seconds - 0.05, timing
    assert timing.ended < thawed_at, (timing, thawed_at)


def _frozen_for(pids: list[int], seconds: float, before_sleep: Callable[[], object] = lambda: None) -> float:
    """Freeze the backends ``pids`` for ``seconds``; the monotonic time of their thaw."""
    with frozen_backends(pids):
        before_sleep()
        time.sleep(seconds)
        return time.monotonic()


def test_a_frozen_database_ends_a_write_at_its_deadline_and_nothing_is_doubled(tmp_path: Path) -> None:
    bodies = concept_scenes(8, seed=11)
    with (
        fresh_postgres_database("contextweb_deadline") as url,
        running_server(url, tmp_path, env={"CONTEXTWEB_WRITE_DEADLINE_SECONDS": f"{DEADLINE_SECONDS:g}"}) as server,
    ):
        model_id, posts = model_with_keyed_posts(server.base_url, bodies, name="deadline", posted=4)

        # Before the commit: frozen while it waits for the model's row, held by an outside transaction.
        with holding_model_row(url, model_id) as outside:

            def freeze_the_waiting_write() -> tuple[str, float]:
                pid, query = backend_when(url, "wait_event_type = 'Lock'")
                # The lock is let go at once, but the frozen backend cannot take it.
                return query, _frozen_for([pid], DEADLINE_SECONDS + FREEZE_MARGIN_SECONDS, outside.commit)

            answer, (query, thawed_at), timing = answer_while(
                server.base_url, lambda client: post_keyed_once(client, model_id, posts[4]), freeze_the_waiting_write
            )
        assert "FOR UPDATE" in query.upper(), query
        _assert_cut_at_the_deadline(
            answer, timing, thawed_at, "the write deadline", DEADLINE_SECONDS, "nothing was changed"
        )

        # During the commit: frozen while a deferred trigger sleeps in its COMMIT.
        def frozen_in_commit(table: str, request: Callable[[httpx.Client], httpx.Response]) -> None:
            """``request`` held in its COMMIT (a trigger on ``table``) and frozen there: cut at the deadline."""

            def freeze_the_commit() -> tuple[str, float]:
                pid, query = backend_when(url, "wait_event = 'PgSleep'")
                thawed_at = _frozen_for([pid], DEADLINE_SECONDS + FREEZE_MARGIN_SECONDS)
                backend_gone(url, pid)
                return query, thawed_at

            with slow_commits(url, table, COMMIT_SLEEP_SECONDS):
                answer, (query, thawed_at), timing = answer_while(server.base_url, request, freeze_the_commit)
            assert query.strip().upper().startswith("COMMIT"), query
            _assert_cut_at_the_deadline(
                answer, timing, thawed_at, "the write deadline", DEADLINE_SECONDS, "may have stored the write"
            )

        frozen_in_commit("scene", lambda client: post_keyed_once(client, model_id, posts[5]))
        with httpx.Client(base_url=server.base_url, timeout=30) as client:
            for post in (posts[4], posts[5], posts[6]):  # the two retries, then one more scene
                retried = post_keyed_once(client, model_id, post)
                assert retried.status_code == 201, retried.text
            # Thawed, the first backend found its client gone before it had the lock: nothing stored.
            assert not posts[4].replayed
            # The second had the COMMIT: it committed once thawed, and the retry replays that scene.
            assert posts[5].replayed
            assert not posts[6].replayed
        problems = model_invariants(url, [server.base_url], model_id, posts[:7])
        assert not problems, "\n".join(problems)

        # A keyed model creation frozen in its COMMIT: the thawed backend commits it, and the retry
        # with the key answers that model instead of making a second one.
        creation = {"name": "in-doubt", "hyperparameters": FAST_HYPERPARAMETERS}
        frozen_in_commit(
            "model",
            lambda client: client.post("/v1/models", json=creation, headers={"Idempotency-Key": "create-in-doubt"}),
        )
        with httpx.Client(base_url=server.base_url, timeout=30) as client:
            retried = client.post("/v1/models", json=creation, headers={"Idempotency-Key": "create-in-doubt"})
            assert retried.status_code == 201 and retried.headers["idempotent-replayed"] == "true", retried.text
            names = [model["name"] for model in client.get("/v1/models").json()]
        assert sorted(names) == ["deadline", "in-doubt"], names


def backend_gone(url: str, pid: int, seconds: float = 10.0) -> None:
    """Wait until the thawed backend ``pid`` has finished (committed or not) and exited."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        try:
            backend_when(url, f"pid = {int(pid)}", seconds=0.05)
        except AssertionError:
            return
        time.sleep(0.05)
    raise AssertionError(f"backend {pid} still runs {seconds} s after its thaw")


def test_a_frozen_database_ends_a_reads_version_check_at_its_deadline(tmp_path: Path) -> None:
    """Every backend of the database frozen, the pooled connections' included: a read's check of
    the model's version (one primary-key read) is cut at its 5 s deadline and answered 503, where
    it would otherwise wait for the thaw; after the thaw the model reads again."""
    with fresh_postgres_database("contextweb_read_deadline") as url, running_server(url, tmp_path) as server:
        model_id = create_model(server.base_url, FAST_HYPERPARAMETERS, name="read-deadline")
        with httpx.Client(base_url=server.base_url, timeout=30) as client:
            for _ in range(3):  # a few pooled connections, all of whose backends are frozen below
                assert client.get(f"/v1/models/{model_id}").status_code == 200
        pids = database_backends(url)
        assert pids, "the server holds no connection to its database"

        deadline = VERSION_CHECK_DEADLINE_SECONDS
        with frozen_backends(pids), httpx.Client(base_url=server.base_url, timeout=deadline + 5) as client:
            started = time.monotonic()  # frozen first: without the deadline this GET times out
            answer = client.get(f"/v1/models/{model_id}")
            timing = Timing(started, time.monotonic())
            thawed_at = float("inf")  # after the answer, by construction
        _assert_cut_at_the_deadline(answer, timing, thawed_at, "the deadline", deadline)
        with httpx.Client(base_url=server.base_url, timeout=30) as client:
            assert client.get(f"/v1/models/{model_id}").status_code == 200


def test_writes_queued_behind_one_cut_by_its_deadline_fail_fast(tmp_path: Path) -> None:
    """The database frozen (every backend stopped) and refusing new connections: the first of four
    writes posted at once to one model is cut at its deadline; the three queued behind it answer
    503 at once (the lost connection invalidated the pool's others, so each tries a new connection,
    refused) instead of each waiting out its own deadline on another frozen pooled connection."""
    bodies = concept_scenes(12, seed=17)
    with (
        fresh_postgres_database("contextweb_queued_deadline") as url,
        running_server(url, tmp_path, env={"CONTEXTWEB_WRITE_DEADLINE_SECONDS": f"{DEADLINE_SECONDS:g}"}) as server,
        httpx.Client(base_url=server.base_url, timeout=60) as client,
    ):
        model_id, posts = model_with_keyed_posts(server.base_url, bodies, name="queued", posted=4)
        # Several pooled connections, all frozen below: reads sent at once open more of them, when
        # they overlap on the server (on a busy machine they may not: so until there are four).
        pids: list[int] = []
        for _ in range(50):
            at_once([partial(client.get, f"/v1/models/{model_id}") for _ in range(8)])
            pids = database_backends(url)
            if len(pids) >= 4:
                break
        assert len(pids) >= 4, pids

        with connections_refused(database_name(url)), frozen_backends(pids):
            answers = at_once([partial(_timed_post, server.base_url, model_id, post) for post in posts[4:8]])
        assert all(answer.status_code == 503 and answer.headers["retry-after"] for answer, _ in answers), [
            answer.text for answer, _ in answers
        ]
        slowest = max(seconds for _, seconds in answers)
        assert slowest < 2 * DEADLINE_SECONDS, [(answer.json()["error"], seconds) for answer, seconds in answers]

        for post in posts[4:]:  # the database back: every retry stores its scene, once
            _post_until_stored(client, model_id, post)
        problems = model_invariants(url, [server.base_url], model_id, posts)
        assert not problems, "\n".join(problems)


def _timed_post(base_url: str, model_id: str, post: KeyedPost) -> tuple[httpx.Response, float]:
    """One attempt of ``post`` on a connection of its own: the answer and the seconds it took."""
    started = time.monotonic()
    with httpx.Client(base_url=base_url, timeout=60) as client:
        answer = post_keyed_once(client, model_id, post)
    return answer, time.monotonic() - started


def _post_until_stored(client: httpx.Client, model_id: str, post: KeyedPost, seconds: float = 20.0) -> None:
    """Retry ``post`` as a robot does (503s after their ``Retry-After``) until it is a 201."""
    deadline = time.monotonic() + seconds
    while (answer := post_keyed_once(client, model_id, post)).status_code == 503 and time.monotonic() < deadline:
        time.sleep(min(float(answer.headers["retry-after"]), 1.0))
    assert answer.status_code == 201, answer.text


def test_writes_behind_one_that_found_the_database_unresponsive_fail_fast(tmp_path: Path) -> None:
    """The database frozen for the server (a TCP proxy between them relays nothing on the open
    connections and blackholes new ones, as a stalled database server does): six writes posted at
    once to one model. The first waits out its deadline; each of the others would then wait out a
    time-out of its own, one after the other (a new connection's, 3 s), up to 18 s for the last.
    For a moment after a write found the database unresponsive, they answer 503 at once instead."""
    bodies = concept_scenes(12, seed=19)
    with (
        fresh_postgres_database("contextweb_frozen_proxy") as url,
        TcpProxy() as proxy,
        running_server(
            proxy.url_for(url), tmp_path, env={"CONTEXTWEB_WRITE_DEADLINE_SECONDS": f"{DEADLINE_SECONDS:g}"}
        ) as server,
        httpx.Client(base_url=server.base_url, timeout=60) as client,
    ):
        model_id, posts = model_with_keyed_posts(server.base_url, bodies, name="frozen", posted=4)
        proxy.freeze()
        try:
            answers = at_once([partial(_timed_post, server.base_url, model_id, post) for post in posts[4:10]])
        finally:
            proxy.restore()
        assert all(answer.status_code == 503 and answer.headers["retry-after"] for answer, _ in answers), [
            answer.text for answer, _ in answers
        ]
        seconds = sorted(seconds for _, seconds in answers)
        assert seconds[-1] < 2 * DEADLINE_SECONDS, seconds
        assert sum(seconds < DEADLINE_SECONDS + 1.0 for seconds in seconds) >= 5, seconds

        for post in posts[4:]:  # the database back: every retry stores its scene, once
            _post_until_stored(client, model_id, post)
        problems = model_invariants(url, [server.base_url], model_id, posts)
        assert not problems, "\n".join(problems)


def test_a_frozen_database_ends_a_models_catch_up_and_first_load_at_the_load_deadline(tmp_path: Path) -> None:
    """Two processes on one database. B is behind A by two scenes, so its next GET of the model catches
    up (a snapshot read of the rows written since). That read's backend is frozen while it waits
    for a table the test holds: it is cut at the load deadline and answered 503, where it would
    otherwise hold the model's lock until the thaw. After the thaw, B reloads and agrees with A.

    Then B's first load of a model A created, frozen the same way, holds the registry's lock, which
    B's first load of another model waits for: the frozen one is cut at the load deadline, and the
    other is answered 200 before the thaw."""
    bodies = concept_scenes(8, seed=23)
    env = {"CONTEXTWEB_LOAD_DEADLINE_SECONDS": f"{DEADLINE_SECONDS:g}"}
    with fresh_postgres_database("contextweb_load_deadline") as url:
        a, b = start_servers([url, url], tmp_path, env=env)
        try:
            model_id, posts = model_with_keyed_posts(a.base_url, bodies, name="load-deadline", posted=4)
            with httpx.Client(base_url=b.base_url, timeout=30) as client:
                assert client.get(f"/v1/models/{model_id}").status_code == 200  # B loads it
            with httpx.Client(base_url=a.base_url, timeout=30) as client:
                for post in posts[4:6]:
                    assert post_keyed_once(client, model_id, post).status_code == 201  # B is behind now

            with psycopg.connect(libpq_url(url)) as outside:
                outside.execute("LOCK TABLE token_batch IN ACCESS EXCLUSIVE MODE")

                def freeze_the_catch_up() -> float:
                    pid, _ = backend_when(url, "wait_event_type = 'Lock'")
                    return _frozen_for(
                        [pid], DEADLINE_SECONDS + FREEZE_MARGIN_SECONDS, before_sleep=outside.commit
                    )  # the table released: only the freeze holds the read now

                answer, thawed_at, timing = answer_while(
                    b.base_url, lambda client: client.get(f"/v1/models/{model_id}"), freeze_the_catch_up
                )
            _assert_cut_at_the_deadline(answer, timing, thawed_at, "the load deadline", DEADLINE_SECONDS)

            answers = {}
            for server in (a, b):
                with httpx.Client(base_url=server.base_url, timeout=30) as client:
                    answer = client.get(f"/v1/models/{model_id}")
                    assert answer.status_code == 200, answer.text
                    answers[server.base_url] = answer.json()["scene_count"]
            assert set(answers.values()) == {6}, answers

            frozen_model, queued_model = (create_model(a.base_url, FAST_HYPERPARAMETERS, name=f"new {i}") for i in "12")
            queued: list[tuple[httpx.Response, float]] = []

            def get_queued_model() -> None:
                with httpx.Client(base_url=b.base_url, timeout=60) as client:
                    queued.append((client.get(f"/v1/models/{queued_model}"), time.monotonic()))

            with psycopg.connect(libpq_url(url)) as outside:
                outside.execute("LOCK TABLE model IN ACCESS EXCLUSIVE MODE")

                def freeze_the_first_load() -> float:
                    pid, _ = backend_when(url, "wait_event_type = 'Lock'")
                    behind = threading.Thread(target=get_queued_model)  # waits for the registry's lock
                    behind.start()
                    thawed_at = _frozen_for([pid], DEADLINE_SECONDS + FREEZE_MARGIN_SECONDS, outside.commit)
                    behind.join(30)
                    return thawed_at

                answer, thawed_at, timing = answer_while(
                    b.base_url, lambda client: client.get(f"/v1/models/{frozen_model}"), freeze_the_first_load
                )
            _assert_cut_at_the_deadline(answer, timing, thawed_at, "the load deadline", DEADLINE_SECONDS)
            ((queued_answer, queued_at),) = queued
            assert queued_answer.status_code == 200, queued_answer.text
            assert queued_at < thawed_at, (queued_at, thawed_at)
            with httpx.Client(base_url=b.base_url, timeout=30) as client:
                assert client.get(f"/v1/models/{frozen_model}").status_code == 200
        finally:
            stop_all([a, b])


def test_a_write_to_a_model_whose_reload_just_failed_is_refused_before_it_waits_for_a_lock(tmp_path: Path) -> None:
    """Process B's write to a model that process A wrote to fails in its catch-up (its backend ended
    while new connections are refused): the undo's reload fails too, and the model stays
    unavailable on B while the reload's 1 s back-off runs. The next write to B, sent at once with
    connections allowed again, finds the model's row held by an outside transaction: it is
    answered 503 ``model_unavailable`` before it waits for that lock. Without the early refusal it
    waits for the lock's time-out (10 s), as each write queued behind a failed one would in turn.
    (A failed write whose only change is its scene no longer needs a reload: it is taken back
    exactly, tests/test_model_writer.py; a failed catch-up does need one.)"""
    bodies = concept_scenes(8, seed=29)
    with fresh_postgres_database("contextweb_early_refusal") as url:
        a, b = start_servers([url, url], tmp_path)
        try:
            model_id, posts = model_with_keyed_posts(a.base_url, bodies, name="early-refusal", posted=3)
            with httpx.Client(base_url=b.base_url, timeout=30) as client:
                assert client.get(f"/v1/models/{model_id}").status_code == 200  # B loads it
            with httpx.Client(base_url=a.base_url, timeout=30) as client:
                assert post_keyed_once(client, model_id, posts[3]).status_code == 201  # B is behind now
            with (
                httpx.Client(base_url=b.base_url, timeout=30) as client,
                psycopg.connect(libpq_url(url)) as tables,
                psycopg.connect(libpq_url(url)) as outside,
            ):
                tables.execute("LOCK TABLE token_batch IN ACCESS EXCLUSIVE MODE")  # holds B's catch-up
                row_taken = threading.Event()
                answered = threading.Event()

                def take_the_row() -> None:  # waits for the write's lock, so gets the row when its backend ends
                    outside.execute("SELECT 1 FROM incremental_lda_state WHERE model_id = %s FOR UPDATE", (model_id,))
                    row_taken.set()

                def end_the_catch_up() -> None:
                    pid, _ = backend_when(url, "wait_event_type = 'Lock' AND query LIKE '%token_batch%'")
                    taker.start()
                    backend_when(url, f"wait_event_type = 'Lock' AND pid <> {pid} AND query LIKE '%FOR UPDATE%'")
                    with connections_refused(database_name(url)):
                        end_backend(pid)
                        answered.wait(20)  # the write's answer: its undo's reload has failed
                    tables.commit()

                taker = threading.Thread(target=take_the_row)
                fault = threading.Thread(target=end_the_catch_up)
                fault.start()
                failed = post_keyed_once(client, model_id, posts[4])
                answered.set()
                fault.join(30)  # connections allowed again
                assert failed.status_code == 503, failed.text
                assert row_taken.wait(10), "the outside transaction never got the model's row"
                started = time.monotonic()
                refused = post_keyed_once(client, model_id, posts[5])
                seconds = time.monotonic() - started
                outside.commit()
                taker.join(10)
            assert refused.status_code == 503 and refused.headers["retry-after"], refused.text
            assert refused.json()["error"] == "model_unavailable", refused.text
            assert seconds < 0.5, seconds
            with httpx.Client(base_url=b.base_url, timeout=30) as client:
                for post in posts[4:]:  # the database back: every retry stores its scene, once
                    _post_until_stored(client, model_id, post)
            problems = model_invariants(url, [a.base_url, b.base_url], model_id, posts)
            assert not problems, "\n".join(problems)
        finally:
            stop_all([a, b])
