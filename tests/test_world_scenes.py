"""Scenes (§V): pure scenes hold one context's objects, mixed scenes the asked proportions (Table VI)."""

from __future__ import annotations

from collections import Counter

import pytest

from core.errors import InvalidInputError
from sim.world import World, WorldConfig, generate_scenes, scene_from_nouns, table_vi_scenes


def test_scene_tokens_are_nouns_adjectives_and_applicable_verbs() -> None:
    world = World.paper(seed=0)
    scene = generate_scenes(world, 1, seed=4)[0]
    expected = [c for obj in scene.objects for c in (*obj.concepts, *obj.behaviours)]
    assert scene.tokens() == expected
    assert scene.tokens(with_verbs=False) == [c for obj in scene.objects for c in obj.concepts]
    assert set(scene.tokens()) <= set(world.vocabulary.concepts)


def test_pure_scenes_in_a_four_context_world_hold_only_their_contexts_concepts() -> None:
    world = World.generic(4, seed=3)
    config = world.config
    own_concepts = {
        context.name: {
            c for obj in world.objects if obj.noun in context.nouns for c in (*obj.concepts, *obj.behaviours)
        }
        for context in config.contexts
    }
    scenes = world.scenes(200, seed=1)
    sizes = Counter(len(scene.objects) for scene in scenes)
    assert set(sizes) == {3, 4, 5}
    assert {scene.object_contexts[0] for scene in scenes} == {c.name for c in config.contexts}
    for scene in scenes:
        (context,) = set(scene.object_contexts)
        assert scene.mixture == {context: 1.0} and not scene.is_mixed
        assert all(obj.noun in config.context(context).nouns for obj in scene.objects)
        assert set(scene.tokens()) <= own_concepts[context]
        assert len({obj.object_id for obj in scene.objects}) == len(scene.objects)


def test_mixed_scenes_follow_the_given_proportions() -> None:
    world = World.paper(seed=0)
    mixture = {"playroom": 2 / 3, "workshop": 1 / 3}
    scenes = generate_scenes(world, 20, seed=2, objects_per_scene=6, mixture=mixture)
    for scene in scenes:
        assert Counter(scene.object_contexts) == {"playroom": 4, "workshop": 2}
        assert scene.mixture == pytest.approx(mixture)
        assert scene.is_mixed
        for obj, context in zip(scene.objects, scene.object_contexts, strict=True):
            assert obj.noun in world.config.context(context).nouns


def test_mixed_scenes_round_each_scene_to_the_nearest_split() -> None:
    world = World.paper(seed=0)
    for scene in generate_scenes(world, 30, seed=5, mixture={"kitchen": 0.5, "workshop": 0.5}):
        counts = Counter(scene.object_contexts)
        assert abs(counts["kitchen"] - counts["workshop"]) <= 1
        assert sum(scene.mixture.values()) == pytest.approx(1.0)


def test_table_vi_scenes_have_the_papers_objects_and_true_proportions() -> None:
    world = World.paper(seed=0)
    specs = {spec.name: spec for spec in table_vi_scenes()}
    assert len(specs) == 6
    assert specs["playroom+workshop"].nouns == {"box": 3, "ball": 1, "cylinder": 1, "tool": 1}
    assert specs["kitchen+workshop"].mixture == {"kitchen": 0.5, "workshop": 0.5}
    for spec in specs.values():
        scene = scene_from_nouns(world, spec, seed=1, objects=world.test_objects)
        assert Counter(obj.noun for obj in scene.objects) == spec.nouns
        assert scene.mixture == pytest.approx(spec.mixture)
        assert all(obj.split == "test" for obj in scene.objects)
        assert sum(spec.paper_prediction.values()) == pytest.approx(1.0, abs=0.01)


def test_scenes_are_a_function_of_the_seed() -> None:
    world = World.paper(seed=0)
    first = generate_scenes(world, 10, seed=8)
    assert first == generate_scenes(world, 10, seed=8)
    assert first != generate_scenes(world, 10, seed=9)
    # A config and its World with the same seed draw the same objects, hence the same scenes.
    assert generate_scenes(WorldConfig.paper(), 10, seed=0) == generate_scenes(World.paper(seed=0), 10, seed=0)


def test_scenes_can_be_restricted_to_contexts_and_object_pools() -> None:
    world = World.paper(seed=0)
    scenes = generate_scenes(world, 20, seed=3, objects=world.train_objects, contexts=["kitchen"])
    assert all(set(s.object_contexts) == {"kitchen"} for s in scenes)
    assert all(obj.split == "train" for s in scenes for obj in s.objects)


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"mixture": {"kitchen": 0.5, "workshop": 0.4}}, "mixture"),
        ({"mixture": {"kitchen": 1.5, "workshop": -0.5}}, "mixture.kitchen"),
        ({"mixture": {"attic": 1.0}}, "context"),
        ({"contexts": ["attic"]}, "context"),
        ({"objects_per_scene": (5, 3)}, "objects_per_scene"),
        ({"objects": []}, "objects"),
    ],
)
def test_invalid_scene_requests_name_the_field(kwargs: dict, field: str) -> None:
    with pytest.raises(InvalidInputError) as error:
        generate_scenes(World.paper(seed=0), 3, seed=0, **kwargs)
    assert error.value.field == field


def test_invalid_noun_scenes_name_the_field() -> None:
    world = World.paper(seed=0)
    with pytest.raises(InvalidInputError, match="nouns: unknown noun 'spoon'"):
        scene_from_nouns(world, {"spoon": 2})
    with pytest.raises(InvalidInputError, match="nouns.cup"):
        scene_from_nouns(world, {"cup": -1, "plate": 2})
    with pytest.raises(InvalidInputError, match="n_scenes"):
        generate_scenes(world, -1)
