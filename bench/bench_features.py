"""Speed of Table III feature extraction (``python -m bench.bench_features [--quick]``).

Times, as medians over repeated runs after a warm-up, on a 5,000-point noisy
capped cylinder and 1 s of 16 kHz audio:

- ``entity``: e from one cloud + the audio + a finger series (one look);
- ``interaction``: everything one interaction yields: f from its two clouds, plus
  e_a and the finger statistics;
- the parts: the numba surface kernel, the cKDTree neighbour search, the MFCC.

References measured in the same run, reported as ratios: the same surface estimate
as a plain per-point numpy / np.linalg loop (:func:`numpy_local_surfaces`, also the
tests' correctness reference), and librosa's MFCC alone. Writes
``bench/results/features.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from collections.abc import Callable

import librosa
import numpy as np
from scipy.spatial import cKDTree

from bench import RESULTS
from core.features._kernels import _SLOPE_MIN_COS, _VARIANCE_FLOOR, local_surfaces
from core.features.extract import (
    AUDIO_HOP_SECONDS,
    AUDIO_WINDOW_SECONDS,
    MEL_BANDS,
    NEIGHBOURS,
    NUMERICALLY_FLAT,
    audio_features,
    effect_features,
    entity_features,
    finger_statistics,
    planar_f_thresholds,
)
from core.payloads import Audio, FingerSeries, PointCloud

CLOUD_POINTS = 5_000
SAMPLE_RATE = 16_000
REPEATS = 30
REFERENCE_REPEATS = 3


def numpy_local_surfaces(
    points: np.ndarray, neighbours: np.ndarray, centroid: np.ndarray, f_critical: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The kernel's surface estimate, one point at a time with np.linalg (the reference).

    Same definition, independent route: eigh for the PCA frames, an explicit design
    matrix and row-weighted lstsq for the per-kind fits, the jet and the plane, and the principal curvatures as the
    eigenvalues of the shape operator I^-1 II instead of the kernel's closed-form H and K.
    """
    frames = np.empty((len(points), 3, 3))
    for i, row in enumerate(neighbours):
        _, vectors = np.linalg.eigh(np.cov(points[row], rowvar=False))
        normal = vectors[:, 0] if vectors[:, 0] @ (points[i] - centroid) >= 0 else -vectors[:, 0]
        frames[i] = [vectors[:, 1], vectors[:, 2], normal]
    normals = frames[:, 2].copy()
    curvatures = np.empty((len(points), 2))
    radii = np.empty(len(points))
    planar = np.empty(len(points), dtype=bool)
    for i, row in enumerate(neighbours):
        u, v, h = ((points[row] - points[i]) @ frames[i].T).T
        radii[i] = radius = np.sqrt(np.mean(u * u + v * v))
        u, v, h = u / radius, v / radius, h / radius
        tilt = normals[row] @ frames[i].T
        usable = tilt[:, 2] > _SLOPE_MIN_COS
        slope_u, slope_v = -tilt[usable, 0] / tilt[usable, 2], -tilt[usable, 1] / tilt[usable, 2]
        nought, one, us, vs = np.zeros(usable.sum()), np.ones(usable.sum()), u[usable], v[usable]
        design = np.vstack(
            [
                np.column_stack([u * u, u * v, v * v, u, v, np.ones_like(u)]),
                np.column_stack([2 * us, vs, nought, one, nought, nought]),
                np.column_stack([nought, us, 2 * vs, nought, one, nought]),
            ]
        )
        target = np.concatenate([h, slope_u, slope_v])
        is_height = np.arange(len(target)) < len(h)
        height_fit = np.linalg.lstsq(design[is_height], target[is_height], rcond=None)
        height_variance = np.sum((target[is_height] - design[is_height] @ height_fit[0]) ** 2) / (len(h) - 6)
        slope_variance = np.inf
        if (~is_height).sum() > 5:
            slope_design = design[~is_height, :5]  # the slopes do not involve f
            slope_fit = np.linalg.lstsq(slope_design, target[~is_height], rcond=None)[0]
            slope_variance = np.sum((target[~is_height] - slope_design @ slope_fit) ** 2) / ((~is_height).sum() - 5)
        weight = np.where(is_height, 1 / (height_variance + _VARIANCE_FLOOR), 1 / (slope_variance + _VARIANCE_FLOOR))
        root = np.sqrt(weight)
        jet = np.linalg.lstsq(design * root[:, None], target * root, rcond=None)[0]
        plane = np.linalg.lstsq(design[:, 3:] * root[:, None], target * root, rcond=None)[0]
        jet_rss = np.sum(weight * (target - design @ jet) ** 2)
        plane_rss = np.sum(weight * (target - design[:, 3:] @ plane) ** 2)
        dof = len(target) - 6
        planar[i] = ((plane_rss - jet_rss) / 3) / (jet_rss / dof) <= f_critical[dof]
        a, b, c, d, e, _ = jet
        first_form = np.array([[1 + d * d, d * e], [d * e, 1 + e * e]])
        second_form = np.array([[2 * a, b], [b, 2 * c]]) / np.sqrt(1 + d * d + e * e)
        shape_operator = -np.linalg.solve(first_form, second_form)
        curvatures[i] = np.sort(np.linalg.eigvals(shape_operator).real)[::-1] / radius
    return normals, curvatures, radii, planar


def capped_cylinder(rng: np.random.Generator, count: int, noise: float = 0.001) -> np.ndarray:
    """A 6 cm x 12 cm upright can seen whole (side and top), with Gaussian sensor noise."""
    radius, height = 0.03, 0.12
    on_top = rng.random(count) < radius / (radius + 2 * height)
    angle = rng.uniform(-np.pi, np.pi, count)
    spoke = np.where(on_top, radius * np.sqrt(rng.random(count)), radius)
    z = np.where(on_top, height, rng.uniform(0.0, height, count))
    points = np.column_stack([spoke * np.cos(angle), 0.5 + spoke * np.sin(angle), z])
    return points + rng.normal(0.0, noise, points.shape)


def rattle(rng: np.random.Generator, seconds: float = 1.0) -> np.ndarray:
    """Shaken-object audio: decaying noise bursts four times a second."""
    time_axis = np.arange(int(seconds * SAMPLE_RATE)) / SAMPLE_RATE
    envelope = np.exp(-30.0 * (time_axis % 0.25))
    return (0.5 * envelope * rng.normal(0.0, 1.0, time_axis.size)).clip(-1, 1).astype(np.float32)


def timed_ms(work: Callable[[], object], repeats: int) -> tuple[float, float]:
    """Median and minimum wall time (ms) of ``work`` over ``repeats`` runs after one warm-up run.

    The median is the figure; the minimum shows what an uncontended core gives on a shared machine.
    """
    work()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        work()
        times.append(time.perf_counter() - start)
    return 1e3 * statistics.median(times), 1e3 * min(times)


def main() -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="few repeats (a smoke run, not a measurement)")
    args = parser.parse_args(sys.argv[1:])
    repeats, reference_repeats = (3, 1) if args.quick else (REPEATS, REFERENCE_REPEATS)
    rng = np.random.default_rng(0)
    before = PointCloud(capped_cylinder(rng, CLOUD_POINTS))
    after = PointCloud(before.points + np.array([0.1, 0.0, 0.0]))
    audio = Audio(rattle(rng), SAMPLE_RATE)
    grip = np.linspace(0.0, 1.0, 200)
    finger = FingerSeries(grip**2, 0.8 * grip)
    points = before.points
    centroid = points.mean(axis=0)
    tree = cKDTree(points)
    _, neighbours = tree.query(points, k=NEIGHBOURS)
    f_critical = planar_f_thresholds(NEIGHBOURS)

    def interaction() -> None:
        effect_features(before, after)
        audio_features(audio)
        finger_statistics(finger.haptic)
        finger_statistics(finger.proprioceptive)

    def librosa_mfcc() -> None:
        librosa.feature.mfcc(
            y=audio.samples,
            sr=SAMPLE_RATE,
            n_mfcc=13,
            n_fft=round(AUDIO_WINDOW_SECONDS * SAMPLE_RATE),
            hop_length=round(AUDIO_HOP_SECONDS * SAMPLE_RATE),
            n_mels=MEL_BANDS,
            center=False,
        )

    timings = {
        "entity": timed_ms(lambda: entity_features(before, audio, finger), repeats),
        "interaction": timed_ms(interaction, repeats),
        "surface_kernel": timed_ms(
            lambda: local_surfaces(points, neighbours, centroid, 0.0, f_critical, NUMERICALLY_FLAT), repeats
        ),
        "neighbour_search": timed_ms(lambda: cKDTree(points).query(points, k=NEIGHBOURS), repeats),
        "audio_features": timed_ms(lambda: audio_features(audio), repeats),
        "reference_librosa_mfcc": timed_ms(librosa_mfcc, repeats),
        "reference_numpy_surface": timed_ms(
            lambda: numpy_local_surfaces(points, neighbours, centroid, f_critical), reference_repeats
        ),
    }
    medians = {name: median for name, (median, _) in timings.items()}
    ratios = {
        "numpy_surface_over_kernel": medians["reference_numpy_surface"] / medians["surface_kernel"],
        "audio_features_over_librosa": medians["audio_features"] / medians["reference_librosa_mfcc"],
        "neighbour_search_share_of_entity": medians["neighbour_search"] / medians["entity"],
    }
    result = {
        "cloud_points": CLOUD_POINTS,
        "audio_seconds": 1.0,
        "sample_rate": SAMPLE_RATE,
        "neighbours": NEIGHBOURS,
        "repeats": repeats,
        "reference_repeats": reference_repeats,
        "cpu_count": os.cpu_count(),
        "load_average_1min": os.getloadavg()[0],
        "median_ms": medians,
        "min_ms": {name: minimum for name, (_, minimum) in timings.items()},
        "ratios": ratios,
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "features.json").write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    for name, (median, minimum) in timings.items():
        print(f"{name:>26}: {median:9.2f} ms median, {minimum:9.2f} ms min")
    for name, value in ratios.items():
        print(f"{name:>34}: {value:9.2f}x")
    return result


if __name__ == "__main__":
    main()
