"""The concept web: a Markov random field over concepts, settled by loopy BP (§III-B).

Variables follow the vocabulary's structure (``docs/concept_web.md`` gives the
reasons for every choice below):

- one categorical *noun* variable whose states are the nouns (exactly one noun);
- one binary variable per dichotomic adjective pair, state 0 = the first
  adjective, state 1 = the second (exactly one of each pair);
- one binary variable per verb, state 0 = inactive, state 1 = active.

Every concept is one (variable, state): the paper's 29 concepts are 29
variable-states over 19 variables. Two variables share an edge when any of their
concepts co-occurred in training (the paper's ε_ij). The clique energy of Eq. 4
on an edge (u, v) is

    ψ_K(s, t) = [1 - P(x_u = s | x_v = t)] + [1 - P(x_v = t | x_u = s)],

which is |val(x) - E(x | ·)| for a binary variable and half the L1 distance
between a state's indicator vector and its conditional expectation for the
noun variable. Conditionals come from co-occurrence counts plus ``pseudo_count``;
the clique factor is ``exp(-β_e ψ_K)`` with ``β_e = β / mean degree of u and v``.
The unary energy of Eq. 3 is ``ψ_C(c) = -log P(c)`` for the perception
probability P(c), so the unary factor is P(c) clipped to
``[probability_floor, 1 - probability_floor]``; a verb's inactive state gets
``1 - P(verb)`` and a verb whose behaviour was not applied gets (1, 1).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from core.concept_web import _checks, _lbp_kernels
from core.errors import InvalidInputError
from core.vocabulary import Vocabulary

#: β of exp(-β_e ψ_K): the value whose no-evidence marginals best match training frequencies.
DEFAULT_BETA = 4.0
#: Pseudo-count added to every joint state count (Jeffreys / Krichevsky–Trofimov estimate).
DEFAULT_PSEUDO_COUNT = 0.5
#: Perception probabilities are clipped to [floor, 1 - floor], so ψ_C = -log P(c) ≤ 6.9.
DEFAULT_PROBABILITY_FLOOR = 1e-3
#: Damping of the max-product pass by default; the sum-product pass runs undamped
#: (:meth:`ConceptWeb.infer`; docs/concept_web.md, "Inference").
DEFAULT_DAMPING = 0.5

_STATE_KEYS = ("concepts", "cooccurrence", "n_objects", "beta", "pseudo_count", "probability_floor")


def _read_only(array: np.ndarray) -> np.ndarray:
    array.flags.writeable = False
    return array


#: The kernel's per-pass flags (``runs``, ``cold``), made once rather than on every call.
_PASS_FLAGS = {(a, b): _read_only(np.array([a, b])) for a in (False, True) for b in (False, True)}


@dataclass(frozen=True)
class WebInference:
    """The settled concept web of one object.

    ``probabilities[c]`` is the sum-product marginal P(c active), in
    ``vocabulary.concepts`` order; ``map_configuration[c]`` says whether c is active
    in the max-product configuration (per-variable argmax of the max-marginals,
    so exactly one noun and one adjective per pair). ``iterations`` is the larger
    of the two passes' iteration counts; ``converged`` is true when both converged.
    Without the sum-product pass (``infer_many(…, marginals=False)``) ``probabilities``
    is NaN and ``messages`` None, and the counts are the max-product pass's.
    """

    probabilities: np.ndarray
    map_configuration: np.ndarray
    iterations: int
    converged: bool
    messages: np.ndarray | None = field(default=None, repr=False, compare=False)
    """The sum-product pass's final messages, (n_directed, K): a warm start for
    :meth:`ConceptWeb.infer_many`'s ``start``; None when not kept."""
    max_messages: np.ndarray | None = field(default=None, repr=False, compare=False)
    """The max-product pass's final messages, (n_directed, K): a warm start for
    :meth:`ConceptWeb.infer_many`'s ``max_start``; None when not kept."""


@dataclass(frozen=True)
class WebPotentials:
    """A pairwise MRF as plain, strictly positive factors (exp of minus the energies).

    ``unary[v, s]`` and ``pairwise[e, s, t]`` are padded with zeros to the largest
    cardinality; ``variable_edges[e] = (u, v)`` with u < v, and ``pairwise[e, s, t]``
    is the factor of ``x_u = s, x_v = t``.
    """

    variable_names: tuple[str, ...]
    cardinalities: np.ndarray
    unary: np.ndarray
    variable_edges: np.ndarray
    pairwise: np.ndarray


@dataclass(frozen=True)
class _MessageGraph:
    """The flat arrays the kernels read (layout in ``_lbp_kernels``)."""

    cardinalities: np.ndarray
    sources: np.ndarray
    targets: np.ndarray
    factor_start: np.ndarray
    factors: np.ndarray
    incoming_start: np.ndarray
    incoming: np.ndarray
    plan: tuple[np.ndarray, ...]
    """Where the binary part of the kernels finds its messages (``_binary_plan``)."""

    @classmethod
    def build(cls, cardinalities: np.ndarray, variable_edges: np.ndarray, pairwise: np.ndarray) -> _MessageGraph:
        u, v = variable_edges[:, 0], variable_edges[:, 1]
        sources = np.stack([u, v], axis=1).reshape(-1).astype(np.int64)
        targets = np.stack([v, u], axis=1).reshape(-1).astype(np.int64)
        directed = (table for forward in pairwise for table in (forward, forward.T))
        tables = [t[: cardinalities[a], : cardinalities[b]].ravel() for t, a, b in zip(directed, sources, targets)]
        sizes = cardinalities[sources] * cardinalities[targets]
        return cls(
            cardinalities=cardinalities.astype(np.int64),
            sources=sources,
            targets=targets,
            factor_start=np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64),
            factors=np.concatenate(tables) if tables else np.zeros(0),
            incoming_start=np.concatenate([[0], np.cumsum(np.bincount(targets, minlength=len(cardinalities)))]).astype(
                np.int64
            ),
            incoming=np.argsort(targets, kind="stable").astype(np.int64),
            plan=_binary_plan(cardinalities.astype(np.int64), variable_edges, pairwise, sources, targets),
        )

    @property
    def arrays(self) -> tuple[np.ndarray | tuple[np.ndarray, ...], ...]:
        """The ``graph`` tuple the kernels read (its last item the ``plan`` tuple)."""
        return (
            self.cardinalities,
            self.sources,
            self.targets,
            self.factor_start,
            self.factors,
            self.incoming_start,
            self.incoming,
            self.plan,
        )


def _binary_plan(
    cardinalities: np.ndarray,
    variable_edges: np.ndarray,
    pairwise: np.ndarray,
    sources: np.ndarray,
    targets: np.ndarray,
) -> tuple[np.ndarray, ...]:
    """The layout of ``_lbp_kernels.propagate``'s binary part, in this order:

    - ``pair_variables`` (2, n_pairs): the edges (u, v) between two binary variables; row 0 the
      sources of slots 0..n_pairs-1 (u -> v), row 1 those of slots n_pairs.. (v -> u);
    - ``pair_binary`` (2, n_pairs): the same variables as indices into ``binary_variables``;
    - ``pair_factors`` (4, 2 n_pairs): per slot, the factors of (a, b) = (0, 0), (0, 1), (1, 0), (1, 1);
    - ``binary_variables``: the variables with two states;
    - ``binary_slots`` (n_groups, max in-degree, 4): the slot of the t-th incoming message (CSR
      order) of binary variable 4 g + lane, the last slot (always 1.0) where it has fewer;
    - ``flat_slot`` (n_directed): the slot of a message entering a binary variable, else -1;
    - ``flat_directed``: the directed edge of each slot;
    - the other directed edges, done one at a time: into a binary variable from another, from a
      binary variable into another, and between two variables that are not binary.
    """
    binary = cardinalities == 2
    u, v = variable_edges[:, 0], variable_edges[:, 1]
    pairs = np.flatnonzero(binary[u] & binary[v])
    n_pairs = len(pairs)
    binary_variables = np.flatnonzero(binary).astype(np.int64)
    binary_index = np.full(len(cardinalities), -1, dtype=np.int64)
    binary_index[binary_variables] = np.arange(len(binary_variables))
    pair_variables = np.stack([u[pairs], v[pairs]]).astype(np.int64).reshape(2, n_pairs)
    forward = pairwise[pairs, :2, :2].reshape(n_pairs, 4)
    backward = pairwise[pairs, :2, :2].transpose(0, 2, 1).reshape(n_pairs, 4)
    pair_factors = np.ascontiguousarray(np.concatenate([forward, backward]).T)
    into_binary = np.flatnonzero(binary[targets])
    is_pair_message = np.zeros(len(sources), dtype=bool)
    is_pair_message[2 * pairs] = is_pair_message[2 * pairs + 1] = True
    flat_directed = np.concatenate([2 * pairs, 2 * pairs + 1, into_binary[~is_pair_message[into_binary]]]).astype(
        np.int64
    )
    flat_slot = np.full(len(sources), -1, dtype=np.int64)
    flat_slot[flat_directed] = np.arange(len(flat_directed))
    incoming = np.argsort(targets, kind="stable")
    in_degree = np.bincount(targets, minlength=len(cardinalities))
    n_groups = -(-len(binary_variables) // 4)
    max_degree = int(in_degree[binary_variables].max(initial=0))
    slots_by_variable = np.full((n_groups * 4, max_degree), len(flat_directed))
    # Each message's rank among those entering its target, in CSR (stable) order.
    entering_target = targets[incoming]
    rank = np.arange(len(incoming)) - np.concatenate([[0], np.cumsum(in_degree)])[entering_target]
    into = binary[entering_target]
    slots_by_variable[binary_index[entering_target[into]], rank[into]] = flat_slot[incoming[into]]
    binary_slots = slots_by_variable.reshape(n_groups, 4, max_degree).transpose(0, 2, 1)
    plan = (
        pair_variables,
        binary_index[pair_variables],
        pair_factors,
        binary_variables,
        np.ascontiguousarray(binary_slots, dtype=np.int64),
        flat_slot,
        flat_directed,
        np.flatnonzero(~is_pair_message & binary[targets]).astype(np.int64),
        np.flatnonzero(binary[sources] & ~binary[targets]).astype(np.int64),
        np.flatnonzero(~binary[sources] & ~binary[targets]).astype(np.int64),
    )
    for array in plan:
        array.flags.writeable = False
    return plan


def _pass_settings(
    damping: Any,
    tolerance: Any,
    max_iterations: Any,
    sum_product: tuple[float, int] | None,
    max_product: tuple[float, int] | None,
) -> tuple[np.ndarray, float, np.ndarray]:
    """Validated (damping (2,), tolerance, max_iterations (2,)) of the sum- and max-product passes
    (read-only arrays; :func:`_validated_pass_settings`), memoised: a caller settles with the
    same few settings again and again."""
    if sum_product is None and max_product is None:  # the common case, without building pairs
        try:
            return _memoised_pass_settings(damping, tolerance, max_iterations, None, None, None, None)
        except TypeError:  # not hashable: validated (and refused) below, uncached
            return _validated_pass_settings(damping, tolerance, max_iterations, None, None)
    try:
        own = [(None, None) if pair is None else tuple(pair) for pair in (sum_product, max_product)]
        if any(len(pair) != 2 for pair in own):
            raise TypeError
        return _memoised_pass_settings(damping, tolerance, max_iterations, *own[0], *own[1])
    except TypeError:  # not hashable, or not pairs: validated (and refused) below, uncached
        return _validated_pass_settings(damping, tolerance, max_iterations, sum_product, max_product)


@functools.lru_cache(maxsize=64, typed=True)
def _memoised_pass_settings(
    damping: Any,
    tolerance: Any,
    max_iterations: Any,
    sum_damping: Any,
    sum_iterations: Any,
    max_damping: Any,
    max_pass_iterations: Any,
) -> tuple[np.ndarray, float, np.ndarray]:
    """``typed``: True is not taken for 1, nor 1.0 for 1, so a refused value is never found here."""
    sum_product = None if sum_damping is None and sum_iterations is None else (sum_damping, sum_iterations)
    max_product = None if max_damping is None and max_pass_iterations is None else (max_damping, max_pass_iterations)
    return _validated_pass_settings(damping, tolerance, max_iterations, sum_product, max_product)


def _validated_pass_settings(
    damping: Any,
    tolerance: Any,
    max_iterations: Any,
    sum_product: tuple[float, int] | None,
    max_product: tuple[float, int] | None,
) -> tuple[np.ndarray, float, np.ndarray]:
    """``damping`` None is the default: the sum-product pass undamped (unless ``sum_product``
    sets it), the max-product pass at :data:`DEFAULT_DAMPING`."""
    if damping is None:
        damping = DEFAULT_DAMPING
        if sum_product is None:
            sum_product = (0.0, max_iterations)
    damping = _checks.real(damping, "damping", low=0.0, high=1.0, high_open=True)
    tolerance = _checks.real(tolerance, "tolerance", low=0.0, low_open=True)
    max_iterations = _checks.count(max_iterations, "max_iterations", minimum=1)
    dampings, counts = [], []
    for own in (sum_product, max_product):
        pass_damping, pass_iterations = (damping, max_iterations) if own is None else own
        dampings.append(_checks.real(pass_damping, "damping", low=0.0, high=1.0, high_open=True))
        counts.append(_checks.count(pass_iterations, "max_iterations", minimum=1))
    dampings_array, counts_array = np.array(dampings), np.array(counts, dtype=np.int64)
    dampings_array.flags.writeable = False
    counts_array.flags.writeable = False
    return dampings_array, tolerance, counts_array


def loopy_belief_propagation(
    potentials: WebPotentials, *, damping: float = DEFAULT_DAMPING, tolerance: float = 1e-6, max_iterations: int = 100
) -> tuple[np.ndarray, np.ndarray, int, bool]:
    """Sum-product marginals and max-product max-marginals (both (n_var, K)) of any pairwise MRF.

    Returns ``(marginals, max_marginals, iterations, converged)`` with the same
    meaning of ``iterations`` and ``converged`` as :class:`WebInference`.
    """
    cardinalities = np.asarray(potentials.cardinalities, dtype=np.int64)
    edges = np.asarray(potentials.variable_edges, dtype=np.int64).reshape(-1, 2)
    n_var, width = len(cardinalities), int(cardinalities.max(initial=1))
    unary = np.ascontiguousarray(potentials.unary, dtype=np.float64)
    pairwise = np.asarray(potentials.pairwise, dtype=np.float64)
    if unary.shape != (n_var, width) or pairwise.shape != (len(edges), width, width):
        raise InvalidInputError(
            "potentials", f"unary must be ({n_var}, {width}) and pairwise ({len(edges)}, {width}, {width})"
        )
    if (cardinalities < 1).any() or (edges < 0).any() or (edges >= n_var).any() or (edges[:, 0] >= edges[:, 1]).any():
        raise InvalidInputError(
            "potentials", "cardinalities must be >= 1 and every edge (u, v) must have 0 <= u < v < n_var"
        )
    states = np.arange(width)
    valid_unary = states[None, :] < cardinalities[:, None]
    valid_pairwise = valid_unary[edges[:, 0]][:, :, None] & valid_unary[edges[:, 1]][:, None, :]
    if not (np.isfinite(unary).all() and np.isfinite(pairwise).all()):
        raise InvalidInputError("potentials", "factors must be finite")
    if (unary[valid_unary] <= 0).any() or (pairwise[valid_pairwise] <= 0).any():
        raise InvalidInputError("potentials", "factors must be strictly positive on every state")
    graph = _MessageGraph.build(cardinalities, edges, pairwise)
    dampings, tolerance, counts = _pass_settings(damping, tolerance, max_iterations, None, None)
    marginals, max_marginals = np.zeros((1, n_var, width)), np.zeros((1, n_var, width))
    iterations, converged = np.zeros((1, 2), dtype=np.int64), np.zeros((1, 2), dtype=np.bool_)
    _lbp_kernels.propagate_many(
        unary[None],
        np.ones((1, n_var), dtype=np.bool_),
        graph.arrays,
        float(dampings[0]),
        tolerance,
        int(counts[0]),
        marginals,
        max_marginals,
        iterations,
        converged,
    )
    return marginals[0], max_marginals[0], int(iterations.max()), bool(converged.all())


class ConceptWeb:
    """An MRF over a vocabulary's concepts with clique potentials from co-occurrence counts.

    The learned state is its sufficient statistics: ``cooccurrence[i, j]``, the
    number of training objects in which concepts i and j were both active (the
    diagonal counts each concept), and ``n_objects``. Build it with :meth:`fit`
    or :meth:`from_state`; ``concept_variable[c]`` and ``concept_state[c]`` locate
    concept c in the MRF.
    """

    def __init__(
        self,
        vocabulary: Vocabulary,
        cooccurrence: np.ndarray,
        n_objects: int,
        *,
        beta: float = DEFAULT_BETA,
        pseudo_count: float = DEFAULT_PSEUDO_COUNT,
        probability_floor: float = DEFAULT_PROBABILITY_FLOOR,
    ) -> None:
        self.vocabulary = _checks.vocabulary(vocabulary)
        self.beta = _checks.real(beta, "beta", low=0.0)
        self.pseudo_count = _checks.real(pseudo_count, "pseudo_count", low=0.0, low_open=True)
        self.probability_floor = _checks.real(
            probability_floor, "probability_floor", low=0.0, high=0.5, low_open=True, high_open=True
        )
        self.n_objects = _checks.count(n_objects, "n_objects", minimum=1)
        self.cooccurrence = _checks.cooccurrence(cooccurrence, vocabulary, self.n_objects)
        self._describe_states()
        self._variable_edges = self._co_occurring_variables()
        self._pairwise = self._clique_factors()
        self._graph = _MessageGraph.build(self._cardinalities, self._variable_edges, self._pairwise)
        self._kernel_graph = self._graph.arrays
        self._kernel_layout = (self.concept_variable, self.concept_state, self._verb_variables, self._verb_concepts)
        self._clip = (self.probability_floor, 1.0 - self.probability_floor)
        self._uniform = np.zeros((len(self._graph.sources), self._width))
        _lbp_kernels.uniform_messages(self._graph.cardinalities, self._graph.targets, self._uniform)

    @classmethod
    def fit(
        cls,
        vocabulary: Vocabulary,
        configurations: Sequence[Sequence[str]] | np.ndarray,
        *,
        beta: float = DEFAULT_BETA,
        pseudo_count: float = DEFAULT_PSEUDO_COUNT,
        probability_floor: float = DEFAULT_PROBABILITY_FLOOR,
    ) -> ConceptWeb:
        """Learn the web from the training objects' concept sets.

        ``configurations`` is a list of concept-name lists (one noun, one
        adjective of every pair, the active verbs) or an (n_objects, n_concepts)
        0/1 array in ``vocabulary.concepts`` order.
        """
        active = _checks.configuration_matrix(_checks.vocabulary(vocabulary), configurations).astype(np.int64)
        return cls(
            vocabulary,
            active.T @ active,
            active.shape[0],
            beta=beta,
            pseudo_count=pseudo_count,
            probability_floor=probability_floor,
        )

    @classmethod
    def from_state(cls, vocabulary: Vocabulary, state: dict[str, Any]) -> ConceptWeb:
        """Rebuild a web exported by :meth:`to_state`; its potentials are bit-identical."""
        if not isinstance(state, dict):
            raise InvalidInputError("state", f"expected a dict, got {type(state).__name__}")
        missing = [key for key in _STATE_KEYS if key not in state]
        if missing:
            raise InvalidInputError("state", f"missing keys {missing}")
        if list(state["concepts"]) != list(_checks.vocabulary(vocabulary).concepts):
            raise InvalidInputError("state.concepts", "the state was learned over a different vocabulary")
        return cls(
            vocabulary,
            state["cooccurrence"],
            state["n_objects"],
            beta=state["beta"],
            pseudo_count=state["pseudo_count"],
            probability_floor=state["probability_floor"],
        )

    def to_state(self) -> dict[str, np.ndarray | int | float | list]:
        """Everything needed to rebuild this web exactly."""
        return {
            "concepts": list(self.vocabulary.concepts),
            "cooccurrence": self.cooccurrence.copy(),
            "n_objects": self.n_objects,
            "beta": self.beta,
            "pseudo_count": self.pseudo_count,
            "probability_floor": self.probability_floor,
        }

    @property
    def edges(self) -> np.ndarray:
        """(n_edges, 2) concept index pairs i < j that co-occurred in training (the web of Fig. 8)."""
        i, j = np.nonzero(np.triu(self.cooccurrence, k=1))
        return np.stack([i, j], axis=1)

    @property
    def edge_weights(self) -> np.ndarray:
        """The co-occurrence count of each pair in :attr:`edges`."""
        i, j = np.nonzero(np.triu(self.cooccurrence, k=1))
        return self.cooccurrence[i, j]

    def potentials(self, perception: np.ndarray) -> WebPotentials:
        """The factors of one object's MRF (Eqs. 2–4): what :meth:`infer` solves when ``applied`` is None."""
        unary, _ = self._evidence(*self._check_perception(perception, None, batched=False))
        return WebPotentials(
            self.variable_names,
            self._cardinalities.copy(),
            unary[0],
            self._variable_edges.copy(),
            self._pairwise.copy(),
        )

    def infer(
        self,
        perception: np.ndarray,
        *,
        applied: np.ndarray | None = None,
        damping: float | None = None,
        tolerance: float = 1e-6,
        max_iterations: int = 100,
    ) -> WebInference:
        """Settle one object's web from its perception probabilities P(c), shape (n_concepts,).

        ``applied`` (n_verbs,) bool marks the verbs whose behaviour was applied.
        A verb not applied carries no evidence: it gets an uninformative unary
        whatever its perception value and only *receives* messages, so its
        probability is the web's prediction of that affordance and it does not
        feed back into the web. ``None`` takes every verb's value as evidence.

        ``damping`` None (the default): the sum-product pass runs undamped and the max-product
        pass at :data:`DEFAULT_DAMPING`; a number damps both. Damping changes the path, not the
        fixed points: undamped, the sum-product pass settles the paper's web in fewer than half
        the iterations, and settles more of the hardest evidence; the max-product pass keeps its
        damping because undamped it lands on other fixed points (other MAPs) more often
        (docs/concept_web.md, "Inference", has the measurements).
        """
        return self._infer(
            *self._check_perception(perception, applied, batched=False), damping, tolerance, max_iterations
        )[0]

    def infer_many(
        self,
        perceptions: np.ndarray,
        *,
        applied: np.ndarray | None = None,
        damping: float | None = None,
        tolerance: float = 1e-6,
        max_iterations: int = 100,
        start: Sequence[WebInference] | None = None,
        sum_product: tuple[float, int] | None = None,
        max_start: Sequence[WebInference] | None = None,
        max_product: tuple[float, int] | None = None,
        marginals: bool = True,
    ) -> list[WebInference]:
        """:meth:`infer` for (n_objects, n_concepts) perceptions (and (n_objects, n_verbs) ``applied``) in one call.

        ``start`` warm-starts the sum-product pass: one earlier inference of this web
        per object, whose final sum-product messages become the starting ones. On
        evidence close to the earlier one it settles in fewer iterations, to the same
        marginals within the tolerance's reach (docs/concept_web.md). The max-product
        pass starts from uniform messages unless ``max_start`` (one earlier inference
        per object) gives its max-product messages (uniform for an inference that has
        none): started elsewhere than uniform it can settle on another of its fixed
        points, which changes the MAP configuration (docs/concept_web.md measures how
        often). ``damping`` as in :meth:`infer` (None: the sum-product pass undamped, the
        max-product pass at :data:`DEFAULT_DAMPING`). ``sum_product`` and ``max_product`` =
        (damping, max_iterations) of one pass when they differ from those. ``marginals``
        false skips the sum-product pass (``probabilities`` NaN, ``messages`` None)
        for a caller that needs only the MAP configuration.
        """
        values, mask = self._check_perception(perceptions, applied, batched=True)
        if not isinstance(marginals, bool):
            raise InvalidInputError("marginals", f"expected a bool, got {marginals!r}")
        return self._infer(
            values,
            mask,
            damping,
            tolerance,
            max_iterations,
            self._start_messages(start, len(values), "start"),
            sum_product,
            self._start_messages(max_start, len(values), "max_start"),
            max_product,
            marginals,
        )

    def _start_messages(self, start: Sequence[WebInference] | None, n_objects: int, name: str) -> np.ndarray | None:
        """Starting messages (a fresh array) from earlier inferences: their sum-product messages
        (``start``, every one required) or their max-product ones (``max_start``, uniform where missing)."""
        if start is None:
            return None
        shape = self._uniform.shape
        kept = [
            item.messages if name == "start" else item.max_messages for item in start if isinstance(item, WebInference)
        ]
        if (
            len(start) != n_objects
            or len(kept) != n_objects
            or not all(
                (messages is None and name == "max_start") or (messages is not None and messages.shape == shape)
                for messages in kept
            )
        ):
            raise InvalidInputError(name, f"expected one inference of this web per object ({n_objects}), with messages")
        return np.array([self._uniform if messages is None else messages for messages in kept])

    def _infer(
        self,
        perceptions: np.ndarray,
        applied: np.ndarray | None,
        damping: float | None,
        tolerance: float,
        max_iterations: int,
        start: np.ndarray | None = None,
        sum_product: tuple[float, int] | None = None,
        max_start: np.ndarray | None = None,
        max_product: tuple[float, int] | None = None,
        marginals: bool = True,
    ) -> list[WebInference]:
        """Both passes for every object in one kernel call (``_lbp_kernels.settle_many``);
        ``start`` and ``max_start`` are fresh arrays the kernel may overwrite."""
        dampings, tolerance, counts = _pass_settings(damping, tolerance, max_iterations, sum_product, max_product)
        n_objects, n_concepts = perceptions.shape
        shape = (n_objects, *self._uniform.shape)
        # A cold pass's messages, padding included, are written by the kernel before they are read.
        if not marginals:
            sum_messages = np.empty((n_objects, 0, 0))
        else:
            sum_messages = np.empty(shape) if start is None else start
        max_messages = np.empty(shape) if max_start is None else max_start
        probabilities = np.empty((n_objects, n_concepts))
        map_configuration = np.empty((n_objects, n_concepts), dtype=np.bool_)
        iterations = np.empty((n_objects, 2), dtype=np.int64)
        converged = np.empty((n_objects, 2), dtype=np.bool_)
        _lbp_kernels.settle_many(
            np.ascontiguousarray(perceptions),
            np.ones((n_objects, len(self._verb_variables)), dtype=np.bool_)
            if applied is None
            else np.ascontiguousarray(applied),
            self._kernel_layout,
            self._clip,
            self._kernel_graph,
            _PASS_FLAGS[marginals, True],
            _PASS_FLAGS[start is None, max_start is None],
            dampings,
            tolerance,
            counts,
            probabilities,
            map_configuration,
            iterations,
            converged,
            sum_messages,
            max_messages,
        )
        # Per object in Python: for the few objects of a scene, quicker than two numpy reductions.
        steps, settled = [max(row) for row in iterations.tolist()], [all(row) for row in converged.tolist()]
        return [
            WebInference(
                probabilities[i],
                map_configuration[i],
                steps[i],
                settled[i],
                sum_messages[i] if marginals else None,
                max_messages[i],
            )
            for i in range(n_objects)
        ]

    def _check_perception(
        self, perception: Any, applied: Any, *, batched: bool
    ) -> tuple[np.ndarray, np.ndarray | None]:
        n_concepts, n_verbs = len(self.vocabulary.concepts), len(self.vocabulary.verbs)
        if (
            type(perception) is np.ndarray
            and perception.dtype == np.float64
            and perception.ndim == (2 if batched else 1)
            and perception.shape[-1] == n_concepts
            and perception.size
            and 0.0 <= perception.min()
            and perception.max() <= 1.0
        ):
            # The common case in two reductions (NaN fails both comparisons); anything else is
            # checked in full below, which names the problem.
            values = perception if batched else perception[None]
        elif batched:
            values = _checks.probabilities(perception, "perceptions", ("n_objects", n_concepts))
        else:
            values = _checks.probabilities(perception, "perception", (n_concepts,))[None]
        if applied is None:
            return values, None
        mask = _checks.applied_mask(applied, (len(values), n_verbs) if batched else (n_verbs,))
        return values, mask.reshape(len(values), n_verbs)

    def _evidence(self, perceptions: np.ndarray, applied: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """Unary factors exp(-ψ_C) = P(c) of Eq. 3, clipped, (n_objects, n_var, K), and which variables send."""
        clipped = np.clip(perceptions, self.probability_floor, 1.0 - self.probability_floor)
        unary = np.zeros((len(clipped), len(self._cardinalities), self._width))
        unary[:, self.concept_variable, self.concept_state] = clipped
        unary[:, self._verb_variables, 0] = 1.0 - clipped[:, self._verb_concepts]
        sends = np.ones(unary.shape[:2], dtype=np.bool_)
        if applied is not None:
            unary[:, self._verb_variables, :2] = np.where(applied[:, :, None], unary[:, self._verb_variables, :2], 1.0)
            sends[:, self._verb_variables] = applied
        return unary, sends

    def _describe_states(self) -> None:
        """Map concepts to (variable, state), and every state to its concept indicator.

        A state's indicator is ``offset + sign * 1[concept active]``: a concept's own
        state is (0, +1) and a verb's inactive state is (1, -1), so every joint state
        count follows from the concept co-occurrence matrix and ``n_objects``.
        """
        vocabulary = self.vocabulary
        n_nouns, n_pairs, n_verbs = len(vocabulary.nouns), len(vocabulary.adjective_pairs), len(vocabulary.verbs)
        self.variable_names: tuple[str, ...] = (
            ("noun",) + tuple(f"{a}/{b}" for a, b in vocabulary.adjective_pairs) + tuple(vocabulary.verbs)
        )
        self._cardinalities = np.array([n_nouns] + [2] * (n_pairs + n_verbs), dtype=np.int64)
        self._width = int(self._cardinalities.max())
        self.concept_variable = np.concatenate(
            [np.zeros(n_nouns, dtype=np.int64), 1 + np.repeat(np.arange(n_pairs), 2), 1 + n_pairs + np.arange(n_verbs)]
        ).astype(np.int64)
        self.concept_state = np.concatenate(
            [np.arange(n_nouns), np.tile([0, 1], n_pairs), np.ones(n_verbs, dtype=np.int64)]
        ).astype(np.int64)
        self._verb_concepts = n_nouns + 2 * n_pairs + np.arange(n_verbs)
        self._verb_variables = 1 + n_pairs + np.arange(n_verbs)
        shape = (len(self._cardinalities), self._width)
        self._state_concept = np.zeros(shape, dtype=np.int64)
        self._state_offset, self._state_sign = np.zeros(shape), np.zeros(shape)
        self._state_concept[self.concept_variable, self.concept_state] = np.arange(len(self.concept_variable))
        self._state_sign[self.concept_variable, self.concept_state] = 1.0
        self._state_concept[self._verb_variables, 0] = self._verb_concepts
        self._state_offset[self._verb_variables, 0] = 1.0
        self._state_sign[self._verb_variables, 0] = -1.0

    def _co_occurring_variables(self) -> np.ndarray:
        """Variable pairs (u < v) with any two concepts that co-occurred in training (ε_ij)."""
        incidence = np.zeros((len(self._cardinalities), len(self.concept_variable)))
        incidence[self.concept_variable, np.arange(len(self.concept_variable))] = 1.0
        linked = incidence @ (self.cooccurrence > 0) @ incidence.T
        return np.argwhere(np.triu(linked, k=1) > 0).astype(np.int64)

    def _clique_factors(self) -> np.ndarray:
        """exp(-β_e ψ_K) with ψ_K(s, t) = 2 - P(s | t) - P(t | s) (Eq. 4) from smoothed joint counts.

        β_e = β / (mean degree of the edge's two variables): a variable's total pull
        from the web stays of order β whatever the size of the vocabulary.
        """
        u, v = self._variable_edges[:, 0], self._variable_edges[:, 1]
        counts, total = self.cooccurrence.astype(np.float64), float(self.n_objects)
        diagonal = np.diag(counts)
        cs, ct = self._state_concept[u], self._state_concept[v]
        a_s, b_s = self._state_offset[u][:, :, None], self._state_sign[u][:, :, None]
        a_t, b_t = self._state_offset[v][:, None, :], self._state_sign[v][:, None, :]
        joint = (
            a_s * a_t * total
            + a_s * b_t * diagonal[ct][:, None, :]
            + b_s * a_t * diagonal[cs][:, :, None]
            + b_s * b_t * counts[cs[:, :, None], ct[:, None, :]]
        )
        states = np.arange(self._width)
        valid_u = states[None, :] < self._cardinalities[u][:, None]
        valid_v = states[None, :] < self._cardinalities[v][:, None]
        smoothed = np.where(valid_u[:, :, None] & valid_v[:, None, :], joint + self.pseudo_count, 0.0)
        given_t = smoothed / np.maximum(smoothed.sum(axis=1, keepdims=True), self.pseudo_count)
        given_s = smoothed / np.maximum(smoothed.sum(axis=2, keepdims=True), self.pseudo_count)
        degree = np.bincount(self._variable_edges.reshape(-1), minlength=len(self._cardinalities))
        strength = self.beta * 2.0 / (degree[u] + degree[v])
        return np.where(smoothed > 0, np.exp(-strength[:, None, None] * (2.0 - given_t - given_s)), 0.0)
