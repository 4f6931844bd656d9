"""Raw sensor payloads, as an iCub (or any robot) bridge sends them (§II-C).

Units and frames: point clouds are in metres in the robot's table frame
(x to the robot's right, y forward away from the robot, z up, origin on the
table surface in front of the robot); audio is mono PCM in [-1, 1] with its
sample rate in Hz; finger series are the index finger's haptic (tactile
pressure, arbitrary sensor units) and proprioceptive (joint angle, radians)
readings sampled at the same instants during a grasp.

Constructors validate and raise :class:`core.errors.InvalidInputError` naming
the field, so nothing downstream meets a malformed array.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.errors import InvalidInputError

MIN_SAMPLE_RATE = 4_000
MAX_SAMPLE_RATE = 192_000

# Bounds on a payload's magnitudes. The features square what they are given (a cloud's
# covariance, a spectrum's power), so a finite value far enough out made them overflow:
# coordinates of ~1e160 m failed the surface fit's eigen-solver (a 500), and audio samples of
# 1e20 overflowed the spectrum's float32 power into a 422 on no field of the request. Each bound
# is far beyond any real sensor's range and far inside where the squares overflow.
MAX_COORDINATE_METRES = 1_000.0
"""A point's largest coordinate in the table frame: no robot's depth sensor sees a kilometre."""
MAX_AUDIO_MAGNITUDE = 2.0**31
"""PCM lies in [-1, 1]; integer PCM, up to 32 bits, is read as it is (the MFCC ranges of e_a do not
depend on a constant gain). The spectrum's float32 power overflows beyond ≈ 1e15."""
MAX_FINGER_MAGNITUDE = 1e9
"""A finger reading's largest magnitude: tactile pressure in sensor units, joint angle in radians."""


def _finite_array(
    values: object, field: str, ndim: int, dtype: type = np.float64, *, limit: float, unit: str = ""
) -> np.ndarray:
    """``values`` as an ``ndim``-dimensional array of ``dtype``, every value finite and at most
    ``limit`` (in ``unit``) in magnitude; otherwise an :class:`InvalidInputError` on ``field``."""
    try:
        array: np.ndarray = np.asarray(values, dtype=np.float64)  # checked before a narrower dtype could overflow
    except (TypeError, ValueError) as error:
        raise InvalidInputError(field, f"must be numeric ({error})") from None
    if array.ndim != ndim:
        raise InvalidInputError(field, f"must have {ndim} dimension(s), got shape {array.shape}")
    peak = float(np.abs(array).max(initial=0.0))  # one pass: NaN and infinity carry into the peak
    if not np.isfinite(peak):
        raise InvalidInputError(field, "contains NaN or infinite values")
    if peak > limit:
        raise InvalidInputError(
            field, f"values must lie within ±{limit:,.0f}{unit}, got one of magnitude {peak:.3g}{unit}"
        )
    return array if dtype is np.float64 else array.astype(dtype)


@dataclass(frozen=True)
class PointCloud:
    """A Kinect-like snapshot of one object: ``points`` is an (n, 3) array in metres."""

    points: np.ndarray

    def __post_init__(self) -> None:
        points = _finite_array(self.points, "point_cloud.points", 2, limit=MAX_COORDINATE_METRES, unit=" m")
        if points.shape[1] != 3:
            raise InvalidInputError("point_cloud.points", f"must be (n, 3) xyz rows, got shape {points.shape}")
        if points.shape[0] == 0:
            raise InvalidInputError("point_cloud.points", "is empty")
        object.__setattr__(self, "points", points)


@dataclass(frozen=True)
class Audio:
    """Mono PCM ``samples`` in [-1, 1] at ``sample_rate`` Hz (recorded while shaking)."""

    samples: np.ndarray
    sample_rate: int

    def __post_init__(self) -> None:
        samples = _finite_array(self.samples, "audio.samples", 1, np.float32, limit=MAX_AUDIO_MAGNITUDE)
        if samples.size == 0:
            raise InvalidInputError("audio.samples", "is empty (zero-length audio)")
        if not (MIN_SAMPLE_RATE <= int(self.sample_rate) <= MAX_SAMPLE_RATE):
            raise InvalidInputError(
                "audio.sample_rate", f"{self.sample_rate} Hz is outside [{MIN_SAMPLE_RATE}, {MAX_SAMPLE_RATE}]"
            )
        object.__setattr__(self, "samples", samples)
        object.__setattr__(self, "sample_rate", int(self.sample_rate))


@dataclass(frozen=True)
class FingerSeries:
    """Index-finger ``haptic`` and ``proprioceptive`` readings during a grasp, same length."""

    haptic: np.ndarray
    proprioceptive: np.ndarray

    def __post_init__(self) -> None:
        haptic = _finite_array(self.haptic, "finger.haptic", 1, limit=MAX_FINGER_MAGNITUDE)
        proprioceptive = _finite_array(self.proprioceptive, "finger.proprioceptive", 1, limit=MAX_FINGER_MAGNITUDE)
        if haptic.size < 2:
            raise InvalidInputError("finger.haptic", "needs at least 2 samples")
        if haptic.shape != proprioceptive.shape:
            raise InvalidInputError(
                "finger.proprioceptive",
                f"length {proprioceptive.size} does not match finger.haptic length {haptic.size}",
            )
        object.__setattr__(self, "haptic", haptic)
        object.__setattr__(self, "proprioceptive", proprioceptive)


@dataclass(frozen=True)
class Interaction:
    """One behaviour applied to one object: the clouds before and after, plus the
    audio (shake) and finger series (grasp) when that behaviour records them."""

    behaviour: str
    before: PointCloud
    after: PointCloud
    audio: Audio | None = None
    finger: FingerSeries | None = None


@dataclass(frozen=True)
class ObjectRecording:
    """Everything the robot sensed of one object: the initial look and each interaction.

    ``look`` is the first snapshot (e_v); the audio and finger features of e come
    from the interactions that record them.
    """

    look: PointCloud
    interactions: tuple[Interaction, ...]

    @property
    def audio(self) -> Audio | None:
        return next((i.audio for i in self.interactions if i.audio is not None), None)

    @property
    def finger(self) -> FingerSeries | None:
        return next((i.finger for i in self.interactions if i.finger is not None), None)
