"""Quick runs of the context experiments (Figs. 9, 12, 13, 14): files written, summaries sane.

The runs share the recorded features of recognition's quick objects
(``context_scenes.object_features`` memoises them), so only the first one records.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest

from core.vocabulary import paper_vocabulary
from experiments import noise, raw_vs_web, recognition, sigma

#: Not one of the report's seeds (0-4): a test must not pin what the report judges.
TEST_SEED = 7


def run_quick(module: ModuleType, out: Path) -> dict[str, Any]:
    parser = argparse.ArgumentParser()
    module.add_arguments(parser)
    args = parser.parse_args([])
    args.out, args.quick, args.seed, args.json = out, True, TEST_SEED, False
    return module.run(args)


def csv_rows(path: Path) -> list[dict[str, str]]:
    with path.open(encoding="utf-8") as handle:
        return list(csv.DictReader(handle))


def test_sigma_curve(tmp_path: Path) -> None:
    summary = run_quick(sigma, tmp_path)
    assert (tmp_path / "sigma.png").stat().st_size > 0
    rows = csv_rows(tmp_path / "sigma.csv")
    assert [float(row["sigma"]) for row in rows] == list(sigma.SIGMAS)
    curve = np.array(summary["log_likelihood"])
    assert curve.shape == (len(sigma.SIGMAS),) and np.isfinite(curve).all() and (curve < 0).all()
    assert summary["best_sigma"] == sigma.SIGMAS[int(np.argmax(curve))]
    assert summary["best_log_likelihood"] == pytest.approx(curve.max())
    accuracy = np.array(summary["overall_accuracy"])
    assert ((accuracy >= 0) & (accuracy <= 1)).all()
    # σ = 0 is the context alone: its P* cannot tell the nouns of one context apart, so it decides worse than the web.
    assert accuracy[0] < accuracy[-1]


def test_noise_grid(tmp_path: Path) -> None:
    summary = run_quick(noise, tmp_path)
    assert (tmp_path / "noise.png").stat().st_size > 0
    levels, sigmas = noise.QUICK_NOISE_LEVELS, noise.QUICK_SIGMAS
    assert len(csv_rows(tmp_path / "noise.csv")) == len(levels) * (2 + len(sigmas))
    grid = np.array(summary["in_context_accuracy"])
    assert grid.shape == (len(levels), len(sigmas))
    for values in (grid, np.array(summary["perception_accuracy"]), np.array(summary["concept_web_accuracy"])):
        assert ((values >= 0) & (values <= 1)).all()
    # Reversing 90 % of the perceived probabilities wrecks the prototypes' decisions.
    perception = summary["perception_accuracy"]
    assert perception[0] > perception[-1]


def test_reversal_noise_keeps_distributions_and_reverses_what_it_selects() -> None:
    vocabulary = paper_vocabulary()
    rng = np.random.default_rng(0)
    perception = rng.random((4, len(vocabulary)))
    perception[:, :6] /= perception[:, :6].sum(axis=1, keepdims=True)
    perception[:, 7:16:2] = 1.0 - perception[:, 6:16:2]
    np.testing.assert_allclose(noise.reverse_perceptions(perception, vocabulary, 0.0, rng), perception)
    reversed_all = noise.reverse_perceptions(perception, vocabulary, 1.0, rng)
    np.testing.assert_allclose(reversed_all[:, :6].sum(axis=1), 1.0)
    np.testing.assert_allclose(reversed_all[:, 6:16], perception[:, 6:16].reshape(4, 5, 2)[:, :, ::-1].reshape(4, 10))
    np.testing.assert_allclose(reversed_all[:, 16:], 1.0 - perception[:, 16:])
    np.testing.assert_allclose(reversed_all[:, :6], (1.0 - perception[:, :6]) / 5.0)


def test_raw_vs_web(tmp_path: Path) -> None:
    summary = run_quick(raw_vs_web, tmp_path)
    assert (tmp_path / "raw_vs_web.png").stat().st_size > 0
    assert len(csv_rows(tmp_path / "raw_vs_web.csv")) > 0
    curves = summary["score_by_scenes"]
    assert set(curves) == {
        "concept_web",
        "concept_web_entity",
        *(f"raw_{b}_bins" for b in raw_vs_web.QUICK_BIN_COUNTS),
    }
    for values in curves.values():
        assert len(values) == len(raw_vs_web.QUICK_SCENE_COUNTS)
        assert all(0.0 <= value <= 1.0 for value in values)
    # From 20 scenes the concept web names the context of unseen scenes well above chance.
    assert curves["concept_web"][-1] > 0.5
    needed = summary["scenes_to_exceed_half"]["concept_web"]
    assert needed is not None and needed <= raw_vs_web.QUICK_SCENE_COUNTS[-1]


def test_raw_tokens_bin_each_feature_over_its_range() -> None:
    entities = {"a": np.array([0.0, 5.0, 1.0]), "b": np.array([1.0, 5.0, 3.0]), "c": np.array([0.5, 5.0, 2.0])}
    corpus = raw_vs_web.raw_corpus(entities, 4)
    assert corpus.vocab_size == 12
    assert corpus.words["a"].tolist() == [0, 4, 8]  # minima fall in bin 0; a constant feature too
    assert corpus.words["b"].tolist() == [3, 4, 11]  # maxima fall in the last bin
    assert corpus.words["c"].tolist() == [2, 4, 10]


def test_in_context_recognition_is_a_recognition_method() -> None:
    setup, _ = sigma.fitted_setup(TEST_SEED, quick=True)
    assert list(recognition.METHODS) == ["perception", "concept_web", "in_context", "in_context_log"]
    probabilities = recognition.METHODS["in_context"](setup)
    assert probabilities.shape == setup.perception.shape
    np.testing.assert_allclose(probabilities[:, : len(setup.vocabulary.nouns)].sum(axis=1), 1.0)
    assert np.array_equal(probabilities, recognition.METHODS["in_context"](setup))
