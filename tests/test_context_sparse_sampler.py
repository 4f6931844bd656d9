"""The sweep kernels for many contexts (``"lanes"``, ``"sparse"``) against Eq. 5 and the dense sweep.

Each kernel lays the contexts out on [0, 1) in its own order, so the same uniforms give other
contexts than the dense sweep: what must agree is the probability of each context (checked
exactly, by feeding a fine grid of uniforms) and the chain's stationary distribution (checked
against the enumerated posterior), while the counts stay those of the assignments.
"""

from __future__ import annotations

import numpy as np
import pytest

from core.context.lda import LANES_FROM_CONTEXTS, SPARSE_FROM_CONTEXTS, SWEEP_KERNELS, LDAState, sweep_kernel
from core.errors import InvalidInputError
from tests.test_context_sampler import chain_total_variation

KERNELS = sorted(SWEEP_KERNELS)
NEW_KERNELS = ["lanes", "sparse"]


def _corpus_state(docs: list[list[int]], vocab_size: int, n_contexts: int, alpha: float, xi: float) -> LDAState:
    words = np.array([w for doc in docs for w in doc], dtype=np.int32)
    offsets = np.concatenate([[0], np.cumsum([len(doc) for doc in docs])]).astype(np.int32)
    return LDAState.from_arrays(alpha, xi, vocab_size, n_contexts, words, np.zeros_like(words), offsets)


def _random_state(seed: int, n_docs: int, vocab_size: int, n_contexts: int, alpha: float, xi: float) -> LDAState:
    rng = np.random.default_rng(seed)
    docs = [list(rng.integers(0, vocab_size, size=rng.integers(1, 30))) for _ in range(n_docs)]
    state = _corpus_state(docs, vocab_size, n_contexts, alpha, xi)
    state.initialize_randomly(rng)
    return state


def _eq5_conditional(state: LDAState, token: int, doc: int) -> np.ndarray:
    """P(z_token = k | z_¬token, w) of Eq. 5, normalised."""
    own = np.eye(state.n_contexts)[state.assignments[token]]
    w = state.words[token]
    p = (
        (state.n_wk[w] - own + state.xi)
        / (state.n_k - own + state.vocab_size * state.xi)
        * (state.n_dk[doc] - own + state.alpha)
    )
    return p / p.sum()


@pytest.mark.parametrize("n_contexts", [5, 11, 19, 40])
@pytest.mark.parametrize("kernel", KERNELS)
def test_a_grid_of_uniforms_lands_on_each_context_with_its_eq5_probability(kernel: str, n_contexts: int) -> None:
    """The first token of the last scene, drawn with u on a grid of n points: context k gets
    the share P(k) of them, up to one point per end of each of the (at most three, for the
    sparse buckets) intervals of [0, 1) that the kernel maps to k. Deterministic, no sampling noise."""
    state = _random_state(n_contexts, n_docs=40, vocab_size=12, n_contexts=n_contexts, alpha=0.7, xi=0.3)
    doc = state.n_documents - 1
    token = int(state.doc_offsets[doc])
    expected = _eq5_conditional(state, token, doc)
    n_points = 20_000
    length = int(state.doc_offsets[doc + 1]) - token
    hits = np.zeros(n_contexts)
    base = (state.words.copy(), state.assignments.copy(), state.doc_offsets.copy())
    counts = (state.n_wk.copy(), state.n_k.copy(), state.n_dk.copy())
    for point in range(n_points):
        z = base[1].copy()
        n_wk, n_k, n_dk = (c.copy() for c in counts)
        uniforms = np.full(length, 0.5)
        uniforms[0] = (point + 0.5) / n_points
        SWEEP_KERNELS[kernel](
            base[0], z, base[2], doc, doc + 1, n_wk, n_k, n_dk, n_contexts, state.alpha, state.xi, state.vocab_size,
            uniforms,
        )  # fmt: skip
        hits[z[token]] += 1
    assert np.abs(hits / n_points - expected).max() <= 3 / n_points + 1e-9


@pytest.mark.parametrize(
    ("docs", "vocab_size", "n_contexts", "sweeps", "tolerance"),
    [
        # 6 tokens, K = 2: 64 assignments; expected total variation of 30,000 draws ≈ 0.02.
        ([[0, 1, 1], [2, 2, 0]], 3, 2, 30_000, 0.03),
        # 4 tokens, K = 3: 81 assignments; expected total variation of 40,000 draws ≈ 0.02.
        ([[0, 1], [1, 2]], 3, 3, 40_000, 0.04),
    ],
)
@pytest.mark.parametrize("kernel", NEW_KERNELS)
def test_chain_visits_states_with_the_exact_posterior(
    kernel: str, docs: list[list[int]], vocab_size: int, n_contexts: int, sweeps: int, tolerance: float
) -> None:
    """P(z | w) ∝ exp(log P(w, z)) over every assignment, against the chain's visit frequencies
    (the same check as the dense sweep's in tests/test_context_sampler.py)."""
    state = _corpus_state(docs, vocab_size, n_contexts, alpha=0.5, xi=0.5)
    assert chain_total_variation(state, sweeps, kernel) < tolerance
    assert state.invariant_violations() == []


@pytest.mark.parametrize("kernel", NEW_KERNELS)
def test_counts_equal_a_recount_and_a_window_sweep_leaves_earlier_scenes_alone(kernel: str) -> None:
    """Unused concepts (empty word lists) and contexts that empty and refill along the way included."""
    state = _random_state(3, n_docs=60, vocab_size=80, n_contexts=37, alpha=0.1, xi=0.1)
    rng = np.random.default_rng(4)
    state.sweep(rng, 10, kernel=kernel)
    assert state.invariant_violations() == []
    before = state.assignments.copy()
    start = int(state.doc_offsets[45])
    state.sweep(rng, 5, first_doc=45, kernel=kernel)
    assert np.array_equal(state.assignments[:start], before[:start])
    assert not np.array_equal(state.assignments[start:], before[start:])
    assert state.invariant_violations() == []


@pytest.mark.parametrize("kernel", NEW_KERNELS)
def test_a_state_rebuilt_from_its_assignments_continues_bit_identically(kernel: str) -> None:
    """A restore keeps words, assignments, offsets and the generator's state (counts are recounted):
    the kernels rebuild everything else from those, so the chain goes on unchanged."""
    through, restored = (_random_state(5, 30, 50, 40, 0.1, 0.1) for _ in range(2))
    through_rng, restored_rng = np.random.default_rng(6), np.random.default_rng(6)
    through.sweep(through_rng, 6, kernel=kernel)
    restored.sweep(restored_rng, 3, kernel=kernel)
    saved_generator = restored_rng.bit_generator.state
    restored = LDAState.from_arrays(
        restored.alpha, restored.xi, restored.vocab_size, restored.n_contexts,
        restored.words.copy(), restored.assignments.copy(), restored.doc_offsets.copy(),
    )  # fmt: skip
    restored_rng = np.random.Generator(np.random.PCG64())
    restored_rng.bit_generator.state = saved_generator
    restored.sweep(restored_rng, 3, kernel=kernel)
    assert np.array_equal(through.assignments, restored.assignments)


def test_the_default_kernel_is_chosen_by_k_alone() -> None:
    """Dense below LANES_FROM_CONTEXTS (every K of the paper's experiments and of the service's
    default max_contexts, so their chains are unchanged), then lanes, then sparse; ``sweep``
    without a kernel runs exactly the chosen one."""
    assert [sweep_kernel(k) for k in (1, 3, 10, LANES_FROM_CONTEXTS - 1)] == ["dense"] * 4
    assert [sweep_kernel(k) for k in (LANES_FROM_CONTEXTS, 50, SPARSE_FROM_CONTEXTS - 1)] == ["lanes"] * 3
    assert [sweep_kernel(k) for k in (SPARSE_FROM_CONTEXTS, 2 * SPARSE_FROM_CONTEXTS)] == ["sparse"] * 2
    for n_contexts in (3, LANES_FROM_CONTEXTS, SPARSE_FROM_CONTEXTS):
        default, explicit, other = (_random_state(7, 20, 30, n_contexts, 0.1, 0.1) for _ in range(3))
        default.sweep(np.random.default_rng(8), 3)
        explicit.sweep(np.random.default_rng(8), 3, kernel=sweep_kernel(n_contexts))
        other.sweep(np.random.default_rng(8), 3, kernel="dense" if sweep_kernel(n_contexts) == "sparse" else "sparse")
        assert np.array_equal(default.assignments, explicit.assignments)
        assert not np.array_equal(default.assignments, other.assignments)  # so the equality above says something


def test_an_unknown_kernel_is_refused() -> None:
    state = _random_state(9, 5, 5, 2, 0.1, 0.1)
    with pytest.raises(InvalidInputError, match="kernel"):
        state.sweep(np.random.default_rng(0), kernel="alias")
