"""Fig. 10: entropy H̃ per Gibbs sweep, K-incremental from a K = 2 solution vs batch Gibbs with K = 3.

Protocol (§V-A). Each of ``--test-sets`` test sets holds ``--scenes`` pure scenes
of the paper's world (100 in the paper; ``--world``, each object giving the
active concepts of its perceived web, ``experiments.documents``, or its labels
with ``--documents labels``). The K = 2 solution is Algorithm 1 with
K = 2 and the model's ``sweeps`` sweeps; every K-incremental solver starts from
it, opens the third context by Algorithm 3 and runs Gibbs sweeps. They differ in
the tokens that seed the new context and in what follows:

- ``k_incremental_c_low``: the tokens of C_low (the ``paper`` rule);
- ``k_incremental_scene``: the tokens of the scene explained worst (the default
  model's birth move);
- ``..._split``: the same seed, then ``--split-scans`` restricted blocked scans
  that move whole scenes between their K = 2 context and the new one
  (:meth:`LDAState.grow_k_incrementally`, docs/context.md). A scan takes about
  1.2 sweeps' time and is charged as one sweep: the trace has no value for the
  first ``--split-scans`` sweeps.

Other tokens move with probability δ in all four, with the same draws (a generator
seeded by the test set).
The batch solver draws every assignment uniformly from K = 3 contexts (Algorithm 1);
its sweep 0, the random start, has no value. H̃ (Eq. 8, ρ = 0.25) is recorded after
every sweep, ``--sweeps`` in all per solver, and so is the share of scenes whose
most probable context is their true one (contexts matched one-to-one to the true
ones to maximise it): H̃ alone cannot tell the right split from a K = 2-like state.

Convergence (the paper measures it "in terms of entropy" without a rule, and
notes that both solvers end at the minimum entropy): per test set, the target
is the lowest final level among the solvers, a final level being the mean H̃ of
a run's last ``--tail`` sweeps, and ε = max(0.01 nats, 3 × the largest standard
deviation of H̃ over those last sweeps), the samplers' own noise once stationary.
A run has converged at the first sweep s from which the mean H̃ over every
``--window`` consecutive sweeps stays below target + ε; one that never does
before its tail (a local optimum) has not converged (null). ``--window 1`` is the
unsmoothed rule, reported too: there a single noisy sweep late in a stationary
chain resets the count. The control calibrates the rule: the batch chain
continued for ``--sweeps`` more sweeps, already stationary, is scored against the
same target and ε (without taking part in them) and should converge at 0.

Outputs: convergence.csv (test set, solver, sweep, H̃, scene accuracy), convergence.png
(mean H̃ ± std per sweep).
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
from scipy.optimize import linear_sum_assignment

from core.context import IncrementalLDA, low_confidence_concepts
from core.context.k_selection import PAPER_TAU
from core.context.k_selection.paper import PaperSettings
from core.context.k_selection.scenes import ScenesSettings
from core.errors import InvalidInputError
from experiments import documents

SOLVERS = (
    "k_incremental_c_low",
    "k_incremental_scene",
    "k_incremental_c_low_split",
    "k_incremental_scene_split",
    "batch",
)
CONTROL = "batch_continued"
LABELS = {
    "k_incremental_c_low": "K-incremental, C_low start (paper)",
    "k_incremental_scene": "K-incremental, worst-scene start",
    "k_incremental_c_low_split": "K-incremental, C_low start + scene split",
    "k_incremental_scene_split": "K-incremental, worst-scene start + scene split",
    "batch": "batch Gibbs, K = 3",
}
MIN_TOLERANCE = 0.01
FOUND = 0.95
"""A run has found the true contexts when this share of its scenes sits in its true context."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--test-sets", type=int, default=None, help="test sets (10; --quick: 2)")
    parser.add_argument("--scenes", type=int, default=None, help="scenes per test set (100; --quick: 30)")
    parser.add_argument("--sweeps", type=int, default=None, help="sweeps recorded per run (300; --quick: 60)")
    parser.add_argument(
        "--tail", type=int, default=None, help="last sweeps that define the final level (50; --quick: 20)"
    )
    parser.add_argument("--window", type=int, default=10, help="sweeps averaged by the convergence rule")
    parser.add_argument("--split-scans", type=int, default=3, help="restricted blocked scans of the split starts")
    documents.add_arguments(parser)


def scene_accuracy(model: IncrementalLDA, truth: np.ndarray) -> float:
    """Share of scenes whose most probable context is their true context ``truth`` (ids),
    under the one-to-one matching of contexts to true contexts that maximises it."""
    found = model.lda_state.context_given_scene().argmax(axis=1)
    table = np.zeros((int(truth.max()) + 1, model.n_contexts))
    np.add.at(table, (truth, found), 1)
    rows, columns = linear_sum_assignment(table, maximize=True)
    return float(table[rows, columns].sum() / truth.shape[0])


def trace_run(model: IncrementalLDA, sweeps: int, truth: np.ndarray) -> tuple[list[float], list[float]]:
    """H̃ and the scene accuracy now and after each of ``sweeps`` Gibbs sweeps."""
    entropies, accuracies = [model.entropy()], [scene_accuracy(model, truth)]
    for _ in range(sweeps):
        model.sweep()
        entropies.append(model.entropy())
        accuracies.append(scene_accuracy(model, truth))
    return entropies, accuracies


def sweeps_to_converge(
    traces: dict[str, list[float]], tail: int, window: int = 1, controls: dict[str, list[float]] | None = None
) -> dict[str, int | None]:
    """Per solver (and per control, scored against the solvers' target), the first sweep
    from which every ``window``-sweep mean of H̃ stays below the test set's target + ε
    (see module doc). A missing value counts as above."""
    tails = [np.asarray(trace[-tail:]) for trace in traces.values()]
    threshold = min(float(t.mean()) for t in tails) + max(MIN_TOLERANCE, 3.0 * max(float(t.std()) for t in tails))
    converged: dict[str, int | None] = {}
    for solver, trace in {**traces, **(controls or {})}.items():
        values = np.asarray(trace, dtype=float)
        values[~np.isfinite(values)] = np.inf
        means = np.lib.stride_tricks.sliding_window_view(values, window).mean(axis=1)
        above = np.flatnonzero(~(means <= threshold))
        first = int(above[-1]) + 1 if above.size else 0
        converged[solver] = first if first < len(values) - tail else None
    return converged


def run_test_set(
    scenes: list[list[str]], truth: np.ndarray, seed: int, sweeps: int, split_scans: int
) -> tuple[dict[str, list[float]], dict[str, list[float]]]:
    """Every solver's and the control's H̃ and scene-accuracy traces, indexed by sweep
    (``sweeps + 1`` values each, NaN where there is no model to measure)."""
    saved = IncrementalLDA(seed=seed).fit(scenes, n_contexts=2).to_state()
    traces: dict[str, list[float]] = {}
    accuracies: dict[str, list[float]] = {}
    for solver in SOLVERS[:-1]:
        model = IncrementalLDA.from_state(saved)
        state, h = model.lda_state, model.hyperparameters
        if "c_low" in solver:
            seed_tokens = low_confidence_concepts(state, PAPER_TAU)[state.words]
        else:
            worst = int(np.argmin(state.scene_fit()))
            seed_tokens = np.zeros(state.n_tokens, dtype=bool)
            seed_tokens[state.doc_offsets[worst] : state.doc_offsets[worst + 1]] = True
        scans = split_scans if solver.endswith("_split") else 0
        assert isinstance(h.k_rule, ScenesSettings | PaperSettings)  # both rules grow from a δ-start
        state.grow_k_incrementally(seed_tokens, h.k_rule.delta, np.random.default_rng(seed), split_scans=scans)
        entropies, accuracy = trace_run(model, sweeps - scans, truth)
        traces[solver], accuracies[solver] = [np.nan] * scans + entropies, [np.nan] * scans + accuracy
    batch = IncrementalLDA(seed=seed, sweeps=1).fit(scenes, n_contexts=3)
    entropies, accuracy = trace_run(batch, sweeps - 1, truth)
    traces["batch"], accuracies["batch"] = [np.nan, *entropies], [np.nan, *accuracy]
    traces[CONTROL], accuracies[CONTROL] = trace_run(batch, sweeps, truth)
    return traces, accuracies


def _spread(values: list[int | None]) -> dict[str, Any]:
    done = [v for v in values if v is not None]
    if not done:
        return {"converged": f"0/{len(values)}", "median": None, "quartiles": None}
    return {
        "converged": f"{len(done)}/{len(values)}",
        "median": float(np.median(done)),
        "quartiles": [float(q) for q in np.percentile(done, [25, 75])],
    }


def run(args: argparse.Namespace) -> dict[str, Any]:
    if args.window < 1:
        raise InvalidInputError("window", f"must be at least 1 sweep, got {args.window}")
    test_sets = args.test_sets or (2 if args.quick else 10)
    n_scenes = args.scenes or (30 if args.quick else 100)
    sweeps = args.sweeps or (60 if args.quick else 300)
    tail = args.tail or (20 if args.quick else 50)
    docs = documents.experiment_documents(args.world, args.seed, args.documents, args.quick)
    names = (*SOLVERS, CONTROL)
    traces: dict[str, list[list[float]]] = {name: [] for name in names}
    accuracies: dict[str, list[list[float]]] = {name: [] for name in names}
    rules = {"smoothed": args.window, "unsmoothed": 1}
    converged: dict[str, dict[str, list[int | None]]] = {rule: {name: [] for name in names} for rule in rules}
    for test_set in range(test_sets):
        seed = args.seed * 1000 + test_set
        generated = docs.scenes(n_scenes, seed)
        truth = np.unique([_main_context(scene.object_contexts) for scene in generated], return_inverse=True)[1]
        runs, accuracy = run_test_set([docs.scene(scene) for scene in generated], truth, seed, sweeps, args.split_scans)
        for name in names:
            traces[name].append(runs[name])
            accuracies[name].append(accuracy[name])
        control = {CONTROL: runs.pop(CONTROL)}
        for rule, window in rules.items():
            for name, sweep in sweeps_to_converge(runs, tail, window, control).items():
                converged[rule][name].append(sweep)
    _write_csv(args.out / "convergence.csv", traces, accuracies)
    _plot(args.out / "convergence.png", {solver: traces[solver] for solver in SOLVERS})
    checkpoints = [s for s in (3, 5, 10, 20, 50) if s <= sweeps]
    return {
        "world": args.world,
        "documents": args.documents,
        "scenes": n_scenes,
        "window": args.window,
        "split_scans": args.split_scans,
        "sweeps_to_converge": converged["smoothed"],
        "sweeps_to_converge_unsmoothed": converged["unsmoothed"],
        "summary": {rule: {name: _spread(c) for name, c in by_name.items()} for rule, by_name in converged.items()},
        "mean_entropy_at_sweep": {
            name: {s: _mean_of_recorded([t[s] for t in runs]) for s in (5, 10, 20, 50) if s < len(runs[0])}
            for name, runs in traces.items()
        },
        "final_entropy": {name: float(np.mean([np.mean(t[-tail:]) for t in runs])) for name, runs in traces.items()},
        "mean_scene_accuracy_at_sweep": {
            name: {s: _mean_of_recorded([t[s] for t in runs]) for s in checkpoints} for name, runs in accuracies.items()
        },
        "true_contexts_found_at_sweep": {
            name: {s: _share_found([t[s] for t in runs]) for s in checkpoints} for name, runs in accuracies.items()
        },
        "paper": "Fig. 10: from a K = 2 solution, K-incremental Gibbs converges faster than batch Gibbs; both reach the same H̃.",
    }


def _mean_of_recorded(values: list[float]) -> float | None:
    """Mean of the values that exist at this sweep (None before a run has any, e.g. during split scans)."""
    recorded = [v for v in values if np.isfinite(v)]
    return float(np.mean(recorded)) if recorded else None


def _share_found(accuracies: list[float]) -> str | None:
    """How many runs have their scenes in their true contexts at this sweep, as "found/runs" (None before any is measured)."""
    if not any(np.isfinite(a) for a in accuracies):
        return None
    return f"{sum(a >= FOUND for a in accuracies)}/{len(accuracies)}"


def _main_context(object_contexts: tuple[str, ...]) -> str:
    names, counts = np.unique(object_contexts, return_counts=True)
    return str(names[np.argmax(counts)])


def _write_csv(path: Path, traces: dict[str, list[list[float]]], accuracies: dict[str, list[list[float]]]) -> None:
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow(["test_set", "solver", "sweep", "entropy", "scene_accuracy"])
        for solver, runs in traces.items():
            for test_set, (trace, accuracy) in enumerate(zip(runs, accuracies[solver], strict=True)):
                writer.writerows(
                    (test_set, solver, sweep, value, accuracy[sweep])
                    for sweep, value in enumerate(trace)
                    if np.isfinite(value)
                )


def _plot(path: Path, traces: dict[str, list[list[float]]]) -> None:
    figure, axis = plt.subplots(figsize=(7, 4.5))
    for solver, runs in traces.items():
        values = np.array(runs)
        recorded = np.flatnonzero(np.isfinite(values).all(axis=0))
        mean, std = values[:, recorded].mean(axis=0), values[:, recorded].std(axis=0)
        axis.plot(recorded, mean, label=LABELS[solver], linestyle="--" if solver.endswith("_split") else "-")
        axis.fill_between(recorded, mean - std, mean + std, alpha=0.2)
    axis.set(xlabel="Gibbs sweep (a split scan counts as one)", ylabel="H̃ (nats)", title="Fig. 10: entropy per sweep")
    axis.legend(fontsize="small")
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    plt.close(figure)
