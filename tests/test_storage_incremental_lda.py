"""The incremental persistence of Incremental-LDA: what a scene writes is what a restart reads."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from sqlalchemy import Engine, text
from sqlalchemy.exc import IntegrityError

from core.context.incremental import IncrementalLDA
from sim.world import World
from storage.database import create_database_engine, create_session_makers
from storage.repositories import incremental_lda as lda_repository
from storage.repositories import models as model_repository
from storage.repositories import scenes as scene_repository
from storage.repositories.incremental_lda import SceneChanges
from storage.unit_of_work import unit_of_work
from tests.conftest import migrated_database

SMALL_SCENES = [
    ["cup", "plate", "hard"],
    ["ball", "box", "soft", "ball"],
    ["cup", "spoon"],
    ["tool", "cylinder", "hard"],
]
#: Paper-world scenes after small hand-made ones: the contexts grow (K = 3 by the end, seed 5), so
#: updates reassign earlier tokens, which must be rewritten, not only appended.
SCENES = SMALL_SCENES + [
    [concept for obj in scene.objects for concept in obj.concepts]
    for scene in World.paper(0).scenes(12, seed=0, objects_per_scene=3)
]
FAST = {"sweeps": 10, "birth_window": 4, "birth_check_interval": 2, "rejuvenation_tokens": 8}


def _store_model(engine: Engine, lda: IncrementalLDA) -> None:
    _, write = create_session_makers(engine)
    with unit_of_work(write) as session:
        model_repository.add_model(
            session,
            model_id="m",
            name="m",
            seed=1,
            sigma=0.5,
            hyperparameters=lda.hyperparameters.to_dict(),
            vocabulary={},
        )
        lda_repository.create_state(
            session, "m", context_count=lda.n_contexts, state={"rng_state": lda.to_state().rng_state}, words=[]
        )


def _learn_and_store(engine: Engine, lda: IncrementalLDA, words: list[str]) -> int:
    """Learn and store one scene; the number of earlier tokens it reassigned."""
    _, write = create_session_makers(engine)
    first_token = lda.lda_state.n_tokens
    first_word = len(lda.vocabulary)
    update = lda.learn_scene(words)
    with unit_of_work(write) as session:
        lda_repository.save_scene(
            session,
            "m",
            SceneChanges(
                scene_id=update.scene_index,
                first_token=first_token,
                token_words=update.word_ids.tolist(),
                token_contexts=update.assignments.tolist(),
                reassigned=lda_repository.reassigned_rows(update),
                counts=[tuple(row) for row in update.changed_counts.tolist()],
                new_words=[(first_word + i, name, None) for i, name in enumerate(update.vocabulary_additions)],
                context_count=update.contexts_after,
                state={"rng_state": update.rng_state},
                version=update.scene_index + 1,
            ),
        )
    return len(update.reassigned_tokens)


def test_scene_by_scene_writes_reload_to_the_same_corpus(engine: Engine) -> None:
    lda = IncrementalLDA(seed=5, **FAST)
    _store_model(engine, lda)
    reassigned = [_learn_and_store(engine, lda, words) for words in SCENES]
    assert sum(reassigned) > 0  # earlier tokens were moved and rewritten, not only new ones inserted
    read, _ = create_session_makers(engine)
    with read() as session:
        stored = lda_repository.load_corpus(session, "m")
        assert lda_repository.stored_counts(session, "m") == lda_repository.assignment_counts(session, "m")
    state = lda.to_state()
    assert stored.word_names == state.vocabulary
    assert np.array_equal(stored.token_words, state.words)
    assert np.array_equal(stored.token_contexts, state.assignments)
    assert np.array_equal(stored.doc_offsets, state.doc_offsets)
    assert stored.context_count == state.n_contexts and stored.scene_count == len(SCENES)
    assert stored.state["rng_state"] == state.rng_state
    n_kw = np.zeros_like(state.n_kw)
    n_kw[stored.count_entries[:, 0], stored.count_entries[:, 1]] = stored.count_entries[:, 2]
    assert np.array_equal(n_kw, state.n_kw)


def test_an_idempotency_key_is_unique_per_model(engine: Engine) -> None:
    lda = IncrementalLDA(seed=5, **FAST)
    _store_model(engine, lda)
    _, write = create_session_makers(engine)
    row = {"request_hash": bytes(32), "context_count": 1, "map_context": 0, "context_posterior": [1.0], "answer": "{}"}
    with unit_of_work(write) as session:
        scene_repository.add_scene(session, "m", 0, idempotency_key="k", **row)
        scene_repository.add_scene(session, "m", 1, idempotency_key=None, **row)
        scene_repository.add_scene(session, "m", 2, idempotency_key=None, **row)
    with pytest.raises(IntegrityError), unit_of_work(write) as session:
        scene_repository.add_scene(session, "m", 3, idempotency_key="k", **row)
    read, _ = create_session_makers(engine)
    with read() as session:
        assert scene_repository.find_by_idempotency_key(session, "m", "k") == (0, bytes(32), "{}")
        assert scene_repository.find_by_idempotency_key(session, "m", "other") is None
        rows, total = scene_repository.page_scenes(session, "m", offset=1, limit=5)
    assert total == 3 and [scene.id for scene in rows] == [1, 2]


def _plan_nodes(node: dict) -> list[dict]:
    return [node, *(found for child in node.get("Plans", []) for found in _plan_nodes(child))]


@pytest.mark.postgres
def test_rewriting_moved_tokens_never_scans_the_models_tokens(
    postgres_url: str, request: pytest.FixtureRequest
) -> None:
    """With statistics older than the corpus (a fresh table, never analysed), the statement that
    rewrites a scene's moved tokens probes the primary key row by row: an UPDATE ... FROM unnest
    was planned as a hash join over every token of the model, a cost that grew with the corpus."""
    url = migrated_database("postgresql", request, Path())
    engine = create_database_engine(url)
    try:
        _store_model(engine, IncrementalLDA(seed=5, **FAST))
        with engine.begin() as connection:
            connection.execute(
                text("INSERT INTO token SELECT 'm', g, g / 20, g % 29, 0, 0 FROM generate_series(0, 39999) AS g")
            )
            moved = list(range(30_000, 39_000, 150))
            plan = connection.exec_driver_sql(
                "EXPLAIN (FORMAT JSON) " + lda_repository._UPSERT_TOKENS.replace("?", "%s"),
                ("m", 1, moved, [t // 20 for t in moved], [t % 29 for t in moved], [1] * len(moved)),
            ).scalar_one()
    finally:
        engine.dispose()
    nodes = _plan_nodes(plan[0]["Plan"])
    assert nodes[0]["Node Type"] == "ModifyTable" and nodes[0]["Conflict Resolution"] == "UPDATE"
    assert [node["Node Type"] for node in nodes[1:] if node.get("Relation Name") == "token"] == []
