"""One scene thread per process on PostgreSQL: a model's lock held elsewhere stalls only that model.

A real ``contextweb serve`` process (one scene thread, the default) on a real PostgreSQL
database, and a real outside transaction (another process's write, an operator's ``psql``)
holding model A's lock (its state row, ``FOR UPDATE``) for several seconds:

- a scene posted to A waits for the lock, on a write thread, and is learned once it is released
  (a 201, not a refusal: the hold is shorter than the server's ``lock_timeout``);
- meanwhile scenes posted to model B on the same process are learned at once: A's wait holds
  no scene thread (without the postponement, B's scenes would wait behind it on the one thread);
- afterwards both models' invariants hold, and the server logged no error and no psycopg warning.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import psycopg
import pytest
from sqlalchemy import text

from storage.database import create_database_engine
from tests.conftest import FAST_HYPERPARAMETERS, concept_scenes
from tests.faults import KeyedPost, create_model, fresh_postgres_database, libpq_url, model_invariants, post_keyed_once
from tests.servers import running_server

pytestmark = pytest.mark.postgres

HOLD_SECONDS = 4.0
#: B's scenes must each be answered within this while A's lock is held elsewhere (they take milliseconds).
PROMPT_SECONDS = 1.5
#: Scenes each model learns before the lock: past FAST_HYPERPARAMETERS' scheduled growth checks after
#: scenes 1, 2, 3 and 6, so that B's timed scenes (up to the one before the check after scene 12)
#: time the lock's independence, not a growth check (one took 2.25 s in a loaded suite run).
LEARNED_BEFORE = 6
NEXT_GROWTH_CHECK = 11


def test_a_lock_held_elsewhere_stalls_its_model_only(tmp_path: Path) -> None:
    bodies = concept_scenes(16, seed=31)
    posts = {name: [KeyedPost(key=f"{name}-{i}", body=body) for i, body in enumerate(bodies)] for name in "ab"}
    with fresh_postgres_database("contextweb_locks") as url, running_server(url, tmp_path) as server:
        models = {name: create_model(server.base_url, FAST_HYPERPARAMETERS, name=name) for name in "ab"}
        with server.client(timeout=30) as client:
            for name in "ab":
                for post in posts[name][:LEARNED_BEFORE]:
                    assert post_keyed_once(client, models[name], post).status_code == 201
        outside = psycopg.connect(libpq_url(url), autocommit=False)
        try:
            outside.execute("SELECT version FROM incremental_lda_state WHERE model_id = %s FOR UPDATE", (models["a"],))
            locked_at = time.monotonic()
            waited: dict[str, float | int] = {}

            def post_to_a() -> None:
                with server.client(timeout=30) as own:
                    waited["status"] = post_keyed_once(own, models["a"], posts["a"][LEARNED_BEFORE]).status_code
                    waited["seconds"] = time.monotonic() - locked_at

            blocked = threading.Thread(target=post_to_a)
            blocked.start()
            time.sleep(0.5)  # A's scene is on the server, waiting for the lock
            prompt: list[float] = []
            with server.client(timeout=30) as client:
                for post in posts["b"][LEARNED_BEFORE:NEXT_GROWTH_CHECK]:
                    started = time.monotonic()
                    assert post_keyed_once(client, models["b"], post).status_code == 201, post.statuses
                    prompt.append(time.monotonic() - started)
                    if time.monotonic() - locked_at > HOLD_SECONDS - 1:
                        break
            assert blocked.is_alive(), "A's scene did not wait for the lock held elsewhere"
            time.sleep(max(0.0, HOLD_SECONDS - (time.monotonic() - locked_at)))
        finally:
            outside.rollback()
            outside.close()
        blocked.join(30)
        assert waited.get("status") == 201, waited
        assert waited["seconds"] >= HOLD_SECONDS - 0.5, waited
        assert len(prompt) >= 3 and max(prompt) < PROMPT_SECONDS, f"B's scenes took {prompt} s while A waited"
        with server.client(timeout=30) as client:
            for post in posts["a"][LEARNED_BEFORE + 1 : LEARNED_BEFORE + 3]:
                assert post_keyed_once(client, models["a"], post).status_code == 201
        for name in "ab":
            sent = [post for post in posts[name] if post.statuses]
            assert model_invariants(url, [server.base_url], models[name], sent) == [], name
        log = server.log(1_000_000)
        assert "Traceback" not in log
        # The refused lock ends its pipeline early; psycopg's "error ignored terminating <Pipeline>:
        # pipeline aborted" said nothing the refusal had not said, on every such write.
        assert "pipeline aborted" not in log and "error ignored" not in log, log[-3_000:]


def test_every_connection_asks_postgresql_to_end_a_vanished_clients_transaction() -> None:
    """The server's side of each connection ends a transaction whose client vanished: by keepalives
    when the link was quiet, by ``tcp_user_timeout`` when its last answer went unacknowledged (a
    veth link cut under a writer left its backend holding the model's lock for the whole cut
    without it: storage/database.py), and by the idle-in-transaction time-out otherwise. Read back
    from the server, so an option PostgreSQL did not take fails here."""
    with fresh_postgres_database("contextweb_session") as url:
        engine = create_database_engine(url)
        try:
            with engine.connect() as connection:
                settings = {
                    name: connection.execute(text(f"SHOW {name}")).scalar()
                    for name in (
                        "lock_timeout",
                        "idle_in_transaction_session_timeout",
                        "tcp_keepalives_idle",
                        "tcp_keepalives_interval",
                        "tcp_keepalives_count",
                        "tcp_user_timeout",
                    )
                }
        finally:
            engine.dispose()
    assert settings == {
        "lock_timeout": "10s",
        "idle_in_transaction_session_timeout": "1min",
        "tcp_keepalives_idle": "5",
        "tcp_keepalives_interval": "2",
        "tcp_keepalives_count": "2",
        "tcp_user_timeout": "5000",  # milliseconds
    }
