"""Numba kernel of the scene-level collapsed Gibbs sampler behind the ``"scenes"`` K rule.

Each scene is one block of concept counts (CSR: ``scene_offsets``, ``scene_words``,
``scene_counts``) and belongs to exactly one context ``labels[s]``. A context's
counts ``context_counts`` (K × |W|, float) hold whatever it starts with (the scenes
before the window, online) plus its scenes; its concepts follow a Dirichlet with
parameters ``prior`` (|W|) summing to ``prior_total``. Moving scene s to context k
has the collapsed weight of a Dirichlet-multinomial block:

    log Γ(T_k + B) − log Γ(T_k + N_s + B) + Σ_c [log Γ(n_kc + x_sc + β_c) − log Γ(n_kc + β_c)],

and no prior over contexts: under LDA's per-scene θ ~ Dir(α) every context is
equally likely to take a whole scene. The counts are integers, so the weight is computed as the
product of its rising factors (:func:`_block_log_weight`). ``uniforms`` (one per visit, from the caller's
generator) make the draws; visits from ``greedy_from`` on take the best context.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from core.context._gibbs_kernels import _draw


@numba.njit(cache=True, nogil=True)
def partition_scans(
    scene_offsets: np.ndarray,
    scene_words: np.ndarray,
    scene_counts: np.ndarray,
    scene_totals: np.ndarray,
    labels: np.ndarray,
    context_counts: np.ndarray,
    context_totals: np.ndarray,
    prior: np.ndarray,
    prior_total: float,
    order: np.ndarray,
    uniforms: np.ndarray,
    greedy_from: int,
) -> int:
    """Visit the scenes in ``order`` (several scans back to back), resampling each one's
    context; returns how many visits changed a label among the greedy ones."""
    n_contexts = context_counts.shape[0]
    log_weights = np.empty(n_contexts)
    greedy_changes = 0
    for visit in range(order.shape[0]):
        s = order[visit]
        old = labels[s]
        start, stop = scene_offsets[s], scene_offsets[s + 1]
        for j in range(start, stop):
            context_counts[old, scene_words[j]] -= scene_counts[j]
        context_totals[old] -= scene_totals[s]
        best, best_weight = 0, -np.inf
        for k in range(n_contexts):
            weight = _block_log_weight(
                context_counts, k, scene_words, scene_counts, start, stop, context_totals[k] + prior_total, prior
            )
            log_weights[k] = weight
            if weight > best_weight:
                best, best_weight = k, weight
        chosen = best
        if visit < greedy_from:
            total = 0.0
            for k in range(n_contexts):
                total += math.exp(log_weights[k] - best_weight)
                log_weights[k] = total  # now cumulative
            chosen = _draw(log_weights, n_contexts, uniforms[visit])
        elif chosen != old:
            greedy_changes += 1
        labels[s] = chosen
        for j in range(start, stop):
            context_counts[chosen, scene_words[j]] += scene_counts[j]
        context_totals[chosen] += scene_totals[s]
    return greedy_changes


@numba.njit(cache=True, nogil=True, inline="always")
def _block_log_weight(
    context_counts: np.ndarray,
    k: int,
    scene_words: np.ndarray,
    scene_counts: np.ndarray,
    start: int,
    stop: int,
    held: float,
    prior: np.ndarray,
) -> float:
    """The block weight of the module docstring, as the scene's tokens joining context k one by one:
    Π (n_kc + β_c + i) / (T_k + B + t) over the i-th token of each concept c and the t-th of the
    scene. The same value as the log-gamma differences (integer counts: Γ(x + n) / Γ(x) is the
    rising product), with one division a token instead of four log-gammas an entry, which made the
    growth check's cost; the running product is moved to the log before it can underflow."""
    log_weight, weight, t = 0.0, 1.0, 0
    for j in range(start, stop):
        base = context_counts[k, scene_words[j]] + prior[scene_words[j]]
        for i in range(int(scene_counts[j])):
            weight *= (base + i) / (held + t)
            t += 1
            if weight < 1e-200:
                log_weight += math.log(weight)
                weight = 1.0
    return log_weight + math.log(weight)


@numba.njit(cache=True, nogil=True)
def scene_novelty(
    word_ids: np.ndarray,
    words: np.ndarray,
    z: np.ndarray,
    window_start: int,
    window_stop: int,
    n_wk: np.ndarray,
    n_k: np.ndarray,
    n_contexts: int,
    vocab_size: int,
    xi: float,
    strength: float,
) -> float:
    """How much better a fresh context explains a new scene than the best existing one did before
    the window, in nats: log DM(x | β) − max_k log DM(x | n_k + β), x the scene's concept counts
    as one block, β the corpus-centred prior of
    :func:`core.context.scene_partition.corpus_centred_prior` and n_k what context k holds
    without the tokens ``window_start:window_stop`` (the recent scenes, which a first scene of a
    new context may already have pulled into an old one). The block terms are those of
    :func:`partition_scans`, as the scene's tokens joining one by one:
    Π_j (n_kc_j + β_c_j + earlier c_j of the scene) / (T_k + B + j). The model's counts are only
    read (the window's share of them is counted apart and subtracted).
    """
    n_tokens = word_ids.shape[0]
    corpus_total = 0.0
    for k in range(n_contexts):
        corpus_total += n_k[k]
    scale = strength * vocab_size / (corpus_total + vocab_size * xi)
    prior_total = strength * vocab_size
    beta = np.empty(n_tokens)
    earlier = np.empty(n_tokens)
    seen = np.zeros(vocab_size, dtype=np.int32)
    local = np.full(vocab_size, -1, dtype=np.int64)  # each of the scene's concepts, numbered
    n_distinct = 0
    for j in range(n_tokens):
        w = word_ids[j]
        corpus = 0.0
        for k in range(n_contexts):
            corpus += n_wk[w, k]
        beta[j] = scale * (corpus + xi)
        earlier[j] = seen[w]
        seen[w] += 1
        if local[w] < 0:
            local[w] = n_distinct
            n_distinct += 1
    # The window's tokens, counted for the scene's concepts only, are taken off the counts as they
    # are read: the model's arrays are not touched, and the integer differences are the counts.
    window_wk = np.zeros((n_distinct, n_contexts), dtype=np.int64)
    window_k = np.zeros(n_contexts, dtype=np.int64)
    for i in range(window_start, window_stop):
        window_k[z[i]] += 1
        u = local[words[i]]
        if u >= 0:
            window_wk[u, z[i]] += 1
    best = -np.inf
    fresh = 0.0
    for k in range(n_contexts + 1):  # k = n_contexts: the fresh context
        log_weight, weight = 0.0, 1.0
        held = n_k[k] - window_k[k] if k < n_contexts else 0.0
        for j in range(n_tokens):
            w = word_ids[j]
            count = n_wk[w, k] - window_wk[local[w], k] if k < n_contexts else 0.0
            weight *= (count + beta[j] + earlier[j]) / (held + prior_total + j)
            if weight < 1e-200:
                log_weight += math.log(weight)
                weight = 1.0
        log_weight += math.log(weight)
        if k < n_contexts:
            best = max(best, log_weight)
        else:
            fresh = log_weight
    return fresh - best
