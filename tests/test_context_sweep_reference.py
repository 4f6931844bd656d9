"""The dense and lanes sweep kernels, and the online update's token sampler, against plain-Python
references of Eq. 5, bit for bit.

The kernels write a token's counts only when it moves (core/context/_gibbs_kernels.py, the comment
above ``sweep_documents``). The references below do what the textbook does, and what the kernels
did before: take the token out of its counts, compute every weight from the counts without it,
draw, put it back. Python floats are IEEE doubles and numba compiles without fastmath, so the
same expressions on the same values give the same weights, the same draws and the same chain: a
wrong weight, count or layout shows as a different assignment within a few sweeps. (A change in
the last bit of a sum alone shows only when a uniform falls within that bit of a boundary, which
is rare: the lanes kernel's tree of lane sums and the serial lane sums it replaced gave the same
10 million draws on the benchmark's corpora, docs/context.md.)
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

import numpy as np
import pytest

from core.context._gibbs_kernels import LANES, sample_tokens, sweep_documents, sweep_documents_by_lanes

Counts = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def sum_in_order(values: Iterable[float]) -> float:
    """Left to right from 0.0, as a running sum in a loop adds."""
    total = 0.0
    for value in values:
        total += value
    return total


def _take_out(w: int, d: int, k: int, counts: Counts, change: int) -> None:
    _, n_wk, n_k, n_dk = counts
    n_wk[w, k] += change
    n_k[k] += change
    n_dk[d, k] += change


def reference_dense_sweep(
    words: np.ndarray,
    offsets: np.ndarray,
    counts: Counts,
    alpha: float,
    xi: float,
    vocab_size: int,
    uniforms: np.ndarray,
) -> None:
    """One running sum of (n_wk + ξ) / (n_k + |W|ξ) · (n_dk + α), then the first k past u · Σ."""
    u_index = 0
    for d in range(offsets.shape[0] - 1):
        for i in range(offsets[d], offsets[d + 1]):
            _resample(i, d, int(words[i]), counts, alpha, xi, vocab_size, float(uniforms[u_index]))
            u_index += 1


def _resample(i: int, d: int, w: int, counts: Counts, alpha: float, xi: float, vocab_size: int, u: float) -> None:
    """Token ``i`` taken out of its counts (when it has a context), drawn, put back."""
    z, n_wk, n_k, n_dk = counts
    v_xi = vocab_size * xi
    n_contexts = n_k.shape[0]
    if z[i] >= 0:
        _take_out(w, d, int(z[i]), counts, -1)
    cumulative = []
    total = 0.0
    for k in range(n_contexts):
        total += (int(n_wk[w, k]) + xi) * (1.0 / (int(n_k[k]) + v_xi)) * (int(n_dk[d, k]) + alpha)
        cumulative.append(total)
    target = u * total
    new = 0
    while new < n_contexts - 1 and cumulative[new] <= target:
        new += 1
    z[i] = new
    _take_out(w, d, new, counts, 1)


def reference_lanes_sweep(
    words: np.ndarray,
    offsets: np.ndarray,
    counts: Counts,
    alpha: float,
    xi: float,
    vocab_size: int,
    uniforms: np.ndarray,
) -> None:
    """Weights (n_wk + ξ) · ((n_dk + α) · 1 / (n_k + |W|ξ)) summed in LANES interleaved lanes (the even
    and the odd rows of eight apart, then added); the lane whose edge u · Σ passes, then a context
    within it (the layout of ``sweep_documents_by_lanes``)."""
    z, n_wk, n_k, n_dk = counts
    v_xi = vocab_size * xi
    n_contexts = n_k.shape[0]
    depth = (n_contexts + LANES - 1) // LANES
    u_index = 0
    for d in range(offsets.shape[0] - 1):
        for i in range(offsets[d], offsets[d + 1]):
            w = int(words[i])
            _take_out(w, d, int(z[i]), counts, -1)
            weights = [0.0] * (depth * LANES)
            for k in range(n_contexts):
                coefficient = (int(n_dk[d, k]) + alpha) * (1.0 / (int(n_k[k]) + v_xi))
                weights[k] = (int(n_wk[w, k]) + xi) * coefficient
            rows = [weights[j : j + LANES] for j in range(0, depth * LANES, LANES)] + [[0.0] * LANES]
            even = [sum_in_order(row[m] for row in rows[0::2]) for m in range(LANES)]
            odd = [sum_in_order(row[m] for row in rows[1::2]) for m in range(LANES)]
            mass = [even[m] + odd[m] for m in range(LANES)]
            edge = [mass[0], mass[0] + mass[1]]  # edge[m - 1]: the mass of lanes 0..m-1
            edge.append(edge[1] + mass[2])
            edge.append(edge[1] + (mass[2] + mass[3]))
            edge.append(edge[3] + mass[4])
            edge.append(edge[3] + (mass[4] + mass[5]))
            edge.append(edge[5] + mass[6])
            total = edge[3] + ((mass[4] + mass[5]) + (mass[6] + mass[7]))
            target = float(uniforms[u_index]) * total
            u_index += 1
            lane, lower = 0, 0.0
            for m_index in range(LANES - 1):
                if edge[m_index] <= target:
                    lane, lower = m_index + 1, edge[m_index]
            lane = min(lane, min(LANES, n_contexts) - 1)
            target -= lower
            steps, cumulative = 0, 0.0
            for step in range(depth - 1):
                cumulative += weights[lane + step * LANES]
                steps += cumulative <= target
            new = lane + min(steps, (n_contexts - 1 - lane) // LANES) * LANES
            z[i] = new
            _take_out(w, d, new, counts, 1)


def _random_corpus(
    seed: int, n_docs: int, vocab_size: int, n_contexts: int, used_contexts: int
) -> tuple[np.ndarray, np.ndarray, Counts]:
    """Flat corpus with counts; only the first ``used_contexts`` contexts hold tokens at the start."""
    rng = np.random.default_rng(seed)
    lengths = rng.integers(1, 20, size=n_docs)
    offsets = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int32)
    words = rng.integers(0, vocab_size, size=offsets[-1]).astype(np.int32)
    z = rng.integers(0, used_contexts, size=offsets[-1]).astype(np.int32)
    n_wk = np.zeros((vocab_size, n_contexts), dtype=np.int32)
    n_k = np.zeros(n_contexts, dtype=np.int32)
    n_dk = np.zeros((n_docs, n_contexts), dtype=np.int32)
    docs = np.repeat(np.arange(n_docs), lengths)
    np.add.at(n_wk, (words, z), 1)
    np.add.at(n_k, z, 1)
    np.add.at(n_dk, (docs, z), 1)
    return words, offsets, (z, n_wk, n_k, n_dk)


@pytest.mark.parametrize(
    ("kernel", "reference"),
    [(sweep_documents, reference_dense_sweep), (sweep_documents_by_lanes, reference_lanes_sweep)],
)
@pytest.mark.parametrize(
    ("n_contexts", "used_contexts", "vocab_size", "xi"),
    [
        (1, 1, 7, 0.1),
        (3, 3, 29, 0.1),
        # |W|ξ = 1 with contexts empty at the start: 1 / ((n_k − 1) + |W|ξ) of an empty context divides by zero.
        (5, 2, 10, 0.1),
        (11, 11, 40, 0.05),
        (20, 20, 60, 0.1),
        (37, 30, 80, 0.3),
    ],
)
def test_a_sweep_equals_the_textbook_take_out_sample_put_back_bit_for_bit(
    kernel: Callable[..., None],
    reference: Callable[..., None],
    n_contexts: int,
    used_contexts: int,
    vocab_size: int,
    xi: float,
) -> None:
    words, offsets, counts = _random_corpus(n_contexts, 40, vocab_size, n_contexts, used_contexts)
    expected = tuple(array.copy() for array in counts)
    alpha = 0.1
    rng = np.random.default_rng(n_contexts + 1)
    moved = 0
    for _ in range(4):
        uniforms = rng.random(words.shape[0])
        before = counts[0].copy()
        kernel(
            words, counts[0], offsets, 0, offsets.shape[0] - 1, counts[1], counts[2], counts[3], n_contexts, alpha,
            xi, vocab_size, uniforms,
        )  # fmt: skip
        reference(words, offsets, expected, alpha, xi, vocab_size, uniforms)
        for got, want in zip(counts, expected, strict=True):
            assert np.array_equal(got, want)
        moved += int((counts[0] != before).sum())
    assert moved > 0 or n_contexts == 1  # the chain moved, so the equality covers moves as well as stays


@pytest.mark.parametrize(("n_contexts", "vocab_size", "xi"), [(1, 7, 0.1), (3, 29, 0.1), (5, 10, 0.1), (9, 40, 0.05)])
def test_the_online_token_sampler_equals_the_textbook_form_bit_for_bit(
    n_contexts: int, vocab_size: int, xi: float
) -> None:
    """``sample_tokens`` (the online update's sweeps: a list of tokens, repeats allowed, some not yet
    assigned) against the take-out, sample, put-back form, token by token in the list's order."""
    words, offsets, counts = _random_corpus(n_contexts + 50, 40, vocab_size, n_contexts, max(1, n_contexts - 2))
    rng = np.random.default_rng(n_contexts)
    docs = np.repeat(np.arange(offsets.shape[0] - 1), np.diff(offsets))
    unassigned = np.flatnonzero(rng.random(words.shape[0]) < 0.1)
    for i in unassigned:  # tokens not in the counts yet (a new scene's): their first context is drawn
        _take_out(int(words[i]), int(docs[i]), int(counts[0][i]), counts, -1)
        counts[0][i] = -1
    expected = tuple(array.copy() for array in counts)
    alpha, moved = 0.1, 0
    for _ in range(3):
        tokens = rng.integers(0, words.shape[0], size=2 * words.shape[0]).astype(np.int64)
        uniforms = rng.random(tokens.shape[0])
        before = counts[0].copy()
        sample_tokens(
            tokens, docs[tokens].astype(np.int64), words, counts[0], counts[1], counts[2], counts[3], n_contexts,
            alpha, xi, vocab_size, uniforms,
        )  # fmt: skip
        for j, i in enumerate(tokens):
            _resample(int(i), int(docs[i]), int(words[i]), expected, alpha, xi, vocab_size, float(uniforms[j]))
        for got, want in zip(counts, expected, strict=True):
            assert np.array_equal(got, want)
        moved += int((counts[0] != before).sum())
    assert moved > 0 or n_contexts == 1
