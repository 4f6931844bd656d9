"""The incremental persistence of Incremental-LDA: what a scene writes is what a restart reads."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from sqlalchemy import Engine, text
from sqlalchemy.exc import IntegrityError

from app.registry import apply_stored_changes
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
                token_words=update.word_ids,
                token_contexts=update.assignments,
                moved_tokens=update.reassigned_tokens,
                moved_contexts=update.reassigned_contexts,
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
        stored = lda_repository.load_assignments(session, "m")
        assert stored.words.dtype == stored.contexts.dtype == stored.scenes.dtype == np.int32
        start = lda_repository.load_start(session, "m")
        assert lda_repository.stored_counts(session, "m") == lda_repository.assignment_counts(session, "m")
        batches = session.execute(text("SELECT count(*) FROM token_batch WHERE model_id = 'm'")).scalar_one()
    assert batches == len(SCENES), "one token_batch row per learned scene"
    state = lda.to_state()
    assert start.word_names == state.vocabulary and start.checkpoint is None
    assert np.array_equal(stored.words, state.words)
    assert np.array_equal(stored.contexts, state.assignments)
    assert np.array_equal(np.searchsorted(stored.scenes, np.arange(len(SCENES) + 1)), state.doc_offsets)
    assert start.context_count == state.n_contexts and start.scene_count == len(SCENES)
    assert start.state["rng_state"] == state.rng_state
    n_kw = np.zeros_like(state.n_kw)
    n_kw[start.count_entries[:, 0], start.count_entries[:, 1]] = start.count_entries[:, 2]
    assert np.array_equal(n_kw, state.n_kw)


def _checkpoint_now(engine: Engine, lda: IncrementalLDA, version: int) -> None:
    """What every checkpoint_interval-th scene does: the corpus as a checkpoint, older batches compacted."""
    state = lda.lda_state
    _, write = create_session_makers(engine)
    with unit_of_work(write) as session:
        lda_repository.save_checkpoint(
            session,
            "m",
            lda_repository.StoredCheckpoint(
                version=version,
                context_count=state.n_contexts,
                word_count=state.vocab_size,
                words=state.words,
                contexts=state.assignments,
                doc_offsets=state.doc_offsets,
            ),
            compact=True,
        )


def test_checkpoints_compact_the_batches_and_a_process_too_far_behind_is_told_to_reload(engine: Engine) -> None:
    """A checkpoint deletes the batches at or below the previous checkpoint's version: a process up to one
    interval behind catches up from the batches kept, one further behind gets BehindCompactionError."""
    lda = IncrementalLDA(seed=5, **FAST)
    _store_model(engine, lda)
    behind = IncrementalLDA(seed=5, **FAST)  # a second process that stopped following after scene 2
    for words in SCENES[:2]:
        behind.learn_scene(words)
    one_interval_behind = IncrementalLDA(seed=5, **FAST)  # stopped after scene 6
    for words in SCENES[:6]:
        one_interval_behind.learn_scene(words)
    for version, words in enumerate(SCENES, start=1):
        _learn_and_store(engine, lda, words)
        if version in (4, 8):
            _checkpoint_now(engine, lda, version)
    read, _ = create_session_makers(engine)
    with read() as session:
        kept = session.execute(text("SELECT min(version), count(*) FROM token_batch WHERE model_id = 'm'")).one()
        assert tuple(kept) == (5, len(SCENES) - 4), "the batches at or below the first checkpoint (4) are deleted"
        assert lda_repository.compacted_version(session, "m") == 4
        with pytest.raises(lda_repository.BehindCompactionError):
            lda_repository.load_changes(
                session, "m", since_version=2, word_count=len(behind.vocabulary), token_count=behind.lda_state.n_tokens
            )
        changes = lda_repository.load_changes(
            session,
            "m",
            since_version=6,
            word_count=len(one_interval_behind.vocabulary),
            token_count=one_interval_behind.lda_state.n_tokens,
        )
        start = lda_repository.load_start(session, "m")
        with pytest.raises(lda_repository.DamagedBatchError, match="starts at token"):
            lda_repository.load_changes(session, "m", since_version=6, word_count=0, token_count=0)
    assert changes is not None
    apply_stored_changes(one_interval_behind, changes)
    expected, caught_up = lda.to_state(), one_interval_behind.to_state()
    for name in ("words", "assignments", "doc_offsets", "n_kw"):
        assert np.array_equal(getattr(caught_up, name), getattr(expected, name)), name
    assert caught_up.rng_state == expected.rng_state
    assert start.checkpoint is not None and start.checkpoint.version == 8
    assert start.tail.added.shape[0] == expected.words.shape[0] - start.checkpoint.token_count


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
        stored = scene_repository.find_by_idempotency_key(session, "m", "k")
        assert stored is not None and (stored.scene_id, stored.request_hash, stored.answer) == (0, bytes(32), "{}")
        assert scene_repository.find_by_idempotency_key(session, "m", "other") is None
        rows, total = scene_repository.page_scenes(session, "m", offset=1, limit=5)
    assert total == 3 and [scene.id for scene in rows] == [1, 2]


def _plan_nodes(node: dict) -> list[dict]:
    return [node, *(found for child in node.get("Plans", []) for found in _plan_nodes(child))]


@pytest.mark.postgres
def test_catching_up_reads_a_range_of_the_batches_primary_key(
    postgres_url: str, request: pytest.FixtureRequest
) -> None:
    """With statistics older than the corpus (a fresh table, never analysed), the catch-up's read of the
    batches since a version is a range scan of the primary key: no scan of the model's other batches
    (the design needs no second index, docs/scaling.md "Token batches"). The planner may sort the
    range it read (a bitmap scan on an unanalysed table)."""
    url = migrated_database("postgresql", request, Path())
    engine = create_database_engine(url)
    try:
        _store_model(engine, IncrementalLDA(seed=5, **FAST))
        with engine.begin() as connection:
            connection.execute(
                text(
                    "INSERT INTO token_batch SELECT 'm', g, g - 1, (g - 1) * 20, 20, '\\x01'::bytea "
                    "FROM generate_series(1, 40000) AS g"
                )
            )
            plan = connection.exec_driver_sql(
                "EXPLAIN (FORMAT JSON) " + lda_repository._SELECT_BATCHES_SINCE.replace("?", "%s"), ("m", 39_000)
            ).scalar_one()
    finally:
        engine.dispose()
    nodes = _plan_nodes(plan[0]["Plan"])
    assert {node["Node Type"] for node in nodes} <= {"Sort", "Index Scan", "Bitmap Heap Scan", "Bitmap Index Scan"}
    assert [node.get("Index Name") for node in nodes if "Index" in node["Node Type"]] == ["pk_token_batch"]


@pytest.mark.parametrize(
    ("contexts", "words"),
    [
        (np.random.default_rng(3).integers(0, 7, 5_000), np.random.default_rng(4).integers(0, 300, 5_000)),
        (np.array([0, -1, 2, 2]), np.array([1, 1, 3, 3])),  # a negative context: damaged tokens
        (np.array([0, 2**40, 0]), np.array([5, 5, 5])),  # beyond any count table: damaged tokens
        (np.array([], dtype=np.int64), np.array([], dtype=np.int64)),
    ],
)
def test_token_counts_are_the_pairs_counts_whatever_the_ids(contexts: np.ndarray, words: np.ndarray) -> None:
    """n_kw from tokens (``models check``'s right-hand side): one pass where the ids fit a table,
    the sort otherwise; the same counts either way."""
    tokens = lda_repository.StoredAssignments(words=words, contexts=contexts, scenes=np.zeros_like(words))
    assert lda_repository.token_counts(tokens) == dict(Counter(zip(contexts.tolist(), words.tolist(), strict=True)))
