"""Numba kernel of the scene-level collapsed Gibbs sampler behind the ``"scenes"`` K rule.

Each scene is one block of concept counts (CSR: ``scene_offsets``, ``scene_words``,
``scene_counts``) and belongs to exactly one context ``labels[s]``. A context's
counts ``context_counts`` (K × |W|, float) hold whatever it starts with (the scenes
before the window, online) plus its scenes; its concepts follow a Dirichlet with
parameters ``prior`` (|W|) summing to ``prior_total``. Moving scene s to context k
has the collapsed weight of a Dirichlet-multinomial block:

    log Γ(T_k + B) − log Γ(T_k + N_s + B) + Σ_c [log Γ(n_kc + x_sc + β_c) − log Γ(n_kc + β_c)],

and no prior over contexts: under LDA's per-scene θ ~ Dir(α) every context is
equally likely to take a whole scene. ``uniforms`` (one per visit, from the caller's
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
            weight = math.lgamma(context_totals[k] + prior_total) - math.lgamma(
                context_totals[k] + scene_totals[s] + prior_total
            )
            for j in range(start, stop):
                base = context_counts[k, scene_words[j]] + prior[scene_words[j]]
                weight += math.lgamma(base + scene_counts[j]) - math.lgamma(base)
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
