"""The raw level of a scene object as a robot sends it (§II-C; docs/api.md, raw objects): the one encoder.

Every replay reader (object folders, ROS bags, yarp logs) and the simulator turn the arrays they read
into the request models of :mod:`bridge.models` here, and nowhere else:

* each array is checked against what the service accepts (finite values, whole x, y, z points, at
  least one point or sample, a sample rate in range, haptic and proprioceptive series of one length
  and at least 2 samples), so a replay finds a bad recording before it is sent and can say where it
  was read (a file, a topic and a message time) instead of getting a 422 about a request field;
* each cloud is subsampled to at most ``max_points`` points (uniformly, in the order look, then each
  interaction's before and after: the order of the random draws fixes the body sent);
* arrays travel as base64 of little-endian float32 (:func:`bridge.models.float32_base64`).

The service decodes those bodies (app/schemas/observations.py) into ``core.payloads``, which checks
them again for its own callers; the bridge never imports ``core``. The limits both sides need
(the sample rates) are repeated here, and tests/test_bridge_tools.py pins them to core's, as
bridge/models.py does for the sizes of Table III.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np

from bridge.errors import InvalidRecordingError
from bridge.models import Audio, Finger, Interaction, PointCloud, RawObject

MIN_SAMPLE_RATE = 4_000
MAX_SAMPLE_RATE = 192_000
#: Points kept per cloud: a raw object carries up to 27 clouds, and five objects at the simulator's
#: 5,000 points would exceed the service's 8 MiB body limit (docs/bridge.md).
DEFAULT_MAX_POINTS = 1_500


class CloudLike(Protocol):
    @property
    def points(self) -> np.ndarray: ...


class AudioLike(Protocol):
    @property
    def samples(self) -> np.ndarray: ...

    @property
    def sample_rate(self) -> int: ...


class FingerLike(Protocol):
    @property
    def haptic(self) -> np.ndarray: ...

    @property
    def proprioceptive(self) -> np.ndarray: ...


class InteractionLike(Protocol):
    @property
    def behaviour(self) -> str: ...

    @property
    def before(self) -> CloudLike: ...

    @property
    def after(self) -> CloudLike: ...

    @property
    def audio(self) -> AudioLike | None: ...

    @property
    def finger(self) -> FingerLike | None: ...


class RecordingLike(Protocol):
    """What :func:`raw_object` encodes: the shape of a ``core.payloads.ObjectRecording`` (the simulator's)."""

    @property
    def look(self) -> CloudLike: ...

    @property
    def interactions(self) -> Sequence[InteractionLike]: ...


def checked(values: Any, field: str, ndim: int = 1) -> np.ndarray:
    """``values`` as a finite, non-empty float64 array of ``ndim`` dimensions; else an error naming ``field``."""
    try:
        array = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise InvalidRecordingError(field, f"must be numeric ({error})") from None
    if array.ndim != ndim:
        raise InvalidRecordingError(field, f"must have {ndim} dimension(s), got shape {array.shape}")
    if array.size == 0:
        raise InvalidRecordingError(field, "is empty")
    bad = int(array.size - np.count_nonzero(np.isfinite(array)))
    if bad:
        raise InvalidRecordingError(field, f"contains {bad} NaN or infinite values")
    return array


def cloud(points: Any, rng: np.random.Generator, max_points: int, field: str = "points") -> PointCloud:
    """An (n, 3) cloud in metres, subsampled to at most ``max_points`` points."""
    array = checked(points, field, ndim=2)
    if array.shape[1] != 3:
        raise InvalidRecordingError(field, f"must be (n, 3) xyz rows, got shape {array.shape}")
    return PointCloud.of(subsample(array, rng, max_points))


def audio(samples: Any, sample_rate: int, field: str = "audio") -> Audio:
    """Mono PCM in [-1, 1] at ``sample_rate`` Hz."""
    array = checked(samples, f"{field}.samples")
    if not MIN_SAMPLE_RATE <= int(sample_rate) <= MAX_SAMPLE_RATE:
        raise InvalidRecordingError(
            f"{field}.sample_rate", f"{sample_rate} Hz is outside [{MIN_SAMPLE_RATE}, {MAX_SAMPLE_RATE}]"
        )
    return Audio.of(array, int(sample_rate))


def finger(haptic: Any, proprioceptive: Any, field: str = "finger") -> Finger:
    """The index finger's haptic and proprioceptive (radians) readings at the same instants."""
    touch = checked(haptic, f"{field}.haptic")
    angle = checked(proprioceptive, f"{field}.proprioceptive")
    if touch.size < 2:
        raise InvalidRecordingError(f"{field}.haptic", f"needs at least 2 samples, has {touch.size}")
    if touch.shape != angle.shape:
        raise InvalidRecordingError(
            f"{field}.proprioceptive", f"length {angle.size} does not match {field}.haptic length {touch.size}"
        )
    return Finger.of(touch, angle)


def subsample(points: np.ndarray, rng: np.random.Generator, max_points: int) -> np.ndarray:
    """A uniform random subset: keeps the histograms' shapes (they are normalised) at a fraction of the bytes."""
    if len(points) <= max_points:
        return points
    return points[np.sort(rng.choice(len(points), size=max_points, replace=False))]


def raw_object(recording: RecordingLike, rng: np.random.Generator, max_points: int) -> RawObject:
    """The raw payload of a whole recording (the simulator's ``core.payloads.ObjectRecording``)."""
    look = cloud(recording.look.points, rng, max_points, "look.points")
    interactions = []
    for index, interaction in enumerate(recording.interactions):
        field = f"interactions[{index}]"
        interactions.append(
            Interaction(
                behaviour=interaction.behaviour,
                before=cloud(interaction.before.points, rng, max_points, f"{field}.before.points"),
                after=cloud(interaction.after.points, rng, max_points, f"{field}.after.points"),
                audio=None
                if interaction.audio is None
                else audio(interaction.audio.samples, interaction.audio.sample_rate, f"{field}.audio"),
                finger=None
                if interaction.finger is None
                else finger(interaction.finger.haptic, interaction.finger.proprioceptive, f"{field}.finger"),
            )
        )
    return RawObject(look=look, interactions=interactions)
