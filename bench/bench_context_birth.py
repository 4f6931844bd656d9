"""How fast online Incremental-LDA finds a context that appears late (``python -m bench.bench_context_birth``).

Issue 17, goal 6. Each run learns, one scene at a time with default settings
(:meth:`IncrementalLDA.learn_scene`), a stream whose first phase draws its scenes from
all contexts of a world but one, and whose second phase from all of them:

- ``paper``: the paper's world, kitchen and playroom for 30 scenes, then all three
  (``contextweb bridge simulate --contexts kitchen,playroom --contexts
  kitchen,playroom,workshop --scenes 30``: the workshop from scene 30, concepts level);
- ``generic-N`` (N = 2..5): a generic world of N contexts, N − 1 of them for 60
  scenes, then all N for 60 (the issue's "a fourth room after 60 scenes").

Per run: the scene where the late context first appears, K then, the delay until it
is found (0: with that very scene; ``None``: not by the end), found meaning that most
of its scenes learned so far have their largest θ in a context opened since it
appeared, and false births: the largest excess of K over the contexts seen so far, at
any scene. Besides, false births and growth checks on steady streams (every context
from the start, 400 scenes: paper, generic-3, -4 and -5). Seeds 0-9 (the tests use others);
``--seeds 1000-1059`` runs on others, to check that a figure holds beyond the seeds it was
first measured on. Writes ``bench/results/context_birth.json`` (with ``--seeds``,
``context_birth_seeds_START_STOP.json``).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from dataclasses import asdict, dataclass
from typing import Any

from bench import RESULTS
from core.context import IncrementalLDA
from sim.world import World, WorldConfig, generate_scenes

SEEDS = tuple(range(10))
SCENARIOS = ("paper", "generic-2", "generic-3", "generic-4", "generic-5")
STEADY_SCENES = 400


@dataclass(frozen=True)
class BirthRun:
    """One stream learned online: where the late context appeared and when K caught up."""

    scenario: str
    seed: int
    first_appearance: int
    k_before: int
    """K when the late context first appeared."""
    delay: int | None
    late_scenes: int | None
    """Scenes of the late context learned when it was found (its first included), or None."""
    max_excess: int
    final_k: int
    contexts_present: int
    growth_checks: int
    seconds: float


def scenario_stream(scenario: str, seed: int) -> tuple[list[list[str]], list[str], str]:
    """The scenes (concept names) of a scenario, each scene's true context, and the late context."""
    if scenario == "paper":
        world = World(WorldConfig.paper(), seed)
        names = [context.name for context in world.config.contexts]
        early_scenes, late_scenes = 30, 30
        late = "workshop"
        early = [name for name in names if name != late]
    else:
        n_contexts = int(scenario.split("-")[1])
        world = World(WorldConfig.generic(n_contexts, seed), seed)
        names = [context.name for context in world.config.contexts]
        early_scenes, late_scenes = 60, 60
        late = names[-1]
        early = names[:-1]
    phases = [
        generate_scenes(world, early_scenes, seed, contexts=early),
        generate_scenes(world, late_scenes, seed + 1, contexts=names),
    ]
    scenes = [scene for phase in phases for scene in phase]
    return [scene.tokens() for scene in scenes], [scene.object_contexts[0] for scene in scenes], late


def birth_run(scenario: str, seed: int, **hyperparameters: Any) -> BirthRun:
    """Learn one scenario's stream online and measure the late context's delay and false births."""
    scenes, truth, late = scenario_stream(scenario, seed)
    model = IncrementalLDA(seed=seed, **hyperparameters)
    seen: set[str] = set()
    first_appearance, delay, late_scenes, max_excess, checks, k_before = -1, None, None, 0, 0, 0
    started = time.perf_counter()
    for index, (words, context) in enumerate(zip(scenes, truth, strict=True)):
        if context == late and first_appearance < 0:
            first_appearance, k_before = index, model.n_contexts
        seen.add(context)
        update = model.learn_scene(words)
        checks += update.growth_checked
        max_excess = max(max_excess, model.n_contexts - len(seen))
        if first_appearance >= 0 and delay is None and _found(model, truth, late, first_appearance, k_before):
            delay = index - first_appearance
            late_scenes = truth[first_appearance : index + 1].count(late)
    return BirthRun(
        scenario=scenario,
        seed=seed,
        first_appearance=first_appearance,
        k_before=k_before,
        delay=delay,
        late_scenes=late_scenes,
        max_excess=max_excess,
        final_k=model.n_contexts,
        contexts_present=len(seen),
        growth_checks=checks,
        seconds=time.perf_counter() - started,
    )


def _found(model: IncrementalLDA, truth: list[str], late: str, first_appearance: int, k_before: int) -> bool:
    """The late context has a context of its own: most of its scenes learned so far have their
    largest θ in a context opened since it first appeared (index ≥ ``k_before``)."""
    if model.n_contexts <= k_before:
        return False
    theta = model.lda_state.context_given_scene(first_appearance)
    own = [int(row.argmax()) >= k_before for row, context in zip(theta, truth[first_appearance:]) if context == late]
    return 2 * sum(own) > len(own)


def steady_run(scenario: str, seed: int, n_scenes: int = STEADY_SCENES) -> dict[str, int]:
    """False births on a stream whose contexts are all there from the start: the largest excess
    of K over the contexts seen so far, and the growth checks after the first scheduled ones."""
    n_contexts = 3 if scenario == "paper" else int(scenario.split("-")[1])
    config = WorldConfig.paper() if scenario == "paper" else WorldConfig.generic(n_contexts, seed)
    scenes = generate_scenes(World(config, seed), n_scenes, seed)
    model = IncrementalLDA(seed=seed)
    seen: set[str] = set()
    max_excess, late_checks = 0, 0
    for index, scene in enumerate(scenes):
        seen.add(scene.object_contexts[0])
        update = model.learn_scene(scene.tokens())
        late_checks += update.growth_checked and index >= model.hyperparameters.k_rule.birth_check_interval
        max_excess = max(max_excess, model.n_contexts - len(seen))
    return {"seed": seed, "max_excess": max_excess, "final_k": model.n_contexts, "checks_after_start": late_checks}


def summary(runs: list[BirthRun]) -> dict[str, float | int]:
    """Median and worst delay (a miss counts as the rest of the stream), misses, runs with a false birth."""
    delays = [run.delay for run in runs if run.delay is not None]
    late_scenes = [run.late_scenes for run in runs if run.late_scenes is not None]
    return {
        "runs": len(runs),
        "missed": sum(run.delay is None for run in runs),
        "median_delay": statistics.median(delays) if delays else float("nan"),
        "max_delay": max(delays) if delays else float("nan"),
        "median_late_scenes": statistics.median(late_scenes) if late_scenes else float("nan"),
        "max_late_scenes": max(late_scenes) if late_scenes else float("nan"),
        "false_births": sum(run.max_excess > 0 for run in runs),
        "growth_checks_mean": statistics.mean(run.growth_checks for run in runs),
        "seconds_mean": statistics.mean(run.seconds for run in runs),
    }


def seed_range(text: str) -> tuple[int, ...]:
    """``START-STOP`` (both included, START <= STOP, non-negative) as the seeds in between."""
    start, separator, stop = text.partition("-")
    if not (separator and start.isdigit() and stop.isdigit() and int(start) <= int(stop)):
        raise argparse.ArgumentTypeError(f"expected START-STOP with 0 <= START <= STOP, got {text!r}")
    return tuple(range(int(start), int(stop) + 1))


def main() -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="5 seeds instead of 10")
    parser.add_argument("--seeds", type=seed_range, default=None, help="START-STOP, both included (default 0-9)")
    args = parser.parse_args(sys.argv[1:])
    seeds = args.seeds if args.seeds is not None else SEEDS
    seeds = seeds[:5] if args.quick else seeds
    runs = {scenario: [birth_run(scenario, seed) for seed in seeds] for scenario in SCENARIOS}
    steady = {
        scenario: [steady_run(scenario, seed) for seed in seeds]
        for scenario in ("paper", "generic-3", "generic-4", "generic-5")
    }
    result: dict[str, Any] = {
        "seeds": [seeds[0], seeds[-1]],
        "by_scenario": {scenario: summary(rows) for scenario, rows in runs.items()},
        "steady": steady,
        "all": summary([run for rows in runs.values() for run in rows]),
        "runs": [asdict(run) for rows in runs.values() for run in rows],
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    # Other seeds than the default are a check of the default run's figures, kept beside them.
    name = "context_birth" if args.seeds is None else f"context_birth_seeds_{seeds[0]}_{seeds[-1]}"
    (RESULTS / f"{name}.json").write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    for name, row in [*result["by_scenario"].items(), ("all", result["all"])]:
        print(
            f"{name:>10}: delay median {row['median_delay']}, max {row['max_delay']} (its own scenes: median "
            f"{row['median_late_scenes']}, max {row['max_late_scenes']}), missed {row['missed']}/"
            f"{row['runs']}, runs with a false birth {row['false_births']}, growth checks {row['growth_checks_mean']:.1f}"
            f" per run, {row['seconds_mean']:.2f} s per run"
        )
    for scenario, rows in steady.items():
        print(
            f"{scenario + ', steady':>16}: {STEADY_SCENES} scenes, runs with a false birth "
            f"{sum(row['max_excess'] > 0 for row in rows)}/{len(rows)}, K {[row['final_k'] for row in rows]}, "
            f"growth checks after the first scenes {[row['checks_after_start'] for row in rows]}"
        )
    for run in result["runs"]:
        print(
            f"  {run['scenario']:>10} seed {run['seed']}: appears {run['first_appearance']} at K {run['k_before']}, "
            f"delay {run['delay']} ({run['late_scenes']} of its scenes), "
            f"max excess {run['max_excess']}, K {run['final_k']}/{run['contexts_present']}"
        )
    return result


if __name__ == "__main__":
    main()
