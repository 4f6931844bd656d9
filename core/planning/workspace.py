"""iCub's table workspace of numbered positions (§V-E, Fig. 15(a)).

The text fixes the grid only through its two scenarios: a cup goes from
position 8 to position 5 with three consecutive *move right*, and a ball goes
from 7 to 1 in a tree of three levels as well (9⁰ + … + 9³ = 820 nodes).

- 8 → 5 in three *move right* puts 5, 6, 7, 8 in one row, numbered so that
  *move right* lowers the number by one: the numbers grow towards the robot's
  left (read left to right by someone facing iCub across the table, which is
  how Fig. 15 shows it).
- 7 → 1 in three moves then needs a row of exactly 4 positions: 7 is one row
  away from 1 and two columns from it (one *move backward* + two *move right*).
  A 3 × 3 grid would put 8 directly behind 5 (one move), and rows of 5 or more
  make 7 → 1 longer than three moves.

So the grid is 4 columns wide, numbered row-major from 1; the row of 1–4 is
the one nearest the robot and rows grow away from it (*move forward*). The
text needs at least two rows; the default is 3 rows (12 positions), which gives
random scenarios goal distances from 1 to 5 moves, the spread Fig. 16 plots.
Both sizes are constructor parameters.

Cell size: positions are one *move* apart (8 → 5 is three moves), so a move
must leave its cell and a push, which slides objects further (0.15 m against
0.10 m in the paper world's physics), must land in the next cell, not two
away: any cell between 0.10 and 0.20 m. The default 0.15 m puts both at the
largest margin measured in their own spreads (±0.008 m for a move, ±0.03 m for
a push): 2.8 spreads each.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TypeGuard

import numpy as np

from core.errors import InvalidInputError

#: The state of an object that has left the table (fallen, thrown, rolled off).
OFF_TABLE = 0


def _unit_axis(field: str, axis: tuple[float, float, float]) -> np.ndarray:
    vector = np.asarray(axis, dtype=float)
    if vector.shape != (3,) or not np.all(np.isfinite(vector)) or np.linalg.norm(vector) == 0:
        raise InvalidInputError(field, f"must be a non-zero finite 3-vector, got {axis!r}")
    return vector / np.linalg.norm(vector)


@dataclass(frozen=True)
class Workspace:
    """A ``columns`` × ``rows`` grid of table cells of side ``cell_size`` metres.

    Position ``p`` (1-based) is cell ``(column, row) = ((p-1) % columns, (p-1) // columns)``;
    column 0 is at the robot's right, row 0 nearest the robot. ``right_axis``,
    ``forward_axis`` and ``up_axis`` are the robot's right, forward (away from the
    robot) and up directions in the frame of the effect vectors' ``position``
    block, so a learned displacement can be read in grid cells.
    """

    columns: int = 4
    rows: int = 3
    cell_size: float = 0.15
    right_axis: tuple[float, float, float] = (1.0, 0.0, 0.0)
    forward_axis: tuple[float, float, float] = (0.0, 1.0, 0.0)
    up_axis: tuple[float, float, float] = (0.0, 0.0, 1.0)

    def __post_init__(self) -> None:
        for name in ("columns", "rows"):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or value < 1:
                raise InvalidInputError(f"workspace.{name}", f"must be a positive integer, got {value!r}")
        if not (np.isfinite(self.cell_size) and self.cell_size > 0):
            raise InvalidInputError(
                "workspace.cell_size", f"must be a positive length in metres, got {self.cell_size!r}"
            )
        axes = np.stack(
            [_unit_axis(f"workspace.{name}", getattr(self, name)) for name in ("right_axis", "forward_axis", "up_axis")]
        )
        if abs(np.linalg.det(axes)) < 1e-6:
            raise InvalidInputError("workspace.axes", "right, forward and up axes must be linearly independent")

    @property
    def size(self) -> int:
        """Number of positions on the table."""
        return self.columns * self.rows

    @property
    def positions(self) -> range:
        return range(1, self.size + 1)

    def contains(self, position: object) -> TypeGuard[int | np.integer]:
        return (
            isinstance(position, (int, np.integer))
            and not isinstance(position, bool)
            and bool(1 <= position <= self.size)
        )

    def require_position(self, field: str, position: object) -> int:
        """``position`` as an int, or an :class:`InvalidInputError` naming ``field``."""
        if self.contains(position):
            return int(position)
        raise InvalidInputError(field, f"position {position!r} is not on the table (positions 1..{self.size})")

    def cell(self, position: int) -> tuple[int, int]:
        """``(column, row)`` of a position."""
        index = self.require_position("position", position) - 1
        return index % self.columns, index // self.columns

    def position(self, column: int, row: int) -> int:
        """The position number of a cell, or :data:`OFF_TABLE` outside the grid."""
        if 0 <= column < self.columns and 0 <= row < self.rows:
            return row * self.columns + column + 1
        return OFF_TABLE

    def grid_distance(self, start: int, goal: int) -> int:
        """Manhattan distance in cells between two positions."""
        (c0, r0), (c1, r1) = self.cell(start), self.cell(goal)
        return abs(c1 - c0) + abs(r1 - r0)

    def table_frame(self, displacement: np.ndarray) -> np.ndarray:
        """Displacements (…, 3) in the robot's (right, forward, up) frame, metres."""
        axes = np.stack(
            [
                _unit_axis("workspace.right_axis", self.right_axis),
                _unit_axis("workspace.forward_axis", self.forward_axis),
                _unit_axis("workspace.up_axis", self.up_axis),
            ]
        )
        return np.asarray(displacement, dtype=float) @ axes.T

    def layout(self) -> str:
        """The grid as text, robot's side at the bottom, for docs and logs."""
        lines = []
        for row in reversed(range(self.rows)):
            lines.append(" ".join(f"{self.position(column, row):3d}" for column in reversed(range(self.columns))))
        lines.append("      (iCub)".center(4 * self.columns))
        return "\n".join(lines)
