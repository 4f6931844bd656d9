"""Perception probabilities: the Eq. 1 kernel and the batched ``perceive_many`` against references.

The reference is the former per-behaviour code: numpy's broadcast Eq. 1, one
scipy softmax per applied behaviour. The kernel keeps numpy's summation order,
so the tolerances below are far tighter than any perception decision needs.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import pytest
from scipy.special import expit, softmax

from core.errors import InvalidInputError
from core.prototypes import PrototypeSet, fit_prototypes, perceive
from core.prototypes._eq1_kernels import pairwise_sum
from core.prototypes.perception import NO_EVIDENCE, perceive_many
from core.prototypes.prototypes import IRRELEVANT, Eq1Prototypes
from core.vocabulary import Vocabulary
from tests.test_prototypes_fit import VOCABULARY, _effects, _objects, _training


@pytest.fixture(scope="module")
def planted() -> PrototypeSet:
    return fit_prototypes(VOCABULARY, *_training(), method="kmeans", seed=0)


def _numpy_eq1(z: np.ndarray, means: np.ndarray, relevance: np.ndarray) -> np.ndarray:
    relevant = relevance != IRRELEVANT
    relevant[relevant.sum(axis=1) == 0] = True
    squared = ((z[:, None, :] - means[None, :, :]) ** 2 * relevant[None, :, :]).sum(axis=2)
    return np.sqrt(squared) / relevant.sum(axis=1)


def _reference_perceive(prototypes: PrototypeSet, entity: np.ndarray, effects: Mapping[str, np.ndarray]) -> np.ndarray:
    vocabulary, t, b = prototypes.vocabulary, prototypes.temperatures, prototypes.biases
    z = (entity[None] - prototypes.entity_center) / prototypes.entity_scale
    d = _numpy_eq1(z, prototypes.entity_means, prototypes.entity_relevance)[0]
    n_nouns = len(vocabulary.nouns)
    nouns = softmax(-d[:n_nouns] / t["noun"] + b["noun"])
    pairs = d[n_nouns:].reshape(-1, 2)
    first = expit((pairs[:, 1] - pairs[:, 0]) / t["adjective"] + b["adjective"])
    verbs = np.full(len(vocabulary.verbs), NO_EVIDENCE)
    k = len(vocabulary.verbs)
    for behaviour, effect in effects.items():
        dv = _numpy_eq1(effect[None] / prototypes.effect_scale, prototypes.verb_means, prototypes.verb_relevance)[0]
        q = softmax(-dv / t["verb"] + b["verb"])[vocabulary.verbs.index(behaviour)]
        verbs[vocabulary.verbs.index(behaviour)] = q * (k - 1) / (q * (k - 1) + 1.0 - q)
    return np.concatenate([nouns, np.column_stack([first, 1.0 - first]).ravel(), verbs])


def _scene(seed: int, n: int = 5) -> tuple[np.ndarray, list[dict[str, np.ndarray]]]:
    """n objects with 0 to 3 behaviours applied, their effects scaled over four decades."""
    rng = np.random.default_rng(seed)
    entities, _ = _objects(n, rng)
    effects, _ = _effects(3 * n, rng)
    maps = []
    for i in range(n):
        applied = [verb for verb in VOCABULARY.verbs if rng.random() < 0.6]
        maps.append({verb: effects[3 * i + j] * 10 ** rng.uniform(-2, 2) for j, verb in enumerate(applied)})
    return entities, maps


@pytest.mark.parametrize("n", [*range(20), 64, 127, 128, 129, 136, 300, 1000, 4097])
def test_pairwise_sum_adds_in_numpy_order(n: int) -> None:
    # Exact: the kernel reproduces numpy's add.reduce order so that Eq. 1 equals the former numpy code
    # bit for bit. A numpy that changes its order fails here; the kernels' docstring claim then needs revisiting.
    values = np.random.default_rng(n).standard_normal(n + 3) * 10.0 ** np.random.default_rng(0).uniform(-8, 8, n + 3)
    assert pairwise_sum(values, 3, n) == values[3:].sum()


@pytest.mark.parametrize("d", [4, 66, 91, 300])
def test_eq1_kernel_matches_the_numpy_expression(d: int) -> None:
    rng = np.random.default_rng(d)
    means, z = rng.standard_normal((7, d)), 3.0 * rng.standard_normal((11, d))
    relevance = rng.integers(0, 4, (7, d)).astype(np.uint8)
    relevance[2] = IRRELEVANT  # no relevant feature: all of them count
    eq1 = Eq1Prototypes.from_relevance(means, relevance)
    np.testing.assert_allclose(eq1.distances(z), _numpy_eq1(z, means, relevance), rtol=1e-14, atol=0)
    assert eq1.sizes[2] == d and not eq1.weights.flags.writeable


def test_perceive_matches_the_per_behaviour_reference(planted: PrototypeSet) -> None:
    for seed in range(4):
        entities, maps = _scene(seed)
        for entity, effects in zip(entities, maps):
            np.testing.assert_allclose(
                perceive(planted, entity, effects), _reference_perceive(planted, entity, effects), rtol=1e-12, atol=0
            )


def test_perceive_many_is_perceive_row_by_row(planted: PrototypeSet) -> None:
    entities, maps = _scene(7, n=6)
    maps[1], maps[4] = {}, None  # no behaviour applied
    copies = [None if m is None else {k: v.copy() for k, v in m.items()} for m in maps]
    batch = perceive_many(planted, list(entities), maps)
    np.testing.assert_array_equal(batch, [perceive(planted, e, m) for e, m in zip(entities, maps)])
    np.testing.assert_array_equal(perceive_many(planted, entities, maps), batch)  # an (n, 91) array works too
    for original, copy in zip(maps, copies):
        assert (original is None) == (copy is None)
        for verb, vector in (original or {}).items():
            np.testing.assert_array_equal(vector, copy[verb])
    assert perceive_many(planted, [], []).shape == (0, len(VOCABULARY.concepts))
    np.testing.assert_array_equal(
        perceive_many(planted, [entities[0].tolist()], [None])[0], perceive(planted, entities[0])
    )


def test_eq1_constants_are_derived_once(planted: PrototypeSet) -> None:
    assert planted.entity_eq1 is planted.entity_eq1 and planted.verb_eq1 is planted.verb_eq1
    restored = PrototypeSet.from_state(planted.to_state())
    np.testing.assert_array_equal(restored.verb_eq1.weights, planted.verb_eq1.weights)


def test_one_verb_gives_no_verb_evidence() -> None:
    one_verb = Vocabulary(nouns=VOCABULARY.nouns, adjective_pairs=VOCABULARY.adjective_pairs, verbs=("push",))
    entities, labels, effects, _ = _training()
    prototypes = fit_prototypes(one_verb, entities, labels, effects, ["push"] * len(effects), method="kmeans")
    assert perceive(prototypes, entities[0], {"push": effects[0]})[-1] == NO_EVIDENCE
    assert perceive_many(prototypes, entities[:2], [{"push": effects[0]}, None])[:, -1].tolist() == [NO_EVIDENCE] * 2


@pytest.mark.parametrize(
    ("entity", "effects", "field", "problem"),
    [
        (np.full(91, np.nan), {}, "entity", "contains NaN or infinite values"),
        (np.zeros((1, 91)), {}, "entity", "perceive takes one entity vector of 91 features"),
        (["x"] * 91, {}, "entity", "must be numeric"),
        (np.zeros(91), {"push": np.zeros(91)}, "effects.push", "must have 66 features per vector, got shape (91,)"),
        (np.zeros(91), {"push": np.zeros((2, 66))}, "effects.push", "must be one effect vector of 66 features"),
        (
            np.zeros(91),
            {"push": np.zeros(66), "jump": np.zeros(66)},
            "effects",
            "'jump' is not a verb of the vocabulary",
        ),
        (np.zeros(91), {"push": np.zeros(66), "lift": [np.inf] * 66, "jump": 0}, "effects.lift", "contains NaN"),
        (np.full(91, np.inf), {"jump": 0}, "entity", "contains NaN or infinite values"),
    ],
    ids=[
        "nan-entity",
        "2d-entity",
        "text-entity",
        "short-effect",
        "2d-effect",
        "unknown",
        "first-bad-effect",
        "entity-first",
    ],
)
def test_bad_input_names_the_first_bad_field(
    planted: PrototypeSet, entity: object, effects: dict, field: str, problem: str
) -> None:
    with pytest.raises(InvalidInputError) as error:
        perceive(planted, entity, effects)
    assert error.value.field == field and error.value.problem.startswith(problem)
    good = (np.zeros(91), {"shake": np.zeros(66)})
    with pytest.raises(InvalidInputError) as error:
        perceive_many(planted, [good[0], entity, entity], [good[1], effects, {"jump": 0}])
    assert error.value.field == field.replace("entity", "entities[1]").replace("effects", "effects[1]")
    assert error.value.problem.startswith(problem)


def test_perceive_many_needs_one_effect_map_per_entity(planted: PrototypeSet) -> None:
    with pytest.raises(InvalidInputError, match="^effects: has 1 effect maps for 2 entities"):
        perceive_many(planted, np.zeros((2, 91)), [None])
