"""Context feedback's fast options (docs/feedback.md, "Speed"): ``marginals=False`` leaves out the
in-context webs' marginals only; ``warm_map=True`` gives the cold path's documents on the paper
world's scenes; the fold-in and P(c | k) shortcuts give the very numbers of the plain code."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from core.concept_web import ConceptWeb
from core.context import IncrementalLDA, lda
from core.context.feedback import _FoldIn, _words, context_concepts, contextual_feedback
from core.errors import InvalidInputError
from core.vocabulary import Vocabulary
from sim.world import World

FIELDS = ("perception", "web", "in_context", "context_posterior", "context_concepts")


def named_scene(vocabulary: Vocabulary, objects: list) -> tuple[np.ndarray, np.ndarray]:
    """The service's concept-level perception of named objects: a named concept 1, its rivals 0,
    the verbs named applied (1) and the others not applied."""
    perceptions = np.zeros((len(objects), len(vocabulary)))
    for row, obj in zip(perceptions, objects, strict=True):
        row[[vocabulary.index(name) for name in (*obj.concepts, *obj.behaviours)]] = 1.0
    applied = np.array([[verb in obj.behaviours for verb in vocabulary.verbs] for obj in objects])
    perceptions[:, len(vocabulary.nouns) + len(vocabulary.adjectives) :][~applied] = 0.5
    return perceptions, applied


def noisy_scene(vocabulary: Vocabulary, objects: list, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Clear readings of the objects' labels (0.8 / 0.2) with Gaussian noise, every applicable behaviour applied."""
    truth = np.array([[name in (*obj.concepts, *obj.behaviours) for name in vocabulary.concepts] for obj in objects])
    perceptions = np.clip(np.where(truth, 0.8, 0.2) + rng.normal(0.0, 0.1, truth.shape), 0.0, 1.0)
    return perceptions, np.array([[verb in obj.behaviours for verb in vocabulary.verbs] for obj in objects])


def same(first, second) -> bool:
    return (
        first.active_concepts == second.active_concepts
        and (first.iterations, first.converged) == (second.iterations, second.converged)
        and all(np.array_equal(getattr(first, f), getattr(second, f), equal_nan=True) for f in FIELDS)
    )


def paper_scenes(world: World) -> list[tuple[np.ndarray, np.ndarray]]:
    """40 five-object scenes of the paper world: named (as the service gets them) and noisy readings."""
    rng = np.random.default_rng(9)
    drawn = world.scenes(20, seed=4, objects_per_scene=5)
    named = [named_scene(world.vocabulary, list(scene.objects)) for scene in drawn]
    noisy = [noisy_scene(world.vocabulary, list(scene.objects), rng) for scene in drawn]
    return named + noisy


def test_without_marginals_only_the_in_context_webs_are_left_out(world, web, context_model) -> None:
    for perceptions, applied in paper_scenes(world)[::4]:
        full = contextual_feedback(web, context_model, perceptions, world.vocabulary, applied=applied)
        lean = contextual_feedback(web, context_model, perceptions, world.vocabulary, applied=applied, marginals=False)
        assert lean.in_context_web is None and full.in_context_web is not None
        assert same(full, lean)


def test_warm_map_gives_the_cold_paths_documents_on_the_paper_worlds_scenes(world, web, context_model) -> None:
    # Measured over 5,000 service scenes and the sigma experiment's 880: never a different document
    # (docs/feedback.md). On noisier perceptions it sometimes differs, so this is no general law.
    for perceptions, applied in paper_scenes(world):
        settled = web.infer_many(perceptions, applied=applied)
        cold = contextual_feedback(web, context_model, perceptions, world.vocabulary, applied=applied)
        options = {"applied": applied, "perceived": settled, "marginals": False, "warm_map": True}
        warm = contextual_feedback(web, context_model, perceptions, world.vocabulary, **options)
        assert same(cold, warm)
        # Deterministic: the same inputs (the perceived webs' messages included) give the same outputs.
        assert same(warm, contextual_feedback(web, context_model, perceptions, world.vocabulary, **options))


def test_warm_map_starts_the_max_product_passes_warm(world, web, context_model, monkeypatch) -> None:
    perceptions, applied = paper_scenes(world)[22]
    settled = web.infer_many(perceptions, applied=applied)
    calls = []
    infer_many = ConceptWeb.infer_many

    def spy(self, *args, **options):
        calls.append(options)
        return infer_many(self, *args, **options)

    monkeypatch.setattr(ConceptWeb, "infer_many", spy)
    options = {"applied": applied, "perceived": settled, "marginals": False, "warm_map": True}
    contextual_feedback(web, context_model, perceptions, world.vocabulary, **options)
    # The first in-context settling starts from step 1's max-product messages, the next from the last one's.
    assert len(calls) >= 1 and all(a is b for a, b in zip(calls[0]["max_start"], settled, strict=True))
    assert all(call.get("max_product") == (0.0, 30) and call["marginals"] is False for call in calls)


@pytest.mark.parametrize("index", [25, 31])
def test_warm_map_without_max_product_messages_is_the_cold_path(world, web, context_model, monkeypatch, index) -> None:
    # A memo of step 1 that drops the max-product messages (even for one object) costs speed, never a result.
    perceptions, applied = paper_scenes(world)[index]
    settled = web.infer_many(perceptions, applied=applied)
    stripped = [settled[0], dataclasses.replace(settled[1], max_messages=None), *settled[2:]]
    cold = contextual_feedback(web, context_model, perceptions, world.vocabulary, applied=applied)
    calls = []
    infer_many = ConceptWeb.infer_many

    def spy(self, *args, **options):
        calls.append(options)
        return infer_many(self, *args, **options)

    monkeypatch.setattr(ConceptWeb, "infer_many", spy)
    warm = contextual_feedback(
        web, context_model, perceptions, world.vocabulary, applied=applied, perceived=stripped, warm_map=True
    )
    assert calls and all(call.get("max_start") is None for call in calls)
    assert same(cold, warm)
    np.testing.assert_array_equal(cold.in_context_web, warm.in_context_web)


@pytest.mark.parametrize(("option", "value"), [("marginals", "no"), ("warm_map", 1)])
def test_the_options_must_be_bools(world, web, context_model, option: str, value: object) -> None:
    perceptions, applied = paper_scenes(world)[0]
    with pytest.raises(InvalidInputError) as error:
        contextual_feedback(web, context_model, perceptions, world.vocabulary, applied=applied, **{option: value})
    assert error.value.field == option


@pytest.mark.parametrize("small_memo", [False, True])
def test_the_fold_in_is_infer_scene_of_the_documents_words(world, context_model, monkeypatch, small_memo) -> None:
    if small_memo:  # draws longer than the memo keeps, and more seeds than it keeps
        monkeypatch.setattr(lda, "_DRAWN", {})
        monkeypatch.setattr(lda, "_DRAWN_SIZE", 700)
        monkeypatch.setattr(lda, "_DRAWN_SEEDS", 2)
    vocabulary = world.vocabulary
    rng = np.random.default_rng(5)
    # Long and short documents in turn: the memoised random numbers are prefixes of one draw per seed.
    for n_objects in (1, 5, 2, 7, 3):
        document = rng.random((n_objects, len(vocabulary))) < 0.4
        for seed in (0, 3, 12345):
            fold_in = _FoldIn(context_model, vocabulary, seed)
            expected = context_model.infer_scene(_words(document, vocabulary), seed=seed)
            np.testing.assert_array_equal(fold_in(document), expected)
    # Concepts the model never met are ignored, as infer_scene ignores unknown words.
    partial = IncrementalLDA(seed=0, sweeps=10).fit([["cup", "plate", "grasp"], ["box", "push"]])
    document = rng.random((3, len(vocabulary))) < 0.5
    np.testing.assert_array_equal(
        _FoldIn(partial, vocabulary, 1)(document), partial.infer_scene(_words(document, vocabulary), seed=1)
    )


def plain_context_concepts(context_model: IncrementalLDA, vocabulary: Vocabulary) -> tuple[np.ndarray, np.ndarray]:
    """P(c | k) as docs/feedback.md states it, one bincount per context."""
    names, state = vocabulary.concepts, context_model.lda_state
    given, informed = np.zeros((state.n_contexts, len(names))), np.zeros(len(names), dtype=bool)
    if state.n_tokens == 0:
        return given, informed
    position = {name: i for i, name in enumerate(context_model.vocabulary)}
    columns = np.array([position.get(name, -1) for name in names])
    known, column = columns >= 0, np.maximum(columns, 0)
    n_nouns, n_pairs = len(vocabulary.nouns), len(vocabulary.adjective_pairs)
    group = np.concatenate(
        [np.zeros(n_nouns, int), 1 + np.repeat(np.arange(n_pairs), 2), np.full(len(vocabulary.verbs), -1)]
    )
    unseen = state.xi / (state.n_k + state.vocab_size * state.xi)
    phi = np.where(known, context_model.concept_given_context()[:, column], unseen[:, None])
    seen = known & (state.n_kw.sum(axis=0)[column] > 0)
    grouped = group >= 0
    group_seen = np.bincount(group[grouped & seen], minlength=1 + n_pairs) > 0
    normalised = grouped & group_seen[np.maximum(group, 0)]
    totals = np.stack([np.bincount(group[grouped], weights=row[grouped], minlength=1 + n_pairs) for row in phi])
    given[:, normalised] = phi[:, normalised] / totals[:, group[normalised]]
    informed[normalised] = True
    verbs = np.flatnonzero(group == -1)
    if verbs.size and informed[:n_nouns].any() and seen[verbs].any():
        given[:, verbs] = np.minimum(phi[:, verbs] / totals[:, :1], 1.0)
        informed[verbs] = True
    return given, informed


def test_context_concepts_are_the_plain_computation_bit_for_bit(world, context_model) -> None:
    vocabulary = world.vocabulary
    scenes = world.scenes(20, seed=3, objects=world.train_objects)
    without = {"box", "soft", "hard", "push"}  # a noun, a whole adjective pair and a verb never seen
    models = [
        IncrementalLDA(),
        context_model,
        IncrementalLDA(seed=0, sweeps=10).fit([scene.tokens(with_verbs=False) for scene in scenes]),
        IncrementalLDA(seed=0, sweeps=10).fit(
            [[w for w in s.tokens(with_verbs=True) if w not in without] for s in scenes]
        ),
        IncrementalLDA(seed=0, sweeps=10).fit([["cup", "zebra", "grasp"], ["box", "zebra"]]),
    ]
    for model in models:
        table = context_concepts(model, vocabulary)
        given, informed = plain_context_concepts(model, vocabulary)
        np.testing.assert_array_equal(table.given_context, given)
        np.testing.assert_array_equal(table.informed, informed)
    assert not context_concepts(models[3], vocabulary).informed[vocabulary.index("soft")]
    # The table is memoised on the counts it reads: a model that learns a scene is asked afresh.
    learner = models[2]
    before = context_concepts(learner, vocabulary).given_context
    for scene in world.scenes(3, seed=4, objects=world.train_objects):
        learner.learn_scene(scene.tokens(with_verbs=True))
        table = context_concepts(learner, vocabulary)
        given, informed = plain_context_concepts(learner, vocabulary)
        np.testing.assert_array_equal(table.given_context, given)
        np.testing.assert_array_equal(table.informed, informed)
    assert not np.array_equal(before, table.given_context)
    assert not table.given_context.flags.writeable
