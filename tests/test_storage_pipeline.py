"""PostgreSQL's pipeline mode (``storage.database.pipelined``): the errors that arrive when a
pipeline ends are storage failures like a statement's, and a pipeline that ends with the commit
stores all of its statements or none; ``lock_model`` reads the version, the labels and a keyed scene with the lock."""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest
from sqlalchemy import Engine, text
from sqlalchemy.exc import IntegrityError, OperationalError
from sqlalchemy.orm import Session, sessionmaker

from app.errors import is_storage_failure
from storage.database import DriverStatements, create_database_engine, pipelined
from storage.repositories import contexts as context_repository
from storage.repositories import incremental_lda as lda_repository
from storage.repositories import models as model_repository
from storage.repositories import scenes as scene_repository
from storage.unit_of_work import unit_of_work
from tests.conftest import BACKENDS, migrated_database


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
            stored = scene_repository.StoredAnswer(0, b"h" * 32, '{"id":0}')
            assert retried == lda_repository.LockedModel(7, labels, "k", stored)
            fresh = lda_repository.lock_model(session, "m", idempotency_key="new")
            assert fresh == lda_repository.LockedModel(7, labels, "new", None)
    finally:
        engine.dispose()
