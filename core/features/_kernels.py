"""Numba kernels behind :mod:`core.features.extract`: the per-point surface estimate.

Two batched passes over the points. First, local PCA over each point's k nearest
neighbours gives its outward normal and tangent frame (Table III, zenith/azimuth
bins 7-46). Then a degree-2 jet h = a u^2 + b uv + c v^2 + d u + e v + f, fitted in
that frame to the neighbours' positions and to the slopes of their normals, gives
the principal curvatures Q1 >= Q2 behind the shape index (bins 47-66), and an F
test against a plane says whether the bending is real or sensor noise. The public
API and every choice's reason are in ``extract.py`` and ``docs/features.md``.
"""

from __future__ import annotations

import numba
import numpy as np

#: Cyclic Jacobi sweeps on a 3x3 symmetric matrix; converges quadratically, 3-5 suffice.
_JACOBI_SWEEPS = 12
#: Ridge added to the jet's normal equations, relative to their trace, so a locally
#: collinear neighbourhood still solves (the unidentifiable terms go to ~0).
_JET_RIDGE = 1e-10
#: A neighbour's normal tilted more than 60 degrees from the point's (across a sharp
#: edge, or the far side of a thin object) says nothing about this point's slope field.
_SLOPE_MIN_COS = 0.5
#: Added to each kind's residual variance before inverting it into a weight (scaled
#: units, where residuals of real data are >= 1e-8): caps the weight of an exact fit.
_VARIANCE_FLOOR = 1e-12
#: |n . (p - c)| below this fraction of |p - c| counts as "no outward side" (an exactly
#: planar cloud): the normal is then turned to point up (+z, then +y, then +x).
_ORIENTATION_TIE = 1e-9


@numba.njit(cache=True, nogil=True)
def _jacobi_eigen3(a: np.ndarray, vectors: np.ndarray) -> None:
    """Diagonalise the symmetric 3x3 ``a`` in place; eigenvectors go to the columns of ``vectors``."""
    vectors[:, :] = 0.0
    for d in range(3):
        vectors[d, d] = 1.0
    for _ in range(_JACOBI_SWEEPS):
        off = a[0, 1] ** 2 + a[0, 2] ** 2 + a[1, 2] ** 2
        diagonal = a[0, 0] ** 2 + a[1, 1] ** 2 + a[2, 2] ** 2
        if off <= 1e-30 * diagonal or off == 0.0:
            return
        for p in range(2):
            for q in range(p + 1, 3):
                if a[p, q] == 0.0:
                    continue
                theta = (a[q, q] - a[p, p]) / (2.0 * a[p, q])
                t = 1.0 / (abs(theta) + np.sqrt(theta * theta + 1.0))
                if theta < 0.0:
                    t = -t
                c = 1.0 / np.sqrt(t * t + 1.0)
                s = t * c
                for r in range(3):
                    arp = a[r, p]
                    arq = a[r, q]
                    a[r, p] = c * arp - s * arq
                    a[r, q] = s * arp + c * arq
                for r in range(3):
                    apr = a[p, r]
                    aqr = a[q, r]
                    a[p, r] = c * apr - s * aqr
                    a[q, r] = s * apr + c * aqr
                for r in range(3):
                    vrp = vectors[r, p]
                    vrq = vectors[r, q]
                    vectors[r, p] = c * vrp - s * vrq
                    vectors[r, q] = s * vrp + c * vrq


@numba.njit(cache=True, nogil=True)
def _solve_symmetric(m: np.ndarray, rhs: np.ndarray, solution: np.ndarray, size: int) -> None:
    """Solve the positive-definite ``m[:size, :size] x = rhs[:size]`` by Cholesky, overwriting ``m`` by its factor."""
    for j in range(size):
        pivot = m[j, j]
        for k in range(j):
            pivot -= m[j, k] * m[j, k]
        pivot = np.sqrt(max(pivot, 1e-300))
        m[j, j] = pivot
        for i in range(j + 1, size):
            value = m[i, j]
            for k in range(j):
                value -= m[i, k] * m[j, k]
            m[i, j] = value / pivot
    for i in range(size):
        value = rhs[i]
        for k in range(i):
            value -= m[i, k] * solution[k]
        solution[i] = value / m[i, i]
    for i in range(size - 1, -1, -1):
        value = solution[i]
        for k in range(i + 1, size):
            value -= m[k, i] * solution[k]
        solution[i] = value / m[i, i]


@numba.njit(cache=True, nogil=True)
def _orient_outward(normal: np.ndarray, outward: np.ndarray) -> None:
    """Flip ``normal`` to the side of ``outward`` (point minus cloud centroid); ties point up."""
    along = normal[0] * outward[0] + normal[1] * outward[1] + normal[2] * outward[2]
    length = np.sqrt(outward[0] ** 2 + outward[1] ** 2 + outward[2] ** 2)
    if abs(along) <= _ORIENTATION_TIE * length:
        along = normal[2]
        if along == 0.0:
            along = normal[1]
        if along == 0.0:
            along = normal[0]
    if along < 0.0:
        normal[0] = -normal[0]
        normal[1] = -normal[1]
        normal[2] = -normal[2]


@numba.njit(cache=True, nogil=True)
def _pca_frames(points: np.ndarray, neighbours: np.ndarray, centroid: np.ndarray) -> np.ndarray:
    """Per point, rows (t1, t2, n): tangent axes and the outward normal of its neighbourhood's PCA."""
    count, k = neighbours.shape
    frames = np.empty((count, 3, 3))
    covariance = np.empty((3, 3))
    vectors = np.empty((3, 3))
    mean = np.empty(3)
    normal = np.empty(3)
    outward = np.empty(3)
    for i in range(count):
        mean[:] = 0.0
        for j in range(k):
            for d in range(3):
                mean[d] += points[neighbours[i, j], d]
        mean /= k
        covariance[:, :] = 0.0
        for j in range(k):
            for r in range(3):
                offset = points[neighbours[i, j], r] - mean[r]
                for c in range(r, 3):
                    covariance[r, c] += offset * (points[neighbours[i, j], c] - mean[c])
        for r in range(3):
            for c in range(r):
                covariance[r, c] = covariance[c, r]
        _jacobi_eigen3(covariance, vectors)
        smallest = 0
        for d in range(1, 3):
            if covariance[d, d] < covariance[smallest, smallest]:
                smallest = d
        for d in range(3):
            normal[d] = vectors[d, smallest]
            outward[d] = points[i, d] - centroid[d]
        _orient_outward(normal, outward)
        frames[i, 2] = normal
        row = 0
        for e in range(3):
            if e != smallest:
                frames[i, row] = vectors[:, e]
                row += 1
    return frames


@numba.njit(cache=True, nogil=True)
def _accumulate_jet_equations(
    local: np.ndarray, k: int, radius: float, grams: np.ndarray, rhs: np.ndarray, squared_targets: np.ndarray
) -> int:
    """Normal equations of the jet, one set per kind of equation (0: heights, 1: slopes).

    ``local[j]`` = (u, v, h, slope_u, slope_v, has_slope) of neighbour j: frame
    coordinates in metres, scaled here by ``radius`` so that a height residual is in
    units of the neighbourhood's size, like a slope residual. Each neighbour gives
    its height h = a u^2 + b uv + c v^2 + d u + e v + f and, when its normal is
    usable, that normal's slopes dh/du = 2a u + b v + d and dh/dv = b u + 2c v + e.
    Returns the number of slope equations.
    """
    grams[:, :, :] = 0.0
    rhs[:, :] = 0.0
    squared_targets[:] = 0.0
    row = np.empty(6)
    slope_rows = 0
    for j in range(k):
        u = local[j, 0] / radius
        v = local[j, 1] / radius
        height = local[j, 2] / radius
        row[0] = u * u
        row[1] = u * v
        row[2] = v * v
        row[3] = u
        row[4] = v
        row[5] = 1.0
        squared_targets[0] += height * height
        for r in range(6):
            rhs[0, r] += row[r] * height
            for c in range(r, 6):
                grams[0, r, c] += row[r] * row[c]
        if local[j, 5] > 0.0:
            # The two slope rows are sparse: (2u, v, 0, 1, 0, 0) and (0, u, 2v, 0, 1, 0).
            slope_u = local[j, 3]
            slope_v = local[j, 4]
            slope_rows += 2
            squared_targets[1] += slope_u * slope_u + slope_v * slope_v
            grams[1, 0, 0] += 4.0 * u * u
            grams[1, 0, 1] += 2.0 * u * v
            grams[1, 0, 3] += 2.0 * u
            grams[1, 1, 1] += v * v + u * u
            grams[1, 1, 2] += 2.0 * u * v
            grams[1, 1, 3] += v
            grams[1, 1, 4] += u
            grams[1, 2, 2] += 4.0 * v * v
            grams[1, 2, 4] += 2.0 * v
            grams[1, 3, 3] += 1.0
            grams[1, 4, 4] += 1.0
            rhs[1, 0] += 2.0 * u * slope_u
            rhs[1, 1] += v * slope_u + u * slope_v
            rhs[1, 2] += 2.0 * v * slope_v
            rhs[1, 3] += slope_u
            rhs[1, 4] += slope_v
    for kind in range(2):
        for r in range(6):
            for c in range(r):
                grams[kind, r, c] = grams[kind, c, r]
    return slope_rows


@numba.njit(cache=True, nogil=True)
def _weighted_fit(
    grams: np.ndarray,
    rhs: np.ndarray,
    squared_targets: np.ndarray,
    weights: np.ndarray,
    first_column: int,
    gram: np.ndarray,
    right: np.ndarray,
    solution: np.ndarray,
) -> float:
    """Weighted least squares on the columns ``first_column:`` (ridge-stabilised); returns the weighted RSS."""
    size = 6 - first_column
    trace = 0.0
    for r in range(size):
        right[r] = weights[0] * rhs[0, first_column + r] + weights[1] * rhs[1, first_column + r]
        for c in range(size):
            gram[r, c] = (
                weights[0] * grams[0, first_column + r, first_column + c]
                + weights[1] * grams[1, first_column + r, first_column + c]
            )
        trace += gram[r, r]
    for r in range(size):
        gram[r, r] += _JET_RIDGE * trace
    _solve_symmetric(gram, right, solution, size)
    explained = 0.0
    for r in range(size):
        explained += solution[r] * right[r]
    return max(weights[0] * squared_targets[0] + weights[1] * squared_targets[1] - explained, 0.0)


@numba.njit(cache=True, nogil=True)
def _monge_curvatures(jet: np.ndarray) -> tuple[float, float]:
    """Principal curvatures (Q1 >= Q2) at the origin of the patch h(u, v), convex (bending away from n) positive."""
    fxx = 2.0 * jet[0]
    fxy = jet[1]
    fyy = 2.0 * jet[2]
    fx = jet[3]
    fy = jet[4]
    metric = 1.0 + fx * fx + fy * fy
    gaussian = (fxx * fyy - fxy * fxy) / (metric * metric)
    mean = -((1.0 + fx * fx) * fyy - 2.0 * fx * fy * fxy + (1.0 + fy * fy) * fxx) / (2.0 * metric**1.5)
    spread = np.sqrt(max(mean * mean - gaussian, 0.0))
    return mean + spread, mean - spread


@numba.njit(cache=True, nogil=True)
def local_surfaces(
    points: np.ndarray,
    neighbours: np.ndarray,
    centroid: np.ndarray,
    min_radius: float,
    f_critical: np.ndarray,
    numerically_flat: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Normals (n, 3), principal curvatures (n, 2) as (Q1, Q2), neighbourhood radii (n,), planar flags (n,).

    ``neighbours[i]`` holds the indices of point i's k nearest points (itself
    included). Normals point away from ``centroid``. Curvatures are in 1/length,
    positive where the surface bends away from the normal (convex). The jet is a
    weighted least-squares fit: heights and slopes each weighted by the inverse of
    the residual variance of a fit to that kind of equation alone, so exact
    positions dominate on clean data and the neighbours' normals (each averaged over
    its own neighbourhood) on noisy data. A point is planar when the jet's 3
    quadratic terms do not beat the plane h = du + ev + f: F = ((RSS_plane -
    RSS_jet) / 3) / (RSS_jet / dof) <= ``f_critical[dof]`` on the weighted residuals,
    dof = equations - 6; or when its curvedness times its radius is below
    ``numerically_flat``. A neighbourhood whose RMS tangent radius is at most
    ``min_radius`` (coincident points) is planar with zero curvature.
    """
    count, k = neighbours.shape
    frames = _pca_frames(points, neighbours, centroid)
    normals = frames[:, 2, :].copy()
    curvatures = np.zeros((count, 2))
    radii = np.zeros(count)
    planar = np.ones(count, dtype=np.bool_)
    local = np.empty((k, 6))
    grams = np.empty((2, 6, 6))
    rhs = np.empty((2, 6))
    squared_targets = np.empty(2)
    weights = np.empty(2)
    gram = np.empty((6, 6))
    right = np.empty(6)
    jet = np.empty(6)
    plane = np.empty(6)
    for i in range(count):
        radius_sq = 0.0
        for j in range(k):
            neighbour = neighbours[i, j]
            u = 0.0
            v = 0.0
            h = 0.0
            tilt_u = 0.0
            tilt_v = 0.0
            along_normal = 0.0
            for d in range(3):
                offset = points[neighbour, d] - points[i, d]
                u += offset * frames[i, 0, d]
                v += offset * frames[i, 1, d]
                h += offset * frames[i, 2, d]
                tilt_u += normals[neighbour, d] * frames[i, 0, d]
                tilt_v += normals[neighbour, d] * frames[i, 1, d]
                along_normal += normals[neighbour, d] * frames[i, 2, d]
            local[j, 0] = u
            local[j, 1] = v
            local[j, 2] = h
            usable = along_normal > _SLOPE_MIN_COS
            local[j, 3] = -tilt_u / along_normal if usable else 0.0
            local[j, 4] = -tilt_v / along_normal if usable else 0.0
            local[j, 5] = 1.0 if usable else 0.0
            radius_sq += u * u + v * v
        radius = np.sqrt(radius_sq / k)
        radii[i] = radius
        if radius <= min_radius:
            continue
        slope_rows = _accumulate_jet_equations(local, k, radius, grams, rhs, squared_targets)
        # Feasible weighted least squares: each kind of equation is weighted by the inverse of
        # the residual variance of a jet fitted to that kind alone (the slopes cannot see f).
        weights[0] = 1.0
        weights[1] = 0.0
        height_variance = _weighted_fit(grams, rhs, squared_targets, weights, 0, gram, right, jet) / (k - 6)
        weights[0] = 0.0
        weights[1] = 1.0
        slope_variance = np.inf
        if slope_rows > 5:
            slope_variance = _weighted_fit(grams, rhs, squared_targets, weights, 0, gram, right, jet) / (slope_rows - 5)
        weights[0] = 1.0 / (height_variance + _VARIANCE_FLOOR)
        weights[1] = 1.0 / (slope_variance + _VARIANCE_FLOOR)
        jet_rss = _weighted_fit(grams, rhs, squared_targets, weights, 0, gram, right, jet)
        plane_rss = _weighted_fit(grams, rhs, squared_targets, weights, 3, gram, right, plane)
        q1, q2 = _monge_curvatures(jet)
        curvatures[i, 0] = q1 / radius
        curvatures[i, 1] = q2 / radius
        gain = max(plane_rss - jet_rss, 0.0)
        dof = k + slope_rows - 6
        significant = gain > 0.0 if jet_rss == 0.0 else (gain / 3.0) / (jet_rss / dof) > f_critical[dof]
        planar[i] = not significant or np.sqrt(0.5 * (q1 * q1 + q2 * q2)) < numerically_flat
    return normals, curvatures, radii, planar
