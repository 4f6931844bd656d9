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
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING

import numpy as np
from scipy.optimize import minimize
from scipy.special import expit, log_expit, log_softmax, softmax

from core.errors import InvalidInputError
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
    return softmax(-np.asarray(noun_distances) / prototypes.temperatures["noun"] + prototypes.biases["noun"], axis=-1)


def first_adjective_probabilities(prototypes: PrototypeSet, pair_distances: np.ndarray) -> np.ndarray:
    """P(first adjective) of each pair from (..., n_pairs, 2) distances."""
    pair_distances = np.asarray(pair_distances)
    margins = pair_distances[..., 1] - pair_distances[..., 0]
    return expit(margins / prototypes.temperatures["adjective"] + prototypes.biases["adjective"])


def verb_match_probability(prototypes: PrototypeSet, verb_distances: np.ndarray, verb: int) -> float:
    """P(the effect matches verb ``verb`` rather than another verb), at even prior odds."""
    n_verbs = len(verb_distances)
    if n_verbs < 2:
        return NO_EVIDENCE
    posterior = softmax(-np.asarray(verb_distances) / prototypes.temperatures["verb"] + prototypes.biases["verb"])
    q = float(posterior[verb])
    return q * (n_verbs - 1) / (q * (n_verbs - 1) + 1.0 - q)


def perceive(
    prototypes: PrototypeSet, entity: np.ndarray, effects: Mapping[str, np.ndarray] | None = None
) -> np.ndarray:
    """Per-concept perception probabilities in ``vocabulary.concepts`` order.

    Nouns sum to 1, each adjective pair sums to 1, a verb is the probability that
    its behaviour's effect (``effects[verb]``, 66 dims) matches the verb, or 0.5
    when that behaviour was not applied.
    """
    vocabulary = prototypes.vocabulary
    entity_distances = prototypes.distances(entity)
    if entity_distances.ndim != 1:
        raise InvalidInputError("entity", "perceive takes one entity vector of 91 features")
    n_nouns = len(vocabulary.nouns)
    nouns = noun_probabilities(prototypes, entity_distances[:n_nouns])
    first = first_adjective_probabilities(prototypes, entity_distances[n_nouns:].reshape(-1, 2))
    adjectives = np.column_stack([first, 1.0 - first]).ravel()
    verbs = np.full(len(vocabulary.verbs), NO_EVIDENCE)
    for behaviour, effect in (effects or {}).items():
        if behaviour not in vocabulary.verbs:
            raise InvalidInputError("effects", f"{behaviour!r} is not a verb of the vocabulary")
        try:
            distances = prototypes.effect_distances(effect)
        except InvalidInputError as error:
            raise InvalidInputError(f"effects.{behaviour}", error.problem) from None
        if distances.ndim != 1:
            raise InvalidInputError(f"effects.{behaviour}", "must be one effect vector of 66 features")
        index = vocabulary.verbs.index(behaviour)
        verbs[index] = verb_match_probability(prototypes, distances, index)
    return np.concatenate([nouns, adjectives, verbs])


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
