"""The ``"paper"`` K rule: Algorithm 2 as written, K grows while C_low ≠ ∅.

C_low holds the concepts whose confidence is below τ, and Algorithm 3 starts the new context
with the tokens of C_low. The paper does not define the confidence of a concept's contextual
assignment; here it is P(c | χ) under the concept's best context, max_χ φ_χc (a measure
normalised over contexts would be 1 for every concept at K = 1, and K would never grow).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from core.context.k_selection.base import KRule, KRuleSettings, probability
from core.context.lda import LDAState
from core.errors import InvalidInputError

PAPER_TAU = 0.03
"""τ of C_low by default (docs/context.md has the τ scan behind 0.03)."""


@dataclass(frozen=True)
class PaperSettings(KRuleSettings):
    """Settings of the ``"paper"`` rule (Algorithm 2, C_low ≠ ∅)."""

    name: ClassVar[str] = "paper"

    tau: float = PAPER_TAU
    """τ: a concept is in C_low when its confidence max_χ φ_χc is below τ (docs/context.md has
    the τ scan behind 0.03)."""
    delta: float = 0.05
    """δ: probability that a confident token moves to the new context (Algorithm 3)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if not (isinstance(self.tau, int | float) and 0.0 < self.tau < 1.0):
            raise InvalidInputError("tau", f"must lie in (0, 1), got {self.tau!r}")
        probability(self, "delta")

    def make_rule(self) -> PaperRule:
        return PaperRule(self)


class PaperRule(KRule):
    """K grows while some concept's confidence is below τ (Algorithm 2), from C_low (Algorithm 3)."""

    def __init__(self, settings: PaperSettings) -> None:
        self.settings: PaperSettings = settings

    def grow(self, state: LDAState, rng: np.random.Generator, first_doc: int, *, online: bool, sweeps: int) -> bool:
        """If C_low of scenes ``first_doc:`` is not empty, open K + 1 with its tokens (Algorithm 3)
        and run ``sweeps`` Gibbs sweeps of Eq. 5 on those scenes."""
        s = self.settings
        low = low_confidence_concepts(state, s.tau, first_doc)
        if not low.any():
            return False
        state.grow_k_incrementally(low[state.words[state.window_tokens(first_doc)]], s.delta, rng, first_doc)
        state.sweep(rng, sweeps, first_doc)
        return True

    def open_context(self, state: LDAState, rng: np.random.Generator) -> None:
        """The tokens of C_low start the new context (Algorithm 3 as written, no split passes)."""
        low = low_confidence_concepts(state, self.settings.tau)[state.words]
        state.grow_k_incrementally(low, self.settings.delta, rng, split_scans=0)


def concept_confidence(state: LDAState) -> np.ndarray:
    """Confidence of each concept's contextual assignment: max_χ P(c | χ)."""
    return state.concept_given_context().max(axis=0)


def low_confidence_concepts(state: LDAState, tau: float, first_doc: int = 0) -> np.ndarray:
    """C_low as a mask over the vocabulary: concepts seen in scenes ``first_doc:`` whose
    confidence is below τ."""
    seen = np.zeros(state.vocab_size, dtype=bool)
    seen[state.words[state.window_tokens(first_doc)]] = True
    return seen & (concept_confidence(state) < tau)
