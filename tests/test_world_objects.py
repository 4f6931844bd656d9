"""The world's objects reproduce Tables I and II exactly, split 45/15 by noun, from a seed."""

from __future__ import annotations

import copy
from collections import Counter

import pytest

from core.errors import InvalidInputError
from core.vocabulary import load_world_file
from sim.world import TEST, TRAIN, World, WorldConfig, make_objects

# Table I of the paper, typed from the text (not read from the world file it checks).
TABLE_I = {
    "box":      {"hard": 2, "soft": 14, "noisy": 2, "silent": 14, "tall": 0, "short": 16, "thin": 0, "thick": 16, "round": 0, "edgy": 16},
    "ball":     {"hard": 3, "soft": 7, "noisy": 7, "silent": 3, "tall": 0, "short": 10, "thin": 1, "thick": 9, "round": 10, "edgy": 0},
    "cylinder": {"hard": 14, "soft": 0, "noisy": 5, "silent": 9, "tall": 10, "short": 4, "thin": 9, "thick": 5, "round": 14, "edgy": 0},
    "cup":      {"hard": 11, "soft": 0, "noisy": 1, "silent": 10, "tall": 0, "short": 11, "thin": 0, "thick": 11, "round": 11, "edgy": 0},
    "tool":     {"hard": 5, "soft": 0, "noisy": 5, "silent": 0, "tall": 5, "short": 0, "thin": 0, "thick": 5, "round": 5, "edgy": 0},
    "plate":    {"hard": 4, "soft": 0, "noisy": 0, "silent": 4, "tall": 4, "short": 0, "thin": 0, "thick": 4, "round": 4, "edgy": 0},
}  # fmt: skip

PUSHES = ("push_left", "push_right", "push_forward", "push_backward")
MOVES = ("move_left", "move_right", "move_forward", "move_backward")
ALL_BEHAVIOURS = ("grasp", *PUSHES, *MOVES, "drop", "throw", "knock_down", "shake")
# Table II: cups and plates are only grasped and moved; balls are never pushed.
TABLE_II = {
    "box": ALL_BEHAVIOURS,
    "ball": tuple(b for b in ALL_BEHAVIOURS if b not in PUSHES),
    "cylinder": ALL_BEHAVIOURS,
    "cup": ("grasp", *MOVES),
    "tool": ALL_BEHAVIOURS,
    "plate": ("grasp", *MOVES),
}


@pytest.mark.parametrize("seed", [0, 1, 7])
def test_noun_adjective_cooccurrences_equal_table_i_exactly(seed: int) -> None:
    objects = make_objects(WorldConfig.paper(), seed)
    assert len(objects) == 60
    counted = Counter((obj.noun, adjective) for obj in objects for adjective in obj.adjectives)
    for noun, row in TABLE_I.items():
        for adjective, expected in row.items():
            assert counted[(noun, adjective)] == expected, (noun, adjective)


def test_every_object_has_one_noun_and_one_adjective_per_pair_in_pair_order() -> None:
    config = WorldConfig.paper()
    for obj in make_objects(config, 3):
        assert obj.concepts == (obj.noun, *obj.adjectives)
        for adjective, pair in zip(obj.adjectives, config.vocabulary.adjective_pairs, strict=True):
            assert adjective in pair


def test_behaviours_are_table_ii_exactly() -> None:
    for obj in make_objects(WorldConfig.paper(), 0):
        assert obj.behaviours == TABLE_II[obj.noun], obj.object_id


def test_split_is_45_train_15_test_stratified_by_noun() -> None:
    world = World.paper(seed=5)
    assert len(world.train_objects) == 45 and len(world.test_objects) == 15
    assert {obj.split for obj in world.objects} == {TRAIN, TEST}
    per_noun = Counter(obj.noun for obj in world.objects)
    tested = Counter(obj.noun for obj in world.test_objects)
    for noun, size in per_noun.items():
        # Largest remainder: each noun's test share is its exact quota rounded down or up.
        assert abs(tested[noun] - 15 * size / 60) < 1, noun
        assert tested[noun] >= 1


def test_same_seed_same_objects_and_different_seed_different_labels_or_split() -> None:
    config = WorldConfig.paper()
    assert make_objects(config, 11) == make_objects(config, 11)
    assert make_objects(config, 11) != make_objects(config, 12)
    assert World(config, 11).objects == make_objects(config, 11)


def test_world_config_round_trips_through_its_dictionary() -> None:
    for config in (WorldConfig.paper(), WorldConfig.generic(4, seed=2)):
        assert WorldConfig.from_dict(config.to_dict()) == config


def test_paper_world_keeps_table_iv_contexts() -> None:
    config = WorldConfig.paper()
    assert [c.name for c in config.contexts] == ["kitchen", "playroom", "workshop"]
    assert config.context("kitchen").nouns == ("cup", "plate")
    assert config.contexts_of("ball") == ("playroom",)


@pytest.mark.parametrize("n_contexts", [2, 4, 5])
def test_generic_worlds_have_their_own_nouns_and_shared_adjectives_and_verbs(n_contexts: int) -> None:
    config = WorldConfig.generic(n_contexts, seed=n_contexts)
    paper = WorldConfig.paper()
    assert len(config.contexts) == n_contexts
    nouns = [noun for context in config.contexts for noun in context.nouns]
    assert len(nouns) == len(set(nouns)) == 2 * n_contexts
    assert not set(nouns) & set(paper.vocabulary.nouns)
    assert config.vocabulary.adjective_pairs == paper.vocabulary.adjective_pairs
    assert config.vocabulary.verbs == paper.vocabulary.verbs
    objects = make_objects(config, 1)
    counted = Counter((obj.noun, adjective) for obj in objects for adjective in obj.adjectives)
    for noun, row in config.noun_adjective_counts.items():
        assert all(counted[(noun, adjective)] == count for adjective, count in row.items())
    # Adjectives are shared: every adjective carried in one context is carried in another one too, mostly.
    carried = [{a for obj in objects if obj.noun in c.nouns for a in obj.adjectives} for c in config.contexts]
    shared = set.intersection(*carried)
    assert len(shared) >= 3


def test_generic_worlds_depend_on_their_seed_and_extend_past_the_named_themes() -> None:
    assert WorldConfig.generic(4, seed=1) == WorldConfig.generic(4, seed=1)
    assert WorldConfig.generic(4, seed=1) != WorldConfig.generic(4, seed=2)
    many = WorldConfig.generic(12, seed=0, nouns_per_context=3)
    assert len(many.vocabulary.nouns) == 36
    assert many.contexts[-1].name == "context_12"


def _paper_dict() -> dict:
    return copy.deepcopy(load_world_file("paper"))


@pytest.mark.parametrize(
    ("mutate", "field"),
    [
        (lambda d: d["noun_adjective_counts"]["box"].update(hard=3), "noun_adjective_counts.box"),
        (lambda d: d["noun_adjective_counts"]["box"].update(hard=-1, soft=17), "noun_adjective_counts.box.hard"),
        (lambda d: d["noun_adjective_counts"]["box"].update(heavy=2), "noun_adjective_counts.box"),
        (lambda d: d["noun_adjective_counts"].pop("tool"), "noun_adjective_counts"),
        (lambda d: d["applicability"]["cup"].append("juggle"), "applicability.cup"),
        (lambda d: d["applicability"].pop("plate"), "applicability"),
        (lambda d: d["contexts"]["kitchen"]["nouns"].append("spoon"), "contexts.kitchen.nouns"),
        (lambda d: d["contexts"]["kitchen"]["prevalent"].append("sticky"), "contexts.kitchen.prevalent"),
        (lambda d: d["contexts"].clear(), "contexts"),
        (lambda d: d["objects"].update(test=16), "n_test"),
        (lambda d: d["shapes"].update(box="pyramid"), "shapes.box"),
        (lambda d: d["behaviour_effects"]["throw"].update(kind="teleport"), "behaviour_effect.kind"),
        (lambda d: d["behaviour_effects"]["throw"].update(direction=[0, 0]), "behaviour_effect.direction"),
        (lambda d: d["behaviour_effects"]["drop"].update(topple_probability=2), "behaviour_effect.topple_probability"),
    ],
)
def test_invalid_world_configs_name_the_field(mutate, field: str) -> None:
    data = _paper_dict()
    mutate(data)
    with pytest.raises(InvalidInputError) as error:
        WorldConfig.from_dict(data)
    assert error.value.field == field


def test_invalid_generator_arguments_name_the_field() -> None:
    with pytest.raises(InvalidInputError, match="n_contexts"):
        WorldConfig.generic(0)
    with pytest.raises(InvalidInputError, match="objects_per_noun"):
        WorldConfig.generic(3, objects_per_noun=(5, 2))
    with pytest.raises(InvalidInputError, match="seed"):
        make_objects(WorldConfig.paper(), -1)
    with pytest.raises(InvalidInputError, match="object_id"):
        World.paper().object("spoon_00")
