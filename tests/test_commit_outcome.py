"""A 503 says whether the write may have been stored (PostgreSQL, a real server, real lost connections).

A connection lost before a scene's ``COMMIT`` was sent leaves nothing stored, and the 503 says
"nothing was changed". Once the ``COMMIT`` is on its way, a lost connection leaves the outcome to the
database, which may have committed; the 503 must not promise otherwise (a client without an
Idempotency-Key that trusted "nothing was changed" would post the scene twice), and the retry with
the key gets the stored answer or, as here, a new 201. The commit is held open by a deferred
constraint trigger that sleeps in it, and the server's backend is ended (``pg_terminate_backend``)
while it sleeps; the wait before the commit is an outside transaction holding the model's state row.
"""

from __future__ import annotations

from pathlib import Path

import httpx
import pytest

from tests.conftest import concept_scenes
from tests.faults import (
    answer_while,
    backend_when,
    end_backend,
    fresh_postgres_database,
    holding_model_row,
    model_invariants,
    model_with_keyed_posts,
    post_keyed_once,
    slow_commits,
)
from tests.servers import running_server

pytestmark = pytest.mark.postgres


def _end_backend_when(url: str, condition: str) -> str:
    """End the test database's backend matching ``condition`` once one does; the query it was running."""
    pid, query = backend_when(url, condition)
    end_backend(pid)
    return query


def test_a_503_says_whether_the_commit_was_sent(tmp_path: Path) -> None:
    bodies = concept_scenes(8, seed=3)
    with fresh_postgres_database("contextweb_commit") as url, running_server(url, tmp_path) as server:
        model_id, posts = model_with_keyed_posts(server.base_url, bodies, name="commit", posted=4)
        # Before the commit: the write waits for the model's row, held by an outside transaction.
        with holding_model_row(url, model_id):
            answer, query, _ = answer_while(
                server.base_url,
                lambda client: post_keyed_once(client, model_id, posts[4]),
                lambda: _end_backend_when(url, "wait_event_type = 'Lock'"),
            )
        assert "FOR UPDATE" in query.upper(), query
        assert answer.status_code == 503, answer.text
        assert answer.json()["error"] == "storage_unavailable" and "nothing was changed" in answer.json()["detail"]

        # During the commit: the backend ends while the deferred trigger sleeps in COMMIT.
        with slow_commits(url, "scene", 30):
            answer, query, _ = answer_while(
                server.base_url,
                lambda client: post_keyed_once(client, model_id, posts[6]),
                lambda: _end_backend_when(url, "wait_event = 'PgSleep'"),
            )
        assert query.strip().upper().startswith("COMMIT"), query
        assert answer.status_code == 503 and answer.headers["retry-after"], answer.text
        detail = answer.json()["detail"]
        assert answer.json()["error"] == "storage_unavailable", answer.text
        assert "may have stored the write" in detail and "same Idempotency-Key" in detail, detail

        with httpx.Client(base_url=server.base_url, timeout=30) as client:
            for post in (posts[4], posts[6], posts[7]):  # the retries, then one more scene
                retried = post_keyed_once(client, model_id, post)
                assert retried.status_code == 201, retried.text
                assert not post.replayed  # the ended transactions stored nothing
        problems = model_invariants(url, [server.base_url], model_id, [posts[i] for i in (0, 1, 2, 3, 4, 6, 7)])
        assert not problems, "\n".join(problems)

        # Not a model's write: a model's creation, its commit ended the same way.
        with slow_commits(url, "model", 30):
            answer, query, _ = answer_while(
                server.base_url,
                lambda client: client.post("/v1/models", json={"name": "in-doubt"}),
                lambda: _end_backend_when(url, "wait_event = 'PgSleep'"),
            )
        assert query.strip().upper().startswith("COMMIT"), query
        assert answer.status_code == 503 and answer.json()["error"] == "storage_unavailable", answer.text
        assert "may have stored the write" in answer.json()["detail"], answer.text
        names = [model["name"] for model in httpx.get(f"{server.base_url}/v1/models", timeout=30).json()]
        assert names == ["commit"], names  # ended in its commit's trigger: not stored, and not listed
