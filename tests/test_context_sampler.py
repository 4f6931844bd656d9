"""The collapsed Gibbs sampler (Eq. 5, Algorithms 1 and 3) against exact references."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.special import gammaln

from core.context.lda import LDAState


def _state(docs: list[list[int]], vocab_size: int, n_contexts: int, alpha: float = 0.5, xi: float = 0.5) -> LDAState:
    words = np.array([w for doc in docs for w in doc], dtype=np.int32)
    offsets = np.concatenate([[0], np.cumsum([len(doc) for doc in docs])]).astype(np.int32)
    return LDAState.from_arrays(alpha, xi, vocab_size, n_contexts, words, np.zeros_like(words), offsets)


def _random_state(seed: int, n_docs: int = 12, vocab_size: int = 9, n_contexts: int = 3) -> LDAState:
    rng = np.random.default_rng(seed)
    docs = [list(rng.integers(0, vocab_size, size=rng.integers(1, 9))) for _ in range(n_docs)]
    state = _state(docs, vocab_size, n_contexts, alpha=0.1, xi=0.1)
    state.initialize_randomly(rng)
    return state


def _reference_joint(state: LDAState) -> float:
    """log P(w, z) written out as in Griffiths & Steyvers (2004)."""
    k, v, a, x = state.n_contexts, state.vocab_size, state.alpha, state.xi
    return float(
        k * (gammaln(v * x) - v * gammaln(x)) + gammaln(state.n_wk + x).sum() - gammaln(state.n_k + v * x).sum()
        + state.n_documents * (gammaln(k * a) - k * gammaln(a))
        + gammaln(state.n_dk + a).sum() - gammaln(state.doc_lengths + k * a).sum()
    )  # fmt: skip


def chain_total_variation(state: LDAState, sweeps: int, kernel: str | None = None) -> float:
    """Total variation between the exact P(z | w) ∝ exp(log P(w, z)), enumerated over every
    assignment of ``state``'s tokens, and the visit frequencies of ``sweeps`` Gibbs sweeps."""
    states = list(itertools.product(range(state.n_contexts), repeat=state.n_tokens))
    log_joint = []
    for z in states:
        state.assignments[:] = z
        state.recount()
        log_joint.append(state.joint_log_likelihood())
    exact = np.exp(np.array(log_joint) - max(log_joint))
    exact /= exact.sum()

    rng = np.random.default_rng(1)
    state.initialize_randomly(rng)
    index = {z: i for i, z in enumerate(states)}
    visits = np.zeros(len(states))
    for _ in range(sweeps):
        state.sweep(rng, kernel=kernel)
        visits[index[tuple(state.assignments.tolist())]] += 1
    return float(0.5 * np.abs(visits / visits.sum() - exact).sum())


def test_gibbs_chain_visits_states_with_the_exact_posterior() -> None:
    # 2 scenes x 3 tokens, K = 2: the 64 assignments can be enumerated.
    state = _state([[0, 1, 1], [2, 2, 0]], vocab_size=3, n_contexts=2)
    assert chain_total_variation(state, 30_000) < 0.03
    assert state.invariant_violations() == []


def test_joint_log_likelihood_matches_the_written_out_formula() -> None:
    state = _random_state(3)
    state.sweep(np.random.default_rng(0), 5)
    assert state.joint_log_likelihood() == pytest.approx(_reference_joint(state), rel=1e-12)


def test_window_log_likelihood_is_the_conditional_given_earlier_scenes() -> None:
    state = _random_state(4, n_docs=20)
    earlier = state.subset(np.arange(14))
    assert state.joint_log_likelihood(14) == pytest.approx(
        _reference_joint(state) - _reference_joint(earlier), rel=1e-10
    )


def test_conditional_entropy_matches_a_direct_computation() -> None:
    state = _random_state(5)
    expected = 0.0
    docs = np.repeat(np.arange(state.n_documents), state.doc_lengths)
    v_xi = state.vocab_size * state.xi
    for i, (w, z, d) in enumerate(zip(state.words, state.assignments, docs, strict=True)):
        own = np.eye(state.n_contexts)[z]
        p = (state.n_wk[w] - own + state.xi) / (state.n_k - own + v_xi) * (state.n_dk[d] - own + state.alpha)
        p /= p.sum()
        expected -= float((p * np.log(p)).sum())
    assert state.conditional_entropy() == pytest.approx(expected, rel=1e-10)


def test_same_seed_same_chain_and_counts_stay_consistent() -> None:
    first, second = _random_state(6), _random_state(6)
    first.sweep(np.random.default_rng(11), 10)
    second.sweep(np.random.default_rng(11), 10)
    assert np.array_equal(first.assignments, second.assignments)
    assert first.invariant_violations() == []


def test_window_sweep_leaves_earlier_scenes_alone() -> None:
    state = _random_state(7, n_docs=10)
    before = state.assignments.copy()
    start = int(state.doc_offsets[6])
    state.sweep(np.random.default_rng(2), 20, first_doc=6)
    assert np.array_equal(state.assignments[:start], before[:start])
    assert state.invariant_violations() == []


def test_k_incremental_start_keeps_confident_tokens_and_moves_low_confidence_ones() -> None:
    state = _random_state(8, n_contexts=2)
    before = state.assignments.copy()
    low = state.words == 3
    state.grow_k_incrementally(low, delta=0.0, rng=np.random.default_rng(0))
    assert state.n_contexts == 3
    assert np.all(state.assignments[low] == 2)
    assert np.array_equal(state.assignments[~low], before[~low])
    assert state.invariant_violations() == []


def test_growth_of_scenes_concepts_and_contexts_keeps_everything() -> None:
    state = LDAState(0.1, 0.1, vocab_size=2)
    rng = np.random.default_rng(0)
    for d in range(100):
        if d % 10 == 0:
            state.add_words(3)
        if d % 30 == 29:
            state.add_context()
        ids = rng.integers(0, state.vocab_size, size=rng.integers(1, 20)).astype(np.int32)
        scene = state.append_document(ids)
        tokens = np.arange(state.doc_offsets[scene], state.n_tokens)
        state.sample_tokens(tokens, rng)
        assert np.array_equal(state.words[tokens], ids)
    assert (state.vocab_size, state.n_contexts, state.n_documents) == (32, 4, 100)
    assert state.invariant_violations() == []


def test_fold_in_leaves_the_counts_unchanged_and_is_seeded() -> None:
    state = _random_state(9)
    counts = state.n_wk.copy()
    scene = np.array([0, 0, 1, 4], dtype=np.int32)
    theta = state.fold_in(scene, np.random.default_rng(3), sweeps=30, burn_in=10)
    again = state.fold_in(scene, np.random.default_rng(3), sweeps=30, burn_in=10)
    assert np.array_equal(state.n_wk, counts)
    assert np.array_equal(theta, again)
    assert theta.shape == (3,) and theta.sum() == pytest.approx(1.0)


@pytest.mark.parametrize("seed", range(6))
def test_fold_in_is_sampling_the_scene_into_a_copy_of_the_counts(seed: int) -> None:
    """The kernel keeps Eq. 5's factors as running floats; written out on a copy of the counts with
    the same uniforms and the same draw rule (the first context whose cumulative weight exceeds
    u · total), θ must be the same: one draw that differed would move it by ≥ 1 / (tokens · sweeps)."""
    rng = np.random.default_rng(seed)
    state = _random_state(seed, n_docs=20, vocab_size=12, n_contexts=int(rng.integers(2, 7)))
    scene = rng.integers(0, state.vocab_size, size=int(rng.integers(3, 25))).astype(np.int32)
    sweeps, burn_in = 12, 4
    uniforms = np.random.default_rng(100 + seed).random(sweeps * scene.shape[0])
    theta = state.fold_in(scene, np.random.default_rng(100 + seed), sweeps=sweeps, burn_in=burn_in)
    n_wk, n_k = state.n_wk.astype(np.float64), state.n_k.astype(np.float64)
    n_contexts, vocab_xi = state.n_contexts, state.vocab_size * state.xi
    n_dk, z, expected, draw = np.zeros(n_contexts), np.full(scene.shape[0], -1), np.zeros(n_contexts), 0
    for sweep in range(sweeps):
        for i, w in enumerate(scene):
            if z[i] >= 0:
                n_wk[w, z[i]] -= 1
                n_k[z[i]] -= 1
                n_dk[z[i]] -= 1
            cumulative = np.cumsum((n_wk[w] + state.xi) / (n_k + vocab_xi) * (n_dk + state.alpha))
            z[i] = min(int(np.searchsorted(cumulative, uniforms[draw] * cumulative[-1], side="right")), n_contexts - 1)
            draw += 1
            n_wk[w, z[i]] += 1
            n_k[z[i]] += 1
            n_dk[z[i]] += 1
        if sweep >= burn_in:
            expected += n_dk + state.alpha
    assert theta == pytest.approx(expected / expected.sum(), abs=1e-12)


def test_reassign_then_restore_returns_the_same_counts() -> None:
    state = _random_state(10)
    counts, saved = state.n_wk.copy(), state.assignments.copy()
    tokens = np.arange(state.n_tokens, dtype=np.int64)
    state.reassign(tokens, (saved + 1) % state.n_contexts)
    assert state.invariant_violations() == []
    state.reassign(tokens, saved)
    assert np.array_equal(state.n_wk, counts)


def _add_scene_step_by_step(
    state: LDAState, word_ids: np.ndarray, rng: np.random.Generator, sweeps: int, rejuvenation_tokens: int
) -> tuple[int, np.ndarray, np.ndarray]:
    """``add_scene_online`` spelled out with the public steps its docstring names, in its draw order."""
    earlier = state.n_tokens
    scene = state.append_document(word_ids)
    state.scene_to_one_context(scene, rng)
    per_sweep = rejuvenation_tokens if earlier else 0
    rejuvenated = rng.integers(0, earlier, sweeps * per_sweep)
    previous = state.assignments[rejuvenated].copy()
    scene_tokens = np.arange(earlier, state.n_tokens)
    for sweep in range(sweeps):
        state.sample_tokens(
            np.concatenate([scene_tokens, rejuvenated[sweep * per_sweep : (sweep + 1) * per_sweep]]), rng
        )
    return scene, rejuvenated, previous


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_online_scene_update_equals_its_steps_one_after_the_other(seed: int) -> None:
    """The fused kernel of ``add_scene_online`` makes the same draws and the same moves as
    appending, the block draw and the token sweeps done one by one (scenes 0 to 11 of a corpus
    learned both ways, from an empty state, with and without rejuvenation)."""
    rng = np.random.default_rng(seed)
    scenes = [rng.integers(0, 9, size=rng.integers(1, 12)).astype(np.int32) for _ in range(12)]
    for rejuvenation_tokens in (0, 5):
        fused, stepped = LDAState(0.1, 0.1, 9, 3), LDAState(0.1, 0.1, 9, 3)
        fused_rng, stepped_rng = np.random.default_rng(seed + 10), np.random.default_rng(seed + 10)
        for word_ids in scenes:
            got = fused.add_scene_online(word_ids, fused_rng, 3, rejuvenation_tokens)
            expected = _add_scene_step_by_step(stepped, word_ids, stepped_rng, 3, rejuvenation_tokens)
            assert got[0] == expected[0]
            assert np.array_equal(got[1], expected[1]) and np.array_equal(got[2], expected[2])
            assert np.array_equal(fused.assignments, stepped.assignments)
            assert np.array_equal(fused.n_wk, stepped.n_wk) and np.array_equal(fused.n_dk, stepped.n_dk)
        assert fused.invariant_violations() == []
        assert fused_rng.random() == stepped_rng.random()  # the same number of draws
