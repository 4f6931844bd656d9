"""The strength of contextual feedback σ (§IV-D, Eq. 6, Eq. 7, Fig. 9).

Protocol:

1. :func:`prepare` (shared with the noise experiment): the paper world is
   recorded, prototypes are fitted on the training objects, the concept web on
   their configurations and every test object is perceived
   (``recognition.make_setup``, the setup of Fig. 13); the context model is
   learned from pure-context scenes of the training objects
   (``context_scenes.train_context_model``).
2. ``--draws`` times, the test objects are cut into pure-context scenes
   (``context_scenes.pure_context_scenes``) and, for every σ ∈ {0, 0.1, …, 1},
   each scene is interpreted in context (``core.context.feedback``).
3. An observation x_n is one test object in one draw; its related concepts
   C^{n+} are its true noun and its 5 true adjectives, the concepts every object
   is labelled with (Appendix) and that Fig. 13 scores. l̂ of Eq. 7
   (``core.context.metrics.average_log_likelihood``) averages log P*(c | x_n, σ)
   over them, P* being Eq. 6's updated probabilities. Two more curves, for
   comparison: C^{n+} with the object's applicable behaviours (Table II) as
   related verbs (not the headline: an applied behaviour's verb is perceived
   from its own effect, which context can hardly improve), and l̂ of the webs
   settled in context (the paper's "in context" columns of Table VII). The mean
   overall accuracy of P*'s decisions (Fig. 13's measure) is reported per σ.

Outputs: sigma.csv (one row per σ), sigma.png (Fig. 9) and a summary with the
best σ (by l̂, and by each curve), the curves and the paper's interval.
"""

from __future__ import annotations

import argparse
import csv
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import numpy as np

from core.context import IncrementalLDA, average_log_likelihood
from core.prototypes import fit_prototypes
from experiments import context_scenes, documents, recognition
from sim.world import DEFAULT_WORLD, World

SIGMAS = tuple(round(0.1 * i, 1) for i in range(11))
CURVES = ("log_likelihood", "log_likelihood_with_verbs", "log_likelihood_in_context_web", "overall_accuracy")
DRAWS = 20
QUICK_DRAWS = 2
QUICK_TRAINING_SCENES = 20
PAPER: dict[str, Any] = {
    "figure": "Fig. 9",
    "best_sigma_interval": [0.4, 0.5],
    "chosen_sigma": 0.5,
    "claim": "l̂ is maximal for σ in [0.4, 0.5] and flat for σ >= 0.7 (context too weak to change the web's decision)",
}
# Independent random streams derived from --seed.
_CONTEXT_MODEL_STREAM = 1
_SCENES_STREAM = 2


@dataclass(frozen=True)
class ContextExperiment:
    """The recognition setup of the test objects plus a context model learned from training scenes."""

    setup: recognition.RecognitionSetup
    context_model: IncrementalLDA


def fitted_setup(
    seed: int, quick: bool, world_name: str = DEFAULT_WORLD, source: str = documents.DEFAULT_SOURCE
) -> tuple[recognition.RecognitionSetup, dict[str, context_scenes.Features]]:
    """Fig. 13's setup (prototypes and web fitted on the training objects, test objects perceived)
    and the features of every object it recorded; ``quick`` takes recognition's quick objects."""
    world = World.paper(seed=seed, difficulty=world_name)
    train, test = recognition.experiment_objects(world, quick)
    features = context_scenes.object_features(world, train + test, seed)
    prototypes = fit_prototypes(world.vocabulary, *recognition.training_data(train, features), seed=seed)
    return recognition.make_setup(world, train, test, features, prototypes, source), features


def prepare(
    seed: int,
    quick: bool,
    training_scenes: int | None = None,
    world_name: str = DEFAULT_WORLD,
    source: str = documents.DEFAULT_SOURCE,
) -> ContextExperiment:
    """Step 1 of the protocol; ``--quick`` uses recognition's quick objects and 20 training scenes."""
    setup, _ = fitted_setup(seed, quick, world_name, source)
    n_scenes = training_scenes or (QUICK_TRAINING_SCENES if quick else context_scenes.TRAINING_SCENES)
    rng = np.random.default_rng([seed, _CONTEXT_MODEL_STREAM])
    model = context_scenes.train_context_model(setup.world, setup.train, rng, n_scenes, words=setup.train_words)
    return ContextExperiment(setup, model)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--draws", type=int, default=None, help=f"draws of test scenes (default {DRAWS}, --quick {QUICK_DRAWS})"
    )
    parser.add_argument("--training-scenes", type=int, default=None,
                        help=f"scenes the context model learns from (default {context_scenes.TRAINING_SCENES})")  # fmt: skip
    documents.add_arguments(parser)


def run(args: argparse.Namespace) -> dict[str, Any]:
    experiment = prepare(args.seed, args.quick, args.training_scenes, args.world, args.documents)
    draws = args.draws or (QUICK_DRAWS if args.quick else DRAWS)
    curves = log_likelihood_curves(experiment, draws, np.random.default_rng([args.seed, _SCENES_STREAM]))
    _write_csv(args.out / "sigma.csv", curves)
    _plot(args.out / "sigma.png", curves)
    best = {name: SIGMAS[int(np.argmax(values))] for name, values in curves.items()}
    return {
        "best_sigma": best["log_likelihood"],
        "best_log_likelihood": max(curves["log_likelihood"]),
        "best_sigma_by": best,
        "sigmas": list(SIGMAS),
        **curves,
        "n_test_objects": len(experiment.setup.test),
        "draws": draws,
        "n_contexts": experiment.context_model.n_contexts,
        "paper": PAPER,
    }


def log_likelihood_curves(
    experiment: ContextExperiment, draws: int, rng: np.random.Generator
) -> dict[str, list[float]]:
    """Per σ: l̂ (Eq. 7) of P* with C^{n+} = noun + adjectives, with the applicable verbs too,
    and of the in-context webs; and the mean overall accuracy of P*'s decisions (Fig. 13's measure)."""
    setup = experiment.setup
    vocabulary = setup.vocabulary
    related = [[vocabulary.index(name) for name in obj.concepts] for obj in setup.test]
    verbs = [[vocabulary.index(name) for name in obj.behaviours] for obj in setup.test]
    scenes = [context_scenes.pure_context_scenes(setup.world, setup.test, rng) for _ in range(draws)]
    curves: dict[str, list[float]] = {name: [] for name in CURVES}
    for sigma in SIGMAS:
        eq_6, webs = zip(*(
            context_scenes.in_context_probabilities(
                setup.web, experiment.context_model, vocabulary, setup.perception, setup.applied, draw,
                sigma=sigma, seed=index,
            )
            for index, draw in enumerate(scenes)
        ))  # fmt: skip
        observations = [(p, n) for p in eq_6 for n in range(len(related))]
        curves["log_likelihood"].append(average_log_likelihood([p[n, related[n]] for p, n in observations]))
        curves["log_likelihood_with_verbs"].append(
            average_log_likelihood([p[n, related[n] + verbs[n]] for p, n in observations])
        )
        curves["log_likelihood_in_context_web"].append(
            average_log_likelihood([p[n, related[n]] for p in webs for n in range(len(related))])
        )
        curves["overall_accuracy"].append(float(np.mean([
            recognition.accuracy_row(vocabulary, setup.test[n], "in_context", p[n])["overall_accuracy"] for p, n in observations
        ])))  # fmt: skip
    return curves


def _write_csv(path: Path, curves: dict[str, list[float]]) -> None:
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow(["sigma", *CURVES])
        for i, sigma in enumerate(SIGMAS):
            writer.writerow([sigma, *(curves[name][i] for name in CURVES)])


def _plot(path: Path, curves: dict[str, list[float]]) -> None:
    """Fig. 9: l̂ against σ, the paper's interval [0.4, 0.5] shaded; accuracy on a second axis."""
    figure, axis = plt.subplots(figsize=(7, 4.5))
    axis.axvspan(*PAPER["best_sigma_interval"], color="0.85", label="paper's best interval")
    axis.plot(SIGMAS, curves["log_likelihood"], "o-", label="P*, C+ = noun + adjectives")
    axis.plot(SIGMAS, curves["log_likelihood_with_verbs"], "s--", label="P*, C+ with applicable verbs")
    axis.plot(SIGMAS, curves["log_likelihood_in_context_web"], "^:", label="in-context webs, noun + adjectives")
    axis.set_xlabel("σ (0: context only, 1: concept web only)")
    axis.set_ylabel("average log-likelihood l̂ (Eq. 7)")
    accuracy = axis.twinx()
    accuracy.plot(SIGMAS, curves["overall_accuracy"], "k.-", alpha=0.5, label="accuracy of P* (right axis)")
    accuracy.set_ylabel("noun + adjective accuracy")
    lines = axis.get_legend_handles_labels()
    more = accuracy.get_legend_handles_labels()
    axis.legend(lines[0] + more[0], lines[1] + more[1], loc="lower right", fontsize="small")
    axis.set_title("Strength of contextual feedback (Fig. 9)")
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    plt.close(figure)
