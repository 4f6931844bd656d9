"""Numba kernel of the sparsity-aware collapsed Gibbs sweep (SparseLDA: Yao, Mimno & McCallum 2009).

Same corpus layout, counts and random-number contract as :mod:`core.context._gibbs_kernels`
(one uniform per sampled token, drawn by the caller). Eq. 5's unnormalised conditional

    p(k) = (n_wk + ξ) (n_dk + α) / (n_k + |W|ξ)

is split into three buckets whose sum is exactly p(k):

    q_k = (α + n_dk) / (n_k + |W|ξ) · n_wk  (the word's contexts: n_wk > 0)
    r_k = ξ n_dk / (n_k + |W|ξ)             (the scene's contexts: n_dk > 0)
    s_k = αξ / (n_k + |W|ξ)                 (smoothing: every context; its sum is kept up to date)

A token reads only the contexts its word and its scene hold, not all K. One uniform
``u`` picks the point ``u (Q + R + S)`` on the buckets laid end to end (q, then r, then
s), so every context keeps Eq. 5's probability: the sweep has the dense sweep's
stationary distribution, but maps a given ``u`` to a different context than it.

The lists of a word's and a scene's non-zero contexts are built from the counts (in
ascending context order) at the start of each call and of each scene: a model restored
between sweeps rebuilds the same lists and continues bit-identically.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def nonzero_contexts(counts: np.ndarray, n_rows: int, n_contexts: int) -> tuple[np.ndarray, np.ndarray]:
    """Per row of ``counts``, its contexts with a non-zero count (ascending) and how many there are."""
    contexts = np.empty((n_rows, n_contexts), dtype=np.int32)
    lengths = np.zeros(n_rows, dtype=np.int32)
    for row in range(n_rows):
        length = 0
        for k in range(n_contexts):
            if counts[row, k] != 0:
                contexts[row, length] = k
                length += 1
        lengths[row] = length
    return contexts, lengths


@numba.njit(cache=True, nogil=True, inline="always")
def _remove(contexts: np.ndarray, length: int, k: int) -> None:
    """Drop context ``k`` from the first ``length`` entries of ``contexts`` (the last one takes its place)."""
    j = 0
    while contexts[j] != k:
        j += 1
    contexts[j] = contexts[length - 1]


@numba.njit(cache=True, nogil=True)
def sweep_documents_sparse(
    words: np.ndarray,
    z: np.ndarray,
    doc_offsets: np.ndarray,
    first_doc: int,
    stop_doc: int,
    n_wk: np.ndarray,
    n_k: np.ndarray,
    n_dk: np.ndarray,
    n_contexts: int,
    alpha: float,
    xi: float,
    vocab_size: int,
    uniforms: np.ndarray,
) -> None:
    """One Gibbs sweep over documents ``first_doc:stop_doc`` (Algorithm 1, Eq. 5), by buckets.

    Arguments as :func:`core.context._gibbs_kernels.sweep_documents`. The per-token work
    is O(contexts of the word + contexts of the scene) instead of O(K), plus O(K) per scene
    and O(|W| K) per call to build the word lists.

    Q is summed in four independent running sums: one would chain every addition to the
    previous one and bound the loop by the adder's latency. Written out in one loop, like
    the dense sweep.
    """
    v_xi = vocab_size * xi
    alpha_xi = alpha * xi
    inverse = np.empty(n_contexts)
    for k in range(n_contexts):
        inverse[k] = 1.0 / (n_k[k] + v_xi)
    word_contexts, word_lengths = nonzero_contexts(n_wk, vocab_size, n_contexts)
    scene_contexts = np.empty(n_contexts, dtype=np.int32)
    coefficient = np.empty(n_contexts)  # (α + n_dk) / (n_k + |W|ξ) of the current scene
    q_weights = np.empty(n_contexts)
    u_index = 0
    for d in range(first_doc, stop_doc):
        smoothing = 0.0  # S = Σ_k s_k
        scene_mass = 0.0  # R = Σ_k r_k
        scene_length = 0
        for k in range(n_contexts):
            count = n_dk[d, k]
            smoothing += alpha_xi * inverse[k]
            coefficient[k] = (alpha + count) * inverse[k]
            if count != 0:
                scene_contexts[scene_length] = k
                scene_length += 1
                scene_mass += xi * count * inverse[k]
        for i in range(doc_offsets[d], doc_offsets[d + 1]):
            w = words[i]
            old = z[i]
            smoothing -= alpha_xi * inverse[old]
            scene_mass -= xi * n_dk[d, old] * inverse[old]
            n_wk[w, old] -= 1
            n_k[old] -= 1
            n_dk[d, old] -= 1
            inverse[old] = 1.0 / (n_k[old] + v_xi)
            smoothing += alpha_xi * inverse[old]
            scene_mass += xi * n_dk[d, old] * inverse[old]
            coefficient[old] = (alpha + n_dk[d, old]) * inverse[old]
            if n_dk[d, old] == 0:
                _remove(scene_contexts, scene_length, old)
                scene_length -= 1
            row = word_contexts[w]
            word_length = word_lengths[w]
            if n_wk[w, old] == 0:
                _remove(row, word_length, old)
                word_length -= 1
            mass_0 = mass_1 = mass_2 = mass_3 = 0.0  # Q = Σ_k q_k, in four independent sums
            whole = word_length - word_length % 4
            for j in range(0, whole, 4):
                q_weights[j] = coefficient[row[j]] * n_wk[w, row[j]]
                q_weights[j + 1] = coefficient[row[j + 1]] * n_wk[w, row[j + 1]]
                q_weights[j + 2] = coefficient[row[j + 2]] * n_wk[w, row[j + 2]]
                q_weights[j + 3] = coefficient[row[j + 3]] * n_wk[w, row[j + 3]]
                mass_0 += q_weights[j]
                mass_1 += q_weights[j + 1]
                mass_2 += q_weights[j + 2]
                mass_3 += q_weights[j + 3]
            for j in range(whole, word_length):
                q_weights[j] = coefficient[row[j]] * n_wk[w, row[j]]
                mass_0 += q_weights[j]
            word_mass = (mass_0 + mass_1) + (mass_2 + mass_3)
            target = uniforms[u_index] * (word_mass + scene_mass + smoothing)
            u_index += 1
            if target < word_mass:
                j = 0
                cumulative = q_weights[0]
                while j < word_length - 1 and cumulative <= target:
                    j += 1
                    cumulative += q_weights[j]
                new = row[j]
            elif scene_length > 0 and target - word_mass < scene_mass:
                target -= word_mass
                j = 0
                cumulative = xi * n_dk[d, scene_contexts[0]] * inverse[scene_contexts[0]]
                while j < scene_length - 1 and cumulative <= target:
                    j += 1
                    cumulative += xi * n_dk[d, scene_contexts[j]] * inverse[scene_contexts[j]]
                new = scene_contexts[j]
            else:
                target -= word_mass + scene_mass
                new = 0
                cumulative = alpha_xi * inverse[0]
                while new < n_contexts - 1 and cumulative <= target:
                    new += 1
                    cumulative += alpha_xi * inverse[new]
            z[i] = new
            smoothing -= alpha_xi * inverse[new]
            scene_mass -= xi * n_dk[d, new] * inverse[new]
            if n_dk[d, new] == 0:
                scene_contexts[scene_length] = new
                scene_length += 1
            if n_wk[w, new] == 0:
                row[word_length] = new
                word_length += 1
            word_lengths[w] = word_length
            n_wk[w, new] += 1
            n_k[new] += 1
            n_dk[d, new] += 1
            inverse[new] = 1.0 / (n_k[new] + v_xi)
            smoothing += alpha_xi * inverse[new]
            scene_mass += xi * n_dk[d, new] * inverse[new]
            coefficient[new] = (alpha + n_dk[d, new]) * inverse[new]
