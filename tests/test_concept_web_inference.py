"""Loopy BP on the concept web (§III-B): exactness on trees, accuracy on loops, contracts."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from core.concept_web import DEFAULT_DAMPING, ConceptWeb, WebPotentials, loopy_belief_propagation
from core.concept_web.reference import exact_probabilities, exact_variable_marginals
from core.errors import InvalidInputError
from core.vocabulary import Vocabulary, paper_vocabulary
from sim.world import TRAIN, WorldConfig, make_objects

PAPER = paper_vocabulary()
NO_VERB_APPLIED = np.zeros(len(PAPER.verbs), dtype=bool)
#: The paper's 45 training objects (Tables I and II): noun, adjectives and every applicable behaviour.
TRAINING = [[*o.concepts, *o.behaviours] for o in make_objects(WorldConfig.paper(), seed=0) if o.split == TRAIN]


#: How close two settlings of the same evidence from different starting messages are (see the warm-start test).
SETTLED_WITHIN = 1e-4


@pytest.fixture(scope="module")
def paper_web() -> ConceptWeb:
    return ConceptWeb.fit(PAPER, TRAINING)


def random_tree(rng: np.random.Generator, n_var: int) -> WebPotentials:
    """A random tree MRF with cardinalities 1–4 and random strictly positive factors."""
    cardinalities = rng.integers(1, 5, size=n_var)
    width = int(cardinalities.max())
    edges = np.array([sorted((int(rng.integers(v)), v)) for v in range(1, n_var)], dtype=np.int64)
    states = np.arange(width)
    unary = np.where(states[None, :] < cardinalities[:, None], rng.uniform(0.05, 1.0, (n_var, width)), 0.0)
    valid = (states[None, :] < cardinalities[edges[:, 0], None])[:, :, None] & (
        states[None, :] < cardinalities[edges[:, 1], None]
    )[:, None, :]
    pairwise = np.where(valid, np.exp(rng.normal(0.0, 1.5, (len(edges), width, width))), 0.0)
    return WebPotentials(tuple(f"x{v}" for v in range(n_var)), cardinalities, unary, edges, pairwise)


def brute_force(potentials: WebPotentials) -> tuple[np.ndarray, np.ndarray]:
    """Exact marginals (n_var, K) and the MAP state of every variable, by enumeration."""
    marginals = np.zeros(potentials.unary.shape)
    best_weight, best_states = -1.0, None
    for states in itertools.product(*(range(c) for c in potentials.cardinalities)):
        weight = np.prod(potentials.unary[np.arange(len(states)), states])
        for (u, v), table in zip(potentials.variable_edges, potentials.pairwise):
            weight *= table[states[u], states[v]]
        marginals[np.arange(len(states)), states] += weight
        if weight > best_weight:
            best_weight, best_states = weight, np.array(states)
    return marginals / marginals.sum(axis=1, keepdims=True), best_states


def small_loopy_web(seed: int) -> tuple[ConceptWeb, np.ndarray]:
    """A 7-variable web (3 nouns, 3 pairs, 3 verbs) trained on random objects, and a random perception."""
    vocabulary = Vocabulary(
        ("box", "ball", "cup"), (("hard", "soft"), ("tall", "short"), ("round", "edgy")), ("push", "shake", "grasp")
    )
    rng = np.random.default_rng(seed)
    adjective_rate, verb_rate = rng.random((3, 3)), rng.random((3, 3))
    configurations = []
    for noun in rng.integers(3, size=40):
        adjectives = [
            a if rng.random() < adjective_rate[noun, j] else b for j, (a, b) in enumerate(vocabulary.adjective_pairs)
        ]
        verbs = [v for j, v in enumerate(vocabulary.verbs) if rng.random() < verb_rate[noun, j]]
        configurations.append([vocabulary.nouns[noun], *adjectives, *verbs])
    return ConceptWeb.fit(vocabulary, configurations), rng.random(len(vocabulary))


def test_trees_are_solved_exactly_like_pgmpy() -> None:
    rng = np.random.default_rng(3)
    for n_var in (2, 5, 9, 14):
        potentials = random_tree(rng, n_var)
        marginals, max_marginals, _, converged = loopy_belief_propagation(
            potentials, tolerance=1e-12, max_iterations=1000
        )
        exact, exact_map = brute_force(potentials)
        assert converged
        np.testing.assert_allclose(marginals, exact_variable_marginals(potentials), atol=1e-6)
        np.testing.assert_allclose(marginals, exact, atol=1e-6)
        np.testing.assert_array_equal(np.argmax(max_marginals, axis=1), exact_map)


def test_undamped_bp_on_a_tree_settles_within_its_size() -> None:
    potentials = random_tree(np.random.default_rng(8), 12)
    _, _, iterations, converged = loopy_belief_propagation(potentials, damping=0.0, tolerance=1e-12)
    # Synchronous BP is exact after diameter (<= n_var - 1) rounds; one more round sees no change.
    assert converged and iterations <= 12


def test_a_fitted_star_web_matches_pgmpy() -> None:
    # Verbs never active together: the only edges join the noun to each verb, a tree.
    vocabulary = Vocabulary(("box", "ball", "cup"), (), ("push", "shake", "grasp", "drop"))
    configurations = (
        [["box", "push"]] * 6
        + [["box", "shake"]] * 2
        + [["ball", "shake"]] * 5
        + [["cup", "grasp"]] * 7
        + [["ball"]] * 3
        + [["cup", "drop"]]
    )
    web = ConceptWeb.fit(vocabulary, configurations)
    assert len(web.edges) == 5
    assert web.potentials(np.full(len(vocabulary), 0.5)).variable_edges.tolist() == [[0, 1], [0, 2], [0, 3], [0, 4]]
    for perception in np.random.default_rng(1).random((4, len(vocabulary))):
        inference = web.infer(perception, tolerance=1e-12, max_iterations=1000)
        np.testing.assert_allclose(inference.probabilities, exact_probabilities(web, perception), atol=1e-6)


def test_loopy_marginals_approximate_enumeration_and_max_product_finds_the_map() -> None:
    errors, map_agreements = [], 0
    for seed in range(20):
        web, perception = small_loopy_web(seed)
        potentials = web.potentials(perception)
        marginals, max_marginals, _, converged = loopy_belief_propagation(
            potentials, tolerance=1e-10, max_iterations=500
        )
        exact, exact_map = brute_force(potentials)
        assert converged
        errors.append(np.abs(marginals - exact).max())
        map_agreements += bool((np.argmax(max_marginals, axis=1) == exact_map).all())
    # Measured with the default beta: worst error 0.071, median 0.008, MAP exact in 19 of 20 webs.
    assert max(errors) < 0.1
    assert np.median(errors) < 0.02
    assert map_agreements >= 18


def test_the_paper_web_is_close_to_exact_inference(paper_web: ConceptWeb) -> None:
    # A noisy perception of a cup whose every behaviour was applied (truth 0.8, rest 0.2, noise 0.1).
    cup = next(c for c in TRAINING if c[0] == "cup")
    truth = np.isin(PAPER.concepts, cup)
    perception = np.clip(np.where(truth, 0.8, 0.2) + np.random.default_rng(0).normal(0.0, 0.1, len(PAPER)), 0.0, 1.0)
    inference = paper_web.infer(perception)
    # pgmpy's exact junction tree takes seconds on these 19 variables; LBP's error measured here: 0.004.
    np.testing.assert_allclose(inference.probabilities, exact_probabilities(paper_web, perception), atol=0.01)


def test_structure_invariants_hold_for_any_perception(paper_web: ConceptWeb) -> None:
    perceptions = np.random.default_rng(0).random((50, len(PAPER)))
    applied = np.random.default_rng(1).random((50, len(PAPER.verbs))) < 0.5
    nouns = [PAPER.index(n) for n in PAPER.nouns]
    pairs = [[PAPER.index(a), PAPER.index(b)] for a, b in PAPER.adjective_pairs]
    for inference in paper_web.infer_many(perceptions, applied=applied):
        assert inference.converged
        assert ((inference.probabilities >= 0) & (inference.probabilities <= 1)).all()
        assert inference.probabilities[nouns].sum() == pytest.approx(1.0, abs=1e-12)
        np.testing.assert_allclose(inference.probabilities[pairs].sum(axis=1), 1.0, atol=1e-12)
        assert inference.map_configuration.dtype == bool
        assert inference.map_configuration[nouns].sum() == 1
        assert (inference.map_configuration[pairs].sum(axis=1) == 1).all()


def test_cup_evidence_follows_training_co_occurrence(paper_web: ConceptWeb) -> None:
    neutral = np.full(len(PAPER), 0.5)
    cup = neutral.copy()
    cup[: len(PAPER.nouns)] = 0.01
    cup[PAPER.index("cup")] = 0.99
    before = paper_web.infer(neutral, applied=NO_VERB_APPLIED)
    after = paper_web.infer(cup, applied=NO_VERB_APPLIED)
    p_before, p_after = before.probabilities, after.probabilities
    # Table I: every cup is hard and short; Table II: cups are never pushed, dropped, thrown.
    for concept in ("hard", "short", "round", "silent"):
        assert p_after[PAPER.index(concept)] > p_before[PAPER.index(concept)]
    for verb in ("push_left", "push_right", "push_forward", "push_backward", "drop", "throw", "knock_down", "shake"):
        assert p_after[PAPER.index(verb)] < p_before[PAPER.index(verb)]
    for verb in ("grasp", "move_left"):
        assert p_after[PAPER.index(verb)] > 0.7  # measured 0.79
    map_concepts = {c for c, on in zip(PAPER.concepts, after.map_configuration) if on}
    assert map_concepts == {
        "cup",
        "hard",
        "silent",
        "short",
        "thick",
        "round",
        "grasp",
        "move_left",
        "move_right",
        "move_forward",
        "move_backward",
    }


def test_an_unapplied_verb_reads_the_web_without_feeding_back(paper_web: ConceptWeb) -> None:
    perception = np.random.default_rng(5).random(len(PAPER))
    applied = np.ones(len(PAPER.verbs), dtype=bool)
    applied[PAPER.verbs.index("shake")] = False
    changed = perception.copy()
    changed[PAPER.index("shake")] = 0.99
    first = paper_web.infer(perception, applied=applied)
    second = paper_web.infer(changed, applied=applied)
    np.testing.assert_array_equal(first.probabilities, second.probabilities)
    # Withholding a verb's evidence changes nothing else than through its own reading.
    everything = paper_web.infer(perception, applied=np.ones(len(PAPER.verbs), dtype=bool))
    assert not np.allclose(everything.probabilities, first.probabilities)


def test_iteration_cap_tolerance_and_damping_are_respected(paper_web: ConceptWeb) -> None:
    perception = np.random.default_rng(2).random(len(PAPER))
    capped = paper_web.infer(perception, damping=0.5, max_iterations=3)
    assert capped.iterations == 3 and not capped.converged
    assert paper_web.infer(perception, max_iterations=3).iterations == 3
    loose = paper_web.infer(perception, tolerance=0.1)
    tight = paper_web.infer(perception, tolerance=1e-10, max_iterations=1000)
    assert loose.converged and tight.converged and loose.iterations < tight.iterations
    heavy = paper_web.infer(perception, damping=0.9, tolerance=1e-10, max_iterations=1000)
    light = paper_web.infer(perception, damping=0.0, tolerance=1e-10, max_iterations=1000)
    assert heavy.iterations > tight.iterations
    # Damping changes the path, not the fixed point.
    np.testing.assert_allclose(heavy.probabilities, tight.probabilities, atol=1e-7)
    np.testing.assert_allclose(light.probabilities, tight.probabilities, atol=1e-7)


def test_by_default_the_sum_product_pass_is_undamped_and_the_max_product_pass_damped(paper_web: ConceptWeb) -> None:
    """The default settles the marginals undamped (same fixed points, fewer iterations, more
    perceptions settled) and keeps the damped max-product pass, hence the MAP, bit for bit."""
    perceptions = np.random.default_rng(0).random((2000, len(PAPER)))
    default = paper_web.infer_many(perceptions)
    spelled_out = paper_web.infer_many(perceptions, damping=DEFAULT_DAMPING, sum_product=(0.0, 100))
    damped = paper_web.infer_many(perceptions, damping=DEFAULT_DAMPING)
    for chosen, same, slow in zip(default, spelled_out, damped, strict=True):
        np.testing.assert_array_equal(chosen.probabilities, same.probabilities)
        np.testing.assert_array_equal(chosen.map_configuration, slow.map_configuration)
        if chosen.converged and slow.converged:
            np.testing.assert_allclose(chosen.probabilities, slow.probabilities, atol=SETTLED_WITHIN)
    # Uniform random evidence on every verb is the web's hardest case: undamped, more of it settles.
    assert sum(item.converged for item in default) > sum(item.converged for item in damped)


def test_same_input_same_output_and_inputs_untouched(paper_web: ConceptWeb) -> None:
    perceptions = np.random.default_rng(4).random((6, len(PAPER)))
    kept = perceptions.copy()
    batch = paper_web.infer_many(perceptions)
    for row, inference in zip(perceptions, batch):
        single = paper_web.infer(row)
        np.testing.assert_array_equal(single.probabilities, inference.probabilities)
        np.testing.assert_array_equal(single.map_configuration, inference.map_configuration)
        assert (single.iterations, single.converged) == (inference.iterations, inference.converged)
    np.testing.assert_array_equal(perceptions, kept)
    again = paper_web.infer_many(perceptions)
    assert all(np.array_equal(a.probabilities, b.probabilities) for a, b in zip(batch, again))


def test_an_isolated_variable_keeps_its_normalised_unary() -> None:
    # "shake" never occurs in training: its variable has no edge, so its marginal is its perception.
    vocabulary = Vocabulary(("box", "cup"), (("hard", "soft"),), ("push", "shake"))
    web = ConceptWeb.fit(vocabulary, [["box", "soft", "push"], ["cup", "hard"], ["box", "hard", "push"]])
    shake = vocabulary.index("shake")
    assert shake not in web.edges
    perception = np.array([0.7, 0.2, 0.6, 0.4, 0.9, 0.3])
    assert web.infer(perception).probabilities[shake] == pytest.approx(0.3, abs=1e-12)
    floor = web.probability_floor
    perception[shake] = 0.0
    assert web.infer(perception).probabilities[shake] == pytest.approx(floor, abs=1e-12)
    not_applied = web.infer(perception, applied=np.array([True, False]))
    assert not_applied.probabilities[shake] == pytest.approx(0.5, abs=1e-12)


def test_a_web_without_edges_needs_no_iteration() -> None:
    web = ConceptWeb.fit(Vocabulary(("box", "cup"), (), ("push",)), [["box"], ["cup"]])
    inference = web.infer(np.array([0.9, 0.3, 0.2]))
    assert (inference.iterations, inference.converged) == (0, True)
    np.testing.assert_allclose(inference.probabilities, [0.75, 0.25, 0.2])


@pytest.mark.parametrize(
    ("perception", "problem"),
    [
        (np.full(5, 0.5), "shape"),
        (np.full((2, 29), 0.5), "shape"),
        (np.r_[np.nan, np.full(28, 0.5)], "finite"),
        (np.r_[-0.1, np.full(28, 0.5)], "[0, 1]"),
        (np.r_[1.2, np.full(28, 0.5)], "[0, 1]"),
        (["a"] * 29, "numeric"),
    ],
)
def test_bad_perceptions_are_refused(paper_web: ConceptWeb, perception: object, problem: str) -> None:
    with pytest.raises(InvalidInputError, match="perception") as error:
        paper_web.infer(perception)
    assert problem in error.value.problem


def test_bad_batches_and_settings_are_refused(paper_web: ConceptWeb) -> None:
    good = np.full(len(PAPER), 0.5)
    with pytest.raises(InvalidInputError) as error:
        paper_web.infer_many(good)
    assert error.value.field == "perceptions"
    for kwargs, field in [
        ({"applied": np.ones(3, dtype=bool)}, "applied"),
        ({"applied": np.ones(len(PAPER.verbs))}, "applied"),
        ({"damping": 1.0}, "damping"),
        ({"damping": -0.1}, "damping"),
        ({"tolerance": 0.0}, "tolerance"),
        ({"max_iterations": 0}, "max_iterations"),
        ({"max_iterations": 2.5}, "max_iterations"),
    ]:
        with pytest.raises(InvalidInputError) as error:
            paper_web.infer(good, **kwargs)
        assert error.value.field == field


def test_bad_potentials_are_refused() -> None:
    potentials = random_tree(np.random.default_rng(0), 4)
    zero = potentials.pairwise.copy()
    zero[0, 0, 0] = 0.0
    broken = WebPotentials(
        potentials.variable_names, potentials.cardinalities, potentials.unary, potentials.variable_edges, zero
    )
    with pytest.raises(InvalidInputError, match="strictly positive"):
        loopy_belief_propagation(broken)


def test_a_warm_start_reaches_the_cold_start_marginals_and_the_same_map(paper_web: ConceptWeb) -> None:
    # A settling at the default tolerance (1e-6 on messages) is within ≈ 5e-5 of its fixed point's
    # marginals on the paper's web, so two settlings from different starts agree within 1e-4.
    rng = np.random.default_rng(11)
    perceptions = rng.random((6, len(PAPER)))
    applied = rng.random((6, len(PAPER.verbs))) < 0.5
    before = paper_web.infer_many(perceptions, applied=applied)
    nearby = np.clip(perceptions + rng.normal(0.0, 0.05, perceptions.shape), 0.0, 1.0)
    cold = paper_web.infer_many(nearby, applied=applied)
    warm = paper_web.infer_many(nearby, applied=applied, start=before)
    undamped = paper_web.infer_many(nearby, applied=applied, start=before, sum_product=(0.0, 100))
    for c, w, u in zip(cold, warm, undamped, strict=True):
        assert c.converged and w.converged and u.converged
        np.testing.assert_allclose(w.probabilities, c.probabilities, atol=SETTLED_WITHIN)
        np.testing.assert_allclose(u.probabilities, c.probabilities, atol=SETTLED_WITHIN)
        # The max-product pass starts cold whatever the start: the same MAP, bit for bit.
        assert np.array_equal(w.map_configuration, c.map_configuration)
        assert np.array_equal(u.map_configuration, c.map_configuration)
    # Started from its own fixed point, the sum-product pass settles within 2 iterations; from uniform it cannot.
    assert all(
        i.converged for i in paper_web.infer_many(perceptions, applied=applied, start=before, sum_product=(0.5, 2))
    )
    assert not any(i.converged for i in paper_web.infer_many(perceptions, applied=applied, sum_product=(0.5, 2)))
    # A start from another applied mask is safe: a verb that does not send keeps uniform messages.
    other = paper_web.infer_many(perceptions, applied=~applied, start=before)
    for c, w in zip(paper_web.infer_many(perceptions, applied=~applied), other, strict=True):
        np.testing.assert_allclose(w.probabilities, c.probabilities, atol=SETTLED_WITHIN)


def test_a_bad_warm_start_is_refused(paper_web: ConceptWeb) -> None:
    perceptions = np.full((2, len(PAPER)), 0.5)
    settled = paper_web.infer_many(perceptions)
    with pytest.raises(InvalidInputError, match="start"):
        paper_web.infer_many(perceptions, start=settled[:1])
    with pytest.raises(InvalidInputError, match="start"):
        paper_web.infer_many(perceptions, start=[settled[0], "not an inference"])  # type: ignore[list-item]
