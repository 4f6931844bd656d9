"""Online Incremental-LDA finds a late context within a few scenes (issue 17, goal 6), without
opening contexts that are not there. Seeds 100-129: ``bench.bench_context_birth`` measures on 0-9.

The bounds are rates with room for other seeds, set from 900 late-context runs on seeds that
nothing was tuned on (1000-1059, 2000-2059, 3000-3059, 2026-12-06; docs/context.md): the median delay
of any 100 of them was 2 to 4 scenes, 2.3 % of the runs never found the late context, 7.1 % had a
false birth, and none opened more than one context too many. At those rates 100 runs break the
bounds on misses and false births with probability under 1 % each (binomial)."""

from __future__ import annotations

import math
import statistics

import numpy as np
import pytest

from bench.bench_context_birth import SCENARIOS, birth_run, steady_run
from core.context import IncrementalLDA
from core.context.k_selection import ScenesSettings
from core.context.k_selection.base import NOVELTY_MIN_WINDOW
from core.context.lda import LDAState
from sim.world import WorldConfig, generate_scenes

SEEDS = range(100, 120)


@pytest.fixture(scope="module")
def late_runs() -> list:
    return [birth_run(scenario, seed) for scenario in SCENARIOS for seed in SEEDS]


def test_a_late_context_is_found_within_five_scenes_at_the_median(late_runs: list) -> None:
    # A miss counts as never found, so misses push the median up instead of leaving it.
    delays = [math.inf if run.delay is None else run.delay for run in late_runs]
    assert statistics.median(delays) <= 5, delays
    assert sum(run.delay is None for run in late_runs) <= 6 * len(late_runs) // 100, delays


def test_a_late_context_is_found_within_five_scenes_in_most_runs(late_runs: list) -> None:
    """Within 5 scenes of its first appearance (the issue's goal, in stream scenes): in 88.3 % of 900
    runs on seeds 1000-1059, 2000-2059 and 3000-3059, against 72.7 % when every novelty-triggered
    check decided on the last 20 scenes (docs/context.md). 80 of 100 fails at 88.3 % with
    probability under 1 % (binomial), and at 72.7 % with probability 95 %."""
    delays = [run.delay for run in late_runs]
    assert sum(delay is not None and delay <= 5 for delay in delays) >= 80 * len(late_runs) // 100, delays


def test_a_novelty_check_decides_on_the_scenes_since_the_earliest_novel_one() -> None:
    """The window of a check that a novel scene triggers: from the earliest scene of the last
    ``novelty_window`` that was itself novel against the contexts before them, else the last
    NOVELTY_MIN_WINDOW scenes. (K held at 1 while learning, so that the workshop scene stays in
    the kitchen's context and the rule alone is seen.)"""
    model = IncrementalLDA(seed=0, max_contexts=1)
    rule = ScenesSettings().make_rule()
    kitchen, workshop = ["cup", "plate", "grasp", "cup", "spoon"], ["hammer", "nail", "hammer", "push", "saw"]
    for _ in range(40):
        model.learn_scene(kitchen)
    state = model.lda_state
    model._add_concepts(workshop)
    workshop_ids, kitchen_ids = model._ids(workshop), model._ids(kitchen)
    assert rule.growth_window(state, kitchen_ids) is None
    assert rule.growth_window(state, workshop_ids) == state.n_documents + 1 - NOVELTY_MIN_WINDOW
    model.learn_scene(workshop)
    first_workshop = state.n_documents - 1
    for _ in range(6):
        model.learn_scene(kitchen)
    assert state.first_novel_scene(state.n_documents - 15, 1.0) == first_workshop
    assert state.first_novel_scene(first_workshop + 1, 1.0) is None
    assert rule.growth_window(state, workshop_ids) == first_workshop
    for _ in range(20):  # the workshop scene has left the last novelty_window scenes
        model.learn_scene(kitchen)
    assert rule.growth_window(state, workshop_ids) == state.n_documents + 1 - NOVELTY_MIN_WINDOW


def test_late_contexts_rarely_open_a_context_that_is_not_there(late_runs: list) -> None:
    excess = [run.max_excess for run in late_runs]
    assert sum(e > 0 for e in excess) <= 14 * len(late_runs) // 100 and max(excess) <= 1, excess


STEADY_SEEDS = range(100, 130)
"""Streams per scenario: a rate, not a few seeds' exact K. On seeds 1000-1059, 2000-2059 and
3000-3059 (nothing tuned on them) the paper world ended at its K in 179 of 180 streams with 1 false
birth, and generic-5 in 53, 56 and 53 of 60 with 1 false birth each; a generic room is sometimes read
as one context too few (docs/context.md). The bounds below fail a seed set with probability under
1 % at an exact-K rate of 90 % (binomial), and under 4 % at a false-birth rate of 4 %."""


@pytest.mark.parametrize("scenario", ["paper", "generic-5"])
def test_steady_streams_keep_k_and_check_growth_rarely(scenario: str) -> None:
    """Every context from the start: K found and no false birth in all but a few streams, and after
    the first scheduled checks only the doubling ones (4 in 400 scenes) and a few that novelty triggers."""
    scheduled = 4  # after scenes 50, 100, 200 and 400 (birth_check_interval 25)
    true_k = 3 if scenario == "paper" else 5
    rows = [steady_run(scenario, seed) for seed in STEADY_SEEDS]
    outcomes = [(row["final_k"], row["max_excess"]) for row in rows]
    assert sum(row["final_k"] == true_k for row in rows) >= 23, outcomes
    assert sum(row["max_excess"] > 0 for row in rows) <= 3, outcomes
    assert all(scheduled <= row["checks_after_start"] <= scheduled + 8 for row in rows), rows


def test_novelty_is_zero_for_a_repeated_scene_and_large_for_unseen_concepts() -> None:
    """The trigger's evidence: a scene already learned many times fits its context better than a
    fresh one; a scene of concepts no context holds is explained better by a fresh context."""
    model = IncrementalLDA(seed=0)
    for _ in range(30):
        model.learn_scene(["cup", "plate", "grasp", "cup"])
    state = model.lda_state
    known = state.scene_novelty(model._ids(["cup", "plate", "grasp", "cup"]), state.n_documents, 1.0)
    model._add_concepts(["hammer", "nail"])
    unseen = state.scene_novelty(model._ids(["hammer", "nail", "hammer", "grasp"]), state.n_documents, 1.0)
    assert known < 0.0 < unseen
    before = (state.n_wk.copy(), state.n_k.copy())
    state.scene_novelty(model._ids(["hammer", "nail"]), state.n_documents - 10, 1.0)
    assert (state.n_wk == before[0]).all() and (state.n_k == before[1]).all()


def plain_novelty(state: LDAState, word_ids: np.ndarray, first_doc: int, strength: float) -> float:
    """scene_novelty's formula in numpy: the window's tokens taken off every context's counts."""
    n_wk, n_k, vocab_size = state.n_wk.astype(float), state.n_k.astype(float), state.vocab_size
    start = state.doc_offsets[first_doc]
    held_wk, held_k = n_wk.copy(), n_k.copy()
    np.subtract.at(held_wk, (state.words[start:], state.assignments[start:]), 1.0)
    np.subtract.at(held_k, state.assignments[start:], 1.0)
    beta = strength * vocab_size / (n_k.sum() + vocab_size * state.xi) * (n_wk[word_ids].sum(axis=1) + state.xi)
    earlier = np.array([np.sum(word_ids[:j] == w) for j, w in enumerate(word_ids)])
    steps = np.arange(len(word_ids))

    def log_fit(counts: np.ndarray, held: float) -> float:
        return float(np.sum(np.log((counts + beta + earlier) / (held + strength * vocab_size + steps))))

    best = max(log_fit(held_wk[word_ids, k], held_k[k]) for k in range(state.n_contexts))
    return log_fit(np.zeros(len(word_ids)), 0.0) - best


def test_novelty_takes_the_window_off_the_contexts() -> None:
    model = IncrementalLDA(seed=1)
    for scene in generate_scenes(WorldConfig.paper(), 40, 5):
        model.learn_scene(scene.tokens())
    state = model.lda_state
    for scene in generate_scenes(WorldConfig.paper(), 5, 6):
        word_ids = model._ids(scene.tokens())
        for first_doc in (state.n_documents, state.n_documents - 3, state.n_documents - 20):
            expected = plain_novelty(state, word_ids, first_doc, 1.0)
            assert state.scene_novelty(word_ids, first_doc, 1.0) == pytest.approx(expected, rel=1e-9, abs=1e-9)
