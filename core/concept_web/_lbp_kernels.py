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
def scratch(n_var: int, n_directed: int, width: int) -> tuple:
    """Working arrays for :func:`propagate`, allocated once for any number of runs on one graph."""
    return np.zeros((n_directed, width)), np.zeros((n_var, width)), np.zeros(width), np.zeros(width)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def pair_scratch(plan: tuple) -> tuple:
    """Working arrays of the binary part of :func:`propagate` (the ``plan`` of its graph)."""
    n_binary, n_slots = plan[3].shape[0], plan[6].shape[0] + 1
    return np.ones((4, n_slots)), np.zeros((3, n_binary)), np.zeros((3, 2 * plan[0].shape[1]))


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _binary_products(unary, plan, flat_0, flat_1, binary_product, product) -> None:
    """The products of every binary variable from the flat per-state message arrays, without
    rescaling; ``binary_product`` rows: state 0, state 1, and the lowest partial product, which
    :func:`_all_products` watches to redo, with rescaling, a variable whose product got tiny.

    Four variables at a time (``plan``'s ``binary_slots``, (n_groups, max in-degree, 4)): each
    product is a chain of dependent multiplications in CSR order, so one chain alone waits on
    every multiplication; four side by side keep the multiplier busy. A variable with fewer
    incoming messages, and a lane past the last variable, multiply by the last slot's 1.0,
    which changes no bit (nor the lowest partial product).
    """
    binary_variables, binary_slots = plan[3], plan[4]
    n_binary = binary_variables.shape[0]
    for g in range(binary_slots.shape[0]):
        first = 4 * g
        a0 = a1 = b0 = b1 = c0 = c1 = d0 = d1 = 1.0
        if first < n_binary:
            a0, a1 = unary[binary_variables[first], 0], unary[binary_variables[first], 1]
        if first + 1 < n_binary:
            b0, b1 = unary[binary_variables[first + 1], 0], unary[binary_variables[first + 1], 1]
        if first + 2 < n_binary:
            c0, c1 = unary[binary_variables[first + 2], 0], unary[binary_variables[first + 2], 1]
        if first + 3 < n_binary:
            d0, d1 = unary[binary_variables[first + 3], 0], unary[binary_variables[first + 3], 1]
        low_a = low_b = low_c = low_d = np.inf
        steps = binary_slots[g]
        for t in range(steps.shape[0]):
            sa, sb = np.uint64(steps[t, 0]), np.uint64(steps[t, 1])
            sc, sd = np.uint64(steps[t, 2]), np.uint64(steps[t, 3])
            a0 *= flat_0[sa]
            a1 *= flat_1[sa]
            b0 *= flat_0[sb]
            b1 *= flat_1[sb]
            c0 *= flat_0[sc]
            c1 *= flat_1[sc]
            d0 *= flat_0[sd]
            d1 *= flat_1[sd]
            low_a = min(low_a, max(a0, a1))
            low_b = min(low_b, max(b0, b1))
            low_c = min(low_c, max(c0, c1))
            low_d = min(low_d, max(d0, d1))
        for lane, (p0, p1, lowest) in enumerate(((a0, a1, low_a), (b0, b1, low_b), (c0, c1, low_c), (d0, d1, low_d))):
            if first + lane < n_binary:
                binary_product[0, first + lane] = p0
                binary_product[1, first + lane] = p1
                binary_product[2, first + lane] = lowest
                product[binary_variables[first + lane], 0] = p0
                product[binary_variables[first + lane], 1] = p1


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _all_products(unary, graph, flat_0, flat_1, messages, binary_product, product) -> None:
    """product[v] ∝ unary[v] × the incoming messages at v, multiplied in CSR order, for every
    variable; the messages entering binary variables are read from ``flat_0`` / ``flat_1``
    (slots of ``plan``), the others from ``messages``.

    A product is rescaled whenever its largest entry falls below ``_RESCALE_BELOW``, so a
    variable with many neighbours cannot underflow. A binary variable (most of a web's) is
    first multiplied without rescaling (:func:`_binary_products`); only when a partial
    product fell below the threshold is it done again by the rescaling loop, so every result
    is the rescaling loop's, bit for bit, and the common case carries no conditional division.
    """
    cardinalities, incoming_start, incoming, plan = graph[0], graph[5], graph[6], graph[7]
    flat_slot, binary_variables = plan[5], plan[3]
    _binary_products(unary, plan, flat_0, flat_1, binary_product, product)
    for b in range(binary_variables.shape[0]):
        if binary_product[2, b] >= _RESCALE_BELOW:
            continue
        v = binary_variables[b]
        out_0, out_1 = unary[v, 0], unary[v, 1]
        for k in range(incoming_start[v], incoming_start[v + 1]):
            slot = flat_slot[incoming[k]]
            out_0 *= flat_0[slot]
            out_1 *= flat_1[slot]
            peak = max(max(0.0, out_0), out_1)
            if peak < _RESCALE_BELOW:
                out_0 /= peak
                out_1 /= peak
        product[v, 0] = binary_product[0, b] = out_0
        product[v, 1] = binary_product[1, b] = out_1
    for v in range(np.uint64(cardinalities.shape[0])):
        n = np.uint64(cardinalities[v])
        if n == 2:
            continue
        out = product[v]
        for s in range(n):
            out[s] = unary[v, s]
        for k in range(np.uint64(incoming_start[v]), np.uint64(incoming_start[v + _1])):
            entering = messages[np.uint64(incoming[k])]
            tiny = True
            for s in range(n):
                out[s] *= entering[s]
                tiny &= out[s] < _RESCALE_BELOW
            if tiny:  # the largest entry is below the threshold: rescale by it
                peak = 0.0
                for s in range(n):
                    peak = max(peak, out[s])
                for s in range(n):
                    out[s] /= peak


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _pair_senders(plan, sends, keep) -> None:
    """``keep[slot]``: whether the source of each binary-binary slot sends (1.0) or not (0.0)."""
    pair_variables = plan[0]
    n_pairs = pair_variables.shape[1]
    for direction in range(2):
        for i in range(n_pairs):
            keep[direction * n_pairs + i] = 1.0 if sends[pair_variables[direction, i]] else 0.0


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _pair_messages(plan, binary_product, damping, tolerance, max_product, old_0, old_1, new_0, new_1, cavities) -> bool:
    """Both messages of every edge between two binary variables (the binary edge of
    :func:`propagate`, bit for bit): slot ``i`` carries u -> v and slot ``n_pairs + i`` v -> u.
    The cavities (source product times the reverse message) are gathered first, so that the
    rest reads only contiguous arrays and the compiler vectorises it; ``cavities[2]`` says
    whether each slot's source sends (:func:`_pair_senders`). Returns whether any entry moved
    by ``tolerance`` or more (NaN counts as moved)."""
    pair_variables, pair_binary, pair_factors = plan[0], plan[1], plan[2]
    n_pairs = np.uint64(pair_variables.shape[1])
    p0, p1 = binary_product[0], binary_product[1]
    c0, c1, keep = cavities[0], cavities[1], cavities[2]
    for direction in range(2):
        here = np.uint64(direction) * n_pairs
        there = n_pairs - here
        binary_sources = pair_binary[direction]
        for i in range(n_pairs):
            source = np.uint64(binary_sources[i])
            c0[here + i] = p0[source] * old_1[there + i]
            c1[here + i] = p1[source] * old_0[there + i]
    moved = False
    f0, f1, f2, f3 = pair_factors[0], pair_factors[1], pair_factors[2], pair_factors[3]
    for i in range(np.uint64(2) * n_pairs):
        if max_product:
            v0 = max(c0[i] * f0[i], c1[i] * f2[i])
            v1 = max(c0[i] * f1[i], c1[i] * f3[i])
        else:
            v0 = c0[i] * f0[i] + c1[i] * f2[i]
            v1 = c0[i] * f1[i] + c1[i] * f3[i]
        scale = (1.0 - damping) / (v0 + v1)
        was_0, was_1 = old_0[i], old_1[i]
        m0 = scale * v0 + damping * was_0 if keep[i] > 0.0 else was_0
        m1 = scale * v1 + damping * was_1 if keep[i] > 0.0 else was_1
        moved |= ~((abs(m0 - was_0) < tolerance) & (abs(m1 - was_1) < tolerance))
        new_0[i] = m0
        new_1[i] = m1
    return moved


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _into_binary(graph, sends, product, damping, tolerance, max_product, messages, old_0, old_1, new_0, new_1) -> bool:
    """The messages from a variable of another size into a binary one (:func:`propagate`'s general
    message, bit for bit: each sum adds its terms in the same order), into the flat arrays."""
    cardinalities, sources, factor_start, factors, plan = graph[0], graph[1], graph[3], graph[4], graph[7]
    flat_slot, directed = plan[5], plan[7]
    moved = False
    for j in range(directed.shape[0]):
        sent = np.uint64(directed[j])
        source = np.uint64(sources[sent])
        if not sends[source]:
            continue
        back, slot, start = sent ^ _1, np.uint64(flat_slot[sent]), np.uint64(factor_start[sent])
        v0 = v1 = 0.0
        for a in range(np.uint64(cardinalities[source])):
            cavity = product[source, a] / messages[back, a]
            if max_product:
                v0 = max(v0, cavity * factors[start + _2 * a])
                v1 = max(v1, cavity * factors[start + _2 * a + _1])
            else:
                v0 += cavity * factors[start + _2 * a]
                v1 += cavity * factors[start + _2 * a + _1]
        scale = (1.0 - damping) / (v0 + v1)
        m0 = scale * v0 + damping * old_0[slot]
        m1 = scale * v1 + damping * old_1[slot]
        moved |= ~((abs(m0 - old_0[slot]) < tolerance) & (abs(m1 - old_1[slot]) < tolerance))
        new_0[slot] = m0
        new_1[slot] = m1
    return moved


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _from_binary(
    graph, sends, product, damping, tolerance, max_product, messages, updated, old_0, old_1, computed
) -> bool:
    """The messages from a binary variable into one of another size (:func:`propagate`'s general
    message, bit for bit); the reverse message is read from the flat arrays."""
    cardinalities, sources, targets, factor_start, factors, plan = (
        graph[0],
        graph[1],
        graph[2],
        graph[3],
        graph[4],
        graph[7],
    )
    flat_slot, directed = plan[5], plan[8]
    moved = False
    for j in range(directed.shape[0]):
        sent = np.uint64(directed[j])
        source = np.uint64(sources[sent])
        if not sends[source]:
            continue
        back_slot = np.uint64(flat_slot[sent ^ _1])
        n_target, start = np.uint64(cardinalities[np.uint64(targets[sent])]), np.uint64(factor_start[sent])
        cavity_0 = product[source, 0] / old_0[back_slot]
        cavity_1 = product[source, 1] / old_1[back_slot]
        # The states' values apart from their sum, so that the compiler vectorises over the states.
        for b in range(n_target):
            if max_product:
                computed[b] = max(max(0.0, cavity_0 * factors[start + b]), cavity_1 * factors[start + n_target + b])
            else:
                computed[b] = (0.0 + cavity_0 * factors[start + b]) + cavity_1 * factors[start + n_target + b]
        total = 0.0
        for b in range(n_target):
            total += computed[b]
        scale = (1.0 - damping) / total
        for b in range(n_target):
            fresh = scale * computed[b] + damping * messages[sent, b]
            moved |= ~(abs(fresh - messages[sent, b]) < tolerance)
            updated[sent, b] = fresh
    return moved


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _general_messages(
    graph, sends, product, damping, tolerance, max_product, messages, updated, cavity, computed
) -> bool:
    """The messages between two variables that are not binary, one at a time."""
    cardinalities, sources, targets, factor_start, factors, plan = (
        graph[0],
        graph[1],
        graph[2],
        graph[3],
        graph[4],
        graph[7],
    )
    directed = plan[9]
    moved = False
    for j in range(directed.shape[0]):
        sent = directed[j]
        source = sources[sent]
        if not sends[source]:
            continue
        back = sent ^ 1
        n_source, n_target, start = cardinalities[source], cardinalities[targets[sent]], factor_start[sent]
        for a in range(n_source):
            cavity[a] = product[source, a] / messages[back, a]
        total = 0.0
        for b in range(n_target):
            value = 0.0
            for a in range(n_source):
                term = cavity[a] * factors[start + a * n_target + b]
                if max_product:
                    value = max(value, term)
                else:
                    value += term
            computed[b] = value
            total += value
        scale = (1.0 - damping) / total
        for b in range(n_target):
            fresh = scale * computed[b] + damping * messages[sent, b]
            moved |= not (abs(fresh - messages[sent, b]) < tolerance)
            updated[sent, b] = fresh
    return moved


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
    (padded entries zero). ``work`` is :func:`scratch`'s arrays (their padded entries stay
    zero) followed by :func:`pair_scratch`'s.

    A message update is ``m_new = (1 - damping) * m_computed + damping * m_old``;
    the run has converged when no message entry moved by ``tolerance`` or more in
    one iteration (an entry that became NaN counts as moved). A variable with ``sends[v]`` false only receives: its messages
    stay uniform, so it reads the web without feeding back into it. Returns
    ``(iterations, converged)``; a graph without edges needs no iteration and its
    beliefs are the normalised unaries. ``graph`` is ``(cardinalities, sources,
    targets, factor_start, factors, incoming_start, incoming, plan)``. Every factor is
    strictly positive, so dividing a variable's product by one incoming message
    is the product of the others.

    The messages entering binary variables live in flat per-state arrays (slots of
    ``plan``, double-buffered) while the run lasts, the others in ``messages``. Every edge
    between two binary variables is done by :func:`_pair_messages` (vectorised), the others
    one directed message at a time by :func:`_into_binary`, :func:`_from_binary` and
    :func:`_general_messages`. Each message's arithmetic, and the order of every sum and
    product, is that of the one-message-at-a-time loop this replaced, so the results are
    bit for bit the same (tests/test_concept_web_kernel.py checks them against a plain copy
    of that loop); only the order in which independent messages are computed changed, which
    the synchronous schedule allows.
    """
    cardinalities, sources, targets, plan = graph[0], graph[1], graph[2], graph[7]
    updated, product, cavity, computed, flat, binary_product, cavities = work
    flat_directed = plan[6]
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
    old_0, old_1, new_0, new_1 = flat[0], flat[1], flat[2], flat[3]
    for slot in range(flat_directed.shape[0]):
        old_0[slot] = new_0[slot] = messages[flat_directed[slot], 0]
        old_1[slot] = new_1[slot] = messages[flat_directed[slot], 1]
    _pair_senders(plan, sends, cavities[2])
    iterations = 0
    converged = n_directed == 0
    while not converged and iterations < max_iterations:
        iterations += 1
        _all_products(unary, graph, old_0, old_1, messages, binary_product, product)
        moved = _pair_messages(
            plan, binary_product, damping, tolerance, max_product, old_0, old_1, new_0, new_1, cavities
        )
        moved |= _into_binary(
            graph, sends, product, damping, tolerance, max_product, messages, old_0, old_1, new_0, new_1
        )
        moved |= _from_binary(
            graph, sends, product, damping, tolerance, max_product, messages, updated, old_0, old_1, computed
        )
        moved |= _general_messages(
            graph, sends, product, damping, tolerance, max_product, messages, updated, cavity, computed
        )
        messages, updated = updated, messages
        old_0, new_0, old_1, new_1 = new_0, old_0, new_1, old_1
        converged = not moved
    if iterations % 2 == 1:  # the last messages into variables that are not binary are in ``updated``
        for rows in (plan[8], plan[9]):
            for j in range(rows.shape[0]):
                start_messages[rows[j]] = messages[rows[j]]
    for slot in range(flat_directed.shape[0]):
        start_messages[flat_directed[slot], 0] = old_0[slot]
        start_messages[flat_directed[slot], 1] = old_1[slot]
    _all_products(unary, graph, old_0, old_1, start_messages, binary_product, product)
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
    work = (*scratch(cardinalities.shape[0], targets.shape[0], unary.shape[2]), *pair_scratch(graph[7]))
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
    work = (*scratch(n_var, targets.shape[0], width), *pair_scratch(graph[7]))
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
