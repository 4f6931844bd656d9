"""The planning experiment on the paper world (§V-E, Figs. 15–16), at --quick size."""

from __future__ import annotations

import argparse
import csv
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from core.errors import InvalidInputError
from core.planning import MODES, PRUNING_THRESHOLD, Workspace, prune_behaviours
from experiments import documents, planning
from sim.world import World
from tests.test_planning_effects import synthetic_effects

#: Not one of the report's seeds (0-4): a test must not pin what the report judges.
TEST_SEED = 7


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict[str, Any], Path]:
    out = tmp_path_factory.mktemp("planning")
    parser = argparse.ArgumentParser()
    planning.add_arguments(parser)
    args = parser.parse_args([])
    args.out, args.quick, args.seed, args.json = out, True, TEST_SEED, False
    return planning.run(args), out


def test_fig_15_counts_from_effects_learned_in_the_paper_world(quick_run: tuple[dict[str, Any], Path]) -> None:
    summary, _ = quick_run
    assert summary["fig_15_paper_counts"] == {
        "unpruned_cup_8_to_5": 2380,
        "kitchen_cup_8_to_5": 156,
        "playroom_ball_7_to_1": 820,
    }
    steps = summary["learned_steps"]
    assert steps["move_right"] == steps["push_right"] == [-1, 0]
    assert steps["move_forward"] == steps["push_forward"] == [0, 1]
    assert steps["grasp"] == steps["shake"] == [0, 0]


def test_pruning_learned_from_world_scenes(quick_run: tuple[dict[str, Any], Path]) -> None:
    kept = quick_run[0]["kept_behaviours"]
    assert {context: len(behaviours) for context, behaviours in kept.items()} == {
        "kitchen": 5,
        "playroom": 9,
        "workshop": 13,
    }
    assert not any(b.startswith("push") for b in kept["playroom"])


def test_labelled_scene_source_prunes_the_same() -> None:
    learned = planning.learned_verb_given_context(
        documents.experiment_documents("hard", TEST_SEED, documents.LABELS),
        planning.TRAINING_SCENES,
        TEST_SEED,
        "scenes",
    )
    assert {context: len(prune_behaviours(p).kept) for context, p in learned.items()} == {
        "kitchen": 5,
        "playroom": 9,
        "workshop": 13,
    }


def test_fig_16_reductions_follow_the_paper(quick_run: tuple[dict[str, Any], Path]) -> None:
    summary, _ = quick_run
    for mode in MODES:
        medians = summary["median_nodes"][mode]
        assert medians["workshop"]["reduction"] == 0.0
        assert medians["kitchen"]["reduction"] > medians["playroom"]["reduction"] > 0.0
    assert all(0 < ratio["pruned"] < 1 for ratio in summary["median_astar_over_paper"].values())


def test_outputs_are_written(quick_run: tuple[dict[str, Any], Path]) -> None:
    summary, out = quick_run
    with (out / "results.csv").open(encoding="utf-8") as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == summary["scenarios"] * len(MODES) == planning.QUICK_SCENARIOS * len(MODES)
    assert {row["status_pruned"] for row in rows} == {"solved"}
    # Pruning never shortens a plan; at equal length the paper tree only shrinks (a pruned
    # shortcut, e.g. a throw across two cells, can make the pruned tree deeper and larger).
    assert all(int(row["plan_length_pruned"]) >= int(row["plan_length_unpruned"]) for row in rows)
    same_depth = [
        row for row in rows if row["mode"] == "paper" and row["plan_length_pruned"] == row["plan_length_unpruned"]
    ]
    assert same_depth and all(int(row["nodes_pruned"]) <= int(row["nodes_unpruned"]) for row in same_depth)
    assert (out / "planning.png").stat().st_size > 10_000


def test_same_seed_same_scenarios() -> None:
    effects = synthetic_effects(Workspace(cell_size=0.1))
    kept = {"kitchen": ["move_left", "move_right"], "workshop": list(effects.behaviours)}
    world = World.paper(TEST_SEED)
    first, second, other = (
        planning.random_scenarios(effects, kept, world, 40, np.random.default_rng(seed)) for seed in (3, 3, 4)
    )
    assert first == second and first != other


def test_defaults_and_bad_sizes(tmp_path: Path) -> None:
    parser = argparse.ArgumentParser()
    planning.add_arguments(parser)
    args = parser.parse_args(["--scenarios", "0"])
    assert args.threshold == PRUNING_THRESHOLD and args.pruning_source == "context_model"
    args.out, args.quick, args.seed = tmp_path, True, TEST_SEED
    with pytest.raises(InvalidInputError, match="scenarios: must be at least 1"):
        planning.run(args)
