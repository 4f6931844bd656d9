"""Shared database and app fixtures: every storage and API test runs on SQLite and on PostgreSQL.

Databases are built by the migrations (``alembic upgrade head``), never by
``create_all``. SQLite gets a fresh file per test; PostgreSQL gets one database
for the session (``contextweb_test_<pid>``, so that concurrent test runs never
share one; dropped at the end) whose tables are emptied between tests. Where
no PostgreSQL answers on 127.0.0.1:5432 the PostgreSQL variants are skipped,
saying so. At the end, the data the API tests post: concept-level scenes and
training objects with synthetic features.
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import Engine, create_engine, text

from alembic import command
from app.main import create_app
from app.registry import ModelRuntime
from app.schemas.observations import RawObject as ServiceRawObject
from app.services.perception import raw_recording
from app.services.warmup import warm_up_kernels
from app.settings import Settings
from app.state import AppState
from core.context.incremental import ContextModelState
from core.features.layout import EFFECT_LAYOUT, EFFECT_SIZE, ENTITY_SIZE
from core.payloads import ObjectRecording
from sim.world import World
from storage.database import create_database_engine, create_session_makers
from storage.migrations import alembic_config, upgrade_to_head
from storage.models import Base
from storage.repositories.consistency import check_model

# The paper world, its concept web and its context model as fixtures (tests/paper_feedback.py).
pytest_plugins = ["tests.paper_feedback"]


def pytest_configure(config: pytest.Config) -> None:
    """numba's on-disk cache filled once, in the process that starts the test workers (xdist's
    controller, or the only process), before any worker starts: with an empty cache (a fresh clone,
    as in CI) the service's warm-up compiles for ≈ 67 s on the 2-core machine of 2026-12-02, past
    the start-up deadlines of the tests that start servers, and each worker compiled the same
    kernels at the same time; once the cache is written, a server's start loads it in seconds.
    The kernels only the tests run (tests/kernel_priming.py) compile meanwhile in a process of
    their own, on the other core."""
    if not hasattr(config, "workerinput"):
        priming = subprocess.Popen([sys.executable, "-c", _PRIMING], cwd=Path(__file__).resolve().parents[1])
        warm_up_kernels()
        if priming.wait() != 0:  # the tests that run those kernels say what broke; they only compile later
            print("tests/kernel_priming.py failed: the workers compile those kernels themselves", file=sys.stderr)


_PRIMING = "from tests.kernel_priming import compile_kernels_beyond_the_warm_up as c; c()"


POSTGRES_SERVER_URL = os.environ.get("CONTEXTWEB_TEST_POSTGRES_URL", "postgresql+psycopg://postgres@127.0.0.1:5432")
POSTGRES_TEST_DATABASE = f"contextweb_test_{os.getpid()}"


def _postgres_admin_engine() -> Engine:
    return create_engine(
        f"{POSTGRES_SERVER_URL}/postgres", isolation_level="AUTOCOMMIT", connect_args={"connect_timeout": 3}
    )


@pytest.fixture(scope="session")
def postgres_url() -> Iterator[str]:
    """A freshly created and migrated PostgreSQL test database (skips when no server is reachable)."""
    admin = _postgres_admin_engine()
    try:
        with admin.connect() as connection:
            connection.execute(text(f'DROP DATABASE IF EXISTS "{POSTGRES_TEST_DATABASE}" WITH (FORCE)'))
            connection.execute(text(f'CREATE DATABASE "{POSTGRES_TEST_DATABASE}"'))
    except Exception as error:  # noqa: BLE001 - any failure to reach the server means: skip the PostgreSQL variant
        admin.dispose()
        pytest.skip(
            f"PostgreSQL not reachable at {POSTGRES_SERVER_URL} ({type(error).__name__}): PostgreSQL variant skipped"
        )
    admin.dispose()
    url = f"{POSTGRES_SERVER_URL}/{POSTGRES_TEST_DATABASE}"
    engine = create_database_engine(url)
    upgrade_to_head(engine)
    engine.dispose()
    yield url
    with admin.connect() as connection:
        connection.execute(text(f'DROP DATABASE IF EXISTS "{POSTGRES_TEST_DATABASE}" WITH (FORCE)'))
    admin.dispose()


def _empty_postgres(url: str) -> None:
    engine = create_database_engine(url)
    tables = ", ".join(f'"{table.name}"' for table in Base.metadata.sorted_tables)
    with engine.begin() as connection:
        connection.execute(text(f"TRUNCATE {tables} CASCADE"))
    engine.dispose()


BACKENDS = ["sqlite", pytest.param("postgresql", marks=pytest.mark.postgres)]


def migrated_database(backend: str, request: pytest.FixtureRequest, directory: Path) -> str:
    """The URL of an empty, migrated database of ``backend`` (SQLite files go in ``directory``)."""
    if backend == "sqlite":
        url = f"sqlite:///{directory / 'contextweb.sqlite3'}"
        engine = create_database_engine(url)
        upgrade_to_head(engine)
        engine.dispose()
        return url
    url = request.getfixturevalue("postgres_url")
    _empty_postgres(url)
    return url


@pytest.fixture(params=BACKENDS)
def database_url(request: pytest.FixtureRequest, tmp_path: Path) -> str:
    """The URL of an empty, migrated database of each backend."""
    return migrated_database(request.param, request, tmp_path)


@pytest.fixture
def cli_database(database_url: str, monkeypatch: pytest.MonkeyPatch) -> str:
    """The test database as the CLI's ``CONTEXTWEB_DATABASE_URL``, with no other setting leaking in."""
    for name in ("CONTEXTWEB_ENVIRONMENT", "CONTEXTWEB_WRITE_KEY", "CONTEXTWEB_READ_KEY"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("CONTEXTWEB_DATABASE_URL", database_url)
    return database_url


@pytest.fixture
def engine(database_url: str) -> Iterator[Engine]:
    engine = create_database_engine(database_url)
    yield engine
    engine.dispose()


def make_settings(database_url: str, **overrides: Any) -> Settings:
    """Settings for a test: explicit values, so the developer's CONTEXTWEB_* variables never leak in.

    ``overrides`` are any of Settings' fields, checked by its validation like the defaults here.
    """
    values: dict[str, Any] = {
        "database_url": database_url,
        "environment": "development",
        "write_key": None,
        "read_key": None,
        "sqlite_synchronous": "NORMAL",
    }
    values.update(overrides)
    return Settings(**values)


@contextmanager
def two_processes(database_url: str) -> Iterator[tuple[TestClient, TestClient]]:
    """Two apps on one database, as two processes of a deployment would be (a server error is a 500
    here, as a robot would get it, not an exception in the thread).

    Both apps' route fields are built first, one app after the other, as ``contextweb serve`` does
    (app/serve.py ``serving_app``). FastAPI otherwise builds them on each route's first request,
    here on the two apps' threads at once, inside ``warnings.catch_warnings()``, which is not
    thread-safe: the likeliest cause of a pydantic warning that FastAPI silences and that twice
    escaped into a two-app test's output (``UnsupportedFieldAttributeWarning`` on the aliases
    ``Idempotency-Key`` and ``body``; not reproduced on demand)."""
    first_app, second_app = (create_app(make_settings(database_url)) for _ in range(2))
    for built in (first_app, second_app):
        built.openapi()
    with (
        TestClient(first_app, raise_server_exceptions=False) as first,
        TestClient(second_app, raise_server_exceptions=False) as second,
    ):
        yield first, second


@pytest.fixture
def app(database_url: str) -> FastAPI:
    return create_app(make_settings(database_url))


@pytest.fixture
def client(app: FastAPI) -> Iterator[TestClient]:
    with TestClient(app) as client:
        yield client


#: Incremental-LDA settings small enough for tests (growth checks on a short window, few sweeps).
FAST_HYPERPARAMETERS = {
    "sampler": {"sweeps": 10, "rejuvenation_tokens": 8, "inference_sweeps": 10, "inference_burn_in": 3},
    "k_rule": {"name": "scenes", "birth_window": 6, "birth_check_interval": 3},
}


@pytest.fixture
def model_id(client: TestClient) -> str:
    """A new model with the paper's vocabulary and :data:`FAST_HYPERPARAMETERS`."""
    response = client.post("/v1/models", json={"name": "test", "seed": 11, "hyperparameters": FAST_HYPERPARAMETERS})
    assert response.status_code == 201, response.text
    return response.json()["id"]


CONTEXT_CONCEPTS = {
    "kitchen": ["cup", "plate", "hard", "short", "silent", "round", "grasp", "move_left"],
    "playroom": ["ball", "box", "soft", "noisy", "edgy", "thick", "throw", "shake"],
    "workshop": ["tool", "cylinder", "hard", "tall", "thin", "push_left", "knock_down", "drop"],
}


def concept_scenes(count: int, seed: int) -> list[dict]:
    """Scene bodies of 2–4 concept-level objects, each scene from one of three contexts."""
    rng = np.random.default_rng(seed)
    scenes = []
    for _ in range(count):
        concepts = CONTEXT_CONCEPTS[list(CONTEXT_CONCEPTS)[rng.integers(3)]]
        objects = [{"concepts": list(rng.choice(concepts, size=4, replace=False))} for _ in range(rng.integers(2, 5))]
        scenes.append({"objects": objects})
    return scenes


CELL = 0.1
DISPLACEMENT = {
    "move_right": (CELL, 0, 0), "move_left": (-CELL, 0, 0), "move_forward": (0, CELL, 0), "move_backward": (0, -CELL, 0),
    "push_right": (CELL, 0, 0), "push_left": (-CELL, 0, 0), "push_forward": (0, CELL, 0), "push_backward": (0, -CELL, 0),
    "drop": (0, 0, -0.6), "throw": (0.3, 0.3, -0.7), "knock_down": (0, 0, -0.03), "grasp": (0, 0, 0), "shake": (0, 0, 0),
}  # fmt: skip


def synthetic_training_objects(world: World, seed: int) -> list[dict]:
    """The world's training objects (Table I labels, Table II behaviours) with synthetic features.

    Each concept has its own mean entity vector and each behaviour its own effect, whose
    position block is the grid step the planner should learn (0.1 m cells; drops and throws
    leave the table).
    """
    rng = np.random.default_rng(seed)
    vocabulary = world.vocabulary
    concept_means = {c: rng.normal(0.0, 1.0, ENTITY_SIZE) for c in vocabulary.nouns + vocabulary.adjectives}
    verb_means = {v: rng.normal(0.0, 1.0, EFFECT_SIZE) for v in vocabulary.verbs}
    objects = []
    for obj in world.train_objects:
        entity = sum(concept_means[c] for c in obj.concepts) + rng.normal(0.0, 0.1, ENTITY_SIZE)
        effects = {}
        for verb in obj.behaviours:
            effect = verb_means[verb] + rng.normal(0.0, 0.05, EFFECT_SIZE)
            effect[EFFECT_LAYOUT["position"]] = np.array(DISPLACEMENT[verb]) + rng.normal(0.0, 0.005, 3)
            effects[verb] = effect.tolist()
        objects.append(
            {
                "noun": obj.noun,
                "adjectives": list(obj.adjectives),
                "features": {"entity": entity.tolist(), "effects": effects},
            }
        )
    return objects


def decoded_recording(raw: Any) -> ObjectRecording:
    """What the service makes of a raw object a bridge tool encoded (``bridge.models.RawObject``): its
    schema, then its decoding into ``core.payloads``."""
    return raw_recording(ServiceRawObject.model_validate(raw.model_dump(mode="json")), "raw")


def state_and_model(client: TestClient, model_id: str) -> tuple[AppState, ModelRuntime]:
    """A test app's state and one of its models in memory."""
    state: AppState = client.app_state["contextweb"]
    model = state.registry.get(model_id)
    assert model is not None
    return state, model


def stored_problems(engine: Engine, model_id: str) -> list[str]:
    """``contextweb models check``'s storage problems of the stored model."""
    read, _ = create_session_makers(engine)
    with read() as session:
        return check_model(session, model_id)


def migrate(engine: Engine, action: str, revision: str) -> None:
    """``alembic upgrade`` or ``downgrade`` (``action``) of the database to ``revision``, in one transaction."""
    config = alembic_config()
    with engine.begin() as connection:
        config.attributes["connection"] = connection
        getattr(command, action)(config, revision)


def memory_state(client: TestClient, model_id: str) -> ContextModelState:
    """The model's Incremental-LDA state as the app holds it, after checking its invariants."""
    state: AppState = client.app_state["contextweb"]
    model = state.registry.get(model_id)
    assert model is not None and model.unavailable is None, model and model.unavailable
    model.incremental_lda.check_invariants()
    return model.incremental_lda.to_state()


def assert_same_state(state: ContextModelState, expected: ContextModelState) -> None:
    """Bit for bit: K, the vocabulary, every token's word and context, the scenes, n_kw, the random state."""
    assert state.n_contexts == expected.n_contexts and state.vocabulary == expected.vocabulary
    for name in ("words", "assignments", "doc_offsets", "n_kw"):
        assert np.array_equal(getattr(state, name), getattr(expected, name)), name
    assert state.rng_state == expected.rng_state
