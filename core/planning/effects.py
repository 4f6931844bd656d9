"""Learned effects of behaviours on an object's table position (§V-E).

"The robot plans according to the expected results of actions as learned by
the verb prototypes": the planner's transition model is learned from the
training effect vectors f = e'_v − e_v (Fig. 5), from their ``position`` block
only (EFFECT_LAYOUT["position"]), since the plan is about where the object is.

Choices the paper leaves open, with their reasons:

- **Median, not mean, displacement per behaviour.** A few interactions with
  large displacements (an object that rolls or bounces) would drag a mean
  across cells; the median is the typical outcome the robot expects.
- **Snapped to the nearest cell** of the workspace grid (``cell_size`` metres):
  the planning state is a numbered position (Fig. 15(a)). A behaviour whose
  median displacement rounds to zero cells (grasp, shake) keeps the position.
- **Leaving the table ends a branch.** A behaviour leaves the table when its
  median vertical displacement is below −``fall_height`` (the object ends on
  the floor); a horizontal displacement that lands outside the grid leaves it
  as well, from that position only. Both give the absorbing state
  :data:`~core.planning.workspace.OFF_TABLE`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from core.errors import InvalidInputError
from core.features.layout import EFFECT_LAYOUT, EFFECT_SIZE
from core.planning.workspace import OFF_TABLE, Workspace

#: Default vertical drop (metres) beyond which the object is on the floor: a
#: knocked-down or dropped object moves by centimetres, a fall from a table by
#: its height (≈ 0.6–0.8 m for iCub's table).
FALL_HEIGHT = 0.2


@dataclass(frozen=True)
class BehaviourEffects:
    """The learned transition model: one grid step (or a fall) per behaviour.

    ``displacement[b]`` is the median displacement of behaviour ``b`` in the
    robot's (right, forward, up) frame, metres; ``steps[b]`` its snapped
    ``(columns, rows)`` change of cell (columns grow to the robot's left, rows
    forward); ``leaves_table[b]`` whether it drops the object off the table;
    ``samples[b]`` the number of training effect vectors behind it.
    """

    workspace: Workspace
    behaviours: tuple[str, ...]
    displacement: np.ndarray
    steps: np.ndarray
    leaves_table: np.ndarray
    samples: np.ndarray

    def index(self, behaviour: str) -> int:
        try:
            return self.behaviours.index(behaviour)
        except ValueError:
            raise InvalidInputError(
                "behaviours", f"unknown behaviour {behaviour!r}; learned behaviours are {list(self.behaviours)}"
            ) from None

    def outcome(self, behaviour: str, position: int) -> int:
        """The position after ``behaviour`` is applied at ``position`` (OFF_TABLE if it leaves the table)."""
        b = self.index(behaviour)
        if position == OFF_TABLE or self.leaves_table[b]:
            return OFF_TABLE
        column, row = self.workspace.cell(position)
        return self.workspace.position(column + int(self.steps[b, 0]), row + int(self.steps[b, 1]))

    @cached_property
    def _successors(self) -> np.ndarray:
        table = np.zeros((self.workspace.size + 1, len(self.behaviours)), dtype=np.int64)
        for b, behaviour in enumerate(self.behaviours):
            for position in self.workspace.positions:
                table[position, b] = self.outcome(behaviour, position)
        return table

    def transitions(self, behaviours: Sequence[str]) -> np.ndarray:
        """Successor table (workspace.size + 1, len(behaviours)): row s gives the state after each behaviour.

        Row :data:`OFF_TABLE` (0) is absorbing: an object off the table stays off it.
        """
        return self._successors[:, [self.index(b) for b in behaviours]]

    def largest_step(self, behaviours: Sequence[str]) -> int:
        """The largest grid (Manhattan) step among ``behaviours`` that keep the object on the table."""
        steps = [
            int(np.abs(self.steps[self.index(b)]).sum()) for b in behaviours if not self.leaves_table[self.index(b)]
        ]
        return max(steps, default=0)


def learn_effects(
    effect_vectors: np.ndarray,
    behaviours: Sequence[str],
    workspace: Workspace,
    *,
    fall_height: float = FALL_HEIGHT,
) -> BehaviourEffects:
    """Learn each behaviour's effect on position from training effect vectors f (m, 66).

    ``behaviours[i]`` names the behaviour that produced ``effect_vectors[i]``.
    Behaviours keep the order of their first appearance.
    """
    vectors = np.asarray(effect_vectors, dtype=float)
    if vectors.ndim != 2 or vectors.shape[1] != EFFECT_SIZE:
        raise InvalidInputError("effect_vectors", f"must have shape (m, {EFFECT_SIZE}), got {vectors.shape}")
    if len(vectors) == 0:
        raise InvalidInputError("effect_vectors", "at least one training effect vector is required")
    labels = list(behaviours)
    if len(labels) != len(vectors):
        raise InvalidInputError(
            "behaviours", f"needs one label per effect vector: {len(labels)} labels, {len(vectors)} vectors"
        )
    if not all(isinstance(label, str) and label for label in labels):
        raise InvalidInputError("behaviours", "every label must be a non-empty behaviour name")
    positions = vectors[:, EFFECT_LAYOUT["position"]]
    if not np.all(np.isfinite(positions)):
        raise InvalidInputError("effect_vectors", "the position block holds non-finite values")
    if not (np.isfinite(fall_height) and fall_height > 0):
        raise InvalidInputError("fall_height", f"must be a positive height in metres, got {fall_height!r}")

    names = tuple(dict.fromkeys(labels))
    label_array = np.asarray(labels, dtype=object)
    table_frame = workspace.table_frame(positions)
    displacement = np.stack([np.median(table_frame[label_array == name], axis=0) for name in names])
    samples = np.array([int(np.sum(label_array == name)) for name in names])
    # Columns are numbered towards the robot's left, so a move to the right is a negative column step.
    steps = np.rint(np.column_stack([-displacement[:, 0], displacement[:, 1]]) / workspace.cell_size).astype(np.int64)
    leaves_table = displacement[:, 2] < -fall_height
    return BehaviourEffects(workspace, names, displacement, steps, leaves_table, samples)
