"""Forward planners with context-dependent pruning (§V-E, Figs. 15–16)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from core.planning import MODES, Workspace, learn_effects, plan, plan_in_context, verb_given_context_from_world
from core.planning.effects import BehaviourEffects
from tests.test_planning_effects import CELL, synthetic_effect_vectors, synthetic_effects

EFFECTS = synthetic_effects()
CONTEXTS = verb_given_context_from_world()


def tree_size(branching: int, depth: int) -> int:
    return sum(branching**level for level in range(depth + 1))


def replay(effects: BehaviourEffects, start: int, behaviours: tuple[str, ...]) -> list[int]:
    positions = [start]
    for behaviour in behaviours:
        positions.append(effects.outcome(behaviour, positions[-1]))
    return positions


def test_paper_counts_of_fig_15() -> None:
    cup_unpruned = plan(EFFECTS, {"cup": 8}, "cup", 5, mode="paper")
    cup_kitchen = plan_in_context(EFFECTS, {"cup": 8}, "cup", 5, CONTEXTS["kitchen"], mode="paper")
    ball_playroom = plan_in_context(EFFECTS, {"ball": 7}, "ball", 1, CONTEXTS["playroom"], mode="paper")
    cup_workshop = plan_in_context(EFFECTS, {"cup": 8}, "cup", 5, CONTEXTS["workshop"], mode="paper")
    assert (cup_unpruned.nodes_generated, cup_kitchen.nodes_generated, ball_playroom.nodes_generated) == (
        2380,
        156,
        820,
    )
    assert cup_workshop.nodes_generated == 2380 and cup_workshop.pruned == ()
    assert cup_kitchen.plan == ("move_right",) * 3 and cup_kitchen.positions == (8, 7, 6, 5)
    assert len(cup_kitchen.pruned) == 8 and len(ball_playroom.pruned) == 4
    assert cup_unpruned.nodes_expanded == tree_size(13, 2)


def test_paper_tree_expands_dead_ends_like_the_paper() -> None:
    """Corner to corner, five levels: throw and off-edge moves still count as full subtrees."""
    result = plan(EFFECTS, {"box": 1}, "box", 12, mode="paper")
    assert result.status == "solved" and len(result.plan) == 5
    assert result.nodes_generated == tree_size(13, 5) == 402_234


@pytest.mark.parametrize("context", sorted(CONTEXTS))
def test_graph_searches_are_optimal_and_valid(context: str) -> None:
    workspace = EFFECTS.workspace
    for start in workspace.positions:
        for goal in workspace.positions:
            results = {
                mode: plan_in_context(EFFECTS, {"o": start}, "o", goal, CONTEXTS[context], mode=mode) for mode in MODES
            }
            lengths = {mode: len(r.plan) for mode, r in results.items()}
            assert set(lengths.values()) == {workspace.grid_distance(start, goal)}, (start, goal, lengths)
            for result in results.values():
                assert result.status == "solved"
                assert replay(EFFECTS, start, result.plan) == list(result.positions)
                assert result.positions[-1] == goal
            assert (
                max(results["astar"].nodes_generated, results["bfs"].nodes_generated)
                <= results["paper"].nodes_generated
            )


@st.composite
def random_problems(draw: st.DrawFn) -> tuple[BehaviourEffects, dict[str, int], int]:
    steps = draw(st.lists(st.tuples(st.integers(-2, 2), st.integers(-2, 2)), min_size=1, max_size=5))
    displacements = {f"b{i}": (-c * CELL, r * CELL, 0.0) for i, (c, r) in enumerate(steps)}
    vectors, labels = synthetic_effect_vectors(displacements, per_behaviour=3, noise=0.001)
    effects = learn_effects(vectors, labels, Workspace(cell_size=CELL))
    cells = draw(st.lists(st.integers(1, 12), min_size=2, max_size=4, unique=True))
    table = {f"o{i}": cell for i, cell in enumerate(cells[:-1])}
    return effects, table, cells[-1]


@settings(max_examples=60, deadline=None)
@given(random_problems())
def test_modes_agree_on_random_problems(problem: tuple[BehaviourEffects, dict[str, int], int]) -> None:
    effects, table, goal = problem
    obstacles = {position for name, position in table.items() if name != "o0"}
    bfs = plan(effects, table, "o0", goal, mode="bfs")
    astar = plan(effects, table, "o0", goal, mode="astar")
    paper = plan(effects, table, "o0", goal, mode="paper", node_budget=200_000)
    assert bfs.status == astar.status and bfs.status in ("solved", "unreachable")
    if bfs.status == "solved":
        assert len(astar.plan) == len(bfs.plan)
        for result in (bfs, astar):
            positions = replay(effects, table["o0"], result.plan)
            assert positions[-1] == goal and not obstacles & set(positions) and 0 not in positions
        assert paper.status == "budget_exceeded" or len(paper.plan) == len(bfs.plan)
    else:
        assert paper.status in ("unreachable", "budget_exceeded")


def test_other_objects_block_their_cells() -> None:
    result = plan(EFFECTS, {"cup": 8, "box": 6}, "cup", 5, mode="astar")
    assert result.status == "solved" and len(result.plan) == 5 and 6 not in result.positions


@pytest.mark.parametrize("mode", MODES)
def test_start_at_goal_is_an_empty_plan(mode: str) -> None:
    result = plan(EFFECTS, {"cup": 3}, "cup", 3, mode=mode)
    assert (result.status, result.plan, result.positions, result.nodes_generated) == ("solved", (), (3,), 1)


@pytest.mark.parametrize("mode", MODES)
def test_unreachable_goal_is_reported(mode: str) -> None:
    result = plan(EFFECTS, {"cup": 8}, "cup", 5, behaviours=["grasp", "shake", "move_forward"], mode=mode)
    assert result.status == "unreachable" and "not reachable" in result.message
    assert result.plan == () and set(result.pruned) == set(EFFECTS.behaviours) - {"grasp", "shake", "move_forward"}


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize(
    ("budget", "word"), [({"node_budget": 10}, "node_budget"), ({"depth_budget": 2}, "depth_budget")]
)
def test_budgets_stop_the_search(mode: str, budget: dict[str, int], word: str) -> None:
    result = plan(EFFECTS, {"cup": 8}, "cup", 5, mode=mode, **budget)
    assert result.status == "budget_exceeded" and word in result.message
    assert result.nodes_generated <= budget.get("node_budget", np.inf)


@pytest.mark.parametrize(
    ("table", "object_name", "goal", "options", "field"),
    [
        ({"cup": 8}, "mug", 5, {}, "object"),
        ([("cup", 8)], "cup", 5, {}, "table"),
        ({"cup": 8}, "cup", 13, {}, "goal"),
        ({"cup": 8}, "cup", 0, {}, "goal"),
        ({"cup": 8}, "cup", "5", {}, "goal"),
        ({"cup": 8, "box": 5}, "cup", 5, {}, "goal"),
        ({"cup": 0}, "cup", 5, {}, "table[cup]"),
        ({"cup": 8, "box": 8}, "cup", 5, {}, "table"),
        ({"cup": 8}, "cup", 5, {"behaviours": ["fly"]}, "behaviours"),
        ({"cup": 8}, "cup", 5, {"behaviours": ["grasp", "grasp"]}, "behaviours"),
        ({"cup": 8}, "cup", 5, {"mode": "dfs"}, "mode"),
        ({"cup": 8}, "cup", 5, {"node_budget": 0}, "node_budget"),
        ({"cup": 8}, "cup", 5, {"depth_budget": -1}, "depth_budget"),
    ],
)
def test_bad_requests_name_the_field(table: dict, object_name: str, goal: object, options: dict, field: str) -> None:
    result = plan(EFFECTS, table, object_name, goal, **options)  # type: ignore[arg-type]
    assert result.status == "invalid" and result.field == field and result.message.startswith(f"{field}: ")


def test_context_without_a_learned_behaviour_is_invalid() -> None:
    partial = {verb: p for verb, p in CONTEXTS["kitchen"].items() if verb != "grasp"}
    result = plan_in_context(EFFECTS, {"cup": 8}, "cup", 5, partial)
    assert result.status == "invalid" and result.field == "verb_given_context" and "grasp" in result.message
