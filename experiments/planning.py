"""Planning in context (§V-E, Figs. 15–16): planning-tree sizes with and without context-dependent pruning.

Protocol:

1. Effects: the paper world's training objects are recorded (sim.world) and
   their effect vectors f extracted (core.features.recording_features); each
   behaviour's effect on position is learned from them (core.planning.learn_effects).
2. Pruning: P(verb | context) is learned from scenes of the paper world
   (``--world``; each object gives the active concepts of its perceived web,
   ``experiments.documents``, verbs included, or its labels with
   ``--documents labels``) and
   each context keeps the behaviours the pruning rule keeps. With
   ``--pruning-source context_model`` (default) it is the verb part of the
   context model's P(concept | context) (collapsed-Gibbs LDA, core.context,
   at the world's number of contexts: discovering K is §IV's subject, not
   planning's); each learned context is named after the labelled context whose
   scenes it explains most (a one-to-one assignment), for reporting only. With
   ``scenes`` it is the verb-token frequencies of the scenes of each labelled
   context.
3. Fig. 15: the cup 8 → 5 (unpruned and Kitchen) and the ball 7 → 1 (Playroom)
   in ``paper`` mode: 2,380 / 156 / 820 nodes.
4. Fig. 16: ``--scenarios`` random scenarios, each a uniformly random context,
   one of its nouns as the object, and distinct random start and goal
   positions; each planned unpruned and pruned in every mode.

Outputs: results.csv (one row per scenario and mode), planning.png (Fig. 16's
box plots, one panel per mode) and the summary (canonical counts, median node
counts and reductions per context and mode, A* / paper node ratios).
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
from scipy.optimize import linear_sum_assignment

from core.context.lda import LDAState
from core.errors import InvalidInputError
from core.planning import (
    MODES,
    PRUNING_THRESHOLD,
    BehaviourEffects,
    Workspace,
    learn_effects,
    plan,
    prune_behaviours,
    verb_given_context_from_model,
    verb_given_context_from_scenes,
)
from experiments import context_scenes, documents
from experiments.documents import Documents
from sim.world import World

SCENARIOS = 10_000
QUICK_SCENARIOS = 300
#: Scenes the pruning is learned from, at every size: the paper's context experiments use up
#: to 50, and with 20 the context model misses the paper's 5 / 9 / 13 for 3 seeds of 8.
TRAINING_SCENES = 50
#: Training objects recorded per noun in --quick runs (the full run records all 45).
QUICK_OBJECTS_PER_NOUN = 1
#: The context model's settings (§V: α = ξ = 0.1) and Gibbs sweeps.
ALPHA = XI = 0.1
SWEEPS = 150
PRUNING_SOURCES = ("context_model", "scenes")
# Independent random streams derived from --seed.
_CONTEXT_MODEL_STREAM = 1
_SCENARIO_STREAM = 2

#: Fig. 15's two scenarios: context, object noun, start, goal.
FIG_15 = {
    "unpruned_cup_8_to_5": (None, "cup", 8, 5),
    "kitchen_cup_8_to_5": ("kitchen", "cup", 8, 5),
    "playroom_ball_7_to_1": ("playroom", "ball", 7, 1),
}

CSV_FIELDS = (
    "scenario",
    "context",
    "object",
    "start",
    "goal",
    "mode",
    "plan_length_unpruned",
    "plan_length_pruned",
    "nodes_unpruned",
    "nodes_pruned",
    "expanded_unpruned",
    "expanded_pruned",
    "status_unpruned",
    "status_pruned",
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--scenarios", type=int, default=None, help=f"random scenarios (default {SCENARIOS}, --quick {QUICK_SCENARIOS})"
    )
    parser.add_argument("--threshold", type=float, default=PRUNING_THRESHOLD, help="θ of the pruning rule")
    parser.add_argument("--cell-size", type=float, default=Workspace().cell_size, help="workspace cell size, metres")
    parser.add_argument(
        "--pruning-source",
        choices=PRUNING_SOURCES,
        default="context_model",
        help="where P(verb | context) is learned from",
    )
    documents.add_arguments(parser)


def learned_effects(
    world: World, workspace: Workspace, seed: int, objects_per_noun: int | None = None
) -> BehaviourEffects:
    """Effects learned from the effect vectors of the world's training interactions."""
    objects = world.train_objects
    if objects_per_noun is not None:
        objects = tuple(
            obj for noun in world.vocabulary.nouns for obj in [o for o in objects if o.noun == noun][:objects_per_noun]
        )
    vectors, behaviours = [], []
    for _, effects in context_scenes.object_features(world, objects, seed).values():
        for behaviour, effect in effects.items():
            vectors.append(effect)
            behaviours.append(behaviour)
    return learn_effects(np.array(vectors), behaviours, workspace)


def learned_verb_given_context(docs: Documents, n_scenes: int, seed: int, source: str) -> dict[str, dict[str, float]]:
    """P(verb | context) learned from ``n_scenes`` pure scenes of the world (module docstring, step 2)."""
    world = docs.world
    scenes = docs.scenes(n_scenes, seed)
    tokens = [docs.scene(scene) for scene in scenes]
    labels = [scene.object_contexts[0] for scene in scenes]
    verbs = list(world.vocabulary.verbs)
    if source == "scenes":
        return verb_given_context_from_scenes(tokens, labels, verbs)
    vocabulary, names = world.vocabulary, [context.name for context in world.config.contexts]
    model = LDAState(ALPHA, XI, len(vocabulary), len(names))
    for scene in tokens:
        model.append_document(np.array([vocabulary.index(token) for token in scene], dtype=np.int32))
    rng = np.random.default_rng([seed, _CONTEXT_MODEL_STREAM])
    model.initialize_randomly(rng)
    model.sweep(rng, SWEEPS)
    theta, label_array = model.context_given_scene(), np.array(labels)
    weight = np.stack([theta[label_array == name].sum(axis=0) for name in names])  # labelled × learned contexts
    named, learned = linear_sum_assignment(weight, maximize=True)
    verb_phi = verb_given_context_from_model(model.concept_given_context(), vocabulary.concepts, verbs)
    return {names[i]: dict(zip(verbs, verb_phi[k].tolist(), strict=True)) for i, k in zip(named, learned, strict=True)}


def run(args: argparse.Namespace) -> dict[str, Any]:
    n_scenarios = args.scenarios if args.scenarios is not None else (QUICK_SCENARIOS if args.quick else SCENARIOS)
    if n_scenarios < 1:
        raise InvalidInputError("scenarios", f"must be at least 1, got {n_scenarios}")
    docs = documents.experiment_documents(args.world, args.seed, args.documents, args.quick)
    world = docs.world
    effects = learned_effects(
        world, Workspace(cell_size=args.cell_size), args.seed, QUICK_OBJECTS_PER_NOUN if args.quick else None
    )
    verb_given_context = learned_verb_given_context(docs, TRAINING_SCENES, args.seed, args.pruning_source)
    kept = {
        context: [b for b in effects.behaviours if b in prune_behaviours(p, args.threshold).kept]
        for context, p in sorted(verb_given_context.items())
    }

    rows = random_scenarios(effects, kept, world, n_scenarios, np.random.default_rng([args.seed, _SCENARIO_STREAM]))
    _write_csv(args.out / "results.csv", rows)
    _plot(args.out / "planning.png", rows, sorted(kept))
    return {
        "scenarios": n_scenarios,
        "threshold": args.threshold,
        "pruning_source": args.pruning_source,
        "workspace": {
            "columns": effects.workspace.columns,
            "rows": effects.workspace.rows,
            "cell_size": effects.workspace.cell_size,
            "layout": effects.workspace.layout(),
        },
        "learned_steps": {
            b: "off_table" if off else step
            for b, step, off in zip(effects.behaviours, effects.steps.tolist(), effects.leaves_table, strict=True)
        },
        "kept_behaviours": kept,
        "fig_15_paper_counts": canonical_counts(effects, kept),
        "median_nodes": _medians(rows, sorted(kept)),
        "median_astar_over_paper": _astar_over_paper(rows, sorted(kept)),
        "share_pruned_plan_longer": _share_longer(rows, sorted(kept)),
    }


def canonical_counts(effects: BehaviourEffects, kept: dict[str, list[str]]) -> dict[str, int]:
    """Fig. 15's node counts in ``paper`` mode (2,380 / 156 / 820 in the paper)."""
    counts = {}
    for name, (context, noun, start, goal) in FIG_15.items():
        behaviours = None if context is None else kept[context]
        counts[name] = plan(effects, {noun: start}, noun, goal, behaviours=behaviours, mode="paper").nodes_generated
    return counts


def random_scenarios(
    effects: BehaviourEffects, kept: dict[str, list[str]], world: World, count: int, rng: np.random.Generator
) -> list[dict[str, Any]]:
    """Fig. 16's scenarios: random context, object, start ≠ goal; every mode unpruned and pruned."""
    contexts = sorted(kept)
    positions = np.array(effects.workspace.positions)
    rows = []
    for scenario in range(count):
        context = contexts[rng.integers(len(contexts))]
        nouns = world.config.context(context).nouns
        noun = nouns[rng.integers(len(nouns))]
        start, goal = (int(p) for p in rng.choice(positions, size=2, replace=False))
        for mode in MODES:
            unpruned = plan(effects, {noun: start}, noun, goal, mode=mode)
            pruned = plan(effects, {noun: start}, noun, goal, behaviours=kept[context], mode=mode)
            rows.append(
                {
                    "scenario": scenario,
                    "context": context,
                    "object": noun,
                    "start": start,
                    "goal": goal,
                    "mode": mode,
                    "plan_length_unpruned": len(unpruned.plan),
                    "plan_length_pruned": len(pruned.plan),
                    "nodes_unpruned": unpruned.nodes_generated,
                    "nodes_pruned": pruned.nodes_generated,
                    "expanded_unpruned": unpruned.nodes_expanded,
                    "expanded_pruned": pruned.nodes_expanded,
                    "status_unpruned": unpruned.status,
                    "status_pruned": pruned.status,
                }
            )
    return rows


def _write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.DictWriter(handle, fieldnames=CSV_FIELDS)
        writer.writeheader()
        writer.writerows(rows)


def _column(rows: list[dict[str, Any]], mode: str, context: str, key: str) -> np.ndarray:
    return np.array([row[key] for row in rows if row["mode"] == mode and row["context"] == context], dtype=float)


def _medians(rows: list[dict[str, Any]], contexts: list[str]) -> dict[str, dict[str, dict[str, float]]]:
    """Per mode and context: median nodes unpruned and pruned, and the median reduction 1 − pruned / unpruned."""
    out: dict[str, dict[str, dict[str, float]]] = {}
    for mode in MODES:
        out[mode] = {}
        for context in contexts:
            unpruned = _column(rows, mode, context, "nodes_unpruned")
            pruned = _column(rows, mode, context, "nodes_pruned")
            if len(unpruned):
                out[mode][context] = {
                    "unpruned": float(np.median(unpruned)),
                    "pruned": float(np.median(pruned)),
                    "reduction": float(np.median(1.0 - pruned / unpruned)),
                }
    return out


def _astar_over_paper(rows: list[dict[str, Any]], contexts: list[str]) -> dict[str, dict[str, float]]:
    """Median over scenarios of A*'s generated nodes / the paper tree's, pruned and unpruned."""
    out: dict[str, dict[str, float]] = {}
    for context in contexts:
        paper_pruned = _column(rows, "paper", context, "nodes_pruned")
        if len(paper_pruned):
            out[context] = {
                "pruned": float(np.median(_column(rows, "astar", context, "nodes_pruned") / paper_pruned)),
                "unpruned": float(
                    np.median(
                        _column(rows, "astar", context, "nodes_unpruned")
                        / _column(rows, "paper", context, "nodes_unpruned")
                    )
                ),
            }
    return out


def _share_longer(rows: list[dict[str, Any]], contexts: list[str]) -> dict[str, float]:
    """Per context, the share of scenarios whose shortest plan grows when pruning removes a shortcut."""
    return {
        context: float(
            np.mean(
                _column(rows, "bfs", context, "plan_length_pruned")
                > _column(rows, "bfs", context, "plan_length_unpruned")
            )
        )
        for context in contexts
        if len(_column(rows, "bfs", context, "plan_length_pruned"))
    }


def _plot(path: Path, rows: list[dict[str, Any]], contexts: list[str]) -> None:
    """Fig. 16: per mode, unpruned vs pruned node counts grouped by context (log scale, outliers as stars)."""
    figure, axes = plt.subplots(1, len(MODES), figsize=(5 * len(MODES), 4.2), sharey=False)
    colours = {"nodes_unpruned": "tab:red", "nodes_pruned": "tab:blue"}
    for axis, mode in zip(axes, MODES, strict=True):
        for offset, key in ((-0.18, "nodes_unpruned"), (0.18, "nodes_pruned")):
            data = [_column(rows, mode, context, key) for context in contexts]
            boxes = axis.boxplot(
                data,
                positions=np.arange(len(contexts)) + offset,
                widths=0.3,
                patch_artist=True,
                flierprops={"marker": "*", "markersize": 5},
                medianprops={"color": "black"},
            )
            for box in boxes["boxes"]:
                box.set_facecolor(colours[key])
                box.set_alpha(0.6)
        axis.set_yscale("log")
        axis.set_xticks(np.arange(len(contexts)), [c.capitalize() for c in contexts])
        axis.set_title(f"{mode} mode")
        axis.set_ylabel("nodes generated")
    handles = [plt.Rectangle((0, 0), 1, 1, color=c, alpha=0.6) for c in colours.values()]
    axes[0].legend(handles, ["unpruned", "pruned"], loc="upper left", fontsize="small")
    figure.suptitle(f"Planning-tree sizes of {len({r['scenario'] for r in rows})} random scenarios (Fig. 16)")
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    plt.close(figure)
