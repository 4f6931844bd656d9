"""Table VI: predicted context proportions of three pure and three mixed scenes.

Protocol (§V-A). Incremental-LDA (default rule, K found by the model) learns
``--training-scenes`` random pure scenes of the paper's world (``--world``; each
object gives the active concepts of its perceived web, ``experiments.documents``,
or with ``--documents labels`` its labels). The discovered
contexts are then named: each training scene votes, with its most probable
context, for its true context, and each discovered context takes the name
receiving most of its votes (a context no training scene prefers stays
``unnamed``; two contexts may take the same name, and then their proportions
add up). Each scene of Table VI (e.g. "2 cups, 2 plates") is built from objects
of those nouns, given to :meth:`IncrementalLDA.infer_scene` (fold-in, the model
unchanged), and its posterior θ is summed per name. This is repeated for
``--repeats`` training sets; the table reports mean ± std.

The true proportions are the paper's, by objects (2 of 3 objects from the
Playroom: 66 %). LDA sees tokens, and objects differ in their number of
tokens (with labels a cup brings 5 verbs, a box 13), so the token shares of the
documents are listed too.

Outputs: table_vi.csv (scene, context, true by objects, true by tokens, paper,
ours mean and std), table_vi.png.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import numpy as np

from core.context import IncrementalLDA
from experiments import documents
from experiments.documents import Documents
from sim.world import Scene, table_vi_scenes

UNNAMED = "unnamed"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--training-scenes", type=int, default=None, help="pure training scenes (50; --quick: 20)")
    parser.add_argument("--repeats", type=int, default=None, help="training sets (10; --quick: 2)")
    documents.add_arguments(parser)


def context_names(model: IncrementalLDA, training: tuple[Scene, ...]) -> list[str]:
    """Name of each discovered context: the majority true context of the training scenes preferring it."""
    votes: list[dict[str, int]] = [{} for _ in range(model.n_contexts)]
    for index, scene in enumerate(training):
        preferred = int(np.argmax(model.context_posterior(index)))
        truth = max(scene.mixture, key=scene.mixture.__getitem__)
        votes[preferred][truth] = votes[preferred].get(truth, 0) + 1
    return [max(v, key=v.__getitem__) if v else UNNAMED for v in votes]


def token_shares(scene: Scene, docs: Documents) -> dict[str, float]:
    """Each true context's share of the scene's document tokens."""
    counts: dict[str, int] = {}
    for obj, context in zip(scene.objects, scene.object_contexts, strict=True):
        counts[context] = counts.get(context, 0) + len(docs.words[obj.object_id])
    total = sum(counts.values())
    return {context: count / total for context, count in counts.items()}


def run(args: argparse.Namespace) -> dict[str, Any]:
    n_training = args.training_scenes or (20 if args.quick else 50)
    repeats = args.repeats or (2 if args.quick else 10)
    docs = documents.experiment_documents(args.world, args.seed, args.documents, args.quick)
    config = docs.world.config
    specs = table_vi_scenes()
    names = [context.name for context in config.contexts]
    predicted: dict[str, dict[str, list[float]]] = {
        spec.name: {name: [] for name in [*names, UNNAMED]} for spec in specs
    }
    shares: dict[str, dict[str, list[float]]] = {spec.name: {name: [] for name in names} for spec in specs}
    found_k = []
    for repeat in range(repeats):
        seed = args.seed * 1000 + repeat
        training = docs.scenes(n_training, seed)
        model = IncrementalLDA(seed=seed).fit([docs.scene(scene) for scene in training])
        found_k.append(model.n_contexts)
        labels = context_names(model, training)
        for spec in specs:
            scene = docs.scene_from_nouns(spec, seed)
            theta = model.infer_scene(docs.scene(scene), seed=seed)
            for name in predicted[spec.name]:
                predicted[spec.name][name].append(
                    float(sum(p for p, label in zip(theta, labels, strict=True) if label == name))
                )
            for name in names:
                shares[spec.name][name].append(token_shares(scene, docs).get(name, 0.0))
    rows = [
        {
            "scene": spec.name,
            "context": name,
            "true_by_objects": spec.mixture.get(name, 0.0),
            "true_by_tokens": float(np.mean(shares[spec.name][name])) if name in names else 0.0,
            "paper": spec.paper_prediction.get(name, 0.0),
            "ours_mean": float(np.mean(predicted[spec.name][name])),
            "ours_std": float(np.std(predicted[spec.name][name])),
        }
        for spec in specs
        for name in predicted[spec.name]
        if name in names or np.mean(predicted[spec.name][name]) > 0
    ]
    _write_csv(args.out / "table_vi.csv", rows)
    _plot(args.out / "table_vi.png", rows)
    return {**_summary(rows, specs, found_k, n_training), "world": args.world, "documents": args.documents}


def _summary(rows: list[dict[str, Any]], specs: tuple, found_k: list[int], n_training: int) -> dict[str, Any]:
    scenes: dict[str, Any] = {}
    for spec in specs:
        mine = [r for r in rows if r["scene"] == spec.name]
        truth = max(spec.mixture, key=spec.mixture.__getitem__)
        ours = max(mine, key=lambda r: r["ours_mean"])["context"]
        scenes[spec.name] = {
            "true": spec.mixture,
            "paper": spec.paper_prediction,
            "ours": {r["context"]: round(r["ours_mean"], 4) for r in mine},
            "ours_std": {r["context"]: round(r["ours_std"], 4) for r in mine},
            "true_by_tokens": {r["context"]: round(r["true_by_tokens"], 4) for r in mine if r["true_by_tokens"]},
            "top_context_correct": ours == truth if len(spec.mixture) == 1 or spec.mixture[truth] > 0.5 else None,
        }

    def mean_error(field: str) -> float:
        return float(np.mean([abs(r[field] - r["true_by_objects"]) for r in rows if r["context"] != UNNAMED]))

    return {
        "training_scenes": n_training,
        "contexts_found": found_k,
        "scenes": scenes,
        "mean_abs_error_vs_objects": {
            "ours": round(mean_error("ours_mean"), 4),
            "paper": round(mean_error("paper"), 4),
        },
    }


def _write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def _plot(path: Path, rows: list[dict[str, Any]]) -> None:
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    figure, axes = plt.subplots(2, 3, figsize=(13, 7), sharey=True)
    for axis, scene in zip(axes.flat, scenes, strict=True):
        mine = [r for r in rows if r["scene"] == scene]
        x = np.arange(len(mine))
        axis.bar(x - 0.27, [r["true_by_objects"] for r in mine], 0.27, label="true (objects)")
        axis.bar(x, [r["paper"] for r in mine], 0.27, label="paper")
        axis.bar(x + 0.27, [r["ours_mean"] for r in mine], 0.27, yerr=[r["ours_std"] for r in mine], label="ours")
        axis.set_xticks(x, [r["context"] for r in mine])
        axis.set_title(scene)
    axes.flat[0].set_ylabel("context proportion")
    axes.flat[0].legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    plt.close(figure)
