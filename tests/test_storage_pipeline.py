"""PostgreSQL's pipeline mode (``storage.database.pipelined``): the errors that arrive when a
pipeline ends are storage failures like a statement's, and a pipeline that ends with the commit
stores all of its statements or none; ``lock_model`` reads the version, the labels and a keyed scene with the lock."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from psycopg import pq
from sqlalchemy import Engine, text
from sqlalchemy.exc import IntegrityError, OperationalError
from sqlalchemy.orm import Session, sessionmaker

from app.errors import is_storage_failure
from storage.database import (
    DriverStatements,
    autocommit_reads,
    combined,
    create_database_engine,
    pipelined,
    snapshot,
)
from storage.repositories import contexts as context_repository
from storage.repositories import incremental_lda as lda_repository
from storage.repositories import models as model_repository
from storage.repositories import scenes as scene_repository
from storage.unit_of_work import unit_of_work
from tests.conftest import BACKENDS, migrated_database
from tests.protocol_trace import ProtocolTrace


@pytest.fixture
def postgres(postgres_url: str) -> Iterator[Engine]:
    engine = create_database_engine(postgres_url)
    with engine.begin() as connection:
        connection.execute(text("DROP TABLE IF EXISTS pipeline_probe"))
        connection.execute(text("CREATE TABLE pipeline_probe (id integer PRIMARY KEY)"))
    yield engine
    with engine.begin() as connection:
        connection.execute(text("DROP TABLE pipeline_probe"))
    engine.dispose()


def _stored(engine: Engine) -> list[int]:
    with engine.connect() as connection:
        return [row[0] for row in connection.execute(text("SELECT id FROM pipeline_probe ORDER BY id"))]


def _insert(session: Session, *ids: int) -> None:
    driver = DriverStatements(session)
    for identifier in ids:
        driver.execute("INSERT INTO pipeline_probe (id) VALUES (?)", (identifier,))


@pytest.mark.postgres
def test_a_statement_that_fails_in_a_pipeline_is_raised_as_sqlalchemys_error(postgres: Engine) -> None:
    # In pipeline mode the database reports a failed statement when the pipeline syncs, through
    # the driver alone; it must still be SQLAlchemy's IntegrityError, as a statement's error is.
    with sessionmaker(bind=postgres)() as session:
        with pytest.raises(IntegrityError, match="pipeline_probe_pkey"), pipelined(session):
            _insert(session, 1, 1)
        session.rollback()
    assert _stored(postgres) == []


@pytest.mark.postgres
def test_a_connection_lost_while_a_pipeline_runs_is_a_storage_failure(postgres: Engine, postgres_url: str) -> None:
    # The backend serving the pipeline is terminated (a real backend, by pg_terminate_backend) after
    # the block queued its statements and before the pipeline syncs: a 503, never a bare driver error.
    admin = create_database_engine(postgres_url)
    try:
        with sessionmaker(bind=postgres)() as session:
            backend = session.execute(text("SELECT pg_backend_pid()")).scalar_one()
            with pytest.raises(OperationalError) as raised, pipelined(session):
                _insert(session, 1, 2)
                with admin.connect() as connection:
                    connection.execute(text("SELECT pg_terminate_backend(:pid)"), {"pid": backend})
                    for _ in range(100):
                        gone = connection.execute(
                            text("SELECT count(*) = 0 FROM pg_stat_activity WHERE pid = :pid"), {"pid": backend}
                        ).scalar_one()
                        if gone:
                            break
                        time.sleep(0.02)
            assert is_storage_failure(raised.value)
            session.rollback()
    finally:
        admin.dispose()
    assert _stored(postgres) == []


@pytest.mark.postgres
def test_a_pipeline_that_commits_stores_all_of_its_statements_or_none(postgres: Engine) -> None:
    sessions = sessionmaker(bind=postgres)
    with unit_of_work(sessions) as session:
        with pipelined(session, commit=True):
            _insert(session, 1, 2, 3)
        # The transaction ended with the pipeline: another connection sees the rows already.
        assert _stored(postgres) == [1, 2, 3]
    assert _stored(postgres) == [1, 2, 3]

    with pytest.raises(IntegrityError), unit_of_work(sessions) as session, pipelined(session, commit=True):
        _insert(session, 4, 5, 1)  # 1 is there: the statements before it are not stored either
    assert _stored(postgres) == [1, 2, 3]

    # The session goes on after a committed pipeline: its next transaction is a new one.
    with unit_of_work(sessions) as session:
        _insert(session, 6)
    assert _stored(postgres) == [1, 2, 3, 6]


def _syncs_before_commit(messages: list[str]) -> int:
    return messages[: messages.index('Query "COMMIT"')].count("Sync")


@pytest.mark.postgres
def test_a_pipeline_that_begins_the_transaction_sends_its_begin_in_its_own_round_trip(
    postgres: Engine, tmp_path: Path
) -> None:
    # psycopg sends a transaction's implicit BEGIN with a Sync of its own, a round trip before the
    # block's statements are even sent; with begin=True the BEGIN goes in the block's one Sync.
    trace = ProtocolTrace(postgres, tmp_path)
    sessions = sessionmaker(bind=postgres)
    for begin, syncs in ((False, 2), (True, 1)):
        start = len(trace.sent())
        with unit_of_work(sessions) as session, pipelined(session, begin=begin):
            _insert(session, 10 + begin)
        sent = trace.sent()[start:]
        assert _syncs_before_commit(sent) == syncs, sent
        assert 'Parse "" "BEGIN" 0' in sent[: sent.index("Sync")], sent
    assert _stored(postgres) == [10, 11]


@pytest.mark.postgres
def test_a_transaction_begun_in_a_pipeline_is_one_transaction_and_its_connection_returns_as_it_was(
    postgres: Engine,
) -> None:
    sessions = sessionmaker(bind=postgres)
    # Its statements are one transaction, not each committed on its own: all undone by a rollback …
    with sessions() as session:
        with pipelined(session, begin=True):
            _insert(session, 1, 2)
        assert session.connection().connection.driver_connection.info.transaction_status == pq.TransactionStatus.INTRANS
        session.rollback()
    assert _stored(postgres) == []
    # … all undone when one of them fails …
    with pytest.raises(IntegrityError), unit_of_work(sessions) as session, pipelined(session, begin=True):
        _insert(session, 3, 3)
    assert _stored(postgres) == []
    # … and stored together by the commit, which a pipeline that both begins and commits sends too.
    with unit_of_work(sessions) as session, pipelined(session, begin=True, commit=True):
        _insert(session, 4, 5)
    assert _stored(postgres) == [4, 5]
    # The pool's connection is back in psycopg's default mode, where the next session's
    # statements begin a transaction implicitly again (a read's snapshot relies on it).
    with sessions() as session:
        driver = session.connection().connection.driver_connection
        assert driver.autocommit is False
        _insert(session, 6)
        assert driver.info.transaction_status == pq.TransactionStatus.INTRANS
        session.rollback()
    assert _stored(postgres) == [4, 5]
    # In a session whose transaction has begun, begin=True changes nothing.
    with sessions() as session:
        _insert(session, 7)
        with pipelined(session, begin=True):
            _insert(session, 8)
        session.rollback()
    assert _stored(postgres) == [4, 5]


@pytest.mark.postgres
def test_a_autocommit_reads_is_one_round_trip_and_its_connection_returns_as_it_was(
    postgres: Engine, tmp_path: Path
) -> None:
    # A request's version check (app/registry.py) is one statement: in a snapshot it cost a BEGIN,
    # the statement and a ROLLBACK, each waited for; alone, in autocommit, it is one round trip.
    sessions = sessionmaker(bind=postgres)
    with unit_of_work(sessions) as session:
        _insert(session, 1)
    trace = ProtocolTrace(postgres, tmp_path)
    for read, transaction_control in ((snapshot, 2), (autocommit_reads, 0)):
        start = len(trace.sent())
        with read(sessions) as session:
            assert DriverStatements(session).fetchall("SELECT id FROM pipeline_probe", ()) == [(1,)]
        sent = trace.sent()[start:]
        # Each simple query (psycopg's BEGIN, ROLLBACK, a statement without parameters) and each
        # Sync of the extended protocol is a round trip: psycopg waits for its answer.
        round_trips = [message for message in sent if message.split()[0] in ("Query", "Sync")]
        assert len(round_trips) == 1 + transaction_control, sent
        assert len([message for message in sent if "BEGIN" in message or "ROLLBACK" in message]) == transaction_control
    with sessions() as session:
        assert session.connection().connection.driver_connection.autocommit is False


@pytest.mark.postgres
def test_combined_statements_are_sent_as_one_in_their_order(postgres: Engine, tmp_path: Path) -> None:
    trace = ProtocolTrace(postgres, tmp_path)
    sessions = sessionmaker(bind=postgres)
    with unit_of_work(sessions) as session, pipelined(session, commit=True):
        with combined(session):
            _insert(session, 1, 2)
            DriverStatements(session).execute("UPDATE pipeline_probe SET id = id + 10 WHERE id = ?", (1,))
            # Nothing was sent yet: the block's statements wait for its end …
            assert not [message for message in trace.sent() if "pipeline_probe" in message]
        sent = trace.sent()
    # … and went as one statement, whose parts all ran on the snapshot from before it: the UPDATE
    # did not see the row its own statement inserted.
    statements = [message for message in sent if message.startswith("Parse") and "pipeline_probe" in message]
    assert len(statements) == 1 and statements[0].count("INSERT INTO pipeline_probe") == 2, statements
    assert _stored(postgres) == [1, 2]

    # A query in the block sends what was queued first, so it sees it, and the order holds.
    with unit_of_work(sessions) as session, combined(session):
        _insert(session, 3)
        assert DriverStatements(session).fetchall("SELECT id FROM pipeline_probe ORDER BY id", ()) == [(1,), (2,), (3,)]
        DriverStatements(session).execute("DELETE FROM pipeline_probe WHERE id = ?", (3,))
        _insert(session, 4)
    assert _stored(postgres) == [1, 2, 4]

    # One failing part fails the statement: none of the block's rows is stored.
    with (
        pytest.raises(IntegrityError, match="pipeline_probe_pkey"),
        unit_of_work(sessions) as session,
        pipelined(session, commit=True),
        combined(session),
    ):
        _insert(session, 5, 6, 1)
    assert _stored(postgres) == [1, 2, 4]


@pytest.mark.parametrize("backend", BACKENDS)
def test_lock_model_reads_the_version_and_every_label(backend: str, request: pytest.FixtureRequest, tmp_path) -> None:
    engine = create_database_engine(migrated_database(backend, request, tmp_path))
    try:
        sessions = sessionmaker(bind=engine)
        with unit_of_work(sessions) as session:
            model_repository.add_model(
                session, model_id="m", name="m", seed=1, sigma=0.5, hyperparameters={}, vocabulary={}
            )
            lda_repository.create_state(session, "m", context_count=3, state={}, words=[])
            lda_repository.set_version(session, "m", 7)
            context_repository.set_context_label(session, "m", 0, "kitchen")
            context_repository.set_context_label(session, "m", 2, "workshop")
            row = {"request_hash": b"h" * 32, "context_count": 3, "map_context": 2, "context_posterior": [0, 0, 1]}
            scene_repository.add_scene(session, "m", 0, idempotency_key="k", answer='{"id":0}', **row)
        labels = {0: "kitchen", 2: "workshop"}
        with unit_of_work(sessions) as session:
            locked = lda_repository.lock_model(session, "m", wait=False)
            assert locked == lda_repository.LockedModel(version=7, labels=labels)
            assert lda_repository.lock_model(session, "absent") is None
            # A keyed scene's key is looked up with the lock: a retry finds the stored answer.
            retried = lda_repository.lock_model(session, "m", idempotency_key="k")
            assert retried is not None and retried.stored_under_key is not None
            assert (retried.version, retried.labels, retried.idempotency_key) == (7, labels, "k")
            stored = retried.stored_under_key
            assert (stored.scene_id, stored.request_hash, stored.answer) == (0, b"h" * 32, '{"id":0}')
            fresh = lda_repository.lock_model(session, "m", idempotency_key="new")
            assert fresh == lda_repository.LockedModel(7, labels, "new", None)
    finally:
        engine.dispose()
