"""Fig. 11: uncertain concepts |C_low| and entropy H̃ against K and the number of scenes; where growth stops.

Protocol (§V-A). For each of ``--test-sets`` test sets and each number of scenes
|D| in ``--scene-counts``, pure scenes of the paper's world (``--world``, one
world per ``--seed``; a context drawn uniformly, 3–5 of its objects, each giving
the active concepts of its perceived concept web, ``experiments.documents``; with
``--documents labels`` its true noun, adjectives and applicable verbs) are
learned with K forced from 1 to ``--max-k`` as the paper does: K = 1,
then repeatedly Algorithm 3's start (C_low tokens to the new context, others with
probability δ) followed by the model's Gibbs sweeps. After each K the run
records |C_low| (concepts with max_χ P(c|χ) < τ) and H̃ (Eq. 8, ρ = 0.25).

Then each test set is learned again with K left to the model, once per
K-selection rule (``scenes``, the default scene-partition evidence;
``likelihood``, the token-level birth move; ``paper``, C_low ≠ ∅), and the K
where growth stops is compared with the number of contexts actually present in
its scenes (three scenes hold all three contexts only 22 % of the time). Test
sets that hold every context (world ``paper-all``: one scene of each context,
the others drawn as usual, shuffled) ask the paper's question literally, "does
growth stop at K = 3 from 3 scenes", for |D| of 3 to 10. The same comparison
runs on generic worlds of 2, 4 and 5 contexts (``WorldConfig.generic``) with
``--generic-scenes`` scenes each; their documents are labels (perceiving a new
world per test set would cost a minute each): they test the K rule beyond three
contexts, not perception.

Outputs: fig11.csv (|D|, test set, K, |C_low|, H̃), stop_k.csv (world, |D|,
test set, rule, contexts present, K found), fig11.png (panels a–d of Fig. 11).
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
from experiments.baselines.likelihood_rule import likelihood_model
from experiments.documents import Documents
from sim.world import WorldConfig, generate_scenes

RULES = ("scenes", "likelihood", "paper")
SCENE_COUNTS = (1, 2, 3, 5, 10, 20, 50, 100)
QUICK_SCENE_COUNTS = (3, 20)
GENERIC_CONTEXTS = (2, 4, 5)
#: Test sets holding every context are drawn up to this |D| (beyond it the uniform draw holds them all).
EVERY_CONTEXT_MAX_SCENES = 10


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--test-sets", type=int, default=None, help="test sets per configuration (10; --quick: 2)")
    parser.add_argument("--max-k", type=int, default=6, help="largest forced K (Fig. 11 goes to 6)")
    parser.add_argument("--scene-counts", type=str, default=None, help="comma-separated |D| values")
    parser.add_argument("--generic-scenes", type=int, default=None, help="scenes per generic world (100; --quick: 30)")
    parser.add_argument("--tau", type=float, default=None, help="τ of C_low (default: the model's)")
    documents.add_arguments(parser)


def _tokens(docs: Documents, n_scenes: int, seed: int) -> tuple[list[list[str]], int]:
    scenes = docs.scenes(n_scenes, seed)
    present = len({context for scene in scenes for context in scene.object_contexts})
    return [docs.scene(scene) for scene in scenes], present


def _generic_tokens(config: WorldConfig, n_scenes: int, seed: int) -> tuple[list[list[str]], int]:
    scenes = generate_scenes(config, n_scenes, seed)
    present = len({context for scene in scenes for context in scene.object_contexts})
    return [scene.tokens() for scene in scenes], present


def _tokens_with_every_context(docs: Documents, n_scenes: int, seed: int) -> list[list[str]]:
    """``n_scenes`` (≥ the number of contexts) scenes holding every context: one scene of each,
    the others drawn as usual, in a seeded random order."""
    names = [context.name for context in docs.world.config.contexts]
    scenes = [docs.scenes(1, seed * 100 + i, contexts=[name])[0] for i, name in enumerate(names)]
    scenes += docs.scenes(n_scenes - len(names), seed)
    order = np.random.default_rng(seed).permutation(len(scenes))
    return [docs.scene(scenes[i]) for i in order]


def forced_growth(scenes: list[list[str]], max_k: int, seed: int, tau: float | None) -> list[tuple[int, float]]:
    """(|C_low|, H̃) at K = 1..max_k along Algorithm 3's chain."""
    model = IncrementalLDA(seed=seed, max_contexts=max_k).fit(scenes, n_contexts=1)
    trace = [(len(model.low_confidence_concepts(tau)), model.entropy())]
    while not model.context_cap_reached:
        model.grow_context()
        model.sweep(model.hyperparameters.sampler.sweeps)
        trace.append((len(model.low_confidence_concepts(tau)), model.entropy()))
    return trace


def stopping_k(scenes: list[list[str]], seed: int, rule: str, tau: float | None) -> int:
    """K where growth stops under ``rule`` (τ is the ``paper`` rule's; ``likelihood`` is the
    experiments' baseline, :mod:`experiments.baselines.likelihood_rule`)."""
    if rule == "likelihood":
        return likelihood_model(seed=seed).fit(scenes).n_contexts
    options: dict[str, Any] = {"k_selection": rule}
    if tau is not None and rule == "paper":
        options["tau"] = tau
    return IncrementalLDA(seed=seed, **options).fit(scenes).n_contexts


def run(args: argparse.Namespace) -> dict[str, Any]:
    test_sets = args.test_sets or (2 if args.quick else 10)
    counts = (
        tuple(int(n) for n in args.scene_counts.split(","))
        if args.scene_counts
        else (QUICK_SCENE_COUNTS if args.quick else SCENE_COUNTS)
    )
    max_k = 3 if args.quick else args.max_k
    generic_scenes = args.generic_scenes or (30 if args.quick else 100)
    generic_contexts = GENERIC_CONTEXTS[:1] if args.quick else GENERIC_CONTEXTS
    docs = documents.experiment_documents(args.world, args.seed, args.documents, args.quick)
    paper = docs.world.config

    curves, stops = [], []
    for n_scenes in counts:
        for test_set in range(test_sets):
            seed = args.seed * 1000 + test_set
            scenes, present = _tokens(docs, n_scenes, seed)
            for k, (low, entropy) in enumerate(forced_growth(scenes, max_k, seed, args.tau), start=1):
                curves.append({"scenes": n_scenes, "test_set": test_set, "k": k, "c_low": low, "entropy": entropy})
            for rule in RULES:
                found = stopping_k(scenes, seed, rule, args.tau)
                stops.append(
                    {
                        "world": "paper",
                        "scenes": n_scenes,
                        "test_set": test_set,
                        "rule": rule,
                        "present": present,
                        "found": found,
                    }
                )
    for n_scenes in (n for n in counts if len(paper.contexts) <= n <= EVERY_CONTEXT_MAX_SCENES):
        for test_set in range(test_sets):
            seed = args.seed * 1000 + test_set
            scenes = _tokens_with_every_context(docs, n_scenes, seed)
            for rule in RULES:
                stops.append(
                    {
                        "world": "paper-all",
                        "scenes": n_scenes,
                        "test_set": test_set,
                        "rule": rule,
                        "present": len(paper.contexts),
                        "found": stopping_k(scenes, seed, rule, args.tau),
                    }
                )
    for n_contexts in generic_contexts:
        for test_set in range(test_sets):
            seed = args.seed * 1000 + test_set
            scenes, present = _generic_tokens(WorldConfig.generic(n_contexts, seed), generic_scenes, seed)
            for rule in RULES:
                found = stopping_k(scenes, seed, rule, args.tau)
                stops.append(
                    {
                        "world": f"generic-{n_contexts}",
                        "scenes": generic_scenes,
                        "test_set": test_set,
                        "rule": rule,
                        "present": present,
                        "found": found,
                    }
                )

    _write_csv(args.out / "fig11.csv", curves)
    _write_csv(args.out / "stop_k.csv", stops)
    _plot(args.out / "fig11.png", curves, counts, max_k)
    return {**_summary(curves, stops, counts, max_k), "world": args.world, "documents": args.documents}


def _summary(curves: list[dict], stops: list[dict], counts: tuple[int, ...], max_k: int) -> dict[str, Any]:
    def mean_std(n: int, field: str) -> dict[str, list[float]]:
        values = np.array([[r[field] for r in curves if r["scenes"] == n and r["k"] == k] for k in range(1, max_k + 1)])
        return {"mean": values.mean(axis=1).round(4).tolist(), "std": values.std(axis=1).round(4).tolist()}

    fig11 = {
        str(n): {
            "c_low": mean_std(n, "c_low"),
            "entropy": mean_std(n, "entropy"),
            "k_of_min_entropy": 1 + int(np.argmin(mean_std(n, "entropy")["mean"])),
        }
        for n in counts
    }
    stop_k: dict[str, Any] = {}
    hit_rates: dict[str, Any] = {}
    for world in dict.fromkeys(r["world"] for r in stops):
        for n in dict.fromkeys(r["scenes"] for r in stops if r["world"] == world):
            key = f"{world}@{n}"
            rows = [r for r in stops if r["world"] == world and r["scenes"] == n]
            stop_k[key] = {"present": [r["present"] for r in rows if r["rule"] == RULES[0]]}
            hit_rates[key] = {}
            for rule in RULES:
                found = [r["found"] for r in rows if r["rule"] == rule]
                hits = sum(r["found"] == r["present"] for r in rows if r["rule"] == rule)
                stop_k[key][rule] = found
                hit_rates[key][rule] = f"{hits}/{len(found)}"
    return {
        "fig11": fig11,
        "stop_k": stop_k,
        "hit_rates": hit_rates,
        "paper": "Fig. 11: |C_low| > 0 until K = 3 and 0 from K = 3 once |D| >= 3; minimum H̃ at K = 3.",
    }


def _write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def _plot(path: Path, curves: list[dict], counts: tuple[int, ...], max_k: int) -> None:
    ks = list(range(1, max_k + 1))

    def stats(field: str, n: int, k: int) -> tuple[float, float]:
        values = [r[field] for r in curves if r["scenes"] == n and r["k"] == k]
        return float(np.mean(values)), float(np.std(values))

    figure, axes = plt.subplots(2, 2, figsize=(11, 8))
    for row, (field, label) in enumerate((("c_low", "|C_low|"), ("entropy", "H̃ (nats)"))):
        for n in counts:
            means, stds = zip(*(stats(field, n, k) for k in ks), strict=True)
            axes[row, 0].errorbar(ks, means, yerr=stds, capsize=3, marker="o", label=f"|D| = {n}")
        for k in ks:
            means, stds = zip(*(stats(field, n, k) for n in counts), strict=True)
            axes[row, 1].errorbar(counts, means, yerr=stds, capsize=3, marker="o", label=f"K = {k}")
        axes[row, 0].set(xlabel="K", ylabel=label, xticks=ks)
        axes[row, 1].set(xlabel="|D| (scenes)", ylabel=label, xscale="log")
        for axis in axes[row]:
            axis.legend(fontsize=7)
    for axis, letter in zip(axes.flat, "abcd", strict=True):
        axis.set_title(f"({letter})")
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    plt.close(figure)
