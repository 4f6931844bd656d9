"""The two pools of P(c) and P(c | χ) in the feedback loop (docs/feedback.md, "The hard world"):
Eq. 6's linear one (the paper's, the default) and the logarithmic one measured beside it."""

from __future__ import annotations

import numpy as np
import pytest

from core.context.feedback import PAPER_POOLING, contextual_feedback, pool
from core.errors import InvalidInputError
from tests.test_feedback_loop import boxlike_cup_scene, random_perceptions


def test_the_paper_rule_is_the_default(world, web, context_model) -> None:
    perceptions, applied = boxlike_cup_scene(world)
    default = contextual_feedback(web, context_model, perceptions, world.vocabulary, applied=applied)
    linear = contextual_feedback(web, context_model, perceptions, world.vocabulary, applied=applied, pooling="linear")
    assert PAPER_POOLING == "linear"
    assert np.array_equal(default.in_context, linear.in_context)


def test_log_pool_at_sigma_one_is_the_web_and_at_zero_the_context(world) -> None:
    vocabulary = world.vocabulary
    rng = np.random.default_rng(5)
    web_p, context_p = random_perceptions(vocabulary, 4, rng), random_perceptions(vocabulary, 1, rng)[0]
    informed = np.ones(len(vocabulary), dtype=bool)
    np.testing.assert_allclose(pool(web_p, context_p, informed, 1.0, vocabulary, "log"), web_p, atol=1e-12)
    np.testing.assert_allclose(
        pool(web_p, context_p, informed, 0.0, vocabulary, "log"), np.broadcast_to(context_p, web_p.shape), atol=1e-12
    )
    uninformed = pool(web_p, context_p, np.zeros_like(informed), 0.3, vocabulary, "log")
    assert np.array_equal(uninformed, web_p)


def test_log_pool_keeps_the_structure_and_agreement_raises_confidence(world) -> None:
    """Unlike Eq. 6, two sources that agree on a noun give it more than either did."""
    vocabulary = world.vocabulary
    n_nouns, n_grouped = len(vocabulary.nouns), len(vocabulary.nouns) + len(vocabulary.adjectives)
    web_p = random_perceptions(vocabulary, 3, np.random.default_rng(6))
    cup = vocabulary.index("cup")
    web_p[:, :n_nouns] = 0.1 / (n_nouns - 1)
    web_p[:, cup] = 0.9
    context_p = np.full(len(vocabulary), 0.5)
    context_p[:n_nouns] = 0.0
    context_p[cup], context_p[vocabulary.index("plate")] = 0.73, 0.27
    informed = np.ones(len(vocabulary), dtype=bool)
    log = pool(web_p, context_p, informed, 0.5, vocabulary, "log")
    linear = pool(web_p, context_p, informed, 0.5, vocabulary, "linear")
    np.testing.assert_allclose(log[:, :n_nouns].sum(axis=1), 1.0, atol=1e-12)
    pairs = log[:, n_nouns:n_grouped].reshape(3, -1, 2).sum(axis=2)
    np.testing.assert_allclose(pairs, 1.0, atol=1e-12)
    assert (log[:, cup] > 0.9).all() and (linear[:, cup] < 0.9).all()
    assert (log[:, vocabulary.index("box")] < 1e-6).all()


def test_unknown_pooling_is_refused(world, web, context_model) -> None:
    perceptions, applied = boxlike_cup_scene(world)
    with pytest.raises(InvalidInputError) as error:
        contextual_feedback(web, context_model, perceptions, world.vocabulary, applied=applied, pooling="max")
    assert error.value.field == "pooling"
