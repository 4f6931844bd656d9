"""The concept web's passes as the context loop uses them: skipping the sum-product pass, warm
max-product starts, the unary factors built in the kernel, and the memoised pass settings."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from core.concept_web import DEFAULT_DAMPING, ConceptWeb, loopy_belief_propagation
from core.errors import InvalidInputError
from core.vocabulary import paper_vocabulary
from sim.world import TRAIN, WorldConfig, make_objects

PAPER = paper_vocabulary()
TRAINING = [[*o.concepts, *o.behaviours] for o in make_objects(WorldConfig.paper(), seed=0) if o.split == TRAIN]


@pytest.fixture(scope="module")
def paper_web() -> ConceptWeb:
    return ConceptWeb.fit(PAPER, TRAINING)


def scenes(rng: np.random.Generator, n_objects: int = 5) -> tuple[np.ndarray, np.ndarray]:
    perceptions = rng.random((n_objects, len(PAPER)))
    perceptions[0] = np.round(perceptions[0])  # certain evidence, clipped to the floor
    return perceptions, rng.random((n_objects, len(PAPER.verbs))) < 0.5


def test_without_marginals_the_map_is_the_same_and_the_marginals_are_missing(paper_web: ConceptWeb) -> None:
    rng = np.random.default_rng(1)
    for applied_given in (True, False):
        perceptions, applied = scenes(rng)
        applied = applied if applied_given else None
        full = paper_web.infer_many(perceptions, applied=applied)
        only_map = paper_web.infer_many(perceptions, applied=applied, marginals=False)
        for a, b in zip(full, only_map, strict=True):
            np.testing.assert_array_equal(a.map_configuration, b.map_configuration)
            np.testing.assert_array_equal(a.max_messages, b.max_messages)
            assert np.isnan(b.probabilities).all() and b.messages is None
            assert b.converged and b.iterations <= a.iterations


def test_the_kernels_unary_factors_are_the_documented_potentials(paper_web: ConceptWeb) -> None:
    # infer builds Eq. 3's unaries in the kernel; potentials() builds them in numpy: the same MRF, bit for bit
    # (at loopy_belief_propagation's one damping for both passes).
    rng = np.random.default_rng(2)
    for perception in (rng.random(len(PAPER)), np.round(rng.random(len(PAPER))), np.full(len(PAPER), 0.5)):
        inference = paper_web.infer(perception, damping=DEFAULT_DAMPING)
        marginals, max_marginals, iterations, converged = loopy_belief_propagation(paper_web.potentials(perception))
        np.testing.assert_array_equal(
            inference.probabilities, marginals[paper_web.concept_variable, paper_web.concept_state]
        )
        best = np.argmax(max_marginals, axis=1)[paper_web.concept_variable] == paper_web.concept_state
        np.testing.assert_array_equal(inference.map_configuration, best)
        assert (inference.iterations, inference.converged) == (iterations, converged)


def test_a_max_product_warm_start_from_its_own_fixed_point_settles_at_once(paper_web: ConceptWeb) -> None:
    perceptions, applied = scenes(np.random.default_rng(3))
    cold = paper_web.infer_many(perceptions, applied=applied)
    warm = paper_web.infer_many(perceptions, applied=applied, max_start=cold, max_product=(0.0, 30), marginals=False)
    for c, w in zip(cold, warm, strict=True):
        assert w.converged and w.iterations <= 2
        np.testing.assert_array_equal(c.map_configuration, w.map_configuration)
    # An earlier inference without max-product messages starts its object from uniform messages:
    # with the default settings, that object is settled exactly as a cold start settles it.
    mixed = [cold[0], dataclasses.replace(cold[1], max_messages=None), *cold[2:]]
    again = paper_web.infer_many(perceptions, applied=applied, max_start=mixed)
    np.testing.assert_array_equal(again[1].max_messages, cold[1].max_messages)
    assert again[1].iterations == cold[1].iterations
    assert again[0].iterations < cold[0].iterations


def test_messages_are_deterministic_arrays_with_zero_padding(paper_web: ConceptWeb) -> None:
    perceptions, applied = scenes(np.random.default_rng(4))
    first = paper_web.infer_many(perceptions, applied=applied)
    second = paper_web.infer_many(perceptions, applied=applied)
    binary = paper_web._graph.cardinalities[paper_web._graph.targets] == 2
    for a, b in zip(first, second, strict=True):
        for messages, again in ((a.messages, b.messages), (a.max_messages, b.max_messages)):
            np.testing.assert_array_equal(messages, again)
            assert (messages[binary, 2:] == 0.0).all()
            np.testing.assert_allclose(messages.sum(axis=1), 1.0)


def test_bad_warm_starts_and_flags_are_refused(paper_web: ConceptWeb) -> None:
    perceptions = np.full((2, len(PAPER)), 0.5)
    settled = paper_web.infer_many(perceptions)
    with pytest.raises(InvalidInputError, match="max_start"):
        paper_web.infer_many(perceptions, max_start=settled[:1])
    with pytest.raises(InvalidInputError, match="max_start"):
        paper_web.infer_many(perceptions, max_start=[settled[0], "not an inference"])  # type: ignore[list-item]
    with pytest.raises(InvalidInputError, match="marginals"):
        paper_web.infer_many(perceptions, marginals=1)  # type: ignore[arg-type]
    with pytest.raises(InvalidInputError, match="damping"):
        paper_web.infer_many(perceptions, max_product=(1.0, 30))


def test_memoised_settings_still_refuse_what_equals_a_valid_value(paper_web: ConceptWeb) -> None:
    perception = np.full(len(PAPER), 0.5)
    paper_web.infer(perception, max_iterations=1, damping=0)
    # True == 1 and 0 == 0.0 == False: the memo keys on types, so these are refused as ever.
    with pytest.raises(InvalidInputError, match="max_iterations"):
        paper_web.infer(perception, max_iterations=True, damping=0)
    with pytest.raises(InvalidInputError, match="damping"):
        paper_web.infer(perception, max_iterations=1, damping=False)
    paper_web.infer_many(perception[None], sum_product=(0.0, 30))
    with pytest.raises(InvalidInputError, match="max_iterations"):
        paper_web.infer_many(perception[None], sum_product=(0.0, 30.0))
