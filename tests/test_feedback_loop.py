"""Context feedback (§IV-D, Eq. 6): exactness, structure, convergence, determinism, correction, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from core.concept_web import DEFAULT_DAMPING
from core.context import IncrementalLDA, feedback
from core.context.feedback import context_concepts, contextual_feedback
from core.errors import InvalidInputError
from core.vocabulary import Vocabulary
from sim.world import World, WorldObject

TRUTH = 0.8


def perception_of(vocabulary: Vocabulary, obj: WorldObject) -> np.ndarray:
    """A clear perception: the object's concepts at 0.8, the others at 0.2, nouns normalised."""
    p = np.array(
        [TRUTH if name in obj.concepts or name in obj.behaviours else 1 - TRUTH for name in vocabulary.concepts]
    )
    nouns = slice(0, len(vocabulary.nouns))
    p[nouns] /= p[nouns].sum()
    return p


def boxlike_cup_scene(world: World) -> tuple[np.ndarray, np.ndarray]:
    """A cup perceived as a box (no adjective or verb evidence) among three clearly perceived kitchen objects."""
    vocabulary = world.vocabulary
    kitchen = [obj for obj in world.train_objects if obj.noun in ("cup", "plate")]
    companions = [next(o for o in kitchen if o.noun == "plate"), *[o for o in kitchen if o.noun == "cup"][:2]]
    noisy = np.full(len(vocabulary), 0.5)
    noisy[: len(vocabulary.nouns)] = 0.05
    noisy[vocabulary.index("box")] = 0.6
    noisy[vocabulary.index("cup")] = 0.2
    perceptions = np.array([noisy, *(perception_of(vocabulary, obj) for obj in companions)])
    applied = np.array(
        [[False] * len(vocabulary.verbs)]
        + [[verb in obj.behaviours for verb in vocabulary.verbs] for obj in companions]
    )
    return perceptions, applied


def random_perceptions(vocabulary: Vocabulary, n_objects: int, rng: np.random.Generator) -> np.ndarray:
    p = rng.random((n_objects, len(vocabulary)))
    nouns = slice(0, len(vocabulary.nouns))
    p[:, nouns] /= p[:, nouns].sum(axis=1, keepdims=True)
    pairs = p[:, len(vocabulary.nouns) : len(vocabulary.nouns) + len(vocabulary.adjectives) : 2]
    p[:, len(vocabulary.nouns) + 1 : len(vocabulary.nouns) + len(vocabulary.adjectives) : 2] = 1.0 - pairs
    return p


def test_sigma_one_is_the_web_and_sigma_zero_the_context(world, web, context_model) -> None:
    perceptions, applied = boxlike_cup_scene(world)
    alone = contextual_feedback(web, context_model, perceptions, world.vocabulary, applied=applied, sigma=1.0)
    settled = web.infer_many(perceptions, applied=applied)
    assert np.array_equal(alone.in_context, np.array([s.probabilities for s in settled]))
    assert np.array_equal(alone.web, alone.in_context)
    context_only = contextual_feedback(web, context_model, perceptions, world.vocabulary, applied=applied, sigma=0.0)
    expected = context_only.context_posterior @ context_concepts(context_model, world.vocabulary).given_context
    assert np.array_equal(context_only.in_context, np.broadcast_to(expected, perceptions.shape))
    np.testing.assert_array_equal(context_only.context_concepts, expected)


def test_eq_6_mixes_the_web_and_the_context_linearly(world, web, context_model) -> None:
    perceptions, applied = boxlike_cup_scene(world)
    result = contextual_feedback(web, context_model, perceptions, world.vocabulary, applied=applied, sigma=0.3)
    np.testing.assert_allclose(result.in_context, 0.3 * result.web + 0.7 * result.context_concepts[None, :], atol=1e-15)


@pytest.mark.parametrize("sigma", [0.0, 0.4, 0.9])
def test_in_context_probabilities_keep_the_vocabulary_structure(world, web, context_model, sigma: float) -> None:
    vocabulary = world.vocabulary
    n_nouns, n_adjectives = len(vocabulary.nouns), len(vocabulary.adjectives)
    perceptions = random_perceptions(vocabulary, 5, np.random.default_rng(3))
    result = contextual_feedback(web, context_model, perceptions, vocabulary, sigma=sigma)
    for probabilities in (result.in_context, result.in_context_web):
        np.testing.assert_allclose(probabilities[:, :n_nouns].sum(axis=1), 1.0, atol=1e-9)
        pairs = probabilities[:, n_nouns : n_nouns + n_adjectives].reshape(5, -1, 2).sum(axis=2)
        np.testing.assert_allclose(pairs, 1.0, atol=1e-9)
        assert ((probabilities >= 0.0) & (probabilities <= 1.0)).all()
    np.testing.assert_allclose(result.context_posterior.sum(), 1.0)
    assert result.context_posterior.shape == (context_model.n_contexts,)
    assert len(result.active_concepts) == 5
    assert all(sum(name in vocabulary.nouns for name in words) == 1 for words in result.active_concepts)


def test_each_context_row_is_normalised_by_structure(world, context_model) -> None:
    vocabulary = world.vocabulary
    n_nouns, n_adjectives = len(vocabulary.nouns), len(vocabulary.adjectives)
    table = context_concepts(context_model, vocabulary)
    assert table.informed.all()
    np.testing.assert_allclose(table.given_context[:, :n_nouns].sum(axis=1), 1.0)
    pairs = table.given_context[:, n_nouns : n_nouns + n_adjectives].reshape(len(table.given_context), -1, 2)
    np.testing.assert_allclose(pairs.sum(axis=2), 1.0)
    verbs = table.given_context[:, n_nouns + n_adjectives :]
    assert ((verbs >= 0.0) & (verbs <= 1.0)).all()
    # Every context's prevalent noun (Table IV) carries its noun mass, and grasp applies to every noun (Table II).
    assert {vocabulary.nouns[i] for i in table.given_context[:, :n_nouns].argmax(axis=1)} == {"cup", "box", "cylinder"}
    # Near 1, not 1: the contexts are estimated (the priors, a few stray assignments). The lowest
    # context's grasp was 0.842 over 200 fits on other seeds (world 0, scenes and model seeds
    # 1000-1099 and 3000-3099, 2026-12-06); 0.957 for this fixture, so atol 0.05 held here only.
    assert (table.given_context[:, vocabulary.index("grasp")] >= 0.8).all()


def test_context_pulls_a_boxlike_cup_back_to_cup(world, web, context_model) -> None:
    vocabulary = world.vocabulary
    perceptions, applied = boxlike_cup_scene(world)
    result = contextual_feedback(web, context_model, perceptions, vocabulary, applied=applied, sigma=0.5)
    nouns = slice(0, len(vocabulary.nouns))
    assert vocabulary.nouns[int(np.argmax(result.web[0, nouns]))] == "box"
    assert vocabulary.nouns[int(np.argmax(result.in_context[0, nouns]))] == "cup"
    assert vocabulary.nouns[int(np.argmax(result.in_context_web[0, nouns]))] == "cup"
    assert "cup" in result.active_concepts[0]
    assert result.converged and result.iterations >= 2


def test_the_iteration_cap_stops_an_unsettled_loop(world, web, context_model) -> None:
    perceptions, applied = boxlike_cup_scene(world)
    capped = contextual_feedback(web, context_model, perceptions, world.vocabulary, applied=applied, max_iterations=1)
    assert capped.iterations == 1
    assert not capped.converged


def test_same_seed_same_result_and_inputs_untouched(world, web, context_model) -> None:
    perceptions = random_perceptions(world.vocabulary, 4, np.random.default_rng(8))
    before = perceptions.copy()
    first = contextual_feedback(web, context_model, perceptions, world.vocabulary, sigma=0.5, seed=11)
    second = contextual_feedback(web, context_model, perceptions, world.vocabulary, sigma=0.5, seed=11)
    assert np.array_equal(perceptions, before)
    for field in ("in_context", "in_context_web", "context_posterior", "web"):
        assert np.array_equal(getattr(first, field), getattr(second, field))
    assert first.active_concepts == second.active_concepts
    assert (first.iterations, first.converged) == (second.iterations, second.converged)


def test_a_context_model_without_scenes_or_verbs_has_no_opinion_there(world, web) -> None:
    vocabulary = world.vocabulary
    perceptions, applied = boxlike_cup_scene(world)
    empty = contextual_feedback(web, IncrementalLDA(), perceptions, vocabulary, applied=applied, sigma=0.2)
    assert np.array_equal(empty.in_context, empty.web)
    assert np.isnan(empty.context_concepts).all()
    scenes = world.scenes(30, seed=2, objects=world.train_objects)
    no_verbs = IncrementalLDA(seed=0, sweeps=30).fit([scene.tokens(with_verbs=False) for scene in scenes])
    result = contextual_feedback(web, no_verbs, perceptions, vocabulary, applied=applied, sigma=0.2)
    verbs = slice(len(vocabulary.nouns) + len(vocabulary.adjectives), len(vocabulary))
    assert np.array_equal(result.in_context[:, verbs], result.web[:, verbs])
    assert not np.array_equal(result.in_context[:, : verbs.start], result.web[:, : verbs.start])


@pytest.mark.parametrize(
    ("options", "field"),
    [
        ({"sigma": 1.5}, "sigma"),
        ({"sigma": -0.1}, "sigma"),
        ({"sigma": True}, "sigma"),
        ({"sigma": float("nan")}, "sigma"),
        ({"tolerance": 0.0}, "tolerance"),
        ({"max_iterations": 0}, "max_iterations"),
        ({"seed": -1}, "seed"),
    ],
)
def test_bad_settings_are_refused(world, web, context_model, options: dict, field: str) -> None:
    perceptions, _ = boxlike_cup_scene(world)
    with pytest.raises(InvalidInputError) as error:
        contextual_feedback(web, context_model, perceptions, world.vocabulary, **options)
    assert error.value.field == field


@pytest.mark.parametrize(
    "perceptions",
    [
        np.full(29, 0.5),
        np.full((2, 28), 0.5),
        np.zeros((0, 29)),
        np.full((2, 29), 1.5),
        np.full((1, 29), np.nan),
        [["a"] * 29],
    ],
)
def test_bad_perceptions_are_refused(world, web, context_model, perceptions) -> None:
    with pytest.raises(InvalidInputError) as error:
        contextual_feedback(web, context_model, perceptions, world.vocabulary)
    assert error.value.field == "perceptions"


def test_models_and_vocabulary_must_match(world, web, context_model) -> None:
    perceptions, _ = boxlike_cup_scene(world)
    other = Vocabulary(nouns=("cup",), adjective_pairs=(("hard", "soft"),), verbs=())
    with pytest.raises(InvalidInputError, match="vocabulary"):
        contextual_feedback(web, context_model, perceptions, other)
    with pytest.raises(InvalidInputError, match="context_model"):
        contextual_feedback(web, object(), perceptions, world.vocabulary)  # type: ignore[arg-type]
    with pytest.raises(InvalidInputError, match="web"):
        contextual_feedback(object(), context_model, perceptions, world.vocabulary)  # type: ignore[arg-type]


def test_webs_settled_beforehand_give_the_identical_result(world, web, context_model) -> None:
    rng = np.random.default_rng(3)
    for trial in range(5):
        perceptions = rng.uniform(0, 1, (4, len(world.vocabulary)))
        applied = rng.uniform(size=(4, len(world.vocabulary.verbs))) < 0.5
        fresh = contextual_feedback(web, context_model, perceptions, world.vocabulary, applied=applied, seed=trial)
        reused = contextual_feedback(
            web,
            context_model,
            perceptions,
            world.vocabulary,
            applied=applied,
            seed=trial,
            perceived=web.infer_many(perceptions, applied=applied),
        )
        for field in ("web", "in_context", "in_context_web", "context_posterior"):
            assert np.array_equal(getattr(fresh, field), getattr(reused, field)), field
        assert fresh.active_concepts == reused.active_concepts and fresh.iterations == reused.iterations
    with pytest.raises(InvalidInputError, match="perceived"):
        contextual_feedback(web, context_model, perceptions, world.vocabulary, applied=applied, perceived=[])


def _cold_damped_settle(web, evidence, applied, previous, **options):
    """The loop's settling before warm starts and undamped passes: cold, both passes damped."""
    return web.infer_many(evidence, applied=applied, damping=DEFAULT_DAMPING)


#: How far a settling at the default tolerance (1e-6 on messages) may be from its LBP fixed point's
#: marginals: the old settling (cold, damped) was up to 5e-5 away on these scenes, the new one as well.
FIXED_POINT_TOLERANCE = 1e-4


@pytest.mark.parametrize("undamped_iterations", [feedback.UNDAMPED_ITERATIONS, 1])
def test_warm_undamped_settling_reaches_the_fixed_point_of_the_cold_damped_one(
    world, web, context_model, monkeypatch, undamped_iterations: int
) -> None:
    # One undamped iteration never settles: every object then takes the damped fallback.
    monkeypatch.setattr(feedback, "UNDAMPED_ITERATIONS", undamped_iterations)
    rng = np.random.default_rng(5)
    scenes = [boxlike_cup_scene(world)]
    for _ in range(20):
        objects = rng.choice(len(world.test_objects), 4, replace=False)
        clear = np.array([perception_of(world.vocabulary, world.test_objects[i]) for i in objects])
        noisy = 0.7 * clear + 0.3 * random_perceptions(world.vocabulary, 4, rng)
        scenes.append((noisy, rng.random((4, len(world.vocabulary.verbs))) < 0.6))
    for perceptions, applied in scenes:
        new = contextual_feedback(web, context_model, perceptions, world.vocabulary, applied=applied)
        with monkeypatch.context() as patch:
            patch.setattr(feedback, "_settle", _cold_damped_settle)
            old = contextual_feedback(web, context_model, perceptions, world.vocabulary, applied=applied)
        assert new.active_concepts == old.active_concepts and new.iterations == old.iterations
        assert np.array_equal(new.context_posterior, old.context_posterior)
        assert np.array_equal(new.in_context, old.in_context)
        # Both settle the final in-context evidence to its sum-product fixed point, within the same tolerance.
        fixed_point = web.infer_many(new.in_context, applied=applied, tolerance=1e-13, max_iterations=5000)
        for result in (new, old):
            np.testing.assert_allclose(
                result.in_context_web,
                [inference.probabilities for inference in fixed_point],
                atol=FIXED_POINT_TOLERANCE,
            )
