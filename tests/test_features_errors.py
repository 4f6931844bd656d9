"""Bad input to feature extraction is an InvalidInputError naming the field and the problem."""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import InvalidInputError
from core.features.extract import (
    NEIGHBOURS,
    audio_features,
    effect_features,
    entity_features,
    recording_features,
    surface_estimate,
    visual_features,
)
from core.payloads import Audio, FingerSeries, Interaction, ObjectRecording, PointCloud
from tests.test_features_geometry import sphere_points

GOOD = sphere_points(np.random.default_rng(0), 500)


def _tamper(payload: object, **fields: object) -> object:
    """Change a validated (frozen) payload behind its constructor's back, as mutable arrays allow."""
    for name, value in fields.items():
        object.__setattr__(payload, name, value)
    return payload


@pytest.mark.parametrize(
    ("points", "message"),
    [
        (GOOD[: NEIGHBOURS - 1], rf"cloud.points: has {NEIGHBOURS - 1} points; the local surface fit needs at least"),
        (np.outer(np.linspace(0, 1, 100), [1.0, 2.0, 3.0]), "cloud.points: points are collinear"),
        (np.tile([0.1, 0.2, 0.3], (100, 1)), "cloud.points: all points coincide"),
        (np.where(np.arange(500)[:, None] == 7, np.nan, GOOD), "cloud.points: contains NaN or infinite values"),
        (GOOD[:, :2], r"cloud.points: must be \(n, 3\) xyz rows"),
        (GOOD.ravel(), r"cloud.points: must have 2 dimension\(s\)"),
        (np.empty((0, 3)), "cloud.points: is empty"),
        ([["a", "b", "c"]] * 30, "cloud.points: must be numeric"),
        # Finite but squared past float64 in the surface fit: LinAlgError, a 500 at the service.
        (
            GOOD / np.abs(GOOD).max() * 1e200,
            r"cloud.points: values must lie within ±1,000 m, got one of magnitude 1e\+200 m",
        ),
        (GOOD + 1_001.0, r"cloud.points: values must lie within ±1,000 m, got one of magnitude 1e\+03 m"),
    ],
)
def test_bad_clouds_name_the_cloud_field(points: object, message: str) -> None:
    with pytest.raises(InvalidInputError, match=message):
        visual_features(points)


def test_a_payload_tampered_with_after_validation_is_checked_again() -> None:
    look = PointCloud(GOOD.copy())
    look.points[3, 1] = np.inf
    with pytest.raises(InvalidInputError, match="look.points: contains NaN or infinite values"):
        entity_features(look)


def test_effect_errors_say_which_snapshot_is_bad() -> None:
    with pytest.raises(InvalidInputError, match="after.points: points are collinear"):
        effect_features(GOOD, np.outer(np.linspace(0, 1, 50), [1.0, 0.0, 0.0]))
    with pytest.raises(InvalidInputError, match="before.points: has 3 points"):
        effect_features(GOOD[:3], GOOD)


def test_bad_audio_names_the_audio_field() -> None:
    second = np.zeros(16_000)
    with pytest.raises(InvalidInputError, match=r"audio.samples: is empty \(zero-length audio\)"):
        audio_features(_tamper(Audio(second, 16_000), samples=np.zeros(0, np.float32)))
    with pytest.raises(InvalidInputError, match=r"audio.sample_rate: 5 Hz is outside \[4000, 192000\]"):
        audio_features(_tamper(Audio(second, 16_000), sample_rate=5))
    with pytest.raises(InvalidInputError, match="audio.samples: contains NaN"):
        audio_features(_tamper(Audio(second, 16_000), samples=np.full(16_000, np.nan, np.float32)))
    with pytest.raises(InvalidInputError, match="audio.samples: 100 samples are shorter than one 400-sample"):
        audio_features(Audio(second[:100], 16_000))
    with pytest.raises(InvalidInputError, match="audio: must be an Audio payload or None, got ndarray"):
        entity_features(GOOD, audio=second)


def test_bad_finger_series_name_the_finger_field() -> None:
    finger = FingerSeries(np.arange(10.0), np.arange(10.0))
    with pytest.raises(
        InvalidInputError, match="finger.proprioceptive: length 5 does not match finger.haptic length 10"
    ):
        entity_features(GOOD, finger=_tamper(finger, proprioceptive=np.arange(5.0)))
    with pytest.raises(InvalidInputError, match="finger: must be a FingerSeries payload or None, got tuple"):
        entity_features(GOOD, finger=(np.arange(10.0), np.arange(10.0)))


def test_bad_recordings_name_the_interaction() -> None:
    cloud = PointCloud(GOOD)
    flat_line = PointCloud(np.outer(np.linspace(0, 1, 50), [0.0, 1.0, 0.0]))
    broken = ObjectRecording(look=cloud, interactions=(Interaction("grasp", cloud, flat_line),))
    with pytest.raises(InvalidInputError, match=r"recording.interactions\[0\].after.points: points are collinear"):
        recording_features(broken)
    twice = ObjectRecording(look=cloud, interactions=(Interaction("drop", cloud, cloud),) * 2)
    with pytest.raises(InvalidInputError, match=r"recording.interactions\[1\].behaviour: 'drop' was already applied"):
        recording_features(twice)
    with pytest.raises(InvalidInputError, match="recording: must be an ObjectRecording, got dict"):
        recording_features({"look": cloud})


def test_a_neighbourhood_too_small_for_the_jet_is_refused() -> None:
    with pytest.raises(InvalidInputError, match="neighbours: must be an integer >= 10, got 5"):
        surface_estimate(GOOD, neighbours=5)


def test_recording_features_gives_the_entity_and_one_effect_per_behaviour() -> None:
    cloud = PointCloud(GOOD)
    moved = PointCloud(GOOD + np.array([0.0, 0.1, 0.0]))
    audio = Audio(np.zeros(16_000), 16_000)
    finger = FingerSeries(np.arange(10.0), np.linspace(0, 1, 10))
    recording = ObjectRecording(
        look=cloud,
        interactions=(
            Interaction("grasp", cloud, cloud, finger=finger),
            Interaction("push forward", cloud, moved),
            Interaction("shake", cloud, cloud, audio=audio),
        ),
    )
    entity, effects = recording_features(recording)
    np.testing.assert_array_equal(entity, entity_features(cloud, audio, finger))
    assert list(effects) == ["grasp", "push forward", "shake"]
    np.testing.assert_array_equal(effects["push forward"], effect_features(cloud, moved))
    assert not effects["grasp"].any()


def test_magnitudes_past_what_the_features_can_square_are_refused_on_the_payloads_field() -> None:
    """The bounds of core.payloads: far beyond a real sensor's range, far inside float overflow.
    Audio of 1e20 overflowed the spectrum's float32 power, and the error named no request field."""
    cloud_on_the_bound = GOOD / np.abs(GOOD).max() * 1_000.0
    assert np.all(np.isfinite(visual_features(cloud_on_the_bound)))
    loud = np.sin(np.arange(16_000) / 3.0)
    assert np.all(np.isfinite(audio_features(Audio(loud * 2.0**31, 16_000))))  # 32-bit integer PCM is read
    with pytest.raises(
        InvalidInputError, match=r"audio.samples: values must lie within ±2,147,483,648, got one of magnitude 1e\+20"
    ):
        Audio(loud * 1e20, 16_000)
    with pytest.raises(
        InvalidInputError, match=r"audio.samples: values must lie within ±2,147,483,648, got one of magnitude 1e\+300"
    ):
        Audio(loud * 1e300, 16_000)  # past float32 too: checked before the conversion
    with pytest.raises(
        InvalidInputError, match=r"finger.haptic: values must lie within ±1,000,000,000, got one of magnitude 1e\+160"
    ):
        FingerSeries(np.linspace(0.0, 1e160, 50), np.zeros(50))
    with pytest.raises(InvalidInputError, match=r"finger.proprioceptive: values must lie within ±1,000,000,000"):
        FingerSeries(np.zeros(50), np.full(50, -2e9))
