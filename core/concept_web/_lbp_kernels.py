"""Loopy belief propagation kernels for the concept web (§III-B, Eq. 2).

Flat layout, shared by every kernel:

- ``cardinalities[v]``: number of states of variable ``v``; arrays over states are
  padded to ``K = cardinalities.max()`` and padded entries are never read;
- for an undirected edge ``e = (u, v)``, directed edge ``2e`` carries the message
  ``u -> v`` and ``2e + 1`` the message ``v -> u``, so the reverse of directed edge
  ``d`` is ``d ^ 1``; ``sources[d]`` and ``targets[d]`` are its two variables;
- ``factors[factor_start[d] + a * cardinalities[targets[d]] + b]`` is the clique
  factor ``exp(-beta * psi_K)`` for ``x_source = a, x_target = b`` (the edge's
  table, transposed for ``2e + 1``), stored unpadded so that binary edges stay small;
- ``incoming_start[v] : incoming_start[v + 1]`` slices ``incoming`` to the directed
  edges that end in ``v`` (CSR).

Messages are normalised probability vectors; a variable's product of incoming
messages is rescaled whenever it gets tiny, so a variable with many neighbours
cannot underflow. The schedule is synchronous (every message is computed from the previous
iteration's messages), which makes the result independent of edge order.

Two entry points run :func:`propagate` over a batch of objects in one call, with its
working arrays allocated once (:func:`scratch`): :func:`settle_many` for a
``ConceptWeb`` (it builds the unary factors from the perceptions, can skip the
sum-product pass and warm-start either pass, and reads off the marginals and the MAP)
and :func:`propagate_many` for any pairwise MRF given its unaries
(``loopy_belief_propagation``).
"""

from __future__ import annotations

import numba
import numpy as np

#: Products of incoming messages are rescaled when their largest entry falls below this.
_RESCALE_BELOW = 1e-150
#: Unsigned offsets: an index read from the graph is used as an unsigned number, because numba
#: corrects every signed index for negative values (Python's a[-1]) on each read, which cost
#: ≈ 20 % of an LBP iteration on the paper's web; and uint64 + int64 is a float in numba's typing.
_1, _2, _3 = np.uint64(1), np.uint64(2), np.uint64(3)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _products(unary, cardinalities, incoming_start, incoming, messages, out):
    """out[v] ∝ unary[v] × the incoming messages at v, rescaled so no product underflows.

    A binary variable (most of a web's) multiplies its two products in registers and only
    watches them: when a partial product fell below the rescaling threshold, the variable is
    done again by the general loop, which rescales exactly where it always has. So every
    result is the general loop's, bit for bit, and the common case carries no conditional
    division on its chain of multiplications (which the compiler would turn into one per step).
    """
    for v in range(cardinalities.shape[0]):
        n = cardinalities[v]
        if n == 2:
            p0, p1 = unary[v, 0], unary[v, 1]
            lowest = np.inf
            for k in range(np.uint64(incoming_start[v]), np.uint64(incoming_start[v + 1])):
                entering = np.uint64(incoming[k])
                p0 *= messages[entering, 0]
                p1 *= messages[entering, 1]
                lowest = min(lowest, max(p0, p1))
            if lowest >= _RESCALE_BELOW:
                out[v, 0] = p0
                out[v, 1] = p1
                continue
        for s in range(n):
            out[v, s] = unary[v, s]
        for k in range(incoming_start[v], incoming_start[v + 1]):
            peak = 0.0
            for s in range(n):
                out[v, s] *= messages[incoming[k], s]
                peak = max(peak, out[v, s])
            if peak < _RESCALE_BELOW:
                for s in range(n):
                    out[v, s] /= peak


@numba.njit(cache=True, nogil=True, error_model="numpy")
def scratch(n_var: int, n_directed: int, width: int) -> tuple:
    """Working arrays for :func:`propagate`, allocated once for any number of runs on one graph."""
    return np.zeros((n_directed, width)), np.zeros((n_var, width)), np.zeros(width), np.zeros(width)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def propagate(
    unary: np.ndarray,
    sends: np.ndarray,
    graph: tuple,
    max_product: bool,
    damping: float,
    tolerance: float,
    max_iterations: int,
    beliefs: np.ndarray,
    messages: np.ndarray,
    work: tuple,
) -> tuple[int, bool]:
    """Run sum-product (or max-product) LBP for one object; fill ``beliefs`` (n_var, K).

    ``messages`` (n_directed, K) holds the starting messages on entry (uniform for
    a cold start; a previous run's for a warm start) and the final ones on return
    (padded entries zero). ``work`` is :func:`scratch`'s arrays (their padded entries stay zero).

    A message update is ``m_new = (1 - damping) * m_computed + damping * m_old``;
    the run has converged when no message entry moved by ``tolerance`` or more in
    one iteration. A variable with ``sends[v]`` false only receives: its messages
    stay uniform, so it reads the web without feeding back into it. Returns
    ``(iterations, converged)``; a graph without edges needs no iteration and its
    beliefs are the normalised unaries. ``graph`` is ``(cardinalities, sources,
    targets, factor_start, factors, incoming_start, incoming)``. Every factor is
    strictly positive, so dividing a variable's product by one incoming message
    is the product of the others.
    """
    cardinalities, sources, targets, factor_start, factors, incoming_start, incoming = graph
    updated, product, cavity, computed = work
    n_var = cardinalities.shape[0]
    width = unary.shape[1]
    n_directed = sources.shape[0]
    start_messages = messages
    # Messages alternate between ``messages`` and ``updated``; every message a variable sends is
    # written before it is read, and one it does not send stays uniform in both.
    for d in range(n_directed):
        if not sends[sources[d]]:
            for b in range(cardinalities[targets[d]]):
                messages[d, b] = 1.0 / cardinalities[targets[d]]
                updated[d, b] = messages[d, b]
    iterations = 0
    converged = n_directed == 0
    while not converged and iterations < max_iterations:
        iterations += 1
        _products(unary, cardinalities, incoming_start, incoming, messages, product)
        delta = 0.0
        # Source by source (the edges leaving v are the reverses of those entering it), so a
        # variable's products and whether it sends are read once for all its messages.
        for source in range(n_var):
            if not sends[source]:
                continue
            n_source = cardinalities[source]
            p0, p1 = product[source, 0], product[source, min(1, n_source - 1)]
            for k in range(np.uint64(incoming_start[source]), np.uint64(incoming_start[source + 1])):
                back = np.uint64(incoming[k])  # the message entering source, the reverse of the one it sends
                sent = back ^ _1
                n_target, start = cardinalities[np.uint64(targets[sent])], np.uint64(factor_start[sent])
                if n_source == 2 and n_target == 2:
                    # Binary edge: the cavity (product without the reverse message) up to scale,
                    # p0 / m0 : p1 / m1 = p0 * m1 : p1 * m0, needs no division.
                    c0 = p0 * messages[back, 1]
                    c1 = p1 * messages[back, 0]
                    if max_product:
                        v0 = max(c0 * factors[start], c1 * factors[start + _2])
                        v1 = max(c0 * factors[start + _1], c1 * factors[start + _3])
                    else:
                        v0 = c0 * factors[start] + c1 * factors[start + _2]
                        v1 = c0 * factors[start + _1] + c1 * factors[start + _3]
                    scale = (1.0 - damping) / (v0 + v1)
                    m0 = scale * v0 + damping * messages[sent, 0]
                    m1 = scale * v1 + damping * messages[sent, 1]
                    delta = max(delta, abs(m0 - messages[sent, 0]), abs(m1 - messages[sent, 1]))
                    updated[sent, 0] = m0
                    updated[sent, 1] = m1
                    continue
                for a in range(n_source):
                    cavity[a] = product[source, a] / messages[back, a]
                total = 0.0
                for b in range(n_target):
                    value = 0.0
                    for a in range(n_source):
                        term = cavity[a] * factors[start + np.uint64(a * n_target + b)]
                        if max_product:
                            value = max(value, term)
                        else:
                            value += term
                    computed[b] = value
                    total += value
                scale = (1.0 - damping) / total
                for b in range(n_target):
                    fresh = scale * computed[b] + damping * messages[sent, b]
                    change = abs(fresh - messages[sent, b])
                    delta = max(delta, change)
                    updated[sent, b] = fresh
        messages, updated = updated, messages
        converged = delta < tolerance
    if iterations % 2 == 1:
        start_messages[:] = messages
    _products(unary, cardinalities, incoming_start, incoming, messages, product)
    for v in range(n_var):
        total = 0.0
        for s in range(cardinalities[v]):
            total += product[v, s]
        for s in range(width):
            beliefs[v, s] = product[v, s] / total if s < cardinalities[v] else 0.0
    return iterations, converged


@numba.njit(cache=True, nogil=True, error_model="numpy")
def uniform_messages(cardinalities: np.ndarray, targets: np.ndarray, messages: np.ndarray) -> None:
    """Set every message of ``messages`` (n_directed, K) to the uniform vector (a cold start), padding 0."""
    for d in range(targets.shape[0]):
        n_target = cardinalities[targets[d]]
        for b in range(messages.shape[1]):
            messages[d, b] = 1.0 / n_target if b < n_target else 0.0


@numba.njit(cache=True, nogil=True, error_model="numpy")
def propagate_many(
    unary: np.ndarray,
    sends: np.ndarray,
    graph: tuple,
    damping: float,
    tolerance: float,
    max_iterations: int,
    marginals: np.ndarray,
    max_marginals: np.ndarray,
    iterations: np.ndarray,
    converged: np.ndarray,
) -> None:
    """Sum-product then max-product LBP, both from uniform messages, for every object of
    ``unary`` (n_objects, n_var, K) and ``sends`` (n_objects, n_var): what
    ``loopy_belief_propagation`` solves. ``iterations`` and ``converged`` are
    (n_objects, 2), the sum-product pass in column 0 and the max-product pass in column 1.
    """
    cardinalities, targets = graph[0], graph[2]
    messages = np.empty((targets.shape[0], unary.shape[2]))
    work = scratch(cardinalities.shape[0], targets.shape[0], unary.shape[2])
    for i in range(unary.shape[0]):
        for column in range(2):
            out = marginals[i] if column == 0 else max_marginals[i]
            uniform_messages(cardinalities, targets, messages)
            steps, done = propagate(
                unary[i], sends[i], graph, column == 1, damping, tolerance, max_iterations, out, messages, work
            )
            iterations[i, column] = steps
            converged[i, column] = done


@numba.njit(cache=True, nogil=True, error_model="numpy")
def settle_many(
    perceptions: np.ndarray,
    applied: np.ndarray,
    layout: tuple,
    clip: tuple,
    graph: tuple,
    runs: np.ndarray,
    cold: np.ndarray,
    damping: np.ndarray,
    tolerance: float,
    max_iterations: np.ndarray,
    probabilities: np.ndarray,
    map_configuration: np.ndarray,
    iterations: np.ndarray,
    converged: np.ndarray,
    sum_messages: np.ndarray,
    max_messages: np.ndarray,
) -> None:
    """Settle the concept web of every object of ``perceptions`` (n_objects, n_concepts) in one call.

    The unary factors are ``ConceptWeb._evidence``'s: each concept's perception clipped
    to ``clip`` = (low, high) at its (variable, state), a verb's inactive state 1 − that,
    and a verb not ``applied`` (n_objects, n_verbs) gets (1, 1) and does not send.
    ``layout`` = (concept_variable, concept_state, verb_variables, verb_concepts).
    ``runs``, ``cold``, ``damping`` and ``max_iterations`` (2,), and ``iterations`` and
    ``converged`` (n_objects, 2), hold the sum-product pass in column 0 and the
    max-product pass in column 1. A pass with ``runs`` false is skipped (0 iterations,
    converged, its messages not read: ``sum_messages`` may then be (n_objects, 0, 0)); a
    ``cold`` pass starts from uniform messages, the others from the messages given in
    ``sum_messages`` / ``max_messages`` (n_objects, n_directed, K), which hold each
    pass's final messages on return.
    Fills ``probabilities`` (the sum-product marginal of each concept's state, NaN when
    that pass is skipped) and ``map_configuration`` (whether each concept's state is its
    variable's argmax of the max-marginals, ties to the lowest state, as ``np.argmax``).
    """
    concept_variable, concept_state, verb_variables, verb_concepts = layout
    low, high = clip
    cardinalities, targets = graph[0], graph[2]
    n_var, width = cardinalities.shape[0], max_messages.shape[2]
    unary = np.zeros((n_var, width))
    sends = np.ones(n_var, dtype=np.bool_)
    beliefs = np.zeros((n_var, width))
    best = np.zeros(n_var, dtype=np.int64)
    clipped = np.zeros(perceptions.shape[1])
    work = scratch(n_var, targets.shape[0], width)
    for i in range(perceptions.shape[0]):
        for c in range(perceptions.shape[1]):
            clipped[c] = min(max(perceptions[i, c], low), high)
            unary[concept_variable[c], concept_state[c]] = clipped[c]
        for j in range(verb_variables.shape[0]):
            v = verb_variables[j]
            if applied[i, j]:
                unary[v, 0] = 1.0 - clipped[verb_concepts[j]]
                sends[v] = True
            else:
                unary[v, 0] = 1.0
                unary[v, 1] = 1.0
                sends[v] = False
        for column in range(2):
            if not runs[column]:
                iterations[i, column] = 0
                converged[i, column] = True
                if column == 0:
                    for c in range(concept_variable.shape[0]):
                        probabilities[i, c] = np.nan
                continue
            messages = sum_messages[i] if column == 0 else max_messages[i]
            if cold[column]:
                uniform_messages(cardinalities, targets, messages)
            steps, done = propagate(
                unary,
                sends,
                graph,
                column == 1,
                damping[column],
                tolerance,
                max_iterations[column],
                beliefs,
                messages,
                work,
            )
            iterations[i, column] = steps
            converged[i, column] = done
            if column == 0:
                for c in range(concept_variable.shape[0]):
                    probabilities[i, c] = beliefs[concept_variable[c], concept_state[c]]
            else:
                for v in range(n_var):
                    top = 0
                    for s in range(1, width):
                        if beliefs[v, s] > beliefs[v, top] or (
                            np.isnan(beliefs[v, s]) and not np.isnan(beliefs[v, top])
                        ):
                            top = s
                    best[v] = top
                for c in range(concept_variable.shape[0]):
                    map_configuration[i, c] = best[concept_variable[c]] == concept_state[c]
