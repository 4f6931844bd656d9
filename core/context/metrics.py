"""Scores of a context model: Eq. 7, Eq. 8 and collapsed log-likelihoods.

All logarithms are natural (entropies in nats, log-likelihoods in nats).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.special import gammaln

from core.errors import InvalidInputError

#: ρ of Eq. 8 as the paper sets it "experimentally".
PAPER_RHO = 0.25


def dirichlet_multinomial_log_likelihood(
    counts: np.ndarray,
    totals: np.ndarray,
    concentration: float | np.ndarray,
    dimension: int,
    prior_total: float | None = None,
) -> float:
    """Σ_r log ∫ Π_c p_c^{n_rc} Dir(p | β) dp for count rows ``counts`` (one row per
    Dirichlet draw, ``dimension`` categories):

        Σ_r [ log Γ(B) − log Γ(N_r + B) + Σ_c (log Γ(n_rc + β_c) − log Γ(β_c)) ],  B = Σ_c β_c.

    ``concentration`` is either the symmetric β (B = ``dimension`` · β) or one β_c per
    column of ``counts``, with B = ``prior_total`` (the sum over all ``dimension``
    categories). ``totals[r]`` is N_r, the row's sum over all categories; ``counts`` may
    hold only some of the columns: a column left out adds nothing when it is zero, and
    cancels in a difference of two calls over the same columns when it is not.
    """
    if np.ndim(concentration) == 0:
        beta_total = dimension * float(concentration)
    elif prior_total is None:
        raise ValueError("prior_total is needed with one concentration per column")
    else:
        beta_total = prior_total
    return float(
        counts.shape[0] * gammaln(beta_total)
        - gammaln(totals + beta_total).sum()
        + (gammaln(counts + concentration) - gammaln(concentration)).sum()
    )


def entropy(probabilities: np.ndarray, axis: int = -1) -> np.ndarray:
    """Shannon entropy −Σ p log p along ``axis`` (0 log 0 = 0)."""
    p = np.asarray(probabilities, dtype=float)
    logs = np.log(np.where(p > 0.0, p, 1.0))
    return -(p * logs).sum(axis=axis)


def contextual_entropy(
    concept_given_context: np.ndarray, context_given_scene: np.ndarray, rho: float = PAPER_RHO
) -> float:
    """H̃ = ρ H(C|X) + (1 − ρ) H(X|S) of Eq. 8, from the model's estimates.

    The joint of scene S, context X and concept C is taken as
    P(s, χ, c) = P(s) θ_sχ φ_χc with scenes equally likely (P(s) = 1/|D|),
    θ = P(X|S) (``context_given_scene``, one row per scene) and φ = P(C|X)
    (``concept_given_context``, one row per context, over the whole vocabulary).
    Then H(X|S) = mean_s H(θ_s), and H(C|X) = Σ_χ P(χ) H(φ_χ) with
    P(χ) = mean_s θ_sχ.
    """
    if not 0.0 <= rho <= 1.0:
        raise InvalidInputError("rho", f"must lie in [0, 1], got {rho}")
    phi = np.asarray(concept_given_context, dtype=float)
    theta = np.asarray(context_given_scene, dtype=float)
    if theta.ndim != 2 or theta.shape[0] == 0:
        raise InvalidInputError("context_given_scene", "needs one row per scene and at least one scene")
    if phi.ndim != 2 or phi.shape[0] != theta.shape[1]:
        raise InvalidInputError("concept_given_context", f"needs one row per context ({theta.shape[1]})")
    context_marginal = theta.mean(axis=0)
    concepts_given_contexts = float(context_marginal @ entropy(phi))
    contexts_given_scenes = float(entropy(theta).mean())
    return rho * concepts_given_contexts + (1.0 - rho) * contexts_given_scenes


def average_log_likelihood(related_concept_probabilities: Sequence[Sequence[float]], floor: float = 1e-12) -> float:
    """l̂ of Eq. 7: the mean log-probability of the concepts related to each observation.

    ``related_concept_probabilities[n]`` holds P(c | x_n, σ) for every c in C^{n+},
    the concepts related to observation n. Eq. 7 divides by N|C^{n+}|; as |C^{n+}|
    differs between observations, each observation's log-probabilities are averaged
    first and those averages are then averaged over the N observations, so every
    observation weighs the same. Probabilities below ``floor`` count as ``floor``:
    a single zero would otherwise make l̂ = −∞ and hide every other difference.
    """
    if len(related_concept_probabilities) == 0:
        raise InvalidInputError("related_concept_probabilities", "needs at least one observation")
    means = []
    for n, probabilities in enumerate(related_concept_probabilities):
        p = np.asarray(probabilities, dtype=float)
        if p.ndim != 1 or p.shape[0] == 0:
            raise InvalidInputError(f"related_concept_probabilities[{n}]", "needs at least one related concept")
        if not np.all((p >= 0.0) & (p <= 1.0)):
            raise InvalidInputError(f"related_concept_probabilities[{n}]", "probabilities must lie in [0, 1]")
        means.append(np.log(np.maximum(p, floor)).mean())
    return float(np.mean(means))


#: λ of the relevance ranking: Sievert & Shirley (2014) found λ ≈ 0.6 best in their user study.
RELEVANCE_WEIGHT = 0.6


def concept_relevance(
    concept_given_context: np.ndarray, context_weights: np.ndarray, weight: float = RELEVANCE_WEIGHT
) -> np.ndarray:
    """LDAvis relevance (Sievert & Shirley 2014) of every concept to every context, K × |W|:

        r(c, χ | λ) = λ log φ_χc + (1 − λ) log(φ_χc / p_c),  p_c = Σ_χ P(χ) φ_χc.

    λ = 1 ranks by P(c | χ) alone; λ = 0 by lift, which favours concepts seen only in χ.
    Concepts shared by every context (the move verbs, "round", "silent") have lift ≈ 1 and
    drop, so a person sees what sets a context apart. The marginal p_c is φ mixed by the
    contexts' weights P(χ) (``context_weights``, e.g. their token shares) rather than raw
    concept frequencies: it carries φ's smoothing, so it is never zero and lift stays finite.
    """
    if not 0.0 <= weight <= 1.0:
        raise InvalidInputError("relevance_weight", f"must lie in [0, 1], got {weight}")
    phi = np.asarray(concept_given_context, dtype=float)
    weights = np.asarray(context_weights, dtype=float)
    if phi.ndim != 2 or weights.shape != (phi.shape[0],):
        raise InvalidInputError("context_weights", f"needs one weight per context ({phi.shape[0]})")
    if not (np.all(weights >= 0.0) and weights.sum() > 0.0):
        raise InvalidInputError("context_weights", "weights must be >= 0 and not all zero")
    marginal = (weights / weights.sum()) @ phi
    log_phi = np.log(phi)
    return weight * log_phi + (1.0 - weight) * (log_phi - np.log(marginal))
