"""The incremental persistence of Incremental-LDA: what a scene writes is what a restart reads."""

from __future__ import annotations

import numpy as np
import pytest
from sqlalchemy import Engine
from sqlalchemy.exc import IntegrityError

from core.context.incremental import IncrementalLDA
from storage.database import create_session_makers
from storage.repositories import incremental_lda as lda_repository
from storage.repositories import models as model_repository
from storage.repositories import scenes as scene_repository
from storage.repositories.incremental_lda import SceneChanges
from storage.unit_of_work import unit_of_work

SCENES = [["cup", "plate", "hard"], ["ball", "box", "soft", "ball"], ["cup", "spoon"], ["tool", "cylinder", "hard"]] * 3
FAST = {"sweeps": 10, "likelihood_samples": 2, "birth_window": 4, "birth_check_interval": 2, "rejuvenation_tokens": 8}


def _store_model(engine: Engine, lda: IncrementalLDA) -> None:
    _, write = create_session_makers(engine)
    with unit_of_work(write) as session:
        model_repository.add_model(
            session, model_id="m", name="m", seed=1, sigma=0.5, hyperparameters=FAST, vocabulary={}
        )
        lda_repository.create_state(
            session, "m", context_count=lda.n_contexts, state={"rng_state": lda.to_state().rng_state}, words=[]
        )


def _learn_and_store(engine: Engine, lda: IncrementalLDA, words: list[str]) -> None:
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
                reassigned=list(
                    zip(update.reassigned_tokens.tolist(), update.reassigned_contexts.tolist(), strict=True)
                ),
                counts=[tuple(row) for row in update.changed_counts.tolist()],
                new_words=[(first_word + i, name, None) for i, name in enumerate(update.vocabulary_additions)],
                context_count=update.contexts_after,
                state={"rng_state": update.rng_state},
            ),
        )


def test_scene_by_scene_writes_reload_to_the_same_corpus(engine: Engine) -> None:
    lda = IncrementalLDA(seed=5, **FAST)
    _store_model(engine, lda)
    for words in SCENES:
        _learn_and_store(engine, lda, words)
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
    row = {"request_hash": "h", "context_count": 1, "map_context": 0, "context_posterior": [1.0], "answer": "{}"}
    with unit_of_work(write) as session:
        scene_repository.add_scene(session, "m", 0, idempotency_key="k", **row)
        scene_repository.add_scene(session, "m", 1, idempotency_key=None, **row)
        scene_repository.add_scene(session, "m", 2, idempotency_key=None, **row)
    with pytest.raises(IntegrityError), unit_of_work(write) as session:
        scene_repository.add_scene(session, "m", 3, idempotency_key="k", **row)
    read, _ = create_session_makers(engine)
    with read() as session:
        assert scene_repository.find_by_idempotency_key(session, "m", "k").id == 0
        rows, total = scene_repository.page_scenes(session, "m", offset=1, limit=5)
    assert total == 3 and [scene.id for scene in rows] == [1, 2]
