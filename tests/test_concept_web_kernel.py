"""The vectorised LBP kernel against the plain loop it replaced, bit for bit.

``plain_propagate`` is the one-message-at-a-time synchronous loop of ``_lbp_kernels.propagate``
before its binary edges were batched (commit 13dbd74), in plain Python: the same products in
CSR order with the same rescaling, the same cavities, sums and damping. Python floats are IEEE
doubles like the kernel's, so every marginal, MAP state, message and iteration count must match
exactly; the random MRFs mix cardinalities 1–4 (binary edges, edges with other sizes, variables
that do not send) and include evidence so small that the products are rescaled.
"""

from __future__ import annotations

import numpy as np

from core.concept_web import ConceptWeb, WebPotentials, loopy_belief_propagation
from core.concept_web.web import _MessageGraph
from core.vocabulary import paper_vocabulary
from sim.world import TRAIN, WorldConfig, make_objects

RESCALE_BELOW = 1e-150


def add_up(values: list[float]) -> float:
    """Left to right from 0.0, as the kernel adds (``sum`` may compensate on newer Pythons)."""
    total = 0.0
    for value in values:
        total += value
    return total


def plain_products(unary: np.ndarray, graph: _MessageGraph, messages: list[list[float]]) -> list[list[float]]:
    product = []
    for v, n in enumerate(graph.cardinalities.tolist()):
        out = [float(x) for x in unary[v, :n]]
        for k in range(graph.incoming_start[v], graph.incoming_start[v + 1]):
            peak = 0.0
            for s in range(n):
                out[s] *= messages[graph.incoming[k]][s]
                peak = max(peak, out[s])
            if peak < RESCALE_BELOW:
                out = [x / peak for x in out]
        product.append(out)
    return product


def plain_propagate(
    unary: np.ndarray, sends: np.ndarray, graph: _MessageGraph, max_product: bool, damping: float, max_iterations: int
) -> tuple[list[list[float]], list[list[float]], int]:
    """Beliefs, final messages and iterations of a cold start, tolerance 1e-6."""
    cards, sources, targets = graph.cardinalities.tolist(), graph.sources.tolist(), graph.targets.tolist()
    messages = [[1.0 / cards[t]] * cards[t] for t in targets]
    iterations, converged = 0, not sources
    while not converged and iterations < max_iterations:
        iterations += 1
        product, updated, delta = plain_products(unary, graph, messages), [list(m) for m in messages], 0.0
        for sent, (source, target) in enumerate(zip(sources, targets)):
            if not sends[source]:
                continue
            back, start = sent ^ 1, int(graph.factor_start[sent])
            factors = graph.factors[start : start + cards[source] * cards[target]].tolist()
            if cards[source] == 2 and cards[target] == 2:
                cavity = [product[source][0] * messages[back][1], product[source][1] * messages[back][0]]
            else:
                cavity = [product[source][a] / messages[back][a] for a in range(cards[source])]
            computed = []
            for b in range(cards[target]):
                value = 0.0
                for a in range(cards[source]):
                    term = cavity[a] * factors[a * cards[target] + b]
                    value = max(value, term) if max_product else value + term
                computed.append(value)
            total = add_up(computed)
            scale = (1.0 - damping) / total
            for b in range(cards[target]):
                updated[sent][b] = scale * computed[b] + damping * messages[sent][b]
                delta = max(delta, abs(updated[sent][b] - messages[sent][b]))
        messages, converged = updated, delta < 1e-6
    beliefs = [[x / add_up(row) for x in row] for row in plain_products(unary, graph, messages)]
    return beliefs, messages, iterations


def random_mrf(rng: np.random.Generator, tiny: bool) -> WebPotentials:
    n_var = int(rng.integers(2, 9))
    cards = rng.choice([1, 2, 2, 2, 3, 4], size=n_var)
    width = int(cards.max())
    pairs = [(u, v) for u in range(n_var) for v in range(u + 1, n_var) if rng.random() < 0.6]
    edges = np.array(pairs, dtype=np.int64).reshape(-1, 2)
    states = np.arange(width)
    valid = states[None, :] < cards[:, None]
    unary = np.where(valid, np.exp(3.0 * rng.normal(size=(n_var, width))) * (1e-200 if tiny else 1.0), 0.0)
    pairwise = np.where(
        valid[edges[:, 0]][:, :, None] & valid[edges[:, 1]][:, None, :],
        np.exp(3.0 * rng.normal(size=(len(edges), width, width))),
        0.0,
    )
    return WebPotentials(tuple(f"x{v}" for v in range(n_var)), cards, unary, edges, pairwise)


def test_random_mrfs_settle_exactly_as_the_plain_loop() -> None:
    rng = np.random.default_rng(17)
    for trial in range(40):
        potentials = random_mrf(rng, tiny=trial % 4 == 0)
        damping = 0.5 if trial % 2 else 0.0
        marginals, max_marginals, iterations, _ = loopy_belief_propagation(
            potentials, damping=damping, max_iterations=40
        )
        graph = _MessageGraph.build(potentials.cardinalities, potentials.variable_edges, potentials.pairwise)
        sends = np.ones(len(potentials.cardinalities), dtype=bool)
        expected = [plain_propagate(potentials.unary, sends, graph, mode, damping, 40) for mode in (False, True)]
        for got, (beliefs, _, _) in zip((marginals, max_marginals), expected, strict=True):
            for v, row in enumerate(beliefs):
                assert got[v, : len(row)].tolist() == row, (trial, v)
        assert iterations == max(steps for _, _, steps in expected)


def test_the_paper_web_settles_exactly_as_the_plain_loop() -> None:
    vocabulary = paper_vocabulary()
    objects = make_objects(WorldConfig.paper(), seed=0)
    web = ConceptWeb.fit(vocabulary, [[*o.concepts, *o.behaviours] for o in objects if o.split == TRAIN])
    rng = np.random.default_rng(4)
    perceptions, applied = rng.random((2, len(vocabulary))), rng.random((2, len(vocabulary.verbs))) < 0.6
    graph = web._graph
    for perception, mask, inference in zip(perceptions, applied, web.infer_many(perceptions, applied=applied)):
        unary, sends = web._evidence(perception[None], mask[None])
        # The default sum-product pass is undamped.
        beliefs, messages, steps = plain_propagate(unary[0], sends[0], graph, False, 0.0, 100)
        assert inference.probabilities.tolist() == [
            beliefs[v][s] for v, s in zip(web.concept_variable, web.concept_state)
        ]
        assert [row[: len(m)].tolist() for row, m in zip(inference.messages, messages)] == messages
        assert inference.iterations >= steps
