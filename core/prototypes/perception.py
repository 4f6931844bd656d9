"""From prototype distances (Eq. 1) to per-concept perception probabilities.

The concept web (Eq. 2-4) needs, for every concept, a probability of being
active. The mapping, and why:

- **Nouns**: ``softmax(-D / T_noun + b_noun)`` over the nouns. An object has
  exactly one noun, so the nouns form one distribution; the softmax keeps the
  nearest-prototype decision of the Appendix and turns distances into confidences.
- **Adjective pairs**: ``P(first) = sigmoid((D_second - D_first) / T_adjective + b_pair)``,
  ``P(second) = 1 - P(first)``: the two-class form of the same softmax, since an
  object has exactly one adjective of each dichotomic pair.
- **Verbs**: for a behaviour b applied to the object, with effect f, let
  ``q = softmax(-D(., f) / T_verb + b_verb)`` be the recognition posterior over the
  K verbs. ``P(b active)`` is the probability that f matches b rather than another
  verb, at even prior odds: ``q_b (K - 1) / (q_b (K - 1) + 1 - q_b)``. The robot
  knows it applied b, so "b or not" is the question; q itself carries a 1/K prior,
  and a well recognised push (q ~ 0.4 beside the alike move) then read as "push
  inactive", which the web took as the sign of a cup or plate and turned boxes
  hard and round (docs/prototypes.md has the measurements). A behaviour that was
  not applied gives 0.5: no evidence either way; so does any behaviour when the
  vocabulary has a single verb.
- **Calibration**: the temperature T of each kind and one offset b per noun, per
  adjective pair and per verb maximise the likelihood of the training labels under
  these formulas, with a weak Gaussian prior on the offsets (precision
  ``BIAS_PRECISION``, so that they stay finite on separable data). The offsets
  absorb the concept-dependent scale of Eq. 1: dividing by |R_c| makes a concept
  with few relevant features look systematically far. Distances are leave-one-out
  (each training instance against prototype means that do not contain it):
  in-sample distances to one's own mean are systematically short and would make
  the confidences too sharp.

Cost: a perception is on the service's request path (one per object of a scene).
The applied behaviours' effects go through Eq. 1 as one array, all verbs at once
(numba kernel, ``_eq1_kernels``), and the softmax is written out in numpy
(max-shifted, the arithmetic of ``scipy.special.softmax``, whose per-call dispatch
cost more than the rest); :func:`perceive_many` does a whole scene in one pass.
The probabilities equal the former one-behaviour-at-a-time code bit for bit
(measured on the paper world; ``tests/test_prototypes_perception.py`` holds the
reference at 1e-12).
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from scipy.optimize import minimize
from scipy.special import expit, log_expit, log_softmax

from core.errors import InvalidInputError
from core.features.layout import EFFECT_SIZE, ENTITY_SIZE
from core.vocabulary import Vocabulary

if TYPE_CHECKING:
    from core.prototypes.prototypes import PrototypeSet

NO_EVIDENCE = 0.5
#: Precision of the zero-mean Gaussian prior on the calibration offsets.
BIAS_PRECISION = 0.02
#: Temperatures are searched within this factor of the typical distance, either way.
_TEMPERATURE_RANGE = 1e3


def noun_probabilities(prototypes: PrototypeSet, noun_distances: np.ndarray) -> np.ndarray:
    """softmax(-D / T + b) over the nouns (last axis)."""
    return _softmax(-np.asarray(noun_distances) / prototypes.temperatures["noun"] + prototypes.biases["noun"])


def first_adjective_probabilities(prototypes: PrototypeSet, pair_distances: np.ndarray) -> np.ndarray:
    """P(first adjective) of each pair from (..., n_pairs, 2) distances."""
    pair_distances = np.asarray(pair_distances)
    margins = pair_distances[..., 1] - pair_distances[..., 0]
    return expit(margins / prototypes.temperatures["adjective"] + prototypes.biases["adjective"])


def verb_match_probabilities(prototypes: PrototypeSet, verb_distances: np.ndarray, verbs: np.ndarray) -> np.ndarray:
    """P(effect j matches verb ``verbs[j]`` rather than another verb), at even prior odds,
    from the (m, K) distances of m effects to the K verb prototypes."""
    verb_distances = np.asarray(verb_distances)
    n_verbs = verb_distances.shape[-1]
    if n_verbs < 2:
        return np.full(len(verbs), NO_EVIDENCE)
    posterior = _softmax(-verb_distances / prototypes.temperatures["verb"] + prototypes.biases["verb"])
    q = posterior[np.arange(len(verbs)), verbs]
    return q * (n_verbs - 1) / (q * (n_verbs - 1) + 1.0 - q)


def perceive(
    prototypes: PrototypeSet, entity: np.ndarray, effects: Mapping[str, np.ndarray] | None = None
) -> np.ndarray:
    """Per-concept perception probabilities in ``vocabulary.concepts`` order.

    Nouns sum to 1, each adjective pair sums to 1, a verb is the probability that
    its behaviour's effect (``effects[verb]``, 66 dims) matches the verb, or 0.5
    when that behaviour was not applied.
    """
    return _probabilities(prototypes, _observations(prototypes, [entity], [effects], indexed=False))[0]


def perceive_many(
    prototypes: PrototypeSet,
    entities: Sequence[np.ndarray],
    effects: Sequence[Mapping[str, np.ndarray] | None],
) -> np.ndarray:
    """:func:`perceive` of the n objects of a scene at once: (n, n_concepts), row i equal
    to ``perceive(prototypes, entities[i], effects[i])``, bit for bit.

    The objects are checked together and all their entities, then all their effects,
    go through Eq. 1 in one kernel call, which is what makes a scene cheap. Bad input
    raises the error :func:`perceive` would, its field indexed by the object
    (``entities[2]``, ``effects[2]``, ``effects[2].push``); the first bad object is reported.
    """
    if len(entities) != len(effects):
        raise InvalidInputError("effects", f"has {len(effects)} effect maps for {len(entities)} entities")
    if len(entities) == 0:
        return np.zeros((0, len(prototypes.vocabulary.concepts)))
    return _probabilities(prototypes, _observations(prototypes, entities, effects, indexed=True))


class _Observations(NamedTuple):
    """Checked, standardised observations of n objects: entities z (n, 91) and all their
    effects (m, 66), effect j being object ``owners[j]``'s behaviour ``verbs[j]`` (verb column)."""

    entities: np.ndarray
    effects: np.ndarray
    owners: np.ndarray
    verbs: np.ndarray


def _probabilities(prototypes: PrototypeSet, observed: _Observations) -> np.ndarray:
    """Perception (n, n_concepts) of the observed objects (the module docstring's mapping)."""
    vocabulary = prototypes.vocabulary
    n_objects = len(observed.entities)
    n_nouns, n_entity = len(vocabulary.nouns), len(vocabulary.nouns) + len(vocabulary.adjectives)
    entity_distances = prototypes.entity_eq1.distances(observed.entities)
    out = np.empty((n_objects, len(vocabulary.concepts)))
    out[:, :n_nouns] = noun_probabilities(prototypes, entity_distances[:, :n_nouns])
    first = first_adjective_probabilities(prototypes, entity_distances[:, n_nouns:].reshape(n_objects, -1, 2))
    out[:, n_nouns:n_entity:2] = first
    out[:, n_nouns + 1 : n_entity : 2] = 1.0 - first
    out[:, n_entity:] = NO_EVIDENCE
    if len(observed.verbs):
        verb_distances = prototypes.verb_eq1.distances(observed.effects)
        match = verb_match_probabilities(prototypes, verb_distances, observed.verbs)
        out[observed.owners, n_entity + observed.verbs] = match
    return out


def _observations(
    prototypes: PrototypeSet,
    entities: Sequence[object],
    effects: Sequence[Mapping[str, object] | None],
    *,
    indexed: bool,
) -> _Observations:
    """Check and standardise the objects' observations, in input order.

    Fast path: every entity, then every effect, is stacked into one array and checked
    at once. When that fails (a bad shape, a non-finite value, an unknown behaviour),
    each object is checked on its own, in order, so that the error is the one a
    one-by-one check reports: ``entity`` / ``effects`` / ``effects.<behaviour>``, or
    ``entities[i]`` / ``effects[i]`` / ``effects[i].<behaviour>`` when ``indexed``.
    """
    columns = _verb_columns(prototypes.vocabulary)
    maps = [object_effects or {} for object_effects in effects]
    try:
        entity_rows = np.array(entities, dtype=np.float64)
        verbs = np.array([columns[behaviour] for effect_map in maps for behaviour in effect_map], dtype=np.intp)
        vectors = [vector for effect_map in maps for vector in effect_map.values()]
        effect_rows = np.array(vectors, dtype=np.float64) if vectors else np.zeros((0, EFFECT_SIZE))
    except (KeyError, TypeError, ValueError):
        return _checked_observations(prototypes, entities, maps, indexed)
    if (
        entity_rows.shape != (len(entities), ENTITY_SIZE)
        or effect_rows.shape != (len(verbs), EFFECT_SIZE)
        or not np.isfinite(entity_rows).all()
        or not np.isfinite(effect_rows).all()
    ):
        return _checked_observations(prototypes, entities, maps, indexed)
    owners = np.repeat(np.arange(len(maps)), [len(effect_map) for effect_map in maps])
    return _Observations(
        (entity_rows - prototypes.entity_center) / prototypes.entity_scale,
        effect_rows / prototypes.effect_scale,
        owners,
        verbs,
    )


def _checked_observations(
    prototypes: PrototypeSet, entities: Sequence[object], maps: list[Mapping[str, object]], indexed: bool
) -> _Observations:
    """:func:`_observations`, one object and one effect at a time; raises at the first bad one."""
    columns = _verb_columns(prototypes.vocabulary)
    entity_rows, effect_rows, owners, verbs = [], [], [], []
    for i, (entity, effect_map) in enumerate(zip(entities, maps, strict=True)):
        entity_field, effects_field = (f"entities[{i}]", f"effects[{i}]") if indexed else ("entity", "effects")
        entity_rows.append(prototypes.standardised_entities(entity, entity_field))
        if np.asarray(entity).ndim != 1:
            raise InvalidInputError(entity_field, "perceive takes one entity vector of 91 features")
        for behaviour, effect in effect_map.items():
            if behaviour not in columns:
                raise InvalidInputError(effects_field, f"{behaviour!r} is not a verb of the vocabulary")
            try:
                effect_rows.append(prototypes.standardised_effects(effect))
            except InvalidInputError as error:
                raise InvalidInputError(f"{effects_field}.{behaviour}", error.problem) from None
            if np.asarray(effect).ndim != 1:
                raise InvalidInputError(f"{effects_field}.{behaviour}", "must be one effect vector of 66 features")
            owners.append(i)
            verbs.append(columns[behaviour])
    return _Observations(
        np.concatenate(entity_rows),
        np.concatenate(effect_rows) if effect_rows else np.zeros((0, EFFECT_SIZE)),
        np.array(owners, dtype=np.intp),
        np.array(verbs, dtype=np.intp),
    )


@functools.lru_cache(maxsize=64)
def _verb_columns(vocabulary: Vocabulary) -> dict[str, int]:
    return {verb: i for i, verb in enumerate(vocabulary.verbs)}


def _softmax(x: np.ndarray) -> np.ndarray:
    """softmax over the last axis, shifted by its maximum so that exp cannot overflow
    (the largest term is exp(0) = 1): scipy.special.softmax's arithmetic, operation for
    operation, without its array-API dispatch, which took a third of a perception's
    time when it ran once per applied behaviour."""
    shifted = np.exp(x - x.max(axis=-1, keepdims=True))
    return shifted / shifted.sum(axis=-1, keepdims=True)


def fit_calibration(
    vocabulary: Vocabulary,
    entity_distances: np.ndarray,
    entity_members: np.ndarray,
    verb_distances: np.ndarray,
    verb_members: np.ndarray,
) -> tuple[dict[str, float], dict[str, np.ndarray]]:
    """Maximum a posteriori temperatures and offsets of the noun softmax, the adjective
    sigmoids and the verb softmax, from (leave-one-out) training distances."""
    n_nouns = len(vocabulary.nouns)
    n_pairs = len(vocabulary.adjective_pairs)
    pair_d = entity_distances[:, n_nouns:].reshape(len(entity_distances), n_pairs, 2)
    pair_members = entity_members[:, n_nouns:].reshape(len(entity_members), n_pairs, 2)
    labelled = pair_members.any(axis=2)
    signs = np.where(pair_members[..., 0], 1.0, -1.0)[labelled]
    margins = (pair_d[..., 1] - pair_d[..., 0])[labelled]
    pair_of = np.broadcast_to(np.arange(n_pairs), labelled.shape)[labelled]

    def adjective_nll(temperature: float, bias: np.ndarray) -> float:
        return -log_expit(signs * (margins / temperature + bias[pair_of])).sum()

    noun = _softmax_calibration(entity_distances[:, :n_nouns], entity_members[:, :n_nouns])
    adjective = _calibrate(adjective_nll, np.abs(margins), n_pairs)
    verb = _softmax_calibration(verb_distances, verb_members)
    return (
        {"noun": noun[0], "adjective": adjective[0], "verb": verb[0]},
        {"noun": noun[1], "adjective": adjective[1], "verb": verb[1]},
    )


def _softmax_calibration(distances: np.ndarray, members: np.ndarray) -> tuple[float, np.ndarray]:
    rows = np.arange(len(distances))
    labels = members.argmax(axis=1) if members.shape[1] else np.zeros(len(members), dtype=np.int64)

    def nll(temperature: float, bias: np.ndarray) -> float:
        return -log_softmax(-distances / temperature + bias, axis=1)[rows, labels].sum()

    return _calibrate(nll, distances, members.shape[1])


def _calibrate(
    nll: Callable[[float, np.ndarray], float], distances: np.ndarray, n_offsets: int
) -> tuple[float, np.ndarray]:
    """Minimise nll(T, b) + BIAS_PRECISION / 2 |b|^2 over log T (within a wide band around
    the typical distance) and the offsets b; (1.0, zeros) when there is nothing to fit."""
    positive = np.asarray(distances)[np.asarray(distances) > 0]
    if positive.size == 0 or n_offsets == 0:
        return 1.0, np.zeros(n_offsets)
    log_typical = float(np.log(np.median(positive)))
    bounds = [(log_typical - np.log(_TEMPERATURE_RANGE), log_typical + np.log(_TEMPERATURE_RANGE))]

    def objective(theta: np.ndarray) -> float:
        bias = theta[1:]
        return nll(float(np.exp(theta[0])), bias) + 0.5 * BIAS_PRECISION * float(bias @ bias)

    start = np.concatenate([[log_typical], np.zeros(n_offsets)])
    result = minimize(objective, start, method="L-BFGS-B", bounds=bounds + [(None, None)] * n_offsets)
    return float(np.exp(result.x[0])), result.x[1:].copy()
