"""Audio e_a, haptic e_h and proprioceptive e_p features (Table III, 67-91), and the entity vector e."""

from __future__ import annotations

import librosa
import numpy as np
import pytest

from core.features import ENTITY_LAYOUT, ENTITY_SIZE, FINGER_STATISTICS, VISUAL
from core.features.extract import audio_features, entity_features, finger_statistics, visual_features
from core.payloads import Audio, FingerSeries
from tests.test_features_geometry import sphere_points

RATE = 16_000
SECOND = np.arange(RATE) / RATE


def tone(hz: float = 443.7, amplitude: float = 0.5) -> np.ndarray:
    """A pure tone whose period does not divide the analysis window (so frames differ in phase)."""
    return amplitude * np.sin(2 * np.pi * hz * SECOND)


def test_silence_has_zero_mfcc_ranges() -> None:
    assert np.array_equal(audio_features(Audio(np.zeros(RATE), RATE)), np.zeros(13))


def test_a_steady_tone_varies_little_but_one_switching_on_halfway_varies_a_lot() -> None:
    steady = audio_features(Audio(tone(), RATE))
    switching = audio_features(Audio(np.where(SECOND >= 0.5, tone(), 0.0), RATE))
    assert steady.shape == (13,)
    assert steady.max() < 3.0  # only the phase of the tone within each window changes
    assert switching[0] > 100.0  # the energy coefficient jumps from the silence floor to the tone
    assert np.all(switching >= steady)


def test_mfcc_ranges_equal_librosa_one_call_mfcc() -> None:
    samples = np.random.default_rng(0).normal(0, 0.1, RATE).astype(np.float32) * (SECOND < 0.3)
    reference = librosa.feature.mfcc(y=samples, sr=RATE, n_mfcc=13, n_fft=400, hop_length=160, n_mels=40, center=False)
    np.testing.assert_allclose(audio_features(Audio(samples, RATE)), np.ptp(reference, axis=1), rtol=1e-4, atol=1e-3)


def test_a_linear_ramp_gives_the_exact_six_statistics() -> None:
    ramp = np.arange(10.0)  # 0, 1, ..., 9
    expected = {"change": 9.0, "min": 0.0, "max": 9.0, "mean": 4.5, "variance": 8.25, "std": np.sqrt(8.25)}
    assert finger_statistics(ramp) == pytest.approx([expected[name] for name in FINGER_STATISTICS], rel=1e-12)


def test_entity_vector_puts_each_modality_in_its_named_block() -> None:
    look = sphere_points(np.random.default_rng(0), 1500)
    audio = Audio(np.where(SECOND >= 0.5, tone(), 0.0), RATE)
    finger = FingerSeries(haptic=np.linspace(0.0, 200.0, 50), proprioceptive=np.linspace(1.0, 0.5, 50))
    entity = entity_features(look, audio, finger)
    assert entity.shape == (ENTITY_SIZE,)
    np.testing.assert_array_equal(entity[VISUAL], visual_features(look))
    np.testing.assert_array_equal(entity[ENTITY_LAYOUT["mfcc_range"]], audio_features(audio))
    np.testing.assert_array_equal(entity[ENTITY_LAYOUT["haptic"]], finger_statistics(finger.haptic))
    np.testing.assert_array_equal(entity[ENTITY_LAYOUT["proprioceptive"]], finger_statistics(finger.proprioceptive))
    assert entity[ENTITY_LAYOUT["proprioceptive"]][0] == pytest.approx(-0.5)  # change = last - first


def test_missing_modalities_leave_zero_blocks_and_the_visual_part_alone() -> None:
    look = sphere_points(np.random.default_rng(1), 1500)
    entity = entity_features(look, audio=None, finger=None)
    np.testing.assert_array_equal(entity[VISUAL], visual_features(look))
    for name in ("mfcc_range", "haptic", "proprioceptive"):
        assert not entity[ENTITY_LAYOUT[name]].any()
