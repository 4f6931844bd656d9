"""Robust Growing Neural Gas (RGNG): Qin & Suganthan 2004, "Robust growing neural gas
algorithm with application in cluster analysis", Neural Networks 17, 1135-1148.

The paper's Appendix clusters each concept's features with RGNG in the plane of
(mean, variance). No maintained library implements RGNG, so it is written here,
following the steps of the original algorithm:

1. **Start** with two nodes at random positions in the data's bounding box.
2. **Stage training** at a fixed number of nodes (``_rgng_kernels.train_stage``):
   GNG's competitive Hebbian learning (winner s1, runner-up s2, edge s1-s2
   refreshed, edges of s1 aged and dropped beyond ``max_edge_age``, isolated
   nodes removed) with RGNG's three robust strategies:
   - the *outlier-resistant update*: each node keeps a restricting distance
     sigma_i, initialised at each epoch to the node's harmonic average distance to
     the data; an input farther than sigma_i moves the node by only the harmonic
     mean of the two distances (so outliers pull little), a closer one by the
     usual GNG step;
   - *adaptive modulation of learning rates*, decaying from eps_i to eps_f over a stage;
   - *cluster repulsion* pushing the winner's neighbours away from it, so that two
     nodes do not settle in one cluster.
   A stage ends when prototypes move less than ``tolerance`` over an epoch.
3. **Topology rebuild** and the **MDL value** of the stage's prototypes, with the
   outlier test that codes far-away inputs raw (``description_length``).
4. **Node insertion** between the node with the largest robust local error
   (sum of exp(-d/h) d over its Voronoi set) and its neighbour with the largest
   error; back to 2 until ``max_nodes``.
5. The answer is the prototype set of **minimum MDL** over the stages: the number
   of clusters is chosen by the data.

Choices the 2004 paper leaves to the implementer, and why:
- The data are rescaled to the unit box per dimension before clustering (and the
  prototypes mapped back), so that the repulsion width, the edge lengths and the
  MDL data accuracy eta are dimensionless and both axes weigh the same.
- Learning rates anneal over each stage (a new node needs large steps to find its
  cluster): eps_b 0.1 -> 0.01 as in the authors' reference code, kappa = 1.2; eps_n
  0.002 -> 0.0002, 2.5 times below the reference code's, because edges between
  well-separated clusters stay alive (every input refreshes s1-s2) and the
  neighbour pull drags prototypes towards the other clusters. Measured on six
  sets of three Gaussian blobs (sigma 0.6) plus 20 outliers: with the reference
  rates MDL chose 4 nodes in 2 of 6 sets and the worst centre error was 0.19-0.32;
  with these, 3 nodes in 6 of 6 and 0.10-0.24.
- The repulsion (beta = 0.1, width = 0.02 of the unit box) acts only on nodes that
  crowd one another; a width of 0.05 already pushed the prototypes of separate
  clusters 0.3-0.7 standard deviations off their centres.
- Residual bits per coordinate are ``max(log2(|r| / eta), 0) + 1`` (magnitude and
  sign), so that a residual below the data accuracy still costs one bit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.errors import InvalidInputError
from core.prototypes import _rgng_kernels as kernels


@dataclass(frozen=True)
class RGNGParameters:
    """Hyperparameters of RGNG (symbols of Qin & Suganthan 2004)."""

    max_nodes: int = 8
    epochs_per_stage: int = 40
    eps_winner: tuple[float, float] = (0.1, 0.01)
    eps_neighbour: tuple[float, float] = (0.002, 0.0002)
    max_edge_age: int = 50
    repulsion_strength: float = 0.1
    repulsion_width: float = 0.02
    tolerance: float = 1e-5
    data_accuracy: float = 1e-5
    error_balance: float = 1.2

    def __post_init__(self) -> None:
        if self.max_nodes < 2:
            raise InvalidInputError("rgng.max_nodes", f"must be at least 2, got {self.max_nodes}")
        if self.epochs_per_stage < 1:
            raise InvalidInputError("rgng.epochs_per_stage", f"must be positive, got {self.epochs_per_stage}")
        if not 0.0 < self.data_accuracy < 1.0:
            raise InvalidInputError(
                "rgng.data_accuracy", f"must be in (0, 1) of the unit box, got {self.data_accuracy}"
            )


@dataclass(frozen=True)
class RGNGResult:
    """The minimum-MDL clustering: ``centres`` (k, d), ``assignment`` of each input to
    its nearest centre, ``radii`` (k,) the harmonic average distance of each centre's
    inputs (RGNG's robust cluster radius, 0 for an empty centre), ``outliers``
    flagged by the MDL test, and the MDL value of every stage (index = number of
    nodes - 2)."""

    centres: np.ndarray
    assignment: np.ndarray
    radii: np.ndarray
    outliers: np.ndarray
    mdl_by_stage: np.ndarray

    def represented(self, points: np.ndarray, radius_factor: float) -> np.ndarray:
        """Whether each input lies within ``radius_factor`` robust radii of its centre."""
        gap = np.linalg.norm(np.asarray(points) - self.centres[self.assignment], axis=1)
        return gap <= radius_factor * self.radii[self.assignment]


def robust_growing_neural_gas(
    points: np.ndarray, *, seed: int | np.random.Generator = 0, parameters: RGNGParameters | None = None
) -> RGNGResult:
    """Cluster ``points`` (n, d) with RGNG; the number of clusters is the MDL minimiser."""
    params = parameters or RGNGParameters()
    data = np.asarray(points, dtype=np.float64)
    if data.ndim != 2 or data.shape[0] < 2:
        raise InvalidInputError("rgng.points", f"must be an (n >= 2, d) array, got shape {data.shape}")
    if not np.all(np.isfinite(data)):
        raise InvalidInputError("rgng.points", "contains NaN or infinite values")
    rng = np.random.default_rng(seed)
    low = data.min(axis=0)
    span = data.max(axis=0) - low
    span[span <= 0.0] = 1.0
    unit = np.ascontiguousarray((data - low) / span)
    max_nodes = min(params.max_nodes, len(np.unique(unit, axis=0)))
    if max_nodes < 2:
        centre = data.mean(axis=0, keepdims=True)
        return _result(data, centre, np.zeros(len(data), dtype=bool), np.zeros(0))

    weights = np.zeros((max_nodes, data.shape[1]))
    weights[:2] = rng.uniform(0.0, 1.0, size=(2, data.shape[1]))
    active = np.zeros(max_nodes, dtype=np.bool_)
    active[:2] = True
    ages = np.full((max_nodes, max_nodes), kernels.NO_EDGE, dtype=np.int64)
    best_mdl, best_weights, best_outliers = np.inf, weights[:2].copy(), np.zeros(len(data), dtype=bool)
    mdl_by_stage: list[float] = []
    for stage in range(max_nodes - 1):
        orders = np.stack([rng.permutation(len(unit)) for _ in range(params.epochs_per_stage)])
        kernels.train_stage(
            unit,
            weights,
            active,
            ages,
            orders,
            params.eps_winner,
            params.eps_neighbour,
            params.max_edge_age,
            (params.repulsion_strength, params.repulsion_width),
            params.tolerance,
            stage > 0,
        )
        kernels.rebuild_topology(unit, weights, active, ages)
        mdl, outliers = kernels.description_length(
            unit, weights, active, params.data_accuracy, 1.0, params.error_balance
        )
        mdl_by_stage.append(mdl)
        if mdl < best_mdl:
            best_mdl, best_weights, best_outliers = mdl, weights[active].copy(), outliers
        if active.sum() >= max_nodes:
            break
        _insert_node(unit, weights, active, ages)
    return _result(data, best_weights * span + low, best_outliers, np.asarray(mdl_by_stage))


def _result(data: np.ndarray, centres: np.ndarray, outliers: np.ndarray, mdl_by_stage: np.ndarray) -> RGNGResult:
    distances = np.linalg.norm(data[:, None, :] - centres[None, :, :], axis=2)
    assignment = distances.argmin(axis=1)
    nearest = distances[np.arange(len(data)), assignment]
    counts = np.bincount(assignment, minlength=len(centres))
    inverse = np.bincount(assignment, weights=1.0 / np.maximum(nearest, 1e-12), minlength=len(centres))
    radii = np.divide(counts, inverse, out=np.zeros(len(centres)), where=inverse > 0)
    return RGNGResult(centres, assignment, radii, outliers, mdl_by_stage)


def _insert_node(unit: np.ndarray, weights: np.ndarray, active: np.ndarray, ages: np.ndarray) -> None:
    """Step 4: a new node r halfway between q (largest robust error) and its worst neighbour f."""
    errors = kernels.robust_local_errors(unit, weights, active)
    errors[~active] = -np.inf
    q = int(np.argmax(errors))
    neighbours = np.flatnonzero(ages[q] != kernels.NO_EDGE)
    if len(neighbours) == 0:
        others = np.flatnonzero(active & (np.arange(len(active)) != q))
        neighbours = others[[np.argmin(np.linalg.norm(weights[others] - weights[q], axis=1))]]
    f = int(neighbours[np.argmax(errors[neighbours])])
    r = int(np.flatnonzero(~active)[0])
    weights[r] = 0.5 * (weights[q] + weights[f])
    active[r] = True
    ages[q, f] = ages[f, q] = kernels.NO_EDGE
    ages[q, r] = ages[r, q] = 0
    ages[f, r] = ages[r, f] = 0
