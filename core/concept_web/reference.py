"""Exact reference marginals for a concept web's MRF, computed by pgmpy.

pgmpy (a development dependency, imported here lazily) runs junction-tree belief
propagation, which is exact on any graph. Tests compare our loopy BP with it on
trees, where loopy BP is exact too, and the benchmark times it on the same graph
and potentials.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from core.concept_web.web import ConceptWeb, WebPotentials


def pgmpy_network(potentials: WebPotentials) -> Any:
    """A ``pgmpy`` DiscreteMarkovNetwork with exactly the factors of ``potentials``."""
    from pgmpy.factors.discrete import DiscreteFactor
    from pgmpy.models import DiscreteMarkovNetwork

    names = list(potentials.variable_names)
    cards = [int(c) for c in potentials.cardinalities]
    network = DiscreteMarkovNetwork()
    network.add_nodes_from(names)
    network.add_edges_from((names[u], names[v]) for u, v in potentials.variable_edges)
    factors = [DiscreteFactor([names[v]], [cards[v]], potentials.unary[v, : cards[v]]) for v in range(len(names))]
    for (u, v), table in zip(potentials.variable_edges, potentials.pairwise):
        factors.append(DiscreteFactor([names[u], names[v]], [cards[u], cards[v]], table[: cards[u], : cards[v]]))
    network.add_factors(*factors)
    return network


def exact_variable_marginals(potentials: WebPotentials, network: Any = None) -> np.ndarray:
    """(n_var, K) exact marginals of every variable by pgmpy's BeliefPropagation.

    ``network`` is :func:`pgmpy_network` of ``potentials``, built here when not given.
    """
    from pgmpy.inference import BeliefPropagation

    names = list(potentials.variable_names)
    network = pgmpy_network(potentials) if network is None else network
    result = BeliefPropagation(network).query(names, joint=False, show_progress=False)
    marginals = np.zeros(potentials.unary.shape)
    for v, name in enumerate(names):
        factor = result[name]
        marginals[v, : len(factor.values)] = factor.values / factor.values.sum()
    return marginals


def exact_probabilities(web: ConceptWeb, perception: np.ndarray) -> np.ndarray:
    """P(c active) for every concept, exactly, on the MRF that ``web.infer(perception)`` solves."""
    marginals = exact_variable_marginals(web.potentials(perception))
    return marginals[web.concept_variable, web.concept_state]
