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


def _finite_array(values: object, field: str, ndim: int, dtype: type = np.float64) -> np.ndarray:
    try:
        array: np.ndarray = np.asarray(values, dtype=dtype)
    except (TypeError, ValueError) as error:
        raise InvalidInputError(field, f"must be numeric ({error})") from None
    if array.ndim != ndim:
        raise InvalidInputError(field, f"must have {ndim} dimension(s), got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        raise InvalidInputError(field, "contains NaN or infinite values")
    return array


@dataclass(frozen=True)
class PointCloud:
    """A Kinect-like snapshot of one object: ``points`` is an (n, 3) array in metres."""

    points: np.ndarray

    def __post_init__(self) -> None:
        points = _finite_array(self.points, "point_cloud.points", 2)
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
        samples = _finite_array(self.samples, "audio.samples", 1, np.float32)
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
        haptic = _finite_array(self.haptic, "finger.haptic", 1)
        proprioceptive = _finite_array(self.proprioceptive, "finger.proprioceptive", 1)
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
