"""Rules for the number of contexts K, one strategy object per rule (Algorithm 2's growth test).

- :mod:`~core.context.k_selection.scenes`: ``"scenes"``, scene-partition evidence (the default);
- :mod:`~core.context.k_selection.paper`: ``"paper"``, the paper's C_low ≠ ∅ (Algorithm 2 as written);
- :mod:`~core.context.k_selection.base`: the :class:`KRule` protocol Incremental-LDA calls and the
  settings every rule shares (the cap on K, the online growth-check schedule).

The token-level ``likelihood`` birth move, the first default, is a baseline of the experiments
(``experiments/baselines/likelihood_rule.py``), not a rule the service offers.
"""

from core.context.k_selection.base import KRule, KRuleSettings
from core.context.k_selection.paper import (
    PAPER_TAU,
    PaperRule,
    PaperSettings,
    concept_confidence,
    low_confidence_concepts,
)
from core.context.k_selection.scenes import ScenesRule, ScenesSettings

#: The rules a model can be configured with, by name (stored models name theirs).
K_RULES: dict[str, type[KRuleSettings]] = {ScenesSettings.name: ScenesSettings, PaperSettings.name: PaperSettings}

__all__ = [
    "K_RULES",
    "PAPER_TAU",
    "KRule",
    "KRuleSettings",
    "PaperRule",
    "PaperSettings",
    "ScenesRule",
    "ScenesSettings",
    "concept_confidence",
    "low_confidence_concepts",
]
