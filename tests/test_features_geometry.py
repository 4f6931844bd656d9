"""Visual features e_v (Table III, 1-66) on analytic shapes whose answers are known."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from bench.bench_features import numpy_local_surfaces
from core.features import EFFECT_LAYOUT, HISTOGRAM_BINS
from core.features._kernels import local_surfaces
from core.features.extract import (
    NEIGHBOURS,
    effect_features,
    planar_f_thresholds,
    surface_estimate,
    visual_features,
)
from core.payloads import PointCloud


def sphere_points(rng: np.random.Generator, count: int, radius: float = 0.05, centre=(0.0, 0.5, 0.1)) -> np.ndarray:
    """Uniform samples of a sphere's surface."""
    directions = rng.normal(size=(count, 3))
    return np.asarray(centre) + radius * directions / np.linalg.norm(directions, axis=1, keepdims=True)


def cylinder_points(rng: np.random.Generator, count: int, radius: float = 0.03, length: float = 0.4) -> np.ndarray:
    """The open lateral surface of an upright cylinder (no caps)."""
    angle = rng.uniform(-np.pi, np.pi, count)
    return np.column_stack([radius * np.cos(angle), radius * np.sin(angle), rng.uniform(0.0, length, count)])


def box_points(rng: np.random.Generator, count: int, size=(0.1, 0.2, 0.3)) -> np.ndarray:
    """Uniform samples of an axis-aligned box's six faces, centred on the origin."""
    size = np.asarray(size)
    areas = np.array([size[1] * size[2], size[0] * size[2], size[0] * size[1]])
    face_axis = rng.choice(3, count, p=areas / areas.sum())
    points = rng.uniform(-0.5, 0.5, (count, 3)) * size
    points[np.arange(count), face_axis] = rng.choice([-0.5, 0.5], count) * size[face_axis]
    return points


def block(vector: np.ndarray, name: str) -> np.ndarray:
    return vector[EFFECT_LAYOUT[name]]


def test_surface_kernel_matches_the_numpy_reference_on_a_noisy_ellipsoid_and_plane() -> None:
    rng = np.random.default_rng(1)
    ellipsoid = sphere_points(rng, 600, radius=1.0, centre=(0, 0, 0)) * np.array([0.05, 0.04, 0.03])
    table = np.column_stack([rng.uniform(-0.1, 0.1, (300, 2)), np.full(300, -0.05)])
    points = np.concatenate([ellipsoid, table]) + rng.normal(0.0, 0.001, (900, 3))
    _, neighbours = cKDTree(points).query(points, k=NEIGHBOURS)
    centroid = points.mean(axis=0)
    f_critical = planar_f_thresholds(NEIGHBOURS)
    normals, curvatures, radii, planar = local_surfaces(points, neighbours, centroid, 0.0, f_critical, 0.0)
    reference = numpy_local_surfaces(points, neighbours, centroid, f_critical)
    np.testing.assert_allclose(normals, reference[0], atol=1e-8)
    np.testing.assert_allclose(curvatures, reference[1], rtol=1e-6, atol=1e-6 * np.abs(reference[1]).max())
    np.testing.assert_allclose(radii, reference[2], rtol=1e-10)
    np.testing.assert_array_equal(planar, reference[3])
    assert 0.05 < planar.mean() < 0.95  # the comparison exercised both outcomes of the planarity test


def test_sphere_has_curvature_one_over_radius_radial_normals_and_cap_shape_index() -> None:
    rng = np.random.default_rng(2)
    radius, centre = 0.05, np.array([0.0, 0.5, 0.1])
    points = sphere_points(rng, 5000, radius, centre)
    surface = surface_estimate(points)
    radial = (points - centre) / radius
    assert np.percentile(np.sum(surface.normals * radial, axis=1), 1) > 0.999
    np.testing.assert_allclose(np.median(surface.principal_curvatures, axis=0), [1 / radius, 1 / radius], rtol=0.02)
    features = visual_features(points)
    assert block(features, "shape_index")[-1] > 0.97
    np.testing.assert_allclose(block(features, "position"), centre, atol=2e-3)
    np.testing.assert_allclose(block(features, "dimensions"), 2 * radius, rtol=0.01)


def test_sphere_normal_histograms_follow_the_area_of_each_direction_band() -> None:
    points = sphere_points(np.random.default_rng(3), 5000)
    features = visual_features(points)
    edges = np.linspace(0.0, np.pi, HISTOGRAM_BINS + 1)
    band_area = (np.cos(edges[:-1]) - np.cos(edges[1:])) / 2
    np.testing.assert_allclose(block(features, "normal_zenith"), band_area, atol=0.015)
    np.testing.assert_allclose(block(features, "normal_azimuth"), 1 / HISTOGRAM_BINS, atol=0.015)


def test_normals_towards_a_sphere_centre_read_as_a_cup() -> None:
    rng = np.random.default_rng(4)
    points = sphere_points(rng, 3000, radius=0.05, centre=(0, 0, 0))
    cap = points[points[:, 2] > 0.05 * np.cos(np.pi / 6)]
    _, neighbours = cKDTree(cap).query(cap, k=NEIGHBOURS)
    far_above = np.array([0.0, 0.0, 1.0])
    normals, curvatures, _, _ = local_surfaces(cap, neighbours, far_above, 0.0, planar_f_thresholds(NEIGHBOURS), 0.0)
    assert np.all(normals[:, 2] < 0)
    np.testing.assert_allclose(np.median(curvatures, axis=0), [-20.0, -20.0], rtol=0.03)


def test_cylinder_shape_index_sits_on_the_ridge_value() -> None:
    radius = 0.03
    points = cylinder_points(np.random.default_rng(5), 5000, radius)
    surface = surface_estimate(points)
    q1, q2 = np.median(surface.principal_curvatures, axis=0)
    assert q1 == pytest.approx(1 / radius, rel=0.03) and abs(q2) < 0.03 * q1
    np.testing.assert_allclose(np.median(surface.shape_index), 0.5, atol=0.01)
    ridge_bins = block(visual_features(points), "shape_index")[[14, 15]]  # 0.5 is the edge between them
    assert ridge_bins.sum() > 0.9


def test_saddle_is_curved_with_shape_index_zero() -> None:
    rng = np.random.default_rng(6)
    xy = rng.uniform(-0.03, 0.03, (3000, 2))
    points = np.column_stack([xy, (xy[:, 0] ** 2 - xy[:, 1] ** 2) / (2 * 0.05)])
    surface = surface_estimate(points)
    middle = np.all(np.abs(xy) < 0.02, axis=1)
    assert not surface.planar[middle].any()
    assert np.percentile(np.abs(surface.shape_index[middle]), 95) < 0.05


def test_box_normals_fall_in_the_bins_of_its_six_faces_and_extents_are_exact() -> None:
    size = (0.1, 0.2, 0.3)
    features = visual_features(box_points(np.random.default_rng(7), 5000, size))
    width, height, depth = block(features, "dimensions")
    assert (width, depth, height) == pytest.approx(size, abs=1e-12)
    zenith = block(features, "normal_zenith")
    assert zenith[[0, 9, 10, 19]].sum() > 0.85  # up, the horizontal edge at pi/2, down
    azimuth = block(features, "normal_azimuth")
    assert azimuth[[0, 4, 5, 9, 10, 14, 15, 19]].sum() > 0.85  # -x (+-pi), -y, +x (0), +y
    shape_index = block(features, "shape_index")
    assert shape_index[[9, 10]].sum() > 0.6  # the flat faces
    assert shape_index[:9].sum() < 0.05  # a convex box has no concave points


def test_flat_plane_is_a_valid_surface_with_its_planar_points_split_around_zero() -> None:
    rng = np.random.default_rng(8)
    points = np.column_stack([rng.uniform(0, 0.2, (2000, 2)), np.full(2000, 0.01)])
    features = visual_features(points)
    assert block(features, "normal_zenith")[0] == 1.0
    assert block(features, "normal_azimuth").sum() == 0.0  # every normal is vertical: no azimuth
    shape_index = block(features, "shape_index")
    assert shape_index[9] == shape_index[10] == 0.5
    assert block(features, "dimensions")[1] == 0.0


def test_rotating_a_box_a_quarter_turn_swaps_width_and_depth() -> None:
    points = box_points(np.random.default_rng(9), 3000)
    turned = points[:, [1, 0, 2]] * np.array([-1.0, 1.0, 1.0])
    width, height, depth = block(visual_features(points), "dimensions")
    assert block(visual_features(turned), "dimensions") == pytest.approx([depth, height, width], abs=1e-12)


def test_effect_of_a_pure_translation_is_the_translation_and_nothing_else() -> None:
    before = sphere_points(np.random.default_rng(10), 5000)
    shift = np.array([0.1, -0.05, 0.02])
    effect = effect_features(PointCloud(before), PointCloud(before + shift))
    assert effect.shape == (EFFECT_LAYOUT.size,)
    np.testing.assert_allclose(block(effect, "position"), shift, atol=1e-12)
    np.testing.assert_allclose(block(effect, "dimensions"), 0.0, atol=1e-12)
    for name in ("normal_zenith", "normal_azimuth", "shape_index"):
        assert np.abs(block(effect, name)).sum() < 1e-3


def test_same_cloud_same_features_whether_payload_or_array_and_input_untouched() -> None:
    points = cylinder_points(np.random.default_rng(11), 2000)
    snapshot = points.copy()
    first = visual_features(points)
    np.testing.assert_array_equal(first, visual_features(PointCloud(points)))
    np.testing.assert_array_equal(points, snapshot)
    for name in ("normal_zenith", "normal_azimuth", "shape_index"):
        assert block(first, name).sum() == pytest.approx(1.0)
