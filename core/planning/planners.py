"""Forward planners over the learned effects, with context-dependent pruning (§V-E, Figs. 15–16).

Three modes, all limited by a node budget and a depth budget:

- ``paper``: the paper's "breadth-first forward planning scheme": the tree is
  expanded level by level with every kept behaviour at every node, until a
  level holds the goal. Its node count is the paper's: with b kept behaviours
  and the goal d behaviours away, 1 + b + … + b^d (13 behaviours, d = 3:
  2,380). Like the paper's tree, it expands dead-end nodes (the object off the
  table) too and detects no repeated state. Identical subtrees are counted
  through the number of tree nodes in each state per level, so the count is
  exact without materialising b^d nodes.
- ``bfs``: breadth-first graph search with duplicate-state detection; the goal
  test is on generation (unit costs make that optimal).
- ``astar``: A* with h(p) = ⌈grid distance(p, goal) / largest kept step⌉, the
  fewest behaviours that could still cover the distance: admissible and
  consistent, so the goal test is on expansion and the plan is optimal.

All modes return a plan with the fewest behaviours among the kept ones.

**Node counting.** ``nodes_generated`` counts every node created, the root
included: each expansion generates one child per kept behaviour, counted even
when the child is a repeated state or a dead end (off the table, or into a cell
another object holds) that the graph searches then discard. This is the
paper's count of tree nodes, and what Fig. 16 plots. ``nodes_expanded`` counts
the nodes whose children were generated.
"""

from __future__ import annotations

import heapq
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from core.errors import InvalidInputError
from core.planning.effects import BehaviourEffects
from core.planning.pruning import PRUNING_THRESHOLD, prune_behaviours
from core.planning.workspace import OFF_TABLE

Mode = Literal["paper", "bfs", "astar"]
Status = Literal["solved", "unreachable", "budget_exceeded", "invalid"]
MODES: tuple[str, ...] = ("paper", "bfs", "astar")

#: Default cap on generated nodes: the paper tree of 13 behaviours to depth 6 (5.2 M) fits.
NODE_BUDGET = 10_000_000
#: Default cap on plan length, far above any shortest plan on a table grid.
DEPTH_BUDGET = 64
#: Largest node budget accepted: keeps the paper mode's per-level counts inside int64.
MAX_NODE_BUDGET = 10**15

#: The end of a branch: the object left the table or ran into another object.
DEAD_END = OFF_TABLE


@dataclass(frozen=True)
class PlanResult:
    """Outcome of one planning request.

    ``status`` is ``solved``, ``unreachable``, ``budget_exceeded`` or ``invalid``
    (then ``field`` names the offending input and ``message`` says why).
    ``positions`` are the object's positions along the plan, start first.
    """

    status: Status
    mode: str
    plan: tuple[str, ...] = ()
    positions: tuple[int, ...] = ()
    nodes_expanded: int = 0
    nodes_generated: int = 0
    kept: tuple[str, ...] = ()
    pruned: tuple[str, ...] = ()
    message: str = ""
    field: str | None = None


@dataclass(frozen=True)
class _Problem:
    transitions: np.ndarray
    start: int
    goal: int
    behaviours: tuple[str, ...]
    node_budget: int
    depth_budget: int
    grid_distance: Callable[[int], int]
    largest_step: int


@dataclass(frozen=True)
class _Search:
    status: Status
    path: tuple[tuple[int, int], ...]
    nodes_expanded: int
    nodes_generated: int
    message: str = ""


def plan(
    effects: BehaviourEffects,
    table: Mapping[str, int],
    object_name: str,
    goal: int,
    *,
    behaviours: Sequence[str] | None = None,
    mode: str = "astar",
    node_budget: int = NODE_BUDGET,
    depth_budget: int = DEPTH_BUDGET,
) -> PlanResult:
    """Plan to bring ``object_name`` to position ``goal`` using the kept ``behaviours``.

    ``table`` maps each object on the table to its position; the other objects
    block their cells. ``behaviours`` are the kept ones (default: every learned
    behaviour); the learned ones left out are reported as pruned. Bad requests
    give ``status="invalid"`` with the field named, never an exception.
    """
    kept = tuple(effects.behaviours if behaviours is None else behaviours)
    pruned = tuple(b for b in effects.behaviours if b not in kept)
    try:
        problem = _problem(effects, table, object_name, goal, kept, mode, node_budget, depth_budget)
    except InvalidInputError as error:
        return PlanResult("invalid", mode, kept=kept, pruned=pruned, message=str(error), field=error.field)
    search = {"paper": _paper_tree, "bfs": _breadth_first, "astar": _a_star}[mode](problem)
    return PlanResult(
        status=search.status,
        mode=mode,
        plan=tuple(kept[j] for _, j in search.path),
        positions=(problem.start, *(state for state, _ in search.path)) if search.status == "solved" else (),
        nodes_expanded=search.nodes_expanded,
        nodes_generated=search.nodes_generated,
        kept=kept,
        pruned=pruned,
        message=search.message,
    )


def plan_in_context(
    effects: BehaviourEffects,
    table: Mapping[str, int],
    object_name: str,
    goal: int,
    verb_given_context: Mapping[str, float],
    *,
    threshold: float = PRUNING_THRESHOLD,
    mode: str = "astar",
    node_budget: int = NODE_BUDGET,
    depth_budget: int = DEPTH_BUDGET,
) -> PlanResult:
    """:func:`plan` with the behaviours kept by :func:`prune_behaviours` in the context given by P(verb | χ)."""
    try:
        missing = [b for b in effects.behaviours if b not in verb_given_context]
        if missing:
            raise InvalidInputError("verb_given_context", f"no probability for learned behaviour(s) {missing}")
        pruning = prune_behaviours(verb_given_context, threshold)
    except InvalidInputError as error:
        return PlanResult("invalid", mode, message=str(error), field=error.field)
    kept = [b for b in effects.behaviours if b in pruning.kept]
    return plan(
        effects,
        table,
        object_name,
        goal,
        behaviours=kept,
        mode=mode,
        node_budget=node_budget,
        depth_budget=depth_budget,
    )


def _problem(
    effects: BehaviourEffects,
    table: Mapping[str, int],
    object_name: str,
    goal: int,
    kept: tuple[str, ...],
    mode: str,
    node_budget: int,
    depth_budget: int,
) -> _Problem:
    workspace = effects.workspace
    if mode not in MODES:
        raise InvalidInputError("mode", f"unknown planning mode {mode!r}; modes are {list(MODES)}")
    if not isinstance(node_budget, (int, np.integer)) or not 1 <= node_budget <= MAX_NODE_BUDGET:
        raise InvalidInputError("node_budget", f"must be an integer in 1..{MAX_NODE_BUDGET}, got {node_budget!r}")
    if not isinstance(depth_budget, (int, np.integer)) or depth_budget < 0:
        raise InvalidInputError("depth_budget", f"must be a non-negative integer, got {depth_budget!r}")
    if not isinstance(table, Mapping):
        raise InvalidInputError("table", f"must map object names to positions, got {type(table).__name__}")
    if object_name not in table:
        raise InvalidInputError("object", f"{object_name!r} is not on the table; objects are {sorted(table)}")
    occupied: dict[int, str] = {}
    for name, position in table.items():
        position = workspace.require_position(f"table[{name}]", position)
        if position in occupied:
            raise InvalidInputError("table", f"{name!r} and {occupied[position]!r} both stand at position {position}")
        occupied[position] = name
    start = int(table[object_name])
    goal = workspace.require_position("goal", goal)
    if occupied.get(goal, object_name) != object_name:
        raise InvalidInputError("goal", f"position {goal} is held by {occupied[goal]!r}")
    if len(set(kept)) != len(kept):
        raise InvalidInputError("behaviours", f"repeated behaviour in {list(kept)}")
    transitions = effects.transitions(kept)  # unknown behaviours raise here, naming "behaviours"
    for position, name in occupied.items():
        if name != object_name:
            transitions[transitions == position] = DEAD_END
    goal_cell = workspace.cell(goal)

    def grid_distance(position: int) -> int:
        column, row = workspace.cell(position)
        return abs(column - goal_cell[0]) + abs(row - goal_cell[1])

    return _Problem(
        transitions, start, goal, kept, int(node_budget), int(depth_budget), grid_distance, effects.largest_step(kept)
    )


def _paper_tree(problem: _Problem) -> _Search:
    """Level-by-level full expansion; ``counts[s]`` = number of tree nodes of this level in state s."""
    transitions, branching = problem.transitions, problem.transitions.shape[1]
    counts = np.zeros(len(transitions), dtype=np.int64)
    counts[problem.start] = 1
    levels: list[np.ndarray] = []
    seen_levels: set[frozenset[int]] = set()
    generated, expanded = 1, 0
    while counts[problem.goal] == 0:
        support = np.flatnonzero(counts)
        key = frozenset(support.tolist())
        if branching == 0 or key in seen_levels:
            return _Search(
                "unreachable",
                (),
                expanded,
                generated,
                f"position {problem.goal} is not reachable with behaviours {list(problem.behaviours)}",
            )
        if len(levels) == problem.depth_budget:
            return _Search("budget_exceeded", (), expanded, generated, f"depth_budget {problem.depth_budget} reached")
        level_size = int(counts.sum())
        if generated + level_size * branching > problem.node_budget:
            return _Search(
                "budget_exceeded",
                (),
                expanded,
                generated,
                f"node_budget {problem.node_budget} reached at depth {len(levels) + 1}",
            )
        seen_levels.add(key)
        levels.append(counts)
        following = np.zeros_like(counts)
        np.add.at(following, transitions[support].ravel(), np.repeat(counts[support], branching))
        expanded += level_size
        generated += level_size * branching
        counts = following
    return _Search("solved", _backtrack(transitions, levels, problem.goal), expanded, generated)


def _backtrack(transitions: np.ndarray, levels: list[np.ndarray], goal: int) -> tuple[tuple[int, int], ...]:
    """A path to ``goal`` through the levels' states: the first (state, behaviour) reaching each step."""
    path: list[tuple[int, int]] = []
    target = goal
    for counts in reversed(levels):
        state, behaviour = next(
            (s, j) for s in np.flatnonzero(counts) for j in range(transitions.shape[1]) if transitions[s, j] == target
        )
        path.append((target, behaviour))
        target = int(state)
    return tuple(reversed(path))


def _unwind(parents: dict[int, tuple[int, int] | None], state: int) -> tuple[tuple[int, int], ...]:
    path: list[tuple[int, int]] = []
    while (link := parents[state]) is not None:
        path.append((state, link[1]))
        state = link[0]
    return tuple(reversed(path))


def _breadth_first(problem: _Problem) -> _Search:
    return _best_first(problem, lambda state: 0, goal_on_generation=True)


def _a_star(problem: _Problem) -> _Search:
    step = problem.largest_step

    def heuristic(state: int) -> int:
        return -(-problem.grid_distance(state) // step) if step else 0

    return _best_first(problem, heuristic, goal_on_generation=False)


def _best_first(problem: _Problem, heuristic: Callable[[int], int], goal_on_generation: bool) -> _Search:
    """Graph search in order of f = depth + h, ties to the deeper node, then first in first out.

    With h = 0 this is breadth-first. A state is kept only at a depth lower than
    any seen before; with a consistent h its first expansion is at its least depth.
    """
    start, goal = problem.start, problem.goal
    if start == goal:
        return _Search("solved", (), 0, 1)
    parents: dict[int, tuple[int, int] | None] = {start: None}
    best_depth = {start: 0}
    frontier = [(heuristic(start), 0, 0, start)]
    generated, expanded, cut_by_depth = 1, 0, False
    while frontier:
        _, negative_depth, _, state = heapq.heappop(frontier)
        depth = -negative_depth
        if depth > best_depth[state]:
            continue
        if state == goal:
            return _Search("solved", _unwind(parents, state), expanded, generated)
        if depth == problem.depth_budget:
            cut_by_depth = True
            continue
        expanded += 1
        for behaviour, child in enumerate(problem.transitions[state].tolist()):
            if generated == problem.node_budget:
                return _Search("budget_exceeded", (), expanded, generated, f"node_budget {problem.node_budget} reached")
            generated += 1
            if child == DEAD_END or best_depth.get(child, depth + 2) <= depth + 1:
                continue
            best_depth[child] = depth + 1
            parents[child] = (state, behaviour)
            if goal_on_generation and child == goal:
                return _Search("solved", _unwind(parents, goal), expanded, generated)
            heapq.heappush(frontier, (depth + 1 + heuristic(child), -(depth + 1), generated, child))
    return _exhausted(problem, expanded, generated, cut_by_depth)


def _exhausted(problem: _Problem, expanded: int, generated: int, cut_by_depth: bool) -> _Search:
    if cut_by_depth:
        return _Search("budget_exceeded", (), expanded, generated, f"depth_budget {problem.depth_budget} reached")
    return _Search(
        "unreachable",
        (),
        expanded,
        generated,
        f"position {problem.goal} is not reachable with behaviours {list(problem.behaviours)}",
    )
