"""Prototype extraction (Appendix), Eq. 1 and perception probabilities on a planted world.

The planted world: noun k raises entity features 10k..10k+9 to +3, the first
adjective of pair j raises features 40+5j..44+5j to +2, features 50-90 are
noise of variance 1 for every object (irrelevant to every concept). Every
effect feature carries sensor noise of sd 0.1; push moves features 0-2 by +2
and scatters 10-14 (sd 1: inconsistent), lift moves 3-5 by +2, shake nothing.
"""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import InvalidInputError
from core.prototypes import RELEVANCE_SYMBOLS, PrototypeSet, fit_prototypes, format_prototype_table, perceive
from core.prototypes.prototypes import IRRELEVANT, NEGATIVE, POSITIVE, UNAFFECTED, eq1_distances
from core.vocabulary import Vocabulary

VOCABULARY = Vocabulary(
    nouns=("box", "ball", "cup"), adjective_pairs=(("hard", "soft"), ("tall", "short")), verbs=("push", "lift", "shake")
)
NOISE = slice(50, 91)


def _objects(n: int, rng: np.random.Generator) -> tuple[np.ndarray, list[list[str]]]:
    entities, labels = np.zeros((n, 91)), []
    for row in range(n):
        noun = row % 3
        firsts = rng.random(2) < 0.5
        entities[row, 10 * noun : 10 * noun + 10] = 3.0
        for pair, first in enumerate(firsts):
            if first:
                entities[row, 40 + 5 * pair : 45 + 5 * pair] = 2.0
        entities[row, :50] += 0.1 * rng.standard_normal(50)
        entities[row, NOISE] = rng.standard_normal(41)
        adjectives = [pair[0] if first else pair[1] for pair, first in zip(VOCABULARY.adjective_pairs, firsts)]
        labels.append([VOCABULARY.nouns[noun], *adjectives])
    return entities, labels


def _effects(n: int, rng: np.random.Generator) -> tuple[np.ndarray, list[str]]:
    effects = 0.1 * rng.standard_normal((n, 66))
    verbs = [VOCABULARY.verbs[row % 3] for row in range(n)]
    for row, verb in enumerate(verbs):
        if verb == "push":
            effects[row, 0:3] += 2.0
            effects[row, 10:15] += rng.standard_normal(5)
        elif verb == "lift":
            effects[row, 3:6] += 2.0
    return effects, verbs


def _training(seed: int = 0) -> tuple[np.ndarray, list[list[str]], np.ndarray, list[str]]:
    rng = np.random.default_rng(seed)
    return (*_objects(60, rng), *_effects(30, rng))


@pytest.fixture(scope="module", params=["rgng", "kmeans"])
def planted(request: pytest.FixtureRequest) -> PrototypeSet:
    return fit_prototypes(VOCABULARY, *_training(), method=request.param, seed=0)


def test_planted_relevance_is_recovered(planted: PrototypeSet) -> None:
    box, ball = planted.entity_relevance[0], planted.entity_relevance[1]
    assert np.all(box[0:10] == POSITIVE) and np.all(box[10:30] == NEGATIVE)
    assert np.all(ball[10:20] == POSITIVE) and np.all(ball[0:10] == NEGATIVE)
    assert np.mean(planted.entity_relevance[:, NOISE] == IRRELEVANT) > 0.95
    hard = planted.entity_relevance[len(VOCABULARY.nouns)]
    assert np.all(hard[40:45] == POSITIVE) and np.all(hard[0:30] == IRRELEVANT)  # the noun varies within "hard"
    push, lift, shake = planted.verb_relevance
    assert np.all(push[0:3] == POSITIVE) and np.all(push[10:15] == IRRELEVANT) and np.all(lift[3:6] == POSITIVE)
    assert np.mean(shake == UNAFFECTED) > 0.95


def test_rgng_labels_small_groups_that_kmeans_merges() -> None:
    """Lift leaves push's 3 moved and 5 scattered features unchanged: two groups of 3 and 5
    points near (0, 0), beside a cloud of 55 noise features. RGNG keeps them and the cloud
    '0'; k-means with one cluster per symbol merges groups across symbols."""
    training = _training()
    lift = VOCABULARY.verbs.index("lift")
    rgng = fit_prototypes(VOCABULARY, *training, method="rgng", seed=0).verb_relevance
    kmeans = fit_prototypes(VOCABULARY, *training, method="kmeans", seed=0).verb_relevance
    assert np.all(rgng[lift, 0:3] == UNAFFECTED) and np.all(rgng[lift, 10:15] == UNAFFECTED)
    unmoved = np.r_[6:10, 15:66]
    assert np.mean(rgng[:, unmoved] == UNAFFECTED) > 0.95
    assert np.any(kmeans[lift, np.r_[0:3, 10:15]] != UNAFFECTED)
    assert np.mean(kmeans[:, unmoved] == UNAFFECTED) < 0.9


def test_rgng_and_kmeans_agree_on_the_planted_world() -> None:
    """The comparison the docs report: label agreement and agreement of the '*' sets."""
    training = _training()
    rgng = fit_prototypes(VOCABULARY, *training, method="rgng", seed=0)
    kmeans = fit_prototypes(VOCABULARY, *training, method="kmeans", seed=0)
    labels = np.concatenate([rgng.entity_relevance.ravel(), rgng.verb_relevance.ravel()])
    other = np.concatenate([kmeans.entity_relevance.ravel(), kmeans.verb_relevance.ravel()])
    assert np.mean(labels == other) > 0.95
    star, star_other = labels == IRRELEVANT, other == IRRELEVANT
    assert (star & star_other).sum() / (star | star_other).sum() > 0.95


def test_recognises_unseen_objects_and_effects(planted: PrototypeSet) -> None:
    rng = np.random.default_rng(1)
    entities, labels = _objects(30, rng)
    effects, verbs = _effects(12, rng)
    distances = planted.distances(entities)
    assert distances.shape == (30, 7)
    assert [VOCABULARY.nouns[i] for i in distances[:, :3].argmin(axis=1)] == [label[0] for label in labels]
    verb_distances = planted.effect_distances(effects)
    assert [VOCABULARY.verbs[i] for i in verb_distances.argmin(axis=1)] == verbs
    np.testing.assert_allclose(planted.distances(entities[0]), distances[0])


def test_eq1_matches_the_formula_by_hand() -> None:
    z = np.array([[1.0, 2.0, 3.0, 4.0]])
    means = np.array([[0.0, 0.0, 0.0, 0.0], [1.0, 1.0, 1.0, 1.0]])
    relevance = np.array([[POSITIVE, IRRELEVANT, NEGATIVE, IRRELEVANT], [IRRELEVANT] * 4], dtype=np.uint8)
    # concept 0: features 0 and 2 -> sqrt(1 + 9) / 2; concept 1: no relevant feature -> all four
    np.testing.assert_allclose(eq1_distances(z, means, relevance), [[np.sqrt(10.0) / 2, np.sqrt(14.0) / 4]])


def test_perception_probabilities_obey_the_structure(planted: PrototypeSet) -> None:
    rng = np.random.default_rng(2)
    entities, labels = _objects(6, rng)
    effects, _ = _effects(3, rng)
    for entity, label in zip(entities, labels):
        p = perceive(planted, entity, {"push": effects[0]})
        assert p.shape == (len(VOCABULARY.concepts),)
        assert p[:3].sum() == pytest.approx(1.0)
        np.testing.assert_allclose(p[3:7].reshape(2, 2).sum(axis=1), 1.0)
        assert VOCABULARY.concepts[int(np.argmax(p[:3]))] == label[0]
        for name in label[1:]:
            assert p[VOCABULARY.index(name)] > 0.5
        assert p[VOCABULARY.index("push")] > 0.9 and p[VOCABULARY.index("lift")] == 0.5 == p[VOCABULARY.index("shake")]
    wrong = perceive(planted, entities[0], {"lift": effects[0]})  # a push effect reported as a lift
    assert wrong[VOCABULARY.index("lift")] < 0.1
    assert np.all(np.isfinite(planted.temperatures["noun"])) and planted.temperatures["noun"] > 0


def test_state_round_trip_is_exact(planted: PrototypeSet) -> None:
    state = planted.to_state()
    assert all(isinstance(value, (np.ndarray, dict, str)) for value in state.values())
    restored = PrototypeSet.from_state(state)
    for name, value in planted.to_state().items():
        if isinstance(value, np.ndarray):
            np.testing.assert_array_equal(getattr(restored, name), value)
    assert restored.temperatures == planted.temperatures and restored.vocabulary == planted.vocabulary
    for kind, bias in planted.biases.items():
        np.testing.assert_array_equal(restored.biases[kind], bias)
    entity = _objects(1, np.random.default_rng(3))[0][0]
    np.testing.assert_array_equal(perceive(restored, entity), perceive(planted, entity))
    with pytest.raises(InvalidInputError, match="prototypes.state"):
        PrototypeSet.from_state({"method": "rgng"})
    with pytest.raises(InvalidInputError, match="prototypes.biases.verb"):
        PrototypeSet.from_state({**state, "biases": {**state["biases"], "verb": np.zeros(2)}})


def test_same_seed_same_prototypes_and_inputs_untouched() -> None:
    training = _training()
    copies = [np.copy(item) if isinstance(item, np.ndarray) else list(item) for item in training]
    first = fit_prototypes(VOCABULARY, *training, seed=3)
    second = fit_prototypes(VOCABULARY, *training, seed=3)
    np.testing.assert_array_equal(first.entity_relevance, second.entity_relevance)
    np.testing.assert_array_equal(first.verb_relevance, second.verb_relevance)
    assert first.temperatures == second.temperatures
    np.testing.assert_array_equal(first.biases["noun"], second.biases["noun"])
    for original, copy in zip(training, copies):
        np.testing.assert_array_equal(np.asarray(original, dtype=object), np.asarray(copy, dtype=object))


def test_table_has_one_symbol_row_per_concept(planted: PrototypeSet) -> None:
    table = format_prototype_table(planted)
    rows = table.splitlines()[1:]
    assert [row.split()[0] for row in rows] == list(VOCABULARY.concepts)
    symbols = ["".join(row.split()[1:]) for row in rows]
    assert [len(s) for s in symbols] == [91] * 7 + [66] * 3
    assert set("".join(symbols)) <= set(RELEVANCE_SYMBOLS)
    assert "0" not in "".join(symbols[:7])


def test_single_instance_concept_borrows_pooled_variance() -> None:
    entities, labels, effects, verbs = _training()
    labels[0] = ["box", "hard", "tall"]
    only = [i for i, label in enumerate(labels) if "short" in label][1:]
    for i in only:
        labels[i][2] = "tall"
    prototypes = fit_prototypes(VOCABULARY, entities, labels, effects, verbs)
    short = prototypes.entity_concepts.index("short")
    tall = prototypes.entity_concepts.index("tall")
    assert np.all(prototypes.entity_variances[short] > 0)
    assert np.all(np.isfinite(prototypes.distances(entities[0])))
    assert not np.array_equal(prototypes.entity_variances[short], prototypes.entity_variances[tall])


@pytest.mark.parametrize(
    ("change", "field"),
    [
        (lambda t: (np.zeros((0, 91)), [], t[2], t[3]), "entity_vectors"),
        (lambda t: (t[0][:, :90], t[1], t[2], t[3]), "entity_vectors"),
        (lambda t: (np.where(np.arange(91) == 5, np.nan, t[0]), t[1], t[2], t[3]), "entity_vectors"),
        (lambda t: (t[0], t[1], t[2][:, :65], t[3]), "effect_vectors"),
        (lambda t: (t[0], t[1][:-1], t[2], t[3]), "entity_concepts"),
        (lambda t: (t[0], [[*label[:1], "hard", "tall"] for label in t[1]], t[2], t[3]), "entity_concepts"),
        (lambda t: (t[0], [["box", "ball"]] + t[1][1:], t[2], t[3]), "entity_concepts"),
        (lambda t: (t[0], [["box", "hard", "soft"]] + t[1][1:], t[2], t[3]), "entity_concepts"),
        (lambda t: (t[0], [["crate"]] + t[1][1:], t[2], t[3]), "entity_concepts"),
        (lambda t: (t[0], t[1], t[2], ["push"] * len(t[3])), "effect_verbs"),
        (lambda t: (t[0], t[1], t[2], ["jump"] + t[3][1:]), "effect_verbs"),
    ],
    ids=[
        "empty",
        "short-entity",
        "nan",
        "short-effect",
        "label-count",
        "no-short",
        "two-nouns",
        "both-of-pair",
        "unknown-noun",
        "no-lift",
        "unknown-verb",
    ],
)
def test_bad_training_input_names_the_field(change, field: str) -> None:
    with pytest.raises(InvalidInputError) as error:
        fit_prototypes(VOCABULARY, *change(_training()))
    assert error.value.field == field


def test_bad_query_input_names_the_field(planted: PrototypeSet) -> None:
    entity = np.zeros(91)
    with pytest.raises(InvalidInputError, match="^entity"):
        planted.distances(np.zeros(66))
    with pytest.raises(InvalidInputError, match="^entity: contains NaN"):
        perceive(planted, np.full(91, np.nan))
    with pytest.raises(InvalidInputError, match="^effects.push"):
        perceive(planted, entity, {"push": np.zeros(91)})
    with pytest.raises(InvalidInputError, match="^effects"):
        perceive(planted, entity, {"jump": np.zeros(66)})
    with pytest.raises(InvalidInputError, match="^method"):
        fit_prototypes(VOCABULARY, *_training(), method="dbscan")


def test_a_vocabulary_without_verbs_needs_no_effects() -> None:
    nouns_only = Vocabulary(nouns=VOCABULARY.nouns, adjective_pairs=VOCABULARY.adjective_pairs, verbs=())
    entities, labels = _objects(30, np.random.default_rng(4))
    prototypes = fit_prototypes(nouns_only, entities, labels, np.zeros((0, 66)), [])
    p = perceive(prototypes, entities[0])
    assert p.shape == (7,) and p[:3].sum() == pytest.approx(1.0)
    assert PrototypeSet.from_state(prototypes.to_state()).verb_relevance.shape == (0, 66)
