"""Learning the concept web from training objects (§III-B, Eqs. 3–4), its state and its bad inputs."""

from __future__ import annotations

import json

import numpy as np
import pytest

from core.concept_web import ConceptWeb
from core.concept_web.web import DEFAULT_BETA, DEFAULT_PSEUDO_COUNT
from core.errors import InvalidInputError
from core.vocabulary import Vocabulary, paper_vocabulary
from sim.world import WorldConfig, make_objects

SMALL = Vocabulary(("box", "cup"), (("hard", "soft"),), ("push", "grasp"))
#: box/soft/push+grasp ×3, box/hard/push ×1, cup/hard/grasp ×4.
SMALL_OBJECTS = [["box", "soft", "push", "grasp"]] * 3 + [["box", "hard", "push"]] + [["cup", "hard", "grasp"]] * 4


def test_edges_and_weights_are_the_training_co_occurrences() -> None:
    web = ConceptWeb.fit(SMALL, SMALL_OBJECTS)
    names = SMALL.concepts
    found = {(names[i], names[j]): int(w) for (i, j), w in zip(web.edges, web.edge_weights)}
    assert found == {
        ("box", "hard"): 1,
        ("box", "soft"): 3,
        ("box", "push"): 4,
        ("box", "grasp"): 3,
        ("cup", "hard"): 4,
        ("cup", "grasp"): 4,
        ("hard", "push"): 1,
        ("hard", "grasp"): 4,
        ("soft", "push"): 3,
        ("soft", "grasp"): 3,
        ("push", "grasp"): 3,
    }
    assert web.n_objects == 8
    np.testing.assert_array_equal(np.diag(web.cooccurrence), [4, 4, 5, 3, 4, 7])


def test_clique_factors_follow_eq_4_with_smoothed_conditionals() -> None:
    web = ConceptWeb.fit(SMALL, SMALL_OBJECTS)
    potentials = web.potentials(np.full(len(SMALL), 0.5))
    assert potentials.variable_names == ("noun", "hard/soft", "push", "grasp")
    edges = potentials.variable_edges.tolist()
    assert edges == [[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]]
    # noun x push: joint counts [box: (inactive 0, active 4), cup: (4, 0)] plus the pseudo-count.
    joint = np.array([[0.0, 4.0], [4.0, 0.0]]) + DEFAULT_PSEUDO_COUNT
    push_given_noun = joint / joint.sum(axis=1, keepdims=True)
    noun_given_push = joint / joint.sum(axis=0, keepdims=True)
    energy = (1 - noun_given_push) + (1 - push_given_noun)
    beta_e = DEFAULT_BETA / 3.0  # every variable has 3 neighbours
    np.testing.assert_allclose(potentials.pairwise[edges.index([0, 2])][:2, :2], np.exp(-beta_e * energy), rtol=1e-12)
    # Co-occurring states attract: box & push is the most favoured pair on that edge.
    table = potentials.pairwise[edges.index([0, 2])]
    assert table[0, 1] > table[0, 0] and table[1, 0] > table[1, 1]


def test_unary_factors_are_clipped_perception_probabilities() -> None:
    web = ConceptWeb.fit(SMALL, SMALL_OBJECTS)
    perception = np.array([0.9, 0.0, 0.7, 0.3, 1.0, 0.25])
    unary = web.potentials(perception).unary
    floor = web.probability_floor
    np.testing.assert_allclose(unary, [[0.9, floor], [0.7, 0.3], [floor, 1 - floor], [0.75, 0.25]])


def test_list_and_array_configurations_learn_the_same_web() -> None:
    matrix = np.array([[name in objects for name in SMALL.concepts] for objects in SMALL_OBJECTS], dtype=np.int64)
    from_lists = ConceptWeb.fit(SMALL, SMALL_OBJECTS).to_state()
    from_array = ConceptWeb.fit(SMALL, matrix).to_state()
    np.testing.assert_array_equal(from_lists.pop("cooccurrence"), from_array.pop("cooccurrence"))
    assert from_lists == from_array


def test_state_round_trips_exactly_even_through_json() -> None:
    vocabulary = paper_vocabulary()
    objects = [[*o.concepts, *o.behaviours] for o in make_objects(WorldConfig.paper(), seed=1)]
    web = ConceptWeb.fit(vocabulary, objects, beta=3.0, pseudo_count=1.0)
    state = web.to_state()
    assert set(state) == {"concepts", "cooccurrence", "n_objects", "beta", "pseudo_count", "probability_floor"}
    as_json = json.loads(json.dumps({**state, "cooccurrence": state["cooccurrence"].tolist()}))
    perception = np.random.default_rng(0).random(len(vocabulary))
    expected = web.infer(perception)
    for restored in (ConceptWeb.from_state(vocabulary, state), ConceptWeb.from_state(vocabulary, as_json)):
        restored_state = restored.to_state()
        np.testing.assert_array_equal(restored_state.pop("cooccurrence"), web.cooccurrence)
        assert restored_state == {key: value for key, value in state.items() if key != "cooccurrence"}
        np.testing.assert_array_equal(restored.potentials(perception).pairwise, web.potentials(perception).pairwise)
        inference = restored.infer(perception)
        np.testing.assert_array_equal(inference.probabilities, expected.probabilities)
        np.testing.assert_array_equal(inference.map_configuration, expected.map_configuration)


def test_a_concept_that_never_occurs_gets_the_smoothed_fallback() -> None:
    vocabulary = Vocabulary(("box", "cup", "plate"), (("hard", "soft"),), ("push", "grasp", "shake"))
    web = ConceptWeb.fit(vocabulary, SMALL_OBJECTS)
    # "plate" never occurs: its noun state keeps its edges with pseudo-count-only statistics,
    # which make it the least likely noun when perception does not distinguish the nouns.
    neutral = web.infer(np.full(len(vocabulary), 0.5))
    nouns = neutral.probabilities[:3]
    assert nouns[2] < nouns[:2].min()
    # "shake" never occurs: no edge, so perception alone decides it.
    assert vocabulary.index("shake") not in web.edges
    assert neutral.probabilities[vocabulary.index("shake")] == pytest.approx(0.5, abs=1e-12)


@pytest.mark.parametrize(
    ("configurations", "field", "problem"),
    [
        ([], "configurations", "empty"),
        (np.zeros((0, 6)), "configurations", "empty"),
        ("box soft", "configurations", "list"),
        ([["box", "soft", "teapot"]], "configurations[0]", "unknown concept 'teapot'"),
        ([["box", "soft"], ["box", "cup", "hard"]], "configurations[1]", "exactly one noun"),
        ([["box", "soft"], ["cup"]], "configurations[1]", "exactly one adjective of hard/soft"),
        ([["box", "hard", "soft"]], "configurations[0]", "exactly one adjective"),
        ([["box", "soft"], "cup"], "configurations[1]", "list of concept names"),
        (np.ones((2, 5)), "configurations", "shape"),
        (np.full((2, 6), 2), "configurations", "0 or 1"),
    ],
)
def test_bad_training_sets_are_refused(configurations: object, field: str, problem: str) -> None:
    with pytest.raises(InvalidInputError) as error:
        ConceptWeb.fit(SMALL, configurations)
    assert error.value.field == field
    assert problem in error.value.problem


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"beta": -1.0}, "beta"),
        ({"beta": float("nan")}, "beta"),
        ({"pseudo_count": 0.0}, "pseudo_count"),
        ({"probability_floor": 0.5}, "probability_floor"),
        ({"probability_floor": 0.0}, "probability_floor"),
    ],
)
def test_bad_hyperparameters_are_refused(kwargs: dict, field: str) -> None:
    with pytest.raises(InvalidInputError) as error:
        ConceptWeb.fit(SMALL, SMALL_OBJECTS, **kwargs)
    assert error.value.field == field


def test_bad_states_are_refused() -> None:
    web = ConceptWeb.fit(SMALL, SMALL_OBJECTS)
    state = web.to_state()
    other = Vocabulary(("box", "cup"), (("hard", "soft"),), ("push", "drop"))
    asymmetric = state["cooccurrence"].copy()
    asymmetric[0, 2] += 1
    inconsistent = state["cooccurrence"].copy()
    inconsistent[4, 5] = inconsistent[5, 4] = 0  # push and grasp never together: joint counts go negative
    two_nouns = state["cooccurrence"].copy()
    two_nouns[0, 1] = two_nouns[1, 0] = 1
    cases = [
        (SMALL, {k: v for k, v in state.items() if k != "beta"}, "state"),
        (other, state, "state.concepts"),
        (SMALL, {**state, "cooccurrence": asymmetric}, "cooccurrence"),
        (SMALL, {**state, "cooccurrence": -state["cooccurrence"]}, "cooccurrence"),
        (SMALL, {**state, "cooccurrence": state["cooccurrence"][:3]}, "cooccurrence"),
        (SMALL, {**state, "cooccurrence": inconsistent}, "cooccurrence"),
        (SMALL, {**state, "cooccurrence": two_nouns}, "cooccurrence"),
        (SMALL, {**state, "n_objects": 9}, "cooccurrence"),
        (SMALL, {**state, "n_objects": 0}, "n_objects"),
        (SMALL, "not a dict", "state"),
        ("not a vocabulary", state, "vocabulary"),
    ]
    for vocabulary, bad_state, field in cases:
        with pytest.raises(InvalidInputError) as error:
            ConceptWeb.from_state(vocabulary, bad_state)
        assert error.value.field == field
