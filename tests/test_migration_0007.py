"""Migration 0007 turns a database's token rows into one checkpoint per model (no row per token any more),
on SQLite and PostgreSQL; the code then writes token batches on top, and the downgrade rebuilds the
token rows, with the version of each token's last write, from the checkpoint and the batches."""

from __future__ import annotations

import numpy as np
from sqlalchemy import Engine, inspect, text

from storage.database import create_database_engine, create_session_makers
from storage.repositories import incremental_lda as lda_repository
from storage.repositories.incremental_lda import SceneChanges
from storage.unit_of_work import unit_of_work
from tests.conftest import migrate
from tests.test_migration_0005 import empty_database

__all__ = ["empty_database"]  # the fixture, shared with migration 0005's test

#: (id, scene, word, context, version) token rows of the old database (model version 5).
TOKENS = [(0, 0, 0, 1, 1), (1, 0, 2, 0, 2), (2, 1, 0, 1, 4), (3, 1, 1, 1, 5)]
NOW = "'2026-12-01 00:00:00'"


def _tokens(engine: Engine) -> list[tuple[int, ...]]:
    with engine.connect() as connection:
        rows = connection.execute(text("SELECT id, scene_id, word_id, context, version FROM token ORDER BY id")).all()
    return [tuple(row) for row in rows]


def _old_database(engine: Engine) -> None:
    """Two models at revision 0006: 'm' with 2 scenes of token rows, 'empty' without any."""
    migrate(engine, "upgrade", "0006")
    with engine.begin() as connection:
        for model_id in ("m", "empty"):
            connection.execute(
                text(
                    "INSERT INTO model (id, name, seed, sigma, hyperparameters, hyperparameters_version, vocabulary, "
                    f"created_at, updated_at) VALUES ('{model_id}', 'old', 0, 0.5, '{{}}', 2, '{{}}', {NOW}, {NOW})"
                )
            )
            connection.execute(
                text(
                    "INSERT INTO incremental_lda_state (model_id, scene_count, context_count, state, version, "
                    f"updated_at) VALUES ('{model_id}', 2, 2, '{{\"rng_state\": {{}}}}', 5, {NOW})"
                )
            )
        for word_id, name in enumerate(("cup", "plate", "hard")):
            connection.execute(
                text(f"INSERT INTO word (model_id, id, name, created_at) VALUES ('m', {word_id}, '{name}', {NOW})")
            )
        for token in TOKENS:
            connection.execute(
                text(
                    "INSERT INTO token (model_id, id, scene_id, word_id, context, version) "
                    "VALUES ('m', :id, :scene, :word, :context, :version)"
                ),
                dict(zip(("id", "scene", "word", "context", "version"), token, strict=True)),
            )


def test_upgrading_checkpoints_the_token_rows_and_downgrading_rebuilds_them_with_the_batches(
    empty_database: str,
) -> None:
    engine = create_database_engine(empty_database)
    try:
        _old_database(engine)
        migrate(engine, "upgrade", "head")
        assert "token" not in inspect(engine).get_table_names()
        read, write = create_session_makers(engine)
        with read() as session:
            checkpoint = lda_repository.load_checkpoint(session, "m")
            start = lda_repository.load_start(session, "m")
            stored = lda_repository.load_assignments(session, "m")
            assert lda_repository.load_checkpoint(session, "empty") is None
            assert lda_repository.compacted_version(session, "m") == 5
        assert checkpoint is not None and (checkpoint.version, checkpoint.scene_count, checkpoint.token_count) == (
            5,
            2,
            4,
        )
        assert (checkpoint.context_count, checkpoint.word_count) == (2, 3)
        assert start.tail.added.size == 0 and start.tail.moved.size == 0
        rows = np.array(TOKENS)
        assert np.array_equal(stored.scenes, rows[:, 1]) and np.array_equal(stored.words, rows[:, 2])
        assert np.array_equal(stored.contexts, rows[:, 3])

        with unit_of_work(write) as session:  # a scene learned after the upgrade: one batch, token 1 moved
            lda_repository.save_scene(
                session,
                "m",
                SceneChanges(
                    scene_id=2,
                    first_token=4,
                    token_words=np.array([2, 0]),
                    token_contexts=np.array([0, 1]),
                    moved_tokens=np.array([1]),
                    moved_contexts=np.array([1]),
                    counts=[],
                    new_words=[],
                    context_count=2,
                    state={"rng_state": {}},
                    version=6,
                ),
            )

        migrate(engine, "downgrade", "0006")
        assert _tokens(engine) == [
            (0, 0, 0, 1, 5),
            (1, 0, 2, 1, 6),
            (2, 1, 0, 1, 5),
            (3, 1, 1, 1, 5),
            (4, 2, 2, 0, 6),
            (5, 2, 0, 1, 6),
        ]
        assert "token_batch" not in inspect(engine).get_table_names()
        columns = {column["name"] for column in inspect(engine).get_columns("incremental_lda_checkpoint")}
        assert "compacted_version" not in columns

        migrate(engine, "upgrade", "head")  # and up again: the rebuilt rows checkpoint at the model's version 6
        with read() as session:
            again = lda_repository.load_assignments(session, "m")
            assert lda_repository.compacted_version(session, "m") == 6
        assert again.contexts.tolist() == [1, 1, 1, 1, 0, 1] and again.scenes.tolist() == [0, 0, 1, 1, 2, 2]
    finally:
        engine.dispose()
