"""Concept prototypes (Appendix, Table VIII, Eq. 1) and perception probabilities.

``fit_prototypes`` learns them from labelled entity and effect vectors,
``PrototypeSet.distances`` / ``effect_distances`` give Eq. 1, and ``perceive``
turns one object's observations into per-concept probabilities for the concept web.
"""

from core.prototypes.perception import perceive
from core.prototypes.prototypes import (
    ENTITY_RULE,
    RELEVANCE_SYMBOLS,
    VERB_RULE,
    PrototypeSet,
    RelevanceRule,
    fit_prototypes,
    format_prototype_table,
)
from core.prototypes.rgng import RGNGParameters, RGNGResult, robust_growing_neural_gas

__all__ = [
    "ENTITY_RULE",
    "RELEVANCE_SYMBOLS",
    "VERB_RULE",
    "PrototypeSet",
    "RGNGParameters",
    "RGNGResult",
    "RelevanceRule",
    "fit_prototypes",
    "format_prototype_table",
    "perceive",
    "robust_growing_neural_gas",
]
