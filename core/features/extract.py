"""Sensor payloads to the feature vectors of Table III (§II-C).

``entity_features`` gives e = (e_v, e_a, e_h, e_p) (91 dims, :data:`ENTITY_LAYOUT`),
``effect_features`` gives f = e'_v - e_v (66 dims, :data:`EFFECT_LAYOUT`), and
``recording_features`` does both for everything the robot sensed of one object.
Every block is filled by name from the layout, never by a hard-coded index.

The choices the paper leaves open, each with its reason (docs/features.md has the
long form):

- position is the centroid; dimensions are the axis-aligned extents in the table
  frame, width = x, depth = y, height = z, because "tall" and "knock down" are about
  the vertical extent, which an oriented (PCA) box would rotate away;
- normals come from local PCA over the ``NEIGHBOURS`` nearest points (scipy's cKDTree)
  and point away from the cloud centroid (an exactly planar cloud has no "away": its
  normals point up);
- principal curvatures come from a degree-2 jet ``z = ax^2 + bxy + cy^2 + dx + ey + f``
  fitted in the PCA tangent frame (a numba kernel, :mod:`core.features._kernels`).
  The linear and constant terms absorb the tilt and offset of the PCA plane at
  one-sided neighbourhoods (scan borders, box edges), which the pure quadric would
  read as curvature. The jet fits the neighbours' positions and also the slopes of
  their normals, each kind weighted by the inverse of its own residual variance:
  on clean data the exact positions dominate, and under Kinect-like noise (1-2 mm
  on a 2-3 mm point spacing) the normals, each already averaged over its own
  neighbourhood, still resolve a 4 cm ball where positions alone cannot;
- the shape index is Koenderink's normalised S = (2/pi) arctan((Q1+Q2)/(Q1-Q2)) in
  [-1, 1] (the paper's bare ratio is unbounded, so a fixed-range histogram of it is
  impossible); convex is positive: a sphere is +1 (cap), a cylinder +0.5 (ridge),
  concave ones (normals towards the centre of curvature) -1 (cup) and -0.5 (rut),
  a saddle 0;
- a point is planar when the jet's quadratic terms do not beat a plane, by an F test
  (nominal level ``PLANAR_TEST_LEVEL``; that adapts to the sensor noise and not to
  the point density), or when its curvature is zero to rounding error. A planar
  point has no shape index (0/0); it counts half in each of the two bins either
  side of S = 0, so the histogram still sums to 1, keeps the flat fraction as a
  feature, and mirrors exactly when the normals are flipped;
- histograms use fixed ranges (zenith [0, pi], azimuth [-pi, pi], shape index
  [-1, 1]), ``HISTOGRAM_BINS`` equal bins, a value on an inner edge going to the
  upper bin, and sum to 1; the azimuth histogram weights each normal by its
  horizontal length sin(zenith), since the azimuth of a near-vertical normal (a
  box's top face) is noise; if every normal is vertical it is all zeros;
- MFCC with librosa (maintained): 25 ms Hann windows, 10 ms hop, 40 mel bands,
  dB with librosa's defaults, DCT-II by librosa.feature.mfcc; no edge padding
  (padded edge frames would register the recording's start and end as sound onset
  and offset, so any sound would show a large range). The mel projection, which
  librosa.feature.mfcc(y=...) does with a BLAS product, is a plain einsum here:
  the same numbers, but no BLAS thread pool, which stalls when the cores are busy
  (docs/benchmarks.md);
- finger statistics: change = last - first, min, max, mean, population variance
  (ddof = 0) and its square root;
- a missing modality (``audio`` or ``finger`` is None: the behaviour that records
  it was not applied) leaves its block at zeros, the value of "no signal": a
  silent recording also has MFCC ranges of 0.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import cast

import librosa
import numpy as np
import scipy.special
from numpy.typing import ArrayLike
from scipy.spatial import cKDTree

from core.errors import InvalidInputError
from core.features._kernels import local_surfaces
from core.features.layout import (
    EFFECT_LAYOUT,
    EFFECT_SIZE,
    ENTITY_LAYOUT,
    ENTITY_SIZE,
    FINGER_STATISTICS,
    HISTOGRAM_BINS,
    MFCC_COEFFICIENTS,
    VISUAL,
)
from core.payloads import Audio, FingerSeries, ObjectRecording, PointCloud

#: k of the k-nearest-neighbour surface fit (the point itself included): enough
#: points for a well-posed 6-term jet, few enough to stay local on a 5,000-point cloud.
NEIGHBOURS = 20
#: The jet has 6 unknowns; 4 more points leave the planarity test 4 residual degrees of freedom.
MIN_NEIGHBOURS = 10
#: Nominal level of the planarity test: a point is curved when its jet's quadratic terms
#: beat the plane with F above the (1 - level) quantile of F(3, dof). Nominal, because
#: the residuals of overlapping neighbourhoods are correlated and the weights estimated:
#: chosen so that >= 90% of a plane with 0.5-3 mm noise is planar (measured: 91-97%).
PLANAR_TEST_LEVEL = 1e-6
#: Below this curvedness x neighbourhood radius a point is flat to rounding error
#: (an exact plane), whatever the F test says about residuals of ~1e-17.
NUMERICALLY_FLAT = 1e-6
#: A cloud whose second principal spread is below this fraction of its first is a
#: line: its normals are undefined (an error, unlike a plane, which is a valid surface).
COLLINEAR_SPREAD = 1e-6
#: Spreads below this fraction of the coordinates' magnitude (a cloud) or of the
#: cloud's spread (a neighbourhood) are rounding error: the points coincide. A
#: coincident cloud is an error; a coincident neighbourhood keeps a PCA normal but
#: gets zero curvature (counted as planar).
COINCIDENT_SPREAD = 1e-9

#: A normal whose horizontal length is below this is vertical to rounding error.
_NUMERICALLY_VERTICAL = 1e-9

ZENITH_RANGE = (0.0, np.pi)
AZIMUTH_RANGE = (-np.pi, np.pi)
SHAPE_INDEX_RANGE = (-1.0, 1.0)

AUDIO_WINDOW_SECONDS = 0.025
AUDIO_HOP_SECONDS = 0.010
MEL_BANDS = 40

_DIMENSION_AXIS = {"width": 0, "depth": 1, "height": 2}
_DIMENSION_ORDER = [
    _DIMENSION_AXIS[name.split(".", 1)[1]] for name in EFFECT_LAYOUT.feature_names[EFFECT_LAYOUT["dimensions"]]
]

_FINGER_STATISTIC: dict[str, Callable[[np.ndarray], float]] = {
    "change": lambda series: series[-1] - series[0],
    "min": np.min,
    "max": np.max,
    "mean": np.mean,
    "variance": np.var,
    "std": np.std,
}


@dataclass(frozen=True)
class SurfaceEstimate:
    """Per-point local surface of a cloud: outward unit ``normals`` (n, 3), principal
    curvatures ``(Q1, Q2)`` (n, 2) with Q1 >= Q2 in 1/metre (convex positive), the RMS
    tangent radius (metres) of each point's neighbourhood, and whether it is ``planar``
    (its bending is not significant against the fit's noise, or is zero)."""

    normals: np.ndarray
    principal_curvatures: np.ndarray
    neighbourhood_radius: np.ndarray
    planar: np.ndarray

    @property
    def shape_index(self) -> np.ndarray:
        """Koenderink's S = (2/pi) arctan((Q1+Q2)/(Q1-Q2)) in [-1, 1]; 0 where planar (undefined)."""
        q1, q2 = self.principal_curvatures.T
        return np.where(self.planar, 0.0, (2.0 / np.pi) * np.arctan2(q1 + q2, q1 - q2))


def surface_estimate(cloud: PointCloud | ArrayLike, neighbours: int = NEIGHBOURS) -> SurfaceEstimate:
    """Normals and principal curvatures of every point, from its ``neighbours`` nearest points."""
    return _surface(_checked_points(cloud, "cloud.points"), neighbours, "cloud.points")


def visual_features(cloud: PointCloud | ArrayLike) -> np.ndarray:
    """e_v (66,): position, dimensions, normal zenith/azimuth and shape-index histograms."""
    return _visual(_checked_points(cloud, "cloud.points"), "cloud.points")


def audio_features(audio: Audio) -> np.ndarray:
    """e_a (13,): per MFCC coefficient, its maximum minus its minimum over the frames."""
    audio = _checked_audio(audio)
    window = round(AUDIO_WINDOW_SECONDS * audio.sample_rate)
    hop = round(AUDIO_HOP_SECONDS * audio.sample_rate)
    if audio.samples.size < window:
        raise InvalidInputError(
            "audio.samples",
            f"{audio.samples.size} samples are shorter than one {window}-sample analysis window "
            f"({AUDIO_WINDOW_SECONDS * 1000:.0f} ms at {audio.sample_rate} Hz)",
        )
    power = np.abs(librosa.stft(audio.samples, n_fft=window, hop_length=hop, center=False)) ** 2
    mel_power = np.einsum("mf,ft->mt", _mel_filters(audio.sample_rate, window), power, optimize=False)
    mfcc = librosa.feature.mfcc(S=librosa.power_to_db(mel_power), n_mfcc=MFCC_COEFFICIENTS)
    return (mfcc.max(axis=1) - mfcc.min(axis=1)).astype(np.float64)


@functools.lru_cache(maxsize=16)
def _mel_filters(sample_rate: int, window: int) -> np.ndarray:
    return librosa.filters.mel(sr=sample_rate, n_fft=window, n_mels=MEL_BANDS)


def finger_statistics(series: np.ndarray) -> np.ndarray:
    """e_h or e_p (6,): change (last - first), min, max, mean, variance, std of one finger series."""
    return np.array([_FINGER_STATISTIC[name](series) for name in FINGER_STATISTICS], dtype=np.float64)


def entity_features(
    look: PointCloud | ArrayLike, audio: Audio | None = None, finger: FingerSeries | None = None
) -> np.ndarray:
    """e = (e_v, e_a, e_h, e_p) (91,); a missing modality (None) leaves its block at zeros."""
    return _entity(_checked_points(look, "look.points"), audio, finger, "look.points")


def effect_features(before: PointCloud | ArrayLike, after: PointCloud | ArrayLike) -> np.ndarray:
    """f = e'_v - e_v (66,): the visual change a behaviour caused (Fig. 5)."""
    return _effect(before, after, "")


def recording_features(recording: ObjectRecording) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """e (91,) of one object and f (66,) of each behaviour applied to it.

    The visual part of e comes from the initial look, audio from the interaction
    that recorded sound (shake) and finger statistics from the one that recorded the
    finger (grasp), as in the data-collection protocol of §II-C.
    """
    if not isinstance(recording, ObjectRecording):
        raise InvalidInputError("recording", f"must be an ObjectRecording, got {type(recording).__name__}")
    entity = _entity(
        _checked_points(recording.look, "recording.look.points"),
        recording.audio,
        recording.finger,
        "recording.look.points",
    )
    effects: dict[str, np.ndarray] = {}
    for position, interaction in enumerate(recording.interactions):
        if interaction.behaviour in effects:
            raise InvalidInputError(
                f"recording.interactions[{position}].behaviour",
                f"{interaction.behaviour!r} was already applied to this object (one interaction per behaviour)",
            )
        effects[interaction.behaviour] = _effect(
            interaction.before, interaction.after, f"recording.interactions[{position}]."
        )
    return entity, effects


def _entity(points: np.ndarray, audio: Audio | None, finger: FingerSeries | None, field: str) -> np.ndarray:
    entity = np.zeros(ENTITY_SIZE)
    entity[VISUAL] = _visual(points, field)
    if audio is not None:
        entity[ENTITY_LAYOUT["mfcc_range"]] = audio_features(audio)
    if finger is not None:
        finger = _checked_finger(finger)
        entity[ENTITY_LAYOUT["haptic"]] = finger_statistics(finger.haptic)
        entity[ENTITY_LAYOUT["proprioceptive"]] = finger_statistics(finger.proprioceptive)
    return entity


def _effect(before: PointCloud | ArrayLike, after: PointCloud | ArrayLike, prefix: str) -> np.ndarray:
    before_field, after_field = f"{prefix}before.points", f"{prefix}after.points"
    initial = _visual(_checked_points(before, before_field), before_field)
    final = _visual(_checked_points(after, after_field), after_field)
    return final - initial


def _visual(points: np.ndarray, field: str) -> np.ndarray:
    surface = _surface(points, NEIGHBOURS, field)
    normals = surface.normals
    visual = np.zeros(EFFECT_SIZE)
    visual[EFFECT_LAYOUT["position"]] = points.mean(axis=0)
    visual[EFFECT_LAYOUT["dimensions"]] = np.ptp(points, axis=0)[_DIMENSION_ORDER]
    visual[EFFECT_LAYOUT["normal_zenith"]] = _histogram(np.arccos(np.clip(normals[:, 2], -1.0, 1.0)), ZENITH_RANGE)
    horizontal = np.hypot(normals[:, 0], normals[:, 1])
    horizontal[horizontal < _NUMERICALLY_VERTICAL] = 0.0
    visual[EFFECT_LAYOUT["normal_azimuth"]] = _histogram(
        np.arctan2(normals[:, 1], normals[:, 0]), AZIMUTH_RANGE, horizontal
    )
    visual[EFFECT_LAYOUT["shape_index"]] = _shape_index_histogram(surface)
    return visual


def _surface(points: np.ndarray, neighbours: int, field: str) -> SurfaceEstimate:
    if isinstance(neighbours, bool) or not isinstance(neighbours, int | np.integer) or neighbours < MIN_NEIGHBOURS:
        raise InvalidInputError("neighbours", f"must be an integer >= {MIN_NEIGHBOURS}, got {neighbours!r}")
    if points.shape[0] < neighbours:
        raise InvalidInputError(
            field,
            f"has {points.shape[0]} points; the local surface fit needs at least {neighbours} (its neighbourhood)",
        )
    centroid = points.mean(axis=0)
    centred = points - centroid
    # einsum, not np.cov: np.cov's BLAS product starts a thread pool, slow on busy shared cores.
    covariance = np.einsum("ni,nj->ij", centred, centred, optimize=False) / len(points)
    spread = np.sqrt(np.clip(np.linalg.eigvalsh(covariance), 0.0, None))
    if spread[2] <= COINCIDENT_SPREAD * float(np.abs(points).max()):
        raise InvalidInputError(field, "all points coincide: there is no surface")
    if spread[1] <= COLLINEAR_SPREAD * spread[2]:
        raise InvalidInputError(field, "points are collinear: surface normals and curvatures are undefined")
    _, nearest = cKDTree(points).query(points, k=neighbours)
    normals, curvatures, radii, planar = local_surfaces(
        points,
        nearest.astype(np.int64, copy=False),
        centroid,
        COINCIDENT_SPREAD * float(spread[2]),
        planar_f_thresholds(neighbours),
        NUMERICALLY_FLAT,
    )
    return SurfaceEstimate(normals, curvatures, radii, planar)


@functools.lru_cache(maxsize=8)
def planar_f_thresholds(neighbours: int) -> np.ndarray:
    """The planarity test's critical values, indexed by dof: (1 - level) quantiles of F(3, dof).

    A jet has 6 unknowns and up to 3 equations per neighbour (a height, two slopes).
    """
    dof = np.arange(3 * neighbours - 5)
    thresholds = np.full(dof.size, np.inf)
    # F's quantile function itself (what scipy.stats.f.ppf calls), without importing scipy.stats
    # (a slow import: docs/benchmarks.md).
    thresholds[1:] = scipy.special.fdtri(3, dof[1:], 1.0 - PLANAR_TEST_LEVEL)
    thresholds.setflags(write=False)
    return thresholds


def _histogram(values: np.ndarray, value_range: tuple[float, float], weights: np.ndarray | None = None) -> np.ndarray:
    """Fixed-range, ``HISTOGRAM_BINS``-bin histogram summing to 1 (all zeros if no weight)."""
    low, high = value_range
    bins = np.clip(((values - low) / (high - low) * HISTOGRAM_BINS).astype(np.int64), 0, HISTOGRAM_BINS - 1)
    counts = np.bincount(bins, weights=weights, minlength=HISTOGRAM_BINS).astype(np.float64)
    total = counts.sum()
    return counts / total if total > 0.0 else counts


def _shape_index_histogram(surface: SurfaceEstimate) -> np.ndarray:
    """Curved points by their shape index; each planar point split between the bins around S = 0."""
    planar = surface.planar
    low, high = SHAPE_INDEX_RANGE
    counts = _histogram(surface.shape_index[~planar], SHAPE_INDEX_RANGE) * np.count_nonzero(~planar)
    zero_position = (0.0 - low) / (high - low) * HISTOGRAM_BINS
    around_zero = {int(np.ceil(zero_position)) - 1, int(np.floor(zero_position))}
    for bin_index in around_zero:
        counts[bin_index] += np.count_nonzero(planar) / len(around_zero)
    return counts / planar.size


def _checked_points(cloud: PointCloud | ArrayLike, field: str) -> np.ndarray:
    """The (n, 3) finite points of a payload or a raw array, re-validated (arrays are mutable)."""
    # PointCloud's __post_init__ converts and validates any array-like; its field then holds the array.
    raw = cloud.points if isinstance(cloud, PointCloud) else cast(np.ndarray, cloud)
    try:
        return PointCloud(raw).points
    except InvalidInputError as error:
        raise InvalidInputError(field, error.problem) from None


def _checked_audio(audio: Audio) -> Audio:
    if not isinstance(audio, Audio):
        raise InvalidInputError("audio", f"must be an Audio payload or None, got {type(audio).__name__}")
    return Audio(audio.samples, audio.sample_rate)


def _checked_finger(finger: FingerSeries) -> FingerSeries:
    if not isinstance(finger, FingerSeries):
        raise InvalidInputError("finger", f"must be a FingerSeries payload or None, got {type(finger).__name__}")
    return FingerSeries(finger.haptic, finger.proprioceptive)
