"""Recognition under artificial noise (§V-D, Fig. 14): prototypes alone vs context-enhanced webs.

Protocol:

1. :func:`experiments.sigma.prepare`: prototypes, concept web, the test
   objects' perceptions and a context model learned from training scenes.
2. For every noise probability (10 %–90 %) and each of ``--trials`` trials, the
   test perceptions are corrupted (:func:`reverse_perceptions`) and the test
   objects cut into pure-context scenes (``context_scenes.pure_context_scenes``);
   the same corrupted perceptions and scenes serve every σ (0.1–0.9), so the σ
   columns differ only by σ.
3. Each method decides the noun and the 5 adjectives of every test object
   (Fig. 13's overall accuracy): ``perception`` the corrupted prototype
   perception alone, ``concept_web`` the web settled on it (no context), and
   ``in_context`` P*(c) of Eq. 6 from the context feedback loop at each σ.

Outputs: noise.csv (one row per noise, method and σ: mean and standard
deviation over trials), noise.png (a heatmap of in-context accuracy over noise
× σ, and accuracy against noise per method) and a summary with the accuracy grid.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import numpy as np

from core.vocabulary import Vocabulary
from experiments import context_scenes, documents, recognition
from experiments.sigma import ContextExperiment, prepare

NOISE_LEVELS = tuple(round(0.1 * i, 1) for i in range(1, 10))
SIGMAS = NOISE_LEVELS
TRIALS = 15
QUICK_NOISE_LEVELS = (0.1, 0.5, 0.9)
QUICK_SIGMAS = (0.1, 0.5, 0.9)
QUICK_TRIALS = 2
PAPER = {
    "figure": "Fig. 14",
    "trials": 15,
    "claim": "context-enhanced webs stay accurate as noise grows, while prototype predictions degrade: "
    "the context, detected from many objects, corrects individual wrong predictions",
}
_NOISE_STREAM = 3


def reverse_perceptions(
    perception: np.ndarray, vocabulary: Vocabulary, noise: float, rng: np.random.Generator
) -> np.ndarray:
    """Fig. 14's artificial noise: each concept is selected with probability ``noise`` and its
    perceived probability p reversed to 1 − p.

    - Nouns: each noun is selected on its own and reversed, then the nouns are
      renormalised, since an object has one noun (a noun perceived at 10 % and
      reversed to 90 % becomes the favourite).
    - Adjectives: a dichotomic pair is one perceived probability (its two
      adjectives sum to 1, so reversing one reverses the other): each pair is
      selected once and P(first) becomes 1 − P(first).
    - Verbs: each is selected on its own (a behaviour that was not applied stays
      at 0.5, which reverses to itself).
    """
    n_nouns, n_adjectives = len(vocabulary.nouns), len(vocabulary.adjectives)
    nouns, adjectives, verbs = np.split(perception, [n_nouns, n_nouns + n_adjectives], axis=1)
    nouns = np.where(rng.random(nouns.shape) < noise, 1.0 - nouns, nouns)
    pairs = adjectives.reshape(len(perception), -1, 2)
    pairs = np.where((rng.random(pairs.shape[:2]) < noise)[:, :, None], pairs[:, :, ::-1], pairs)
    verbs = np.where(rng.random(verbs.shape) < noise, 1.0 - verbs, verbs)
    nouns = nouns / nouns.sum(axis=1, keepdims=True)
    return np.concatenate([nouns, pairs.reshape(len(perception), -1), verbs], axis=1)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--trials", type=int, default=None, help=f"trials per noise level (default {TRIALS}, --quick {QUICK_TRIALS})")  # fmt: skip
    documents.add_arguments(parser)


def run(args: argparse.Namespace) -> dict[str, Any]:
    experiment = prepare(args.seed, args.quick, None, args.world, args.documents)
    trials = args.trials or (QUICK_TRIALS if args.quick else TRIALS)
    noise_levels, sigmas = (QUICK_NOISE_LEVELS, QUICK_SIGMAS) if args.quick else (NOISE_LEVELS, SIGMAS)
    accuracy = accuracy_grid(experiment, noise_levels, sigmas, trials, args.seed)
    _write_csv(args.out / "noise.csv", accuracy, noise_levels, sigmas)
    _plot(args.out / "noise.png", accuracy, noise_levels, sigmas)
    means = {method: values.mean(axis=-1) for method, values in accuracy.items()}
    paper_sigma = sigmas.index(0.5) if 0.5 in sigmas else len(sigmas) // 2
    return {
        "noise_levels": list(noise_levels),
        "sigmas": list(sigmas),
        "perception_accuracy": means["perception"].tolist(),
        "concept_web_accuracy": means["concept_web"].tolist(),
        "in_context_accuracy": means["in_context"].tolist(),
        "best_sigma_per_noise": [sigmas[int(np.argmax(row))] for row in means["in_context"]],
        "in_context_minus_perception_at_sigma_0_5": (
            means["in_context"][:, paper_sigma] - means["perception"]
        ).tolist(),
        "trials": trials,
        "n_test_objects": len(experiment.setup.test),
        "paper": PAPER,
    }


def accuracy_grid(
    experiment: ContextExperiment, noise_levels: tuple[float, ...], sigmas: tuple[float, ...], trials: int, seed: int
) -> dict[str, np.ndarray]:
    """Mean overall accuracy over the test objects, per noise level and trial (last axis):
    ``perception`` and ``concept_web`` (noise × trials), ``in_context`` (noise × σ × trials)."""
    setup = experiment.setup
    shape = (len(noise_levels), trials)
    accuracy = {"perception": np.zeros(shape), "concept_web": np.zeros(shape),
                "in_context": np.zeros((len(noise_levels), len(sigmas), trials))}  # fmt: skip
    for i, noise in enumerate(noise_levels):
        for trial in range(trials):
            rng = np.random.default_rng([seed, _NOISE_STREAM, i, trial])
            noisy = reverse_perceptions(setup.perception, setup.vocabulary, noise, rng)
            scenes = context_scenes.pure_context_scenes(setup.world, setup.test, rng)
            webs = setup.web.infer_many(noisy, applied=setup.applied)
            accuracy["perception"][i, trial] = _accuracy(setup, noisy)
            accuracy["concept_web"][i, trial] = _accuracy(setup, np.array([web.probabilities for web in webs]))
            for j, sigma in enumerate(sigmas):
                eq_6, _ = context_scenes.in_context_probabilities(
                    setup.web, experiment.context_model, setup.vocabulary, noisy, setup.applied, scenes,
                    sigma=sigma, seed=trial,
                )  # fmt: skip
                accuracy["in_context"][i, j, trial] = _accuracy(setup, eq_6)
    return accuracy


def _accuracy(setup: recognition.RecognitionSetup, probabilities: np.ndarray) -> float:
    return float(np.mean([
        recognition.accuracy_row(setup.vocabulary, obj, "", probabilities[n])["overall_accuracy"] for n, obj in enumerate(setup.test)
    ]))  # fmt: skip


def _write_csv(
    path: Path, accuracy: dict[str, np.ndarray], noise_levels: tuple[float, ...], sigmas: tuple[float, ...]
) -> None:
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow(["noise", "method", "sigma", "accuracy_mean", "accuracy_std"])
        for i, noise in enumerate(noise_levels):
            for method in ("perception", "concept_web"):
                values = accuracy[method][i]
                writer.writerow([noise, method, "", values.mean(), values.std()])
            for j, sigma in enumerate(sigmas):
                values = accuracy["in_context"][i, j]
                writer.writerow([noise, "in_context", sigma, values.mean(), values.std()])


def _plot(
    path: Path, accuracy: dict[str, np.ndarray], noise_levels: tuple[float, ...], sigmas: tuple[float, ...]
) -> None:
    """Fig. 14: in-context accuracy over noise × σ, and every method's accuracy against noise."""
    figure, (grid, lines) = plt.subplots(1, 2, figsize=(11, 4.5))
    in_context = accuracy["in_context"].mean(axis=-1)
    image = grid.imshow(in_context, origin="lower", vmin=0.0, vmax=1.0, cmap="viridis", aspect="auto")
    grid.set_xticks(range(len(sigmas)), [f"{s:.1f}" for s in sigmas])
    grid.set_yticks(range(len(noise_levels)), [f"{q:.0%}" for q in noise_levels])
    grid.set_xlabel("σ")
    grid.set_ylabel("noise probability")
    grid.set_title("context-enhanced webs")
    figure.colorbar(image, ax=grid, label="accuracy")
    for method in ("perception", "concept_web"):
        lines.plot(noise_levels, accuracy[method].mean(axis=-1), "o-", label=method.replace("_", " "))
    for j, sigma in enumerate(sigmas):
        lines.plot(
            noise_levels, in_context[:, j], "-", alpha=0.35 + 0.6 * (sigma == 0.5), label=f"in context σ={sigma:.1f}"
        )
    lines.set_xlabel("noise probability")
    lines.set_ylabel("accuracy (nouns + adjectives)")
    lines.set_ylim(0.0, 1.0)
    lines.legend(fontsize="x-small", ncol=2)
    figure.suptitle("Recognition under artificial noise (Fig. 14)")
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    plt.close(figure)
