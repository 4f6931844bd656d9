"""Eq. 7, Eq. 8 and the Dirichlet-multinomial log-likelihood."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import gammaln
from scipy.stats import dirichlet_multinomial

from core.context.metrics import (
    PAPER_RHO,
    average_log_likelihood,
    concept_relevance,
    contextual_entropy,
    dirichlet_multinomial_log_likelihood,
)
from core.errors import InvalidInputError


def test_dirichlet_multinomial_matches_scipy_without_the_multinomial_coefficient() -> None:
    counts = np.array([[3, 0, 2, 5], [1, 1, 1, 0]])
    totals = counts.sum(axis=1)
    expected = 0.0
    for row, n in zip(counts, totals, strict=True):
        coefficient = gammaln(n + 1) - gammaln(row + 1).sum()
        expected += dirichlet_multinomial.logpmf(row, np.full(4, 0.3), n) - coefficient
    assert dirichlet_multinomial_log_likelihood(counts, totals, 0.3, 4) == pytest.approx(expected, rel=1e-12)


def test_dirichlet_multinomial_zero_columns_may_be_left_out() -> None:
    counts = np.array([[3, 0, 2, 0]])
    full = dirichlet_multinomial_log_likelihood(counts, counts.sum(axis=1), 0.1, 4)
    assert dirichlet_multinomial_log_likelihood(counts[:, [0, 2]], counts.sum(axis=1), 0.1, 4) == pytest.approx(full)


def test_entropy_eq8_of_uniform_estimates() -> None:
    phi = np.full((3, 8), 1 / 8)
    theta = np.full((5, 3), 1 / 3)
    assert contextual_entropy(phi, theta, rho=1.0) == pytest.approx(math.log(8))
    assert contextual_entropy(phi, theta, rho=0.0) == pytest.approx(math.log(3))
    assert contextual_entropy(phi, theta) == pytest.approx(PAPER_RHO * math.log(8) + (1 - PAPER_RHO) * math.log(3))


def test_entropy_eq8_weights_contexts_by_their_share_of_scenes() -> None:
    phi = np.array([[1.0, 0.0, 0.0, 0.0], [0.25, 0.25, 0.25, 0.25]])
    theta = np.array([[1.0, 0.0], [1.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    assert contextual_entropy(phi, theta, rho=1.0) == pytest.approx(0.25 * math.log(4))
    assert contextual_entropy(phi, theta, rho=0.0) == pytest.approx(0.0)


def test_entropy_eq8_rejects_bad_input() -> None:
    with pytest.raises(InvalidInputError, match="rho"):
        contextual_entropy(np.ones((1, 2)) / 2, np.ones((1, 1)), rho=1.5)
    with pytest.raises(InvalidInputError, match="concept_given_context"):
        contextual_entropy(np.ones((2, 2)) / 2, np.ones((1, 1)))


def test_average_log_likelihood_eq7_averages_each_observation_first() -> None:
    value = average_log_likelihood([[0.5, 0.5], [0.25]])
    assert value == pytest.approx((math.log(0.5) + math.log(0.25)) / 2)


def test_average_log_likelihood_eq7_floors_zero_and_validates() -> None:
    assert average_log_likelihood([[0.0]], floor=1e-6) == pytest.approx(math.log(1e-6))
    with pytest.raises(InvalidInputError, match=r"related_concept_probabilities\[1\]"):
        average_log_likelihood([[0.5], [1.5]])
    with pytest.raises(InvalidInputError, match="related_concept_probabilities"):
        average_log_likelihood([])
    with pytest.raises(InvalidInputError, match=r"related_concept_probabilities\[0\]"):
        average_log_likelihood([[]])


def test_relevance_at_one_ranks_by_probability_and_at_zero_by_lift() -> None:
    # Two contexts over four concepts: "shared" is equally likely in both, "pour" only in the first.
    phi = np.array([[0.45, 0.40, 0.10, 0.05], [0.45, 0.05, 0.10, 0.40]])
    weights = np.array([3.0, 1.0])
    marginal = (weights / weights.sum()) @ phi
    by_probability = concept_relevance(phi, weights, 1.0)
    np.testing.assert_allclose(by_probability, np.log(phi))
    by_lift = concept_relevance(phi, weights, 0.0)
    np.testing.assert_allclose(by_lift, np.log(phi / marginal))
    assert by_lift[0, 0] == pytest.approx(0.0, abs=1e-12)  # a concept shared equally has lift 1
    assert np.argmax(by_probability[0]) == 0 and np.argmax(by_lift[0]) == 1  # the shared concept drops
    np.testing.assert_allclose(concept_relevance(phi, weights, 0.6), 0.6 * by_probability + 0.4 * by_lift)


@pytest.mark.parametrize(
    ("weights", "weight", "field"),
    [(np.array([1.0, 1.0]), 1.5, "relevance_weight"), (np.array([1.0]), 0.6, "context_weights"),
     (np.zeros(2), 0.6, "context_weights")],
)  # fmt: skip
def test_relevance_refuses_a_weight_outside_0_1_and_bad_context_weights(
    weights: np.ndarray, weight: float, field: str
) -> None:
    with pytest.raises(InvalidInputError) as raised:
        concept_relevance(np.full((2, 3), 1 / 3), weights, weight)
    assert raised.value.field == field
