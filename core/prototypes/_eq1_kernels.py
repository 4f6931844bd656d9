"""Numba loop of the prototype distance of Eq. 1; the readable side is ``prototypes.Eq1Prototypes``.

One perception measures ~10 effects against 10 verb prototypes and one entity
against 16 noun and adjective prototypes; numpy spends most of that time
allocating and walking the (n, C, d) broadcast, which this loop avoids (the timings:
docs/benchmarks.md). Each D(c, x) sums its d masked squares in numpy's own pairwise
order (:func:`pairwise_sum`), so the distances equal the former numpy
expression bit for bit and the perception probabilities did not move.
"""

from __future__ import annotations

import numba
import numpy as np

#: numpy's PW_BLOCKSIZE: runs up to this long are summed with 8 interleaved accumulators.
_BLOCK = 128
#: Room for the walk of :func:`pairwise_sum`: each halving adds at most 2 pending nodes, and
#: an int64 length halves fewer than 64 times.
_STACK = 192


@numba.njit(cache=True, nogil=True)
def pairwise_sum(values: np.ndarray, start: int, n: int) -> float:
    """Sum of values[start:start + n] in the order of numpy's float64 ``add.reduce``
    (numpy/_core/src/umath/loops_utils.h.src ``pairwise_sum``): runs of at most 128
    terms by :func:`_block_sum`, longer ones split in two halves at a multiple of 8
    and the halves' sums added. numpy recurses; this walks the same tree with an
    explicit stack, because numba's on-disk cache crashes on recursive functions
    (numba issue #6061)."""
    if n <= _BLOCK:
        return _block_sum(values, start, n)
    # Post-order walk: a node is (start, length, its halves already pushed?).
    node_start = np.empty(_STACK, dtype=np.int64)
    node_length = np.empty(_STACK, dtype=np.int64)
    node_split = np.zeros(_STACK, dtype=np.bool_)
    sums = np.empty(_STACK)
    node_start[0], node_length[0], nodes, n_sums = start, n, 1, 0
    while nodes:
        nodes -= 1
        first, length, split = node_start[nodes], node_length[nodes], node_split[nodes]
        if length <= _BLOCK:
            sums[n_sums] = _block_sum(values, first, length)
            n_sums += 1
        elif split:
            n_sums -= 1
            sums[n_sums - 1] += sums[n_sums]
        else:
            half = length // 2
            half -= half % 8
            node_split[nodes] = True
            node_start[nodes + 1], node_length[nodes + 1], node_split[nodes + 1] = first + half, length - half, False
            node_start[nodes + 2], node_length[nodes + 2], node_split[nodes + 2] = first, half, False
            nodes += 3
    return sums[0]


@numba.njit(cache=True, nogil=True, inline="always")
def _block_sum(values: np.ndarray, start: int, n: int) -> float:
    """numpy's sum of a run of at most 128 terms: a plain loop below 8 terms, else 8
    interleaved accumulators combined pairwise, then the remainder in order."""
    if n < 8:
        total = 0.0
        for i in range(start, start + n):
            total += values[i]
        return total
    r0, r1, r2, r3 = values[start], values[start + 1], values[start + 2], values[start + 3]
    r4, r5, r6, r7 = values[start + 4], values[start + 5], values[start + 6], values[start + 7]
    end = start + n - n % 8
    for i in range(start + 8, end, 8):
        r0 += values[i]
        r1 += values[i + 1]
        r2 += values[i + 2]
        r3 += values[i + 3]
        r4 += values[i + 4]
        r5 += values[i + 5]
        r6 += values[i + 6]
        r7 += values[i + 7]
    total = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    for i in range(end, start + n):
        total += values[i]
    return total


@numba.njit(cache=True, nogil=True)
def eq1_distances(z: np.ndarray, means: np.ndarray, weights: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    """D(c, x_r) = sqrt(sum_i weights[c, i] (x_r^i - mu_c^i)^2) / sizes[c] for rows z (n, d): (n, C).

    The masked squares are summed over all d features, zeros included, to keep
    numpy's summation order (see the module docstring).
    """
    n, d = z.shape
    n_concepts = means.shape[0]
    out = np.empty((n, n_concepts))
    squares = np.empty(d)
    for row in range(n):
        for c in range(n_concepts):
            for i in range(d):
                diff = z[row, i] - means[c, i]
                squares[i] = diff * diff * weights[c, i]
            # Feature vectors (66, 91) fit one block: the inlined block sum saves ~20 % over the call.
            total = _block_sum(squares, 0, d) if d <= _BLOCK else pairwise_sum(squares, 0, d)
            out[row, c] = np.sqrt(total) / sizes[c]
    return out
