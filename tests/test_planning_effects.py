"""The workspace grid and the effects learned from effect vectors (§V-E, Fig. 15(a)).

Also the synthetic effect vectors the other planning tests learn from.
"""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import InvalidInputError
from core.features.layout import EFFECT_LAYOUT, EFFECT_SIZE
from core.planning import OFF_TABLE, BehaviourEffects, Workspace, learn_effects

CELL = 0.1

#: The paper's 13 behaviours with the displacement (right, forward, up) in metres each is made to have.
DISPLACEMENTS: dict[str, tuple[float, float, float]] = {
    "grasp": (0.0, 0.0, 0.0),
    "push_left": (-CELL, 0.0, 0.0),
    "push_right": (CELL, 0.0, 0.0),
    "push_forward": (0.0, CELL, 0.0),
    "push_backward": (0.0, -CELL, 0.0),
    "move_left": (-CELL, 0.0, 0.0),
    "move_right": (CELL, 0.0, 0.0),
    "move_forward": (0.0, CELL, 0.0),
    "move_backward": (0.0, -CELL, 0.0),
    "drop": (0.0, 0.0, -0.01),
    "throw": (0.0, 0.9, -0.7),
    "knock_down": (0.01, 0.02, -0.04),
    "shake": (0.0, 0.0, 0.0),
}


def synthetic_effect_vectors(
    displacements: dict[str, tuple[float, float, float]] = DISPLACEMENTS,
    per_behaviour: int = 12,
    noise: float = 0.01,
    seed: int = 0,
) -> tuple[np.ndarray, list[str]]:
    """Effect vectors f (m, 66) whose position block is each behaviour's displacement plus noise."""
    rng = np.random.default_rng(seed)
    vectors, labels = [], []
    for behaviour, displacement in displacements.items():
        block = np.asarray(displacement) + rng.normal(0.0, noise, size=(per_behaviour, 3))
        f = rng.normal(0.0, 1.0, size=(per_behaviour, EFFECT_SIZE))
        f[:, EFFECT_LAYOUT["position"]] = block
        vectors.append(f)
        labels += [behaviour] * per_behaviour
    return np.concatenate(vectors), labels


def synthetic_effects(workspace: Workspace | None = None) -> BehaviourEffects:
    vectors, labels = synthetic_effect_vectors()
    return learn_effects(vectors, labels, workspace or Workspace(cell_size=CELL))


def test_grid_fits_both_paper_scenarios() -> None:
    effects = synthetic_effects()
    position = 8
    for _ in range(3):
        position = effects.outcome("move_right", position)
    assert position == 5  # cup: 8 -> 5 with three move right
    assert effects.workspace.grid_distance(7, 1) == 3  # ball: 7 -> 1, a tree of three levels


def test_layout_draws_the_numbering() -> None:
    rows = Workspace().layout().splitlines()
    assert rows[0].split() == ["12", "11", "10", "9"] and rows[2].split() == ["4", "3", "2", "1"]


def test_learned_steps_and_falls() -> None:
    effects = synthetic_effects()
    steps = dict(zip(effects.behaviours, effects.steps.tolist(), strict=True))
    assert steps["move_right"] == [-1, 0] and steps["push_forward"] == [0, 1]
    assert steps["grasp"] == steps["shake"] == steps["knock_down"] == steps["drop"] == [0, 0]
    assert effects.behaviours[effects.leaves_table.argmax()] == "throw" and effects.leaves_table.sum() == 1
    assert effects.outcome("throw", 6) == OFF_TABLE
    assert effects.outcome("move_left", 4) == OFF_TABLE  # the left edge: off the grid
    assert effects.outcome("grasp", 6) == 6
    assert effects.largest_step(effects.behaviours) == 1
    assert effects.samples.tolist() == [12] * 13


def test_median_ignores_a_minority_of_outliers() -> None:
    vectors, labels = synthetic_effect_vectors({"push_right": (CELL, 0.0, 0.0)}, per_behaviour=9)
    vectors[:3, EFFECT_LAYOUT["position"]] = (2.0, 0.0, -0.8)  # three pushes rolled the object off
    effects = learn_effects(vectors, labels, Workspace(cell_size=CELL))
    assert effects.steps.tolist() == [[-1, 0]] and not effects.leaves_table[0]


def test_workspace_axes_read_the_sensor_frame() -> None:
    """iCub's root frame: x backward, y right, z up; a move right is +y there."""
    icub = Workspace(cell_size=CELL, right_axis=(0, 1, 0), forward_axis=(-1, 0, 0), up_axis=(0, 0, 1))
    vectors, labels = synthetic_effect_vectors({"move_right": (0.0, CELL, 0.0), "move_forward": (-CELL, 0.0, 0.0)})
    effects = learn_effects(vectors, labels, icub)
    assert effects.outcome("move_right", 8) == 7 and effects.outcome("move_forward", 2) == 6


def test_cell_size_sets_the_snapping() -> None:
    vectors, labels = synthetic_effect_vectors({"push_right": (0.16, 0.0, 0.0)})
    assert learn_effects(vectors, labels, Workspace(cell_size=0.1)).steps.tolist() == [[-2, 0]]
    assert learn_effects(vectors, labels, Workspace(cell_size=0.15)).steps.tolist() == [[-1, 0]]


@pytest.mark.parametrize(
    ("vectors", "labels", "field"),
    [
        (np.zeros((3, EFFECT_SIZE - 1)), ["grasp"] * 3, "effect_vectors"),
        (np.zeros((0, EFFECT_SIZE)), [], "effect_vectors"),
        (np.zeros((3, EFFECT_SIZE)), ["grasp"] * 2, "behaviours"),
        (np.zeros((2, EFFECT_SIZE)), ["grasp", ""], "behaviours"),
        (np.full((2, EFFECT_SIZE), np.nan), ["grasp"] * 2, "effect_vectors"),
    ],
)
def test_learn_effects_rejects_bad_input(vectors: np.ndarray, labels: list[str], field: str) -> None:
    with pytest.raises(InvalidInputError) as error:
        learn_effects(vectors, labels, Workspace())
    assert error.value.field == field


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"columns": 0}, "workspace.columns"),
        ({"rows": 2.5}, "workspace.rows"),
        ({"cell_size": -0.1}, "workspace.cell_size"),
        ({"up_axis": (0, 0, 0)}, "workspace.up_axis"),
        ({"forward_axis": (1, 0, 0)}, "workspace.axes"),
    ],
)
def test_workspace_rejects_bad_geometry(kwargs: dict, field: str) -> None:
    with pytest.raises(InvalidInputError) as error:
        Workspace(**kwargs)
    assert error.value.field == field


def test_unknown_behaviour_is_named() -> None:
    with pytest.raises(InvalidInputError, match="unknown behaviour 'fly'") as error:
        synthetic_effects().outcome("fly", 3)
    assert error.value.field == "behaviours"
