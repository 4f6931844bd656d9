"""Numba loops of Robust Growing Neural Gas (Qin & Suganthan 2004); the readable driver is ``rgng.py``.

Nodes live in fixed-capacity arrays: ``weights`` (capacity, d), ``active``
(capacity,) and the symmetric edge-age matrix ``ages`` (capacity, capacity),
where ``-1`` means "no edge". Every kernel mutates these in place and draws no
random numbers: the presentation orders come from the caller's Generator.
"""

from __future__ import annotations

import numba
import numpy as np

NO_EDGE = -1
_TINY = 1e-12


@numba.njit(cache=True, nogil=True)
def _distance(a: np.ndarray, b: np.ndarray) -> float:
    total = 0.0
    for h in range(a.shape[0]):
        diff = a[h] - b[h]
        total += diff * diff
    return np.sqrt(total)


@numba.njit(cache=True, nogil=True)
def nearest_two(x: np.ndarray, weights: np.ndarray, active: np.ndarray) -> tuple[int, int, float, float]:
    """Winner s1 and second-nearest s2 among the active nodes, with their distances."""
    s1, s2 = -1, -1
    d1, d2 = np.inf, np.inf
    for i in range(weights.shape[0]):
        if not active[i]:
            continue
        d = _distance(x, weights[i])
        if d < d1:
            s2, d2 = s1, d1
            s1, d1 = i, d
        elif d < d2:
            s2, d2 = i, d
    return s1, s2, d1, d2


@numba.njit(cache=True, nogil=True)
def harmonic_average_distances(data: np.ndarray, weights: np.ndarray, active: np.ndarray) -> np.ndarray:
    """Harmonic average distance of all inputs to each node: n / sum_x 1/||x - w_i||."""
    out = np.zeros(weights.shape[0])
    for i in range(weights.shape[0]):
        if not active[i]:
            continue
        inverse_sum = 0.0
        for j in range(data.shape[0]):
            inverse_sum += 1.0 / (_distance(data[j], weights[i]) + _TINY)
        out[i] = data.shape[0] / inverse_sum
    return out


@numba.njit(cache=True, nogil=True)
def _restricted_step(x: np.ndarray, w: np.ndarray, restricting: np.ndarray, i: int, rate: float) -> np.ndarray:
    """Outlier-resistant move of node i towards x (RGNG §3.1).

    The step length is ``rate * min-like(d, sigma_i)``: an input farther than the
    restricting distance sigma_i moves the node by at most the harmonic mean of d
    and sigma_i, and sigma_i shrinks towards it (harmonic mean); a closer input
    moves it by the plain GNG step and sigma_i relaxes to the arithmetic mean.
    """
    d = _distance(x, w) + _TINY
    sigma = restricting[i]
    if d > sigma:
        sigma = 2.0 / (1.0 / d + 1.0 / sigma)
        length = sigma
    else:
        length = d
        sigma = 0.5 * (d + sigma)
    restricting[i] = sigma
    return rate * length * (x - w) / d


@numba.njit(cache=True, nogil=True)
def _remove_isolated(active: np.ndarray, ages: np.ndarray) -> None:
    """Drop nodes that lost every edge, never going below two nodes."""
    for i in range(active.shape[0]):
        if not active[i] or active.sum() <= 2:
            continue
        isolated = True
        for j in range(active.shape[0]):
            if ages[i, j] != NO_EDGE:
                isolated = False
                break
        if isolated:
            active[i] = False


@numba.njit(cache=True, nogil=True)
def train_stage(
    data: np.ndarray,
    weights: np.ndarray,
    active: np.ndarray,
    ages: np.ndarray,
    orders: np.ndarray,
    eps_winner: tuple[float, float],
    eps_neighbour: tuple[float, float],
    max_edge_age: int,
    repulsion: tuple[float, float],
    tolerance: float,
    prune: bool,
) -> int:
    """One growth stage of RGNG at a fixed number of nodes; returns the epochs run.

    Per input x (steps 2-6 of the algorithm): find the winner s1 and runner-up s2;
    create or refresh the edge s1-s2 (age 0); move s1 with the restricted step at
    rate eps_b(t); move each topological neighbour n with rate eps_n(t) plus the
    cluster-repulsion term ``beta * exp(-||w_n - w_s1|| / width) * mean_nb_dist``
    along (w_n - w_s1); age the edges of s1, drop those older than a_max and (when
    ``prune``) the nodes left without edges. Rates decay as
    ``eps(t) = eps_i * (eps_f / eps_i) ** (t / T)`` over the stage. The restricting
    distances restart from the harmonic average distances at each epoch. The stage
    stops when the mean prototype displacement over an epoch is below ``tolerance``.
    """
    n = data.shape[0]
    epochs = orders.shape[0]
    total = epochs * n
    beta, width = repulsion
    capacity = weights.shape[0]
    for epoch in range(epochs):
        start = weights.copy()
        restricting = harmonic_average_distances(data, weights, active)
        for step in range(n):
            x = data[orders[epoch, step]]
            fraction = (epoch * n + step) / total
            rate_b = eps_winner[0] * (eps_winner[1] / eps_winner[0]) ** fraction
            rate_n = eps_neighbour[0] * (eps_neighbour[1] / eps_neighbour[0]) ** fraction
            s1, s2, _, _ = nearest_two(x, weights, active)
            ages[s1, s2] = 0
            ages[s2, s1] = 0
            weights[s1] += _restricted_step(x, weights[s1], restricting, s1, rate_b)
            neighbour_count = 0
            neighbour_distance = 0.0
            for j in range(capacity):
                if ages[s1, j] != NO_EDGE:
                    neighbour_count += 1
                    neighbour_distance += _distance(weights[j], weights[s1])
            mean_neighbour_distance = neighbour_distance / max(neighbour_count, 1)
            for j in range(capacity):
                if ages[s1, j] == NO_EDGE:
                    continue
                move = _restricted_step(x, weights[j], restricting, j, rate_n)
                away = weights[j] - weights[s1]
                gap = _distance(weights[j], weights[s1]) + _TINY
                move += beta * np.exp(-gap / width) * mean_neighbour_distance * away / gap
                weights[j] += move
                ages[s1, j] += 1
                ages[j, s1] += 1
            for j in range(capacity):
                if ages[s1, j] > max_edge_age:
                    ages[s1, j] = NO_EDGE
                    ages[j, s1] = NO_EDGE
            if prune:
                _remove_isolated(active, ages)
        displacement = 0.0
        count = 0
        for i in range(capacity):
            if active[i]:
                displacement += _distance(weights[i], start[i])
                count += 1
        if displacement / count < tolerance:
            return epoch + 1
    return epochs


@numba.njit(cache=True, nogil=True)
def rebuild_topology(data: np.ndarray, weights: np.ndarray, active: np.ndarray, ages: np.ndarray) -> None:
    """Competitive Hebbian rebuild after a stage: one fresh edge s1-s2 per input."""
    ages[:, :] = NO_EDGE
    for j in range(data.shape[0]):
        s1, s2, _, _ = nearest_two(data[j], weights, active)
        ages[s1, s2] = 0
        ages[s2, s1] = 0


@numba.njit(cache=True, nogil=True)
def _voronoi(
    data: np.ndarray, weights: np.ndarray, active: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Winner and its distance per input; member count and harmonic mean distance per node
    (inf for a node without members)."""
    capacity = weights.shape[0]
    winners = np.empty(data.shape[0], dtype=np.int64)
    distances = np.empty(data.shape[0])
    inverse_sum = np.zeros(capacity)
    counts = np.zeros(capacity)
    for j in range(data.shape[0]):
        s1, _, d1, _ = nearest_two(data[j], weights, active)
        winners[j] = s1
        distances[j] = d1
        inverse_sum[s1] += 1.0 / (d1 + _TINY)
        counts[s1] += 1.0
    harmonic = np.full(capacity, np.inf)
    for i in range(capacity):
        if counts[i] > 0:
            harmonic[i] = counts[i] / inverse_sum[i]
    return winners, distances, counts, harmonic


@numba.njit(cache=True, nogil=True)
def robust_local_errors(data: np.ndarray, weights: np.ndarray, active: np.ndarray) -> np.ndarray:
    """Node-insertion criterion: E_i = sum over the Voronoi set of i of exp(-d / h_i) * d.

    h_i is the harmonic mean distance of node i's Voronoi set, so far-away inputs
    (outliers) contribute little error and do not attract new nodes.
    """
    winners, distances, _, harmonic = _voronoi(data, weights, active)
    errors = np.zeros(weights.shape[0])
    for j in range(data.shape[0]):
        s = winners[j]
        errors[s] += np.exp(-distances[j] / (harmonic[s] + _TINY)) * distances[j]
    return errors


@numba.njit(cache=True, nogil=True)
def description_length(
    data: np.ndarray,
    weights: np.ndarray,
    active: np.ndarray,
    accuracy: float,
    value_range: float,
    error_balance: float,
) -> tuple[float, np.ndarray]:
    """MDL of the data given the active prototypes, with the RGNG outlier test (§3.3).

    Costs in bits: a raw value costs ``B = ceil(log2(range / eta)) + 1``; each used
    prototype d*B; each input log2(K + 1) for its index (a prototype or "outlier");
    an inlier kappa * sum_h (max(log2(|x_h - w_h| / eta), 0) + 1) for its residual;
    an outlier d*B for its raw coordinates. Inputs are examined from the most
    outlying (lowest sum_i 1 / (d_i h_i)) inwards; an input becomes an outlier when
    its inlier cost (plus its prototype's cost if it is that prototype's last
    member) exceeds its raw cost. Returns (MDL, outlier mask).
    """
    n, dims = data.shape
    capacity = weights.shape[0]
    raw_bits = np.ceil(np.log2(value_range / accuracy)) + 1.0
    winners, _, counts, harmonic = _voronoi(data, weights, active)
    residual_bits = np.empty(n)
    for j in range(n):
        bits = 0.0
        for h in range(dims):
            bits += max(np.log2(abs(data[j, h] - weights[winners[j], h]) / accuracy + _TINY), 0.0) + 1.0
        residual_bits[j] = error_balance * bits
    closeness = np.zeros(n)
    for j in range(n):
        for i in range(capacity):
            if active[i] and counts[i] > 0:
                closeness[j] += 1.0 / ((_distance(data[j], weights[i]) + _TINY) * harmonic[i])
    outliers = np.zeros(n, dtype=np.bool_)
    used = 0
    for i in range(capacity):
        if counts[i] > 0:
            used += 1
    for j in np.argsort(closeness):
        s = winners[j]
        inlier_cost = residual_bits[j]
        if counts[s] == 1.0:
            inlier_cost += dims * raw_bits
        if inlier_cost > dims * raw_bits:
            outliers[j] = True
            counts[s] -= 1.0
            if counts[s] == 0.0:
                used -= 1
    index_bits = n * np.log2(used + 1.0)
    inlier_bits = 0.0
    for j in range(n):
        if not outliers[j]:
            inlier_bits += residual_bits[j]
    total = used * dims * raw_bits + index_bits + inlier_bits + outliers.sum() * dims * raw_bits
    return total, outliers
