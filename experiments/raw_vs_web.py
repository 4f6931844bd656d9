"""Context from raw features vs context from the concept web (§V-B, Fig. 12).

Protocol:

1. :func:`experiments.sigma.fitted_setup`: every object of the world is
   recorded and its features extracted once; prototypes and the concept web are
   fitted on the training objects.
2. Two ways to turn an object into LDA words:
   - **raw**: its entity vector e (91 features, Table III) discretised into b
     bins per feature, each feature's range (its minimum to its maximum over all
     the objects) cut into b equal widths (a constant feature falls in bin 0);
     the object adds the 91 tokens "feature_i=bin_j";
   - **concept web** (the paper's): the object is perceived (prototypes) and its
     web settled; it adds its active concepts by Table V's rule, verbs included
     (``experiments.documents.perceived_words``, the LDA document of every
     experiment), as the paper's documents do. ``concept_web_entity`` keeps only
     the active noun and adjectives (the concepts of the entity, all the raw
     side sees: its e has no effect features), for comparison; it was the
     headline before issue 15.
   The raw side is swept over bin counts (2, 5, 10, 20, 50): the paper says raw
   features work only with coarse bins (≤ 10) and fall to chance otherwise; the
   sweep measures it rather than assuming it.
3. For every number of scenes (1, 3, 5, 10, 20, 50) and trial: that many pure
   training scenes (§V: a random context, 3–5 of its objects, over all the
   world's objects) and 30 evaluation scenes are drawn. Collapsed-Gibbs LDA with
   K = 3 (the true number of contexts, fixed as in the paper's comparison: how
   K is found is Fig. 11's subject) learns from the training scenes.
4. Score: the probability assigned to the true context. LDA's contexts carry
   no names, so each true context is matched to one learned context by the
   assignment that maximises the training scenes' θ mass on their true contexts
   (``scipy.optimize.linear_sum_assignment``: one-to-one, unlike a per-context
   argmax); the score is the mean, over the *evaluation* scenes, of θ (folded in)
   on the matched context. Held-out scenes keep the matching from being
   flattered: with one training scene, the matching is right for that scene's
   context only and the score falls to chance elsewhere.
5. Fig. 12(a, c): raw for several bin counts and the web, against the number
   of scenes at α = ξ = 0.1; Fig. 12(b, d): both on an α × ξ grid (50 scenes,
   10 bins).

Outputs: raw_vs_web.csv (scenes curve and α × ξ grid), raw_vs_web.png (the four
panels of Fig. 12) and a summary with the scenes each input needs before its
mean score exceeds 0.5.
"""

from __future__ import annotations

import argparse
import csv
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
from scipy.optimize import linear_sum_assignment

from core.context import LDAState
from core.scene import Perception
from experiments import context_scenes, documents
from experiments.recognition import RecognitionSetup
from experiments.sigma import fitted_setup
from sim.world import Scene, World, WorldObject

SCENE_COUNTS = (1, 3, 5, 10, 20, 50)
BIN_COUNTS = (2, 5, 10, 20, 50)
PRIORS = (0.01, 0.05, 0.1, 0.5, 1.0)
TRIALS = 10
GRID_TRIALS = 5
QUICK_SCENE_COUNTS = (1, 5, 20)
QUICK_BIN_COUNTS = (5, 10)
QUICK_PRIORS = (0.1, 1.0)
QUICK_TRIALS = 2
GRID_BINS = 10
EVALUATION_SCENES = 30
N_CONTEXTS = 3
ALPHA = XI = 0.1
SWEEPS = 100
FOLD_IN_SWEEPS, FOLD_IN_BURN_IN = 30, 10
CHANCE = 1.0 / N_CONTEXTS
PAPER = {
    "figure": "Fig. 12",
    "concept_web_scenes_needed": "3-5",
    "raw_scenes_needed": "50, and only with coarse discretisation (10 bins at most); chance (33.3 %) otherwise",
    "concept_web_worst_grid_score": "> 0.5 everywhere on the α-ξ grid",
}
_SCENES_STREAM = 4


@dataclass(frozen=True)
class Corpus:
    """Each object's LDA words (ids) under one representation, and the vocabulary size."""

    words: dict[str, np.ndarray]
    vocab_size: int

    def document(self, scene: Scene) -> np.ndarray:
        return np.concatenate([self.words[obj.object_id] for obj in scene.objects]).astype(np.int32)


def raw_corpus(entities: dict[str, np.ndarray], bins: int) -> Corpus:
    """Tokens "feature_i=bin_j" (id i·b + j) of every object's entity vector, b equal-width bins
    over each feature's range across the objects."""
    ids = list(entities)
    matrix = np.array([entities[object_id] for object_id in ids])
    low, span = matrix.min(axis=0), np.ptp(matrix, axis=0)
    scaled = np.divide(matrix - low, span, out=np.zeros_like(matrix), where=span > 0)
    binned = np.minimum((scaled * bins).astype(np.int64), bins - 1)
    tokens = np.arange(matrix.shape[1]) * bins + binned
    return Corpus(dict(zip(ids, tokens, strict=True)), matrix.shape[1] * bins)


def context_score(
    corpus: Corpus,
    training: Sequence[Scene],
    evaluation: Sequence[Scene],
    contexts: Sequence[str],
    rng: np.random.Generator,
    alpha: float = ALPHA,
    xi: float = XI,
) -> float:
    """Mean θ of the evaluation scenes on their true context (module docstring, steps 3–4)."""
    state = LDAState(alpha, xi, corpus.vocab_size, N_CONTEXTS)
    for scene in training:
        state.append_document(corpus.document(scene))
    state.initialize_randomly(rng)
    state.sweep(rng, SWEEPS)
    theta = state.context_given_scene()
    labels = np.array([scene.object_contexts[0] for scene in training])
    weight = np.stack([theta[labels == name].sum(axis=0) for name in contexts])  # true × learned
    true, learned = linear_sum_assignment(weight, maximize=True)
    matched = dict(zip((contexts[i] for i in true), learned, strict=True))
    return float(np.mean([
        state.fold_in(corpus.document(scene), rng, FOLD_IN_SWEEPS, FOLD_IN_BURN_IN)[matched[scene.object_contexts[0]]]
        for scene in evaluation
    ]))  # fmt: skip


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--trials", type=int, default=None, help=f"trials per setting (default {TRIALS}, --quick {QUICK_TRIALS})")  # fmt: skip
    documents.add_world_argument(parser)


def run(args: argparse.Namespace) -> dict[str, Any]:
    setup, features = fitted_setup(args.seed, args.quick, args.world, documents.LABELS)
    objects = setup.train + setup.test
    scene_counts, bin_counts, priors = (
        (QUICK_SCENE_COUNTS, QUICK_BIN_COUNTS, QUICK_PRIORS) if args.quick else (SCENE_COUNTS, BIN_COUNTS, PRIORS)
    )
    trials = args.trials or (QUICK_TRIALS if args.quick else TRIALS)
    entities = {object_id: entity for object_id, (entity, _) in features.items()}
    corpora = {
        **_web_corpora(setup, features),
        **{f"raw_{b}_bins": raw_corpus(entities, b) for b in bin_counts},
    }
    grid_inputs = ("concept_web", f"raw_{GRID_BINS if GRID_BINS in bin_counts else max(bin_counts)}_bins")
    grid_scenes, grid_trials = max(scene_counts), min(trials, GRID_TRIALS)
    comparison = _Comparison(setup.world, objects, np.random.default_rng([args.seed, _SCENES_STREAM]))
    by_scenes = {n: comparison.scores(corpora, n, trials) for n in scene_counts}
    chosen = {name: corpora[name] for name in grid_inputs}
    grid = {(a, x): comparison.scores(chosen, grid_scenes, grid_trials, a, x) for a in priors for x in priors}
    _write_csv(args.out / "raw_vs_web.csv", by_scenes, grid, grid_scenes)
    _plot(args.out / "raw_vs_web.png", by_scenes, grid, priors, grid_inputs)
    curves = {name: [by_scenes[n][name] for n in scene_counts] for name in corpora}
    return {
        "scene_counts": list(scene_counts),
        "score_by_scenes": curves,
        "scenes_to_exceed_half": {name: _first_above(scene_counts, values, 0.5) for name, values in curves.items()},
        "priors": list(priors),
        "grid_scenes": grid_scenes,
        "grid_score": {name: [[grid[(a, x)][name] for x in priors] for a in priors] for name in grid_inputs},
        "grid_worst": {name: min(value[name] for value in grid.values()) for name in grid_inputs},
        "chance": CHANCE,
        "trials": trials,
        "grid_trials": grid_trials,
        "n_objects": len(objects),
        "paper": PAPER,
    }


@dataclass
class _Comparison:
    """Draws the scenes of each trial (the same for every input) and averages the inputs' scores."""

    world: World
    objects: Sequence[WorldObject]
    rng: np.random.Generator

    def scores(
        self, corpora: dict[str, Corpus], n_scenes: int, trials: int, alpha: float = ALPHA, xi: float = XI
    ) -> dict[str, float]:
        contexts = [context.name for context in self.world.config.contexts]
        totals = dict.fromkeys(corpora, 0.0)
        for _ in range(trials):
            training = self.world.scenes(n_scenes, seed=self.rng, objects=self.objects)
            evaluation = self.world.scenes(EVALUATION_SCENES, seed=self.rng, objects=self.objects)
            for name, corpus in corpora.items():
                totals[name] += context_score(corpus, training, evaluation, contexts, self.rng, alpha, xi) / trials
        return totals


def _web_corpora(setup: RecognitionSetup, features: dict[str, context_scenes.Features]) -> dict[str, Corpus]:
    """Each object's active concepts (Table V) in its concept web settled on its perception, verbs
    included (``concept_web``, the experiments' documents), and its active noun and adjectives only
    (``concept_web_entity``)."""
    objects = setup.train + setup.test
    vocabulary = setup.vocabulary
    words = documents.perceived_words(Perception(vocabulary, setup.prototypes, setup.web), objects, features)
    active = {key: np.array([vocabulary.index(word) for word in names], dtype=np.int64) for key, names in words.items()}
    entity_concepts = len(vocabulary.nouns) + len(vocabulary.adjectives)
    return {
        "concept_web": Corpus(active, len(vocabulary)),
        "concept_web_entity": Corpus({key: ids[ids < entity_concepts] for key, ids in active.items()}, len(vocabulary)),
    }


def _first_above(counts: Sequence[int], values: Sequence[float], threshold: float) -> int | None:
    return next((n for n, value in zip(counts, values, strict=True) if value > threshold), None)


def _write_csv(
    path: Path,
    by_scenes: dict[int, dict[str, float]],
    grid: dict[tuple[float, float], dict[str, float]],
    grid_scenes: int,
) -> None:
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow(["sweep", "input", "scenes", "alpha", "xi", "true_context_probability"])
        for n, values in by_scenes.items():
            writer.writerows(["scenes", name, n, ALPHA, XI, value] for name, value in values.items())
        for (alpha, xi), values in grid.items():
            writer.writerows(["alpha_xi", name, grid_scenes, alpha, xi, value] for name, value in values.items())


def _plot(
    path: Path,
    by_scenes: dict[int, dict[str, float]],
    grid: dict[tuple[float, float], dict[str, float]],
    priors: Sequence[float],
    grid_inputs: Sequence[str],
) -> None:
    """Fig. 12: (a, c) score against scenes per input; (b, d) the α × ξ grids."""
    figure, axes = plt.subplots(1, 1 + len(grid_inputs), figsize=(5 * (1 + len(grid_inputs)), 4.5))
    counts = list(by_scenes)
    for name in next(iter(by_scenes.values())):
        style = ".--" if name.startswith("raw") else "o-"
        axes[0].plot(counts, [by_scenes[n][name] for n in counts], style, label=name.replace("_", " "))
    axes[0].axhline(CHANCE, color="0.6", linewidth=0.8, label="chance")
    axes[0].set_xscale("log")
    axes[0].set_xlabel("scenes encountered")
    axes[0].set_ylabel("probability of the true context")
    axes[0].set_ylim(0.0, 1.0)
    axes[0].legend(fontsize="small")
    for axis, name in zip(axes[1:], grid_inputs, strict=True):
        values = np.array([[grid[(a, x)][name] for x in priors] for a in priors])
        image = axis.imshow(values, origin="lower", vmin=0.0, vmax=1.0, cmap="viridis")
        axis.set_xticks(range(len(priors)), [f"{x:g}" for x in priors])
        axis.set_yticks(range(len(priors)), [f"{a:g}" for a in priors])
        axis.set_xlabel("ξ")
        axis.set_ylabel("α")
        axis.set_title(name.replace("_", " "))
        figure.colorbar(image, ax=axis)
    figure.suptitle("Context from raw features vs from the concept web (Fig. 12)")
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    plt.close(figure)
