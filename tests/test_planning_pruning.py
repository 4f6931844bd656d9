"""Context-dependent pruning learned from data (§V-E: Kitchen 5, Playroom 9, Workshop 13 behaviours)."""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import InvalidInputError
from core.planning import (
    prune_behaviours,
    verb_given_context_from_model,
    verb_given_context_from_scenes,
    verb_given_context_from_world,
)
from core.vocabulary import load_world_file, paper_vocabulary

WORLD = load_world_file("paper")
VERBS = list(WORLD["vocabulary"]["verbs"])
MOVES = ["move_left", "move_right", "move_forward", "move_backward"]
PUSHES = ["push_left", "push_right", "push_forward", "push_backward"]
PAPER_KEPT = {
    "kitchen": {"grasp", *MOVES},
    "playroom": set(VERBS) - set(PUSHES),
    "workshop": set(VERBS),
}


def paper_scenes(count: int, seed: int, with_verbs: bool = True) -> tuple[list[list[str]], list[str]]:
    """Scenes of the paper's world: a context, 3–5 of its objects, each a noun and its applicable behaviours."""
    rng = np.random.default_rng(seed)
    contexts = sorted(WORLD["contexts"])
    scenes, labels = [], []
    for _ in range(count):
        context = contexts[rng.integers(len(contexts))]
        nouns = WORLD["contexts"][context]["nouns"]
        tokens: list[str] = []
        for noun in rng.choice(nouns, size=rng.integers(3, 6)):
            tokens += [str(noun), *(WORLD["applicability"][noun] if with_verbs else ())]
        scenes.append(tokens)
        labels.append(context)
    return scenes, labels


def kept_sets(verb_given_context: dict[str, dict[str, float]]) -> dict[str, set[str]]:
    return {context: set(prune_behaviours(p).kept) for context, p in verb_given_context.items()}


def test_world_applicability_gives_the_paper_behaviour_counts() -> None:
    assert kept_sets(verb_given_context_from_world()) == PAPER_KEPT


def test_table_i_noun_counts_give_the_same_pruning() -> None:
    counts = {noun: sum(list(c.values())[:2]) for noun, c in WORLD["noun_adjective_counts"].items()}
    assert counts["box"] == 16 and counts["ball"] == 10
    assert kept_sets(verb_given_context_from_world(noun_weights=counts)) == PAPER_KEPT


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_scene_verb_tokens_give_the_paper_behaviour_counts(seed: int) -> None:
    scenes, labels = paper_scenes(30, seed)
    assert kept_sets(verb_given_context_from_scenes(scenes, labels, VERBS)) == PAPER_KEPT


def test_noun_only_scenes_with_applicability_give_the_same() -> None:
    scenes, labels = paper_scenes(30, 3, with_verbs=False)
    learned = verb_given_context_from_scenes(scenes, labels, VERBS, applicability=WORLD["applicability"])
    assert kept_sets(learned) == PAPER_KEPT


def test_context_model_distribution_is_sliced_to_verbs() -> None:
    """P(concept | χ) smoothed by ξ, as LDA's φ is: the verb part prunes the same way."""
    vocabulary = paper_vocabulary()
    scenes, labels = paper_scenes(40, 4)
    contexts = sorted(WORLD["contexts"])
    counts = np.full((len(contexts), len(vocabulary)), 0.1)
    for tokens, label in zip(scenes, labels, strict=True):
        for token in tokens:
            counts[contexts.index(label), vocabulary.index(token)] += 1
    phi = counts / counts.sum(axis=1, keepdims=True)
    verb_phi = verb_given_context_from_model(phi, vocabulary.concepts, VERBS)
    assert np.allclose(verb_phi.sum(axis=1), 1.0)
    learned = {c: set(prune_behaviours(verb_phi[k], behaviours=VERBS).kept) for k, c in enumerate(contexts)}
    assert learned == PAPER_KEPT


def test_rule_is_relative_to_the_most_probable_verb() -> None:
    pruning = prune_behaviours({"a": 0.4, "b": 0.3, "c": 0.2, "d": 0.1}, threshold=0.6)
    assert pruning.kept == ("a", "b") and pruning.pruned == ("c", "d")
    assert pruning.relative["c"] == pytest.approx(0.5)
    scaled = prune_behaviours({"a": 40.0, "b": 30.0, "c": 20.0, "d": 10.0}, threshold=0.6)
    assert (scaled.kept, scaled.pruned) == (pruning.kept, pruning.pruned)


@pytest.mark.parametrize(
    ("arguments", "field"),
    [
        (({"a": 0.5}, 0.0), "threshold"),
        (({"a": 0.5}, 1.5), "threshold"),
        (({},), "verb_given_context"),
        (({"a": 0.0, "b": 0.0},), "verb_given_context"),
        (({"a": -0.1, "b": 1.0},), "verb_given_context"),
        ((np.array([0.5, 0.5]),), "behaviours"),
    ],
)
def test_bad_distributions_are_named(arguments: tuple, field: str) -> None:
    with pytest.raises(InvalidInputError) as error:
        prune_behaviours(*arguments)
    assert error.value.field == field


def test_scenes_without_verb_evidence_are_rejected() -> None:
    with pytest.raises(InvalidInputError, match="kitchen") as error:
        verb_given_context_from_scenes([["cup", "plate"]], ["kitchen"], VERBS)
    assert error.value.field == "scenes"
    with pytest.raises(InvalidInputError) as error:
        verb_given_context_from_model(np.ones((2, 3)), ["cup", "grasp", "drop"], ["grasp", "fly"])
    assert error.value.field == "verbs"
