"""Robust Growing Neural Gas on planted 2-D clusters (Qin & Suganthan 2004)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.cluster.vq import kmeans2

from core.errors import InvalidInputError
from core.prototypes.rgng import RGNGParameters, robust_growing_neural_gas

CENTRES = np.array([[0.0, 0.0], [6.0, 1.0], [2.0, 7.0]])
SPREAD = 0.6


def _blobs(seed: int, outliers: int) -> tuple[np.ndarray, np.ndarray]:
    """Three Gaussian blobs of 100 points, plus uniform outliers over a box 4x wider."""
    rng = np.random.default_rng(seed)
    blobs = [centre + SPREAD * rng.standard_normal((100, 2)) for centre in CENTRES]
    noise = rng.uniform(-10.0, 16.0, size=(outliers, 2))
    return np.concatenate(blobs + [noise]), np.array([blob.mean(axis=0) for blob in blobs])


def _worst_centre_error(found: np.ndarray, truth: np.ndarray) -> float:
    return float(np.linalg.norm(truth[:, None, :] - found[None, :, :], axis=2).min(axis=1).max())


def _main_centres(result, n: int = 3) -> np.ndarray:
    """The n centres with the most inputs; MDL may add a node for a clump of outliers."""
    sizes = np.bincount(result.assignment, minlength=len(result.centres))
    return result.centres[np.argsort(sizes)[::-1][:n]]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_recovers_three_centres_despite_outliers(seed: int) -> None:
    """The three blobs' centres, whatever else MDL keeps. MDL stops at exactly 3 nodes on only about
    two seeds in three (on seeds 1000-1199: 3 nodes 137 times, 4 61 times, 5 twice; 2026-12-06); the
    extra nodes hold a clump of outliers. All four conditions held on 150 of 150 other seeds (2000-2149)."""
    points, truth = _blobs(seed, outliers=20)
    result = robust_growing_neural_gas(points, seed=seed)
    assert len(result.centres) in (3, 4, 5), f"MDL chose {len(result.centres)} clusters: {result.mdl_by_stage}"
    sizes = np.sort(np.bincount(result.assignment, minlength=len(result.centres)))[::-1]
    assert sizes[3:].sum() < 20  # an extra node, if any, holds outliers only
    assert _worst_centre_error(_main_centres(result), truth) < 0.6 * SPREAD
    assert result.outliers.sum() >= 5  # the farthest outliers are coded raw by the MDL test


def test_outliers_barely_move_the_centres_where_kmeans_breaks() -> None:
    clean, truth = _blobs(5, outliers=0)
    noisy, _ = _blobs(5, outliers=20)
    robust = robust_growing_neural_gas(noisy, seed=0)
    assert len(robust.centres) in (3, 4)
    extra = np.bincount(robust.assignment, minlength=len(robust.centres))
    assert np.sort(extra)[::-1][3:].sum() < 20  # an extra node, if any, holds outliers only
    assert _worst_centre_error(_main_centres(robust), truth) < 0.6 * SPREAD
    # Without outliers all the nodes are blob centres; 0.6 x SPREAD held on 447 of 500 seeds, 1.1 x on all.
    assert _worst_centre_error(robust_growing_neural_gas(clean, seed=0).centres, truth) < 1.1 * SPREAD
    kmeans = [
        _worst_centre_error(kmeans2(noisy, 3, minit="++", seed=np.random.default_rng(s))[0], truth) for s in range(5)
    ]
    # k-means is dragged by the outliers at best (0.48 here) and spends a centre on them at worst
    assert min(kmeans) > _worst_centre_error(_main_centres(robust), truth) + 0.1
    assert max(kmeans) > 2.0


def test_same_seed_same_result_and_input_untouched() -> None:
    points, _ = _blobs(3, outliers=10)
    before = points.copy()
    first = robust_growing_neural_gas(points, seed=7)
    second = robust_growing_neural_gas(points, seed=7)
    np.testing.assert_array_equal(first.centres, second.centres)
    np.testing.assert_array_equal(first.assignment, second.assignment)
    np.testing.assert_array_equal(points, before)


def test_assignment_is_nearest_centre() -> None:
    points, _ = _blobs(4, outliers=5)
    result = robust_growing_neural_gas(points, seed=0)
    nearest = np.linalg.norm(points[:, None] - result.centres[None], axis=2).argmin(axis=1)
    np.testing.assert_array_equal(result.assignment, nearest)


def test_degenerate_and_bad_input() -> None:
    same = np.ones((5, 2))
    result = robust_growing_neural_gas(same, seed=0)
    np.testing.assert_array_equal(result.centres, [[1.0, 1.0]])
    with pytest.raises(InvalidInputError, match="rgng.points"):
        robust_growing_neural_gas(np.array([[0.0, np.nan], [1.0, 1.0]]))
    with pytest.raises(InvalidInputError, match="rgng.points"):
        robust_growing_neural_gas(np.zeros(4))
    with pytest.raises(InvalidInputError, match="rgng.max_nodes"):
        RGNGParameters(max_nodes=1)
