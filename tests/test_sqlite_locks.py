"""Issue 14, database locks: an outside process holding SQLite's write lock stalls nothing but writes.

A real ``contextweb serve`` process on an SQLite file and a real outside connection
(python's ``sqlite3``, as an operator's ``sqlite3`` shell would) holding
``BEGIN IMMEDIATE`` on the same file for longer than the server's busy timeout:

- a scene post is a 503 ``storage_busy`` with ``Retry-After`` after about the busy
  timeout (not after the lock is released);
- reads (``GET`` of the model, its scenes, its contexts) and ``/readyz`` answer at once
  from their WAL snapshots (``/readyz`` stays ready, the lock noted in the log);
- after the release the same scene (same Idempotency-Key) is learned, nothing of the
  refused attempt was stored, the model's invariants hold, and the model was never
  reloaded (the refused write failed before its memory changed).
"""

from __future__ import annotations

import sqlite3
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import httpx
import pytest

from app.storage_health import PROBE_INTERVAL_SECONDS
from tests.conftest import FAST_HYPERPARAMETERS, concept_scenes, migrated_database
from tests.faults import KeyedPost, create_model, model_invariants, post_keyed_once, stored_scene_count
from tests.servers import running_server

BUSY_TIMEOUT_MS = 1_000
#: A read or a probe must answer within this while the write lock is held elsewhere (issue 14).
PROMPT_SECONDS = 1.0


@contextmanager
def outside_write_lock(database: Path) -> Iterator[sqlite3.Connection]:
    """Another process's view of the database: a connection holding SQLite's write lock until the block ends."""
    connection = sqlite3.connect(database, isolation_level=None, timeout=10)
    try:
        connection.execute("BEGIN IMMEDIATE")
        connection.execute("CREATE TABLE IF NOT EXISTS outside_lock (id INTEGER)")  # a pending write of its own
        yield connection
        connection.execute("ROLLBACK")
    finally:
        connection.close()


def _timed_get(client: httpx.Client, path: str) -> tuple[httpx.Response, float]:
    started = time.monotonic()
    response = client.get(path)
    return response, time.monotonic() - started


@pytest.fixture
def sqlite_url(request: pytest.FixtureRequest, tmp_path: Path) -> str:
    return migrated_database("sqlite", request, tmp_path)


def test_outside_write_lock_gives_storage_busy_while_reads_and_readiness_answer(
    sqlite_url: str, tmp_path: Path
) -> None:
    database = Path(sqlite_url.removeprefix("sqlite:///"))
    env = {"CONTEXTWEB_SQLITE_BUSY_TIMEOUT_MS": str(BUSY_TIMEOUT_MS)}
    bodies = concept_scenes(6, seed=14)
    posts = [KeyedPost(key=f"lock-{i}", body=body) for i, body in enumerate(bodies)]
    with running_server(sqlite_url, tmp_path, env=env, log_level="info") as server:
        model_id = create_model(server.base_url, FAST_HYPERPARAMETERS)
        with server.client(timeout=30) as client:
            for post in posts[:5]:
                assert post_keyed_once(client, model_id, post).status_code == 201
            blocked = posts[5]
            with outside_write_lock(database):
                started = time.monotonic()
                refused = post_keyed_once(client, model_id, blocked)
                refused_after = time.monotonic() - started
                time.sleep(PROBE_INTERVAL_SECONDS)  # the readiness probe is due: /readyz tries its write now
                reads = {
                    path: _timed_get(client, path)
                    for path in (
                        "/readyz",
                        f"/v1/models/{model_id}",
                        f"/v1/models/{model_id}/scenes",
                        f"/v1/models/{model_id}/scenes/0",
                        f"/v1/models/{model_id}/contexts",
                        "/v1/models",
                    )
                }
            assert refused.status_code == 503, refused.text
            assert refused.json()["error"] == "storage_busy"
            assert set(refused.json()) == {"error", "detail", "field"}
            assert int(refused.headers["Retry-After"]) >= 1
            assert refused_after < BUSY_TIMEOUT_MS / 1000 + 2.0, f"the refusal took {refused_after:.1f} s"
            for path, (response, seconds) in reads.items():
                assert response.status_code == 200, f"{path}: {response.status_code} {response.text[:200]}"
                assert seconds < PROMPT_SECONDS, f"{path} took {seconds:.2f} s while the write lock was held"
            assert reads[f"/v1/models/{model_id}"][0].json()["scene_count"] == 5
            assert stored_scene_count(sqlite_url, model_id) == 5, "the refused scene left rows behind"

            learned = post_keyed_once(client, model_id, blocked)
            assert learned.status_code == 201, learned.text
            assert not blocked.replayed, "the refused attempt must not have been stored"
            assert learned.json()["scene_id"] == 5
            assert client.get("/readyz").status_code == 200
        problems = model_invariants(sqlite_url, [server.base_url], model_id, posts)
        assert not problems, problems
        log = server.log(tail=200_000)
        assert "reloaded from the database" not in log, "a write refused before memory changed reloaded the model"
        assert "write lock is held elsewhere" in log


def test_writes_to_many_models_waiting_on_the_lock_leave_the_reads_their_threads(
    sqlite_url: str, tmp_path: Path
) -> None:
    """More models writing than there are worker threads: their writes wait for SQLite's one
    write lock on the write threads (``CONTEXTWEB_WRITE_THREADS``), so a read of another model
    still finds a thread at once. With the writes on the routes' pool, the 8 waiting writes held
    all 4 of its threads and every read waited behind them for the busy timeout. A read of a
    model whose own write is waiting for the lock answers at once too: the write takes the
    model's memory lock only once it holds the database's."""
    import concurrent.futures

    database = Path(sqlite_url.removeprefix("sqlite:///"))
    env = {
        "CONTEXTWEB_SQLITE_BUSY_TIMEOUT_MS": "4000",
        "CONTEXTWEB_WORKER_THREADS": "4",
        "CONTEXTWEB_WRITE_THREADS": "2",
    }
    with running_server(sqlite_url, tmp_path, env=env) as server:
        models = [create_model(server.base_url, FAST_HYPERPARAMETERS) for _ in range(8)]
        quiet_model = create_model(server.base_url, FAST_HYPERPARAMETERS)
        with server.client(timeout=30) as client, concurrent.futures.ThreadPoolExecutor(len(models)) as pool:
            with outside_write_lock(database):
                posts = [
                    pool.submit(client.post, f"/v1/models/{model_id}/scenes", json=body)
                    for model_id, body in zip(models, concept_scenes(len(models), seed=3), strict=True)
                ]
                time.sleep(1.0)  # every post admitted: the write threads blocked on the lock, the rest waiting
                reads = [
                    _timed_get(client, path)
                    for path in (
                        f"/v1/models/{quiet_model}/contexts",
                        f"/v1/models/{quiet_model}/scenes",
                        "/readyz",
                        *(f"/v1/models/{model_id}/contexts" for model_id in models),  # writes waiting on the lock
                    )
                ]
            statuses = sorted(post.result().status_code for post in posts)
    for response, seconds in reads:
        assert response.status_code == 200, response.text
        assert seconds < PROMPT_SECONDS, f"a read took {seconds:.2f} s while writes to 8 models waited on the lock"
    assert set(statuses) <= {201, 503}, statuses  # each write either waited out the lock or was storage_busy
