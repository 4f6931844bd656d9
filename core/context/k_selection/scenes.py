"""The ``"scenes"`` K rule (the default): scene-partition evidence.

A context belongs to a scene (§V draws each scene from one context), so K + 1 is kept when the
best partition of the scenes into K + 1 contexts has more evidence than the best into K, each
context's concepts under a Dirichlet centred on the corpus's concept frequencies
(:mod:`core.context.scene_partition`). The new context then starts from that partition
(Algorithm 3's start with the low-confidence tokens being those of the scenes that move),
followed by Eq. 5's Gibbs sweeps. It finds the contexts present from 3 scenes on; the paper's
C_low rule does not (docs/context.md, "Choosing K", has the measurements).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import ClassVar

import numpy as np

from core.context.k_selection.base import (
    KRule,
    KRuleSettings,
    integer_at_least,
    non_negative_number,
    probability,
    worst_scene_start,
)
from core.context.lda import LDAState
from core.context.scene_partition import SceneBlocks, best_partition, corpus_centred_prior


@dataclass(frozen=True)
class ScenesSettings(KRuleSettings):
    """Settings of the ``"scenes"`` rule."""

    name: ClassVar[str] = "scenes"

    partition_scans: int = 25
    """Sampled scans of each partition search in :meth:`IncrementalLDA.fit`."""
    online_partition_scans: int = 10
    """The same online, where searches start from the model's own partition."""
    partition_random_starts: int = 4
    """In :meth:`IncrementalLDA.fit`: searches from random partitions, besides those from the
    model's own (online, where the model's partition is already a good start, only the latter:
    a check then costs milliseconds)."""
    birth_margin: float = 0.0
    """:meth:`IncrementalLDA.fit` keeps K + 1 if its evidence exceeds K's by more than this many nats."""
    online_birth_margin: float = 3.0
    """The same margin online, where a test runs every ``birth_check_interval`` scenes (3 nats: a
    Bayes factor of 20, "strong" on Kass & Raftery's scale)."""
    birth_proposals: int = 2
    """Searches for K + 1 also start with each of this many worst-explained scenes in the new context."""
    delta: float = 0.05
    """δ of a forced start (:meth:`IncrementalLDA.grow_context`): probability that a confident token
    moves to the new context (Algorithm 3)."""
    split_scans: int = 3
    """Scene-level split passes after a forced start (docs/context.md, "K-incremental starts and
    Fig. 10": 3 passes put the scenes in their true contexts in 10 of 10 test sets)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        probability(self, "delta")
        for name in ("birth_margin", "online_birth_margin"):
            non_negative_number(self, name)
        for name in ("partition_scans", "online_partition_scans", "birth_proposals"):
            integer_at_least(self, name, 1)
        for name in ("partition_random_starts", "split_scans"):
            integer_at_least(self, name, 0)

    def make_rule(self) -> ScenesRule:
        return ScenesRule(self)


class ScenesRule(KRule):
    """K grows when a partition of the scenes into K + 1 contexts has more evidence than into K."""

    def __init__(self, settings: ScenesSettings) -> None:
        self.settings: ScenesSettings = settings

    def grow(self, state: LDAState, rng: np.random.Generator, first_doc: int, *, online: bool, sweeps: int) -> bool:
        """Open context K + 1 if the best partition of scenes ``first_doc:`` into K + 1 contexts has
        more evidence than the best into K, by more than ``birth_margin`` (``online_birth_margin``)
        nats (:mod:`core.context.scene_partition`).

        The searches for K start from the model's own partition (each scene's dominant context);
        those for K + 1 from the best K partition and from it with each of the ``birth_proposals``
        worst-explained scenes moved to the new context; in batch both also from
        ``partition_random_starts`` random partitions. A new context starts from the winning
        partition (every token in its scene's context); in batch ``sweeps`` Gibbs sweeps of Eq. 5
        follow, online the updates' rejuvenation takes over (docs/context.md, "Choosing K").
        """
        s = self.settings
        n_contexts = state.n_contexts
        blocks = _scene_blocks(state, first_doc)
        prior = corpus_centred_prior(state.n_wk.sum(axis=1).astype(np.float64), state.xi, s.scene_prior_strength)
        own = state.n_dk[first_doc:].argmax(axis=1)
        search = partial(
            best_partition, blocks, prior=prior, alpha=state.alpha, rng=rng,
            random_starts=0 if online else s.partition_random_starts,
            sampled_scans=s.online_partition_scans if online else s.partition_scans,
        )  # fmt: skip
        current = search(n_contexts, starts=[own])
        worst_first = np.argsort(state.scene_fit(first_doc), kind="stable")[: s.birth_proposals]
        scenes = np.arange(blocks.n_scenes)
        starts = [current.labels] + [np.where(scenes == worst, n_contexts, current.labels) for worst in worst_first]
        proposed = search(n_contexts + 1, starts=starts)
        if proposed.evidence - current.evidence <= (s.online_birth_margin if online else s.birth_margin):
            return False
        state.add_context()
        tokens = state.window_tokens(first_doc)
        state.reassign(tokens, proposed.labels[state.scene_of(tokens) - first_doc].astype(np.int32))
        if not online:
            state.sweep(rng, sweeps, first_doc)
        return True

    def open_context(self, state: LDAState, rng: np.random.Generator) -> None:
        """The tokens of the scene explained worst start the new context, then ``split_scans``
        scene-level split passes."""
        worst_scene_start(state, rng, self.settings.delta, self.settings.split_scans)


def _scene_blocks(state: LDAState, first_doc: int) -> SceneBlocks:
    """Concept counts of scenes ``first_doc:``, with what each context holds from the scenes before."""
    tokens = state.window_tokens(first_doc)
    words = state.words[tokens].astype(np.int64)
    window_counts = np.zeros((state.n_contexts, state.vocab_size))
    np.add.at(window_counts, (state.assignments[tokens], words), 1.0)
    return SceneBlocks.from_tokens(
        words, state.scene_of(tokens) - first_doc, state.n_documents - first_doc, state.vocab_size,
        state.n_kw - window_counts,
    )  # fmt: skip
