"""The ``likelihood`` K rule, the first default, kept as a baseline of Fig. 11's comparison of rules.

A token-level birth move: propose K + 1 by a K-incremental start (Algorithm 3) and keep it only if
it explains the scenes better. The score is the collapsed joint log-likelihood log P(w, z | K)
(Griffiths & Steyvers 2004) plus the entropy of the sampler's conditionals Σ_i H(z_i | z_¬i, w),
at a few Gibbs samples. The sum is a lower bound on the evidence log P(w | K)
(log P(w) = E[log P(w, z)] + H(z | w), and H(z | w) ≥ Σ_i H(z_i | z_¬i, w)); the joint alone
leaves out the entropy term, which grows with K, and undercounts contexts. The low-confidence
tokens that start the new context are those of the scene the model explains worst (lowest mean
log P(w | s)); every other token keeps its context or moves with probability δ.
``birth_proposals`` such starts (the worst, second worst... scene) are tried and the best kept;
K + 1 wins when its mean score beats K's by more than ``growth_z`` standard errors (0 in batch,
3 online). docs/context.md, "Choosing K", has why ``scenes`` replaced it: it finds no context
before about 20 scenes.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from core.context import Hyperparameters, IncrementalLDA, Priors, SamplerSettings
from core.context.k_selection import KRule, KRuleSettings
from core.context.k_selection.base import (
    integer_at_least,
    non_negative_number,
    probability,
    scene_token_mask,
    worst_scene_start,
)
from core.context.lda import LDAState


@dataclass(frozen=True)
class LikelihoodSettings(KRuleSettings):
    """Settings of the ``likelihood`` birth move."""

    name: ClassVar[str] = "likelihood"

    likelihood_samples: int = 10
    """Samples averaged by the birth move's score."""
    sample_lag: int = 5
    """Sweeps between two of those samples."""
    growth_z: float = 0.0
    """:meth:`IncrementalLDA.fit` keeps K + 1 only if the mean score rises by more than this many
    standard errors (of the difference of the two sample means)."""
    online_growth_z: float = 3.0
    """The same margin online: a long-lived model runs a test every ``birth_check_interval``
    scenes, so each test must rarely accept by chance."""
    birth_proposals: int = 2
    """Proposals per birth move, seeded with the worst-explained scenes in turn."""
    delta: float = 0.05
    """δ: probability that a confident token moves to the new context (Algorithm 3)."""
    split_scans: int = 3
    """Scene-level split passes after each K-incremental start (docs/context.md, "K-incremental
    starts and Fig. 10")."""

    def __post_init__(self) -> None:
        super().__post_init__()
        probability(self, "delta")
        for name in ("growth_z", "online_growth_z"):
            non_negative_number(self, name)
        integer_at_least(self, "likelihood_samples", 2)
        for name in ("sample_lag", "birth_proposals"):
            integer_at_least(self, name, 1)
        integer_at_least(self, "split_scans", 0)

    def make_rule(self) -> LikelihoodRule:
        return LikelihoodRule(self)


class LikelihoodRule(KRule):
    """K grows when a birth move raises log P(w, z | K) + Σ_i H(z_i | z_¬i, w) significantly."""

    def __init__(self, settings: LikelihoodSettings) -> None:
        self.settings: LikelihoodSettings = settings

    def grow(self, state: LDAState, rng: np.random.Generator, first_doc: int, *, online: bool, sweeps: int) -> bool:
        """Propose context K + 1 on scenes ``first_doc:``; keep it if their score improves by more
        than ``growth_z`` (``online_growth_z``) standard errors.

        Both sides get the same Gibbs budget: the current K is sampled ``sweeps`` sweeps before it
        is scored, like each proposal after its K-incremental start. Each of the
        ``birth_proposals`` proposals seeds the new context with one of the scenes explained worst;
        the best-scoring one is compared with the current K.
        """
        s = self.settings
        growth_z = s.online_growth_z if online else s.growth_z
        state.sweep(rng, sweeps, first_doc)
        current = self.growth_score(state, rng, first_doc)
        tokens = state.window_tokens(first_doc)
        saved = state.assignments[tokens].copy()
        worst_first = first_doc + np.argsort(state.scene_fit(first_doc), kind="stable")
        best_score, best_assignments = None, saved
        for seed_scene in worst_first[: s.birth_proposals]:
            state.grow_k_incrementally(
                scene_token_mask(state, first_doc, seed_scene), s.delta, rng, first_doc, split_scans=s.split_scans
            )
            state.sweep(rng, sweeps, first_doc)
            score = self.growth_score(state, rng, first_doc)
            if best_score is None or score.mean() > best_score.mean():
                best_score, best_assignments = score, state.assignments[tokens].copy()
            state.reassign(tokens, saved)
            state.remove_last_context()
        if best_score is None or _improvement_in_standard_errors(best_score, current) <= growth_z:
            return False
        state.add_context()
        state.reassign(tokens, best_assignments)
        return True

    def open_context(self, state: LDAState, rng: np.random.Generator) -> None:
        """The birth move's first proposal: the scene explained worst, then ``split_scans`` passes."""
        worst_scene_start(state, rng, self.settings.delta, self.settings.split_scans)

    def growth_score(self, state: LDAState, rng: np.random.Generator, first_doc: int = 0) -> np.ndarray:
        """The birth move's score of scenes ``first_doc:`` (given the earlier ones),
        log P(w, z | K) + Σ_i H(z_i | z_¬i, w), at ``likelihood_samples`` Gibbs samples
        ``sample_lag`` sweeps apart. Sampling moves the state on."""
        s = self.settings
        scores = np.empty(s.likelihood_samples)
        for i in range(s.likelihood_samples):
            state.sweep(rng, s.sample_lag, first_doc)
            scores[i] = state.joint_log_likelihood(first_doc) + state.conditional_entropy(first_doc)
        return scores


def likelihood_model(*, seed: int = 0, **settings: Any) -> IncrementalLDA:
    """An Incremental-LDA whose K follows the ``likelihood`` rule, from flat settings (those of
    :class:`LikelihoodSettings`, :class:`~core.context.Priors` and
    :class:`~core.context.SamplerSettings`)."""
    groups: dict[type, dict[str, Any]] = {Priors: {}, SamplerSettings: {}, LikelihoodSettings: {}}
    for key, value in settings.items():
        owner = next((cls for cls in groups if key in {f.name for f in dataclasses.fields(cls)}), None)
        if owner is None:
            raise TypeError(f"{key!r} is not a setting of the likelihood rule's model")
        groups[owner][key] = value
    hyperparameters = Hyperparameters(
        priors=Priors(**groups[Priors]),
        sampler=SamplerSettings(**groups[SamplerSettings]),
        k_rule=LikelihoodSettings(**groups[LikelihoodSettings]),
    )
    return IncrementalLDA(seed=seed, hyperparameters=hyperparameters)


def _improvement_in_standard_errors(proposed: np.ndarray, current: np.ndarray) -> float:
    """(mean proposed − mean current) / standard error of that difference."""
    difference = proposed.mean() - current.mean()
    error = np.sqrt(proposed.var(ddof=1) / proposed.shape[0] + current.var(ddof=1) / current.shape[0])
    if error > 0:
        return float(difference / error)
    return np.inf if difference > 0 else -np.inf
