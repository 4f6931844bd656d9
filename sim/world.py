"""The synthetic iCub world (§II, §V): objects, their labels, scenes, and what the robot senses.

A world is data (:class:`WorldConfig`, read from a ``*_world.json`` file, :mod:`sim.data`): the
concept vocabulary, how many objects carry each noun x adjective pair (Table I),
which behaviours apply to each noun (Table II), the contexts and their nouns
(Table IV), the train/test split, and the physics the simulator needs (a shape
primitive per noun, a :class:`sim.sensors.BehaviourEffect` per verb).
:func:`make_objects` turns it into labelled objects, :func:`generate_scenes`
into bags of concepts (§V), and :class:`World` records raw payloads
(:mod:`sim.sensors`). Everything is a deterministic function of a seed.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, TypeGuard

import numpy as np

from core.errors import InvalidInputError
from core.payloads import ObjectRecording
from core.vocabulary import Vocabulary
from sim.data import load_world_file
from sim.sensors import EASY, PRIMITIVES, BehaviourEffect, Difficulty, ObjectBody, make_body, record_object

TRAIN = "train"
TEST = "test"

#: The paper world's difficulties (presets in ``core/data/paper_world.json``, docs/world.md "Difficulty").
WORLDS: tuple[str, ...] = ("easy", "hard")
#: The difficulty the experiments use unless told otherwise (``--world``).
DEFAULT_WORLD = "hard"

# Independent random streams derived from one seed, so that e.g. drawing scenes never
# changes the objects, and recording one object never changes another one's body.
_OBJECTS_STREAM = 0
_BODY_STREAM = 1
_RECORDING_STREAM = 2
_SCENES_STREAM = 3
_NOUN_SCENE_STREAM = 4
_GENERIC_CONFIG_STREAM = 5


def paper_difficulty(name: str, paper: Mapping[str, Any] | None = None) -> Difficulty:
    """The named difficulty preset of ``core/data/paper_world.json`` (``easy``: the defaults)."""
    presets = (paper if paper is not None else load_world_file("paper"))["difficulties"]
    if name not in presets:
        raise InvalidInputError("world", f"unknown difficulty {name!r}; the paper world has {sorted(presets)}")
    return Difficulty.from_dict({"name": name, **presets[name]})


def _is_count(value: object, minimum: int | np.integer = 0) -> TypeGuard[int | np.integer]:
    """An integer (not a bool) of at least ``minimum``."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool) and bool(value >= minimum)


def _rng(seed: int | np.random.Generator, *stream: int) -> np.random.Generator:
    if isinstance(seed, np.random.Generator):
        return seed
    if not _is_count(seed):
        raise InvalidInputError("seed", f"must be a non-negative integer or a numpy Generator, got {seed!r}")
    return np.random.default_rng([int(seed), *stream])


@dataclass(frozen=True)
class ContextSpec:
    """A context (Table IV): the nouns that occur in it and its prevalent concepts."""

    name: str
    nouns: tuple[str, ...]
    prevalent: tuple[str, ...] = ()

    @classmethod
    def from_dict(cls, name: str, data: Mapping[str, Any]) -> ContextSpec:
        return cls(name=name, nouns=tuple(data["nouns"]), prevalent=tuple(data.get("prevalent", ())))

    def to_dict(self) -> dict[str, Any]:
        return {"nouns": list(self.nouns), "prevalent": list(self.prevalent)}


@dataclass(frozen=True)
class WorldConfig:
    """A world as data. ``noun_adjective_counts[noun][adjective]`` is Table I; ``applicability``
    Table II; ``contexts`` Table IV; ``shapes`` the primitive each noun is rendered as (a noun
    named like a primitive may be left out); ``behaviour_effects`` each verb's physics;
    ``difficulty`` how much the objects' looks and the adjectives' ranges overlap."""

    name: str
    vocabulary: Vocabulary
    noun_adjective_counts: dict[str, dict[str, int]]
    applicability: dict[str, tuple[str, ...]]
    contexts: tuple[ContextSpec, ...]
    n_train: int
    n_test: int
    shapes: dict[str, str] = field(default_factory=dict)
    behaviour_effects: dict[str, BehaviourEffect] = field(default_factory=dict)
    difficulty: Difficulty = EASY

    def __post_init__(self) -> None:
        object.__setattr__(self, "noun_adjective_counts", {n: dict(c) for n, c in self.noun_adjective_counts.items()})
        object.__setattr__(self, "applicability", {n: tuple(v) for n, v in self.applicability.items()})
        object.__setattr__(self, "contexts", tuple(self.contexts))
        object.__setattr__(self, "shapes", dict(self.shapes))
        object.__setattr__(self, "behaviour_effects", dict(self.behaviour_effects))
        self._validate_counts()
        self._validate_applicability()
        self._validate_contexts()
        self._validate_split()
        self._validate_physics()

    def _validate_counts(self) -> None:
        vocabulary, counts = self.vocabulary, self.noun_adjective_counts
        if not vocabulary.adjective_pairs:
            raise InvalidInputError(
                "vocabulary.adjective_pairs", "a world counts its objects by adjective pair (Table I)"
            )
        unknown = sorted(set(counts) - set(vocabulary.nouns))
        if unknown:
            raise InvalidInputError("noun_adjective_counts", f"unknown nouns {unknown}")
        for noun in vocabulary.nouns:
            where = f"noun_adjective_counts.{noun}"
            if noun not in counts:
                raise InvalidInputError("noun_adjective_counts", f"no counts for noun {noun!r}")
            row = counts[noun]
            extra = sorted(set(row) - set(vocabulary.adjectives))
            if extra:
                raise InvalidInputError(where, f"unknown adjectives {extra}")
            for adjective in vocabulary.adjectives:
                value = row.get(adjective)
                if not _is_count(value):
                    raise InvalidInputError(f"{where}.{adjective}", f"must be a count >= 0, got {value!r}")
            totals = {f"{a}+{b}": row[a] + row[b] for a, b in vocabulary.adjective_pairs}
            if len(set(totals.values())) > 1:
                raise InvalidInputError(
                    where, f"every adjective pair must sum to the noun's object count, got {totals}"
                )
            if next(iter(totals.values())) == 0:
                raise InvalidInputError(where, "the noun has no objects")

    def _validate_applicability(self) -> None:
        vocabulary = self.vocabulary
        unknown = sorted(set(self.applicability) - set(vocabulary.nouns))
        if unknown:
            raise InvalidInputError("applicability", f"unknown nouns {unknown}")
        for noun in vocabulary.nouns:
            if noun not in self.applicability:
                raise InvalidInputError("applicability", f"no applicable behaviours given for noun {noun!r}")
            verbs = self.applicability[noun]
            bad = sorted(set(verbs) - set(vocabulary.verbs))
            if bad:
                raise InvalidInputError(f"applicability.{noun}", f"{bad} are not verbs of the vocabulary")
            if len(set(verbs)) != len(verbs):
                raise InvalidInputError(f"applicability.{noun}", f"repeated behaviours in {list(verbs)}")

    def _validate_contexts(self) -> None:
        if not self.contexts:
            raise InvalidInputError("contexts", "at least one context is required")
        names = [context.name for context in self.contexts]
        if len(set(names)) != len(names):
            raise InvalidInputError("contexts", f"context names must be unique, got {names}")
        for context in self.contexts:
            if not context.nouns:
                raise InvalidInputError(f"contexts.{context.name}.nouns", "a context needs at least one noun")
            unknown = sorted(set(context.nouns) - set(self.vocabulary.nouns))
            if unknown:
                raise InvalidInputError(f"contexts.{context.name}.nouns", f"unknown nouns {unknown}")
            unknown = sorted(set(context.prevalent) - set(self.vocabulary.concepts))
            if unknown:
                raise InvalidInputError(f"contexts.{context.name}.prevalent", f"unknown concepts {unknown}")

    def _validate_split(self) -> None:
        for name in ("n_train", "n_test"):
            value = getattr(self, name)
            if not _is_count(value):
                raise InvalidInputError(name, f"must be an integer >= 0, got {value!r}")
        total = sum(self.objects_per_noun.values())
        if self.n_train + self.n_test != total:
            raise InvalidInputError(
                "n_test",
                f"n_train + n_test = {self.n_train} + {self.n_test} must equal the {total} objects of the counts",
            )

    def _validate_physics(self) -> None:
        for noun, primitive in self.shapes.items():
            if noun not in self.vocabulary.nouns:
                raise InvalidInputError("shapes", f"unknown noun {noun!r}")
            if primitive not in PRIMITIVES:
                raise InvalidInputError(f"shapes.{noun}", f"{primitive!r} is not one of {PRIMITIVES}")
        for verb, effect in self.behaviour_effects.items():
            if verb not in self.vocabulary.verbs:
                raise InvalidInputError("behaviour_effects", f"unknown verb {verb!r}")
            if not isinstance(effect, BehaviourEffect):
                raise InvalidInputError(f"behaviour_effects.{verb}", "must be a BehaviourEffect")

    @property
    def objects_per_noun(self) -> dict[str, int]:
        """How many objects carry each noun (the sum of any one adjective pair of Table I)."""
        first, second = self.vocabulary.adjective_pairs[0]
        return {
            noun: self.noun_adjective_counts[noun][first] + self.noun_adjective_counts[noun][second]
            for noun in self.vocabulary.nouns
        }

    def context(self, name: str) -> ContextSpec:
        for context in self.contexts:
            if context.name == name:
                return context
        raise InvalidInputError("context", f"unknown context {name!r}; the world has {[c.name for c in self.contexts]}")

    def contexts_of(self, noun: str) -> tuple[str, ...]:
        """The contexts a noun occurs in."""
        return tuple(context.name for context in self.contexts if noun in context.nouns)

    def primitive(self, noun: str) -> str:
        """The shape primitive a noun is rendered as."""
        primitive = self.shapes.get(noun, noun)
        if primitive not in PRIMITIVES:
            raise InvalidInputError("shapes", f"noun {noun!r} has no shape primitive (one of {PRIMITIVES})")
        return primitive

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> WorldConfig:
        """Read the world-file layout (see ``core/data/paper_world.json``)."""
        for key in ("vocabulary", "noun_adjective_counts", "applicability", "contexts", "objects"):
            if key not in data:
                raise InvalidInputError(key, "is required in a world description")
        try:
            return cls(
                name=str(data.get("name", "world")),
                vocabulary=Vocabulary.from_dict(data["vocabulary"]),
                noun_adjective_counts={noun: dict(row) for noun, row in data["noun_adjective_counts"].items()},
                applicability={noun: tuple(verbs) for noun, verbs in data["applicability"].items()},
                contexts=tuple(ContextSpec.from_dict(name, spec) for name, spec in data["contexts"].items()),
                n_train=data["objects"]["train"],
                n_test=data["objects"]["test"],
                shapes=dict(data.get("shapes", {})),
                behaviour_effects={
                    verb: BehaviourEffect.from_dict(effect)
                    for verb, effect in data.get("behaviour_effects", {}).items()
                },
                difficulty=Difficulty.from_dict(data.get("difficulty", {})),
            )
        except (KeyError, TypeError, AttributeError) as error:
            raise InvalidInputError("world", f"malformed world description ({error!r})") from None

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "vocabulary": self.vocabulary.to_dict(),
            "objects": {TRAIN: self.n_train, TEST: self.n_test},
            "noun_adjective_counts": {noun: dict(row) for noun, row in self.noun_adjective_counts.items()},
            "applicability": {noun: list(verbs) for noun, verbs in self.applicability.items()},
            "contexts": {context.name: context.to_dict() for context in self.contexts},
            "shapes": dict(self.shapes),
            "behaviour_effects": {verb: effect.to_dict() for verb, effect in self.behaviour_effects.items()},
            "difficulty": self.difficulty.to_dict(),
        }

    @classmethod
    def from_file(cls, name: str) -> WorldConfig:
        """A world shipped as ``<name>_world.json`` (in ``sim/data``, else ``core/data``)."""
        return cls.from_dict(load_world_file(name))

    @classmethod
    def paper(cls, difficulty: str = "easy") -> WorldConfig:
        """The paper's world: Tables I, II and IV, 45 training and 15 test objects, perceived
        at one of the file's named ``difficulties`` (:data:`WORLDS`; ``easy`` by default)."""
        data = load_world_file("paper")
        return cls.from_dict({**data, "difficulty": paper_difficulty(difficulty, data).to_dict()})

    @classmethod
    def generic(
        cls,
        n_contexts: int,
        seed: int = 0,
        nouns_per_context: int = 2,
        objects_per_noun: tuple[int, int] = (6, 12),
        test_fraction: float = 0.25,
        difficulty: str = "easy",
    ) -> WorldConfig:
        """A world with any number of contexts, for testing context discovery beyond the paper's three.

        The robot is the paper's (same adjective pairs, verbs and behaviour physics);
        each context takes a theme of ``sim/data/generic_world.json`` (in a seeded
        order; past the listed themes, systematic names ``context_7``...) and its
        first ``nouns_per_context`` nouns. Like the paper's world, nouns belong to one
        context while adjectives and verbs are shared: every context leans towards
        one adjective of some pairs (P(first) = 0.15 or 0.85) and is neutral on others
        (0.5); a noun's count for a pair is binomial around its context's tendency
        (± 0.1 per noun). Behaviours follow the noun's handling class (fragile: grasp
        and move, like cups; rolling: no pushes, like balls; robust: all), as in
        Table II. Prevalent concepts (Table IV) are the nouns plus the adjectives at
        least half of the context's objects carry. ``difficulty`` names one of the robot
        world's difficulty presets (:data:`WORLDS`).
        """
        if not _is_count(n_contexts, 1):
            raise InvalidInputError("n_contexts", f"must be an integer >= 1, got {n_contexts!r}")
        if not _is_count(nouns_per_context, 1):
            raise InvalidInputError("nouns_per_context", f"must be an integer >= 1, got {nouns_per_context!r}")
        low, high = _count_range(objects_per_noun, "objects_per_noun")
        if not 0.0 <= test_fraction < 1.0:
            raise InvalidInputError("test_fraction", f"must be in [0, 1), got {test_fraction!r}")
        rng = _rng(seed, _GENERIC_CONFIG_STREAM)
        template = load_world_file("generic")
        robot = load_world_file(template["robot_from"])
        robot_vocabulary = Vocabulary.from_dict(robot["vocabulary"])
        handling: dict[str, list[str]] = template["handling"]
        themes = [template["themes"][i] for i in rng.permutation(len(template["themes"]))]
        contexts: list[ContextSpec] = []
        shapes: dict[str, str] = {}
        applicability: dict[str, tuple[str, ...]] = {}
        counts: dict[str, dict[str, int]] = {}
        sizes: dict[str, int] = {}
        for index in range(n_contexts):
            theme: Mapping[str, Any] = (
                themes[index] if index < len(themes) else {"context": f"context_{index + 1}", "nouns": []}
            )
            nouns = _theme_nouns(theme, nouns_per_context, index)
            tendency = {
                pair: float(rng.choice([0.15, 0.5, 0.85], p=[0.35, 0.3, 0.35]))
                for pair in robot_vocabulary.adjective_pairs
            }
            for noun in nouns:
                name = noun["name"]
                shapes[name] = noun["shape"]
                applicability[name] = tuple(handling[noun["handling"]])
                sizes[name] = size = int(rng.integers(low, high + 1))
                counts[name] = {}
                for pair, p_first in tendency.items():
                    first = int(rng.binomial(size, float(np.clip(p_first + rng.normal(0.0, 0.1), 0.02, 0.98))))
                    counts[name].update({pair[0]: first, pair[1]: size - first})
            context_nouns = tuple(noun["name"] for noun in nouns)
            objects = sum(sizes[noun] for noun in context_nouns)
            # Prevalent: the nouns, and every adjective at least half of the context's objects carry.
            common = tuple(
                a for a in robot_vocabulary.adjectives if 2 * sum(counts[n][a] for n in context_nouns) >= objects
            )
            contexts.append(ContextSpec(theme["context"], context_nouns, context_nouns + common))
        vocabulary = Vocabulary(
            nouns=tuple(sizes), adjective_pairs=robot_vocabulary.adjective_pairs, verbs=robot_vocabulary.verbs
        )
        total = sum(sizes.values())
        n_test = round(test_fraction * total)
        return cls(
            name=f"generic-{n_contexts}-seed{seed}",
            vocabulary=vocabulary,
            noun_adjective_counts=counts,
            applicability=applicability,
            contexts=tuple(contexts),
            n_train=total - n_test,
            n_test=n_test,
            shapes=shapes,
            behaviour_effects={verb: BehaviourEffect.from_dict(e) for verb, e in robot["behaviour_effects"].items()},
            difficulty=paper_difficulty(difficulty, robot),
        )


def _theme_nouns(theme: Mapping[str, Any], wanted: int, index: int) -> list[dict[str, str]]:
    """The theme's first nouns, topped up with systematic ones (shapes and handling in turn)."""
    nouns = [dict(noun) for noun in theme["nouns"][:wanted]]
    handling_cycle = ("robust", "rolling", "fragile")
    for extra in range(len(nouns), wanted):
        nouns.append(
            {
                "name": f"{theme['context']}_object_{extra + 1}",
                "shape": PRIMITIVES[(index + extra) % len(PRIMITIVES)],
                "handling": handling_cycle[(index + extra) % len(handling_cycle)],
            }
        )
    return nouns


def _count_range(value: int | tuple[int, int], field_name: str) -> tuple[int, int]:
    """An inclusive (low, high) range of counts >= 1, from one count or a pair."""
    low: object
    high: object
    if isinstance(value, (int, np.integer)):
        low = high = value  # a bool or a count below 1 too: refused below
    else:
        try:
            low, high = value
        except (TypeError, ValueError):
            low = high = None
    if not (_is_count(low, 1) and _is_count(high, low)):
        raise InvalidInputError(
            field_name, f"must be an integer >= 1 or a (low, high) range with 1 <= low <= high, got {value!r}"
        )
    return int(low), int(high)


@dataclass(frozen=True)
class WorldObject:
    """One labelled object (§II-A): a noun, one adjective per pair (in pair order), its split,
    and the behaviours applicable to it (Table II, in verb order)."""

    object_id: str
    noun: str
    adjectives: tuple[str, ...]
    split: str
    behaviours: tuple[str, ...]

    @property
    def concepts(self) -> tuple[str, ...]:
        """The object's noun and adjective concepts."""
        return (self.noun, *self.adjectives)


def make_objects(config: WorldConfig, seed: int | np.random.Generator = 0) -> tuple[WorldObject, ...]:
    """The labelled objects of a world, whose noun x adjective counts equal Table I exactly.

    Table I fixes, for each noun, how many of its objects carry each adjective of a
    pair, not which objects do: each pair's labels are dealt to the noun's objects
    as an independent random permutation. The test split is stratified by noun:
    noun ``k`` gets ``n_test * N_k / N`` test objects rounded by largest remainder
    (ties broken at random), and its test objects are drawn uniformly among its own.
    Objects are ordered by noun (vocabulary order) then index; ids are ``<noun>_<index>``.
    """
    rng = _rng(seed, _OBJECTS_STREAM)
    vocabulary = config.vocabulary
    per_noun = config.objects_per_noun
    test_quota = _largest_remainder(per_noun, config.n_test, rng)
    objects: list[WorldObject] = []
    for noun in vocabulary.nouns:
        size = per_noun[noun]
        row = config.noun_adjective_counts[noun]
        labels = [
            rng.permutation([first] * row[first] + [second] * row[second])
            for first, second in vocabulary.adjective_pairs
        ]
        is_test = np.zeros(size, dtype=bool)
        is_test[rng.choice(size, size=test_quota[noun], replace=False)] = True
        behaviours = tuple(verb for verb in vocabulary.verbs if verb in config.applicability[noun])
        width = max(2, len(str(size)))
        for i in range(size):
            objects.append(
                WorldObject(
                    object_id=f"{noun}_{i:0{width}d}",
                    noun=noun,
                    adjectives=tuple(str(column[i]) for column in labels),
                    split=TEST if is_test[i] else TRAIN,
                    behaviours=behaviours,
                )
            )
    return tuple(objects)


def _largest_remainder(sizes: Mapping[str, float], total: int, rng: np.random.Generator) -> dict[str, int]:
    """Split ``total`` over the keys in proportion to ``sizes`` (Hamilton's method, random tie order)."""
    grand = sum(sizes.values())
    exact = {key: total * size / grand for key, size in sizes.items()}
    quota = {key: math.floor(value) for key, value in exact.items()}
    order = list(sizes)
    tie_break = rng.permutation(len(order))
    ranked = sorted(range(len(order)), key=lambda i: (-(exact[order[i]] - quota[order[i]]), tie_break[i]))
    for i in ranked[: total - sum(quota.values())]:
        quota[order[i]] += 1
    return quota


@dataclass(frozen=True)
class Scene:
    """A scene (§V): its objects, each object's true context, and the true context proportions."""

    objects: tuple[WorldObject, ...]
    object_contexts: tuple[str, ...]
    mixture: dict[str, float]

    def tokens(self, with_verbs: bool = True) -> list[str]:
        """The scene as a bag of concepts (an LDA document, Table V): per object its noun, its
        adjectives and, ``with_verbs``, the verb of every behaviour applicable to it.

        Verbs come from applicability (Table II), not from recognition: a behaviour the
        robot may perform on an object is evidence of the object's kind, which is what
        the concept web would activate; ``with_verbs=False`` gives nouns and adjectives
        only. The choice matters for Algorithm 2's stopping rule (docs/world.md, "Scenes").
        """
        tokens: list[str] = []
        for obj in self.objects:
            tokens.extend(obj.concepts)
            if with_verbs:
                tokens.extend(obj.behaviours)
        return tokens

    @property
    def is_mixed(self) -> bool:
        return len(self.mixture) > 1


@dataclass(frozen=True)
class SceneSpec:
    """A scene described by its nouns (Table VI): ``nouns`` counts, ``mixture`` the true
    context proportions, ``paper_prediction`` what the paper's model predicted."""

    name: str
    nouns: dict[str, int]
    mixture: dict[str, float]
    paper_prediction: dict[str, float]

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> SceneSpec:
        return cls(
            name=str(data["name"]),
            nouns={noun: int(count) for noun, count in data["nouns"].items()},
            mixture={context: float(p) for context, p in data["mixture"].items()},
            paper_prediction={context: float(p) for context, p in data.get("paper_prediction", {}).items()},
        )


def table_vi_scenes() -> tuple[SceneSpec, ...]:
    """The six scenes of Table VI: three pure, three mixed, with their true proportions."""
    return tuple(SceneSpec.from_dict(spec) for spec in load_world_file("paper")["table_vi_scenes"])


def _config_and_objects(
    config_or_world: WorldConfig | World, seed: int | np.random.Generator, objects: Sequence[WorldObject] | None
) -> tuple[WorldConfig, tuple[WorldObject, ...]]:
    if isinstance(config_or_world, World):
        config, pool = config_or_world.config, config_or_world.objects
    elif isinstance(config_or_world, WorldConfig):
        config = config_or_world
        pool = make_objects(config, seed) if objects is None else ()
    else:
        raise InvalidInputError("world", f"expected a WorldConfig or a World, got {type(config_or_world).__name__}")
    if objects is not None:
        pool = tuple(objects)
        if not pool:
            raise InvalidInputError("objects", "the object pool is empty")
        unknown = sorted({obj.noun for obj in pool} - set(config.vocabulary.nouns))
        if unknown:
            raise InvalidInputError("objects", f"objects of nouns {unknown} are not in world {config.name!r}")
    return config, pool


def _draw(pool: Sequence[WorldObject], count: int, rng: np.random.Generator, what: str) -> list[WorldObject]:
    """``count`` distinct objects of the pool; when the pool is smaller, all of it plus repeats
    drawn with replacement (a small test pool must still fill a Table VI scene)."""
    if not pool:
        raise InvalidInputError("objects", f"the object pool has no {what}")
    chosen = list(rng.choice(len(pool), size=min(count, len(pool)), replace=False))
    chosen += list(rng.integers(0, len(pool), size=count - len(chosen)))
    return [pool[i] for i in chosen]


def _scene(parts: Sequence[tuple[str, WorldObject]], rng: np.random.Generator) -> Scene:
    order = rng.permutation(len(parts))
    contexts = tuple(parts[i][0] for i in order)
    counts: dict[str, int] = {}
    for context in contexts:
        counts[context] = counts.get(context, 0) + 1
    mixture = {context: count / len(contexts) for context, count in counts.items()}
    return Scene(objects=tuple(parts[i][1] for i in order), object_contexts=contexts, mixture=mixture)


def _validate_mixture(config: WorldConfig, mixture: Mapping[str, float]) -> dict[str, float]:
    if not mixture:
        raise InvalidInputError("mixture", "needs at least one context")
    for context, share in mixture.items():
        config.context(context)
        if isinstance(share, bool) or not (isinstance(share, (int, float)) and 0.0 < share <= 1.0):
            raise InvalidInputError(f"mixture.{context}", f"must be a proportion in (0, 1], got {share!r}")
    if abs(sum(mixture.values()) - 1.0) > 1e-6:
        raise InvalidInputError("mixture", f"proportions must sum to 1, got {sum(mixture.values())!r}")
    return dict(mixture)


def generate_scenes(
    config_or_world: WorldConfig | World,
    n_scenes: int,
    seed: int | np.random.Generator = 0,
    objects: Sequence[WorldObject] | None = None,
    contexts: Sequence[str] | None = None,
    objects_per_scene: int | tuple[int, int] = (3, 5),
    mixture: Mapping[str, float] | None = None,
) -> tuple[Scene, ...]:
    """Scenes as in §V: a pure scene picks a context uniformly (among ``contexts``, default all)
    and then 3-5 (``objects_per_scene``, inclusive) random objects of the pool (default every
    object of the world) whose noun occurs in that context. With ``mixture`` every scene is
    mixed: its objects are split over the contexts in those proportions by largest remainder
    (e.g. {"playroom": 2/3, "workshop": 1/3} with 6 objects gives 4 + 2, Table VI).
    Objects within a scene are distinct unless the context's pool is too small.
    """
    if not _is_count(n_scenes):
        raise InvalidInputError("n_scenes", f"must be an integer >= 0, got {n_scenes!r}")
    config, pool = _config_and_objects(config_or_world, seed, objects)
    low, high = _count_range(objects_per_scene, "objects_per_scene")
    rng = _rng(seed, _SCENES_STREAM)
    shares = _validate_mixture(config, mixture) if mixture is not None else None
    names = tuple(shares or (contexts if contexts is not None else (c.name for c in config.contexts)))
    if not names:
        raise InvalidInputError("contexts", "needs at least one context to draw scenes from")
    by_context = {name: [obj for obj in pool if obj.noun in config.context(name).nouns] for name in names}
    scenes = []
    for _ in range(n_scenes):
        size = int(rng.integers(low, high + 1))
        if shares is not None:
            allocation = _largest_remainder(shares, size, rng)
        else:
            allocation = {names[int(rng.integers(len(names)))]: size}
        parts = [
            (context, obj)
            for context, count in allocation.items()
            if count
            for obj in _draw(by_context[context], count, rng, f"object of context {context!r}")
        ]
        scenes.append(_scene(parts, rng))
    return tuple(scenes)


def scene_from_nouns(
    config_or_world: WorldConfig | World,
    nouns: Mapping[str, int] | SceneSpec,
    seed: int | np.random.Generator = 0,
    objects: Sequence[WorldObject] | None = None,
) -> Scene:
    """A scene with exactly these noun counts (e.g. Table VI's "2 cups, 2 plates"), objects drawn
    from the pool (default every object). Each noun must belong to exactly one context."""
    config, pool = _config_and_objects(config_or_world, seed, objects)
    counts = nouns.nouns if isinstance(nouns, SceneSpec) else dict(nouns)
    if not counts or sum(counts.values()) < 1:
        raise InvalidInputError("nouns", "a scene needs at least one object")
    rng = _rng(seed, _NOUN_SCENE_STREAM)
    parts: list[tuple[str, WorldObject]] = []
    for noun, count in counts.items():
        if noun not in config.vocabulary.nouns:
            raise InvalidInputError("nouns", f"unknown noun {noun!r}")
        if not _is_count(count):
            raise InvalidInputError(f"nouns.{noun}", f"must be a count >= 0, got {count!r}")
        homes = config.contexts_of(noun)
        if len(homes) != 1:
            raise InvalidInputError(f"nouns.{noun}", f"must belong to exactly one context, belongs to {list(homes)}")
        candidates = [obj for obj in pool if obj.noun == noun]
        parts += [(homes[0], obj) for obj in _draw(candidates, int(count), rng, f"{noun!r}")] if count else []
    return _scene(parts, rng)


class World:
    """A world made concrete from a seed: its objects, their physical bodies, and recordings."""

    def __init__(self, config: WorldConfig, seed: int = 0) -> None:
        _rng(seed)
        self.config = config
        self.seed = int(seed)
        self.objects = make_objects(config, seed)
        self._index = {obj.object_id: i for i, obj in enumerate(self.objects)}
        self._bodies: dict[str, ObjectBody] = {}

    @classmethod
    def paper(cls, seed: int = 0, difficulty: str = "easy") -> World:
        return cls(WorldConfig.paper(difficulty), seed)

    @classmethod
    def generic(cls, n_contexts: int, seed: int = 0, **options: Any) -> World:
        return cls(WorldConfig.generic(n_contexts, seed, **options), seed)

    @property
    def vocabulary(self) -> Vocabulary:
        return self.config.vocabulary

    @property
    def train_objects(self) -> tuple[WorldObject, ...]:
        return tuple(obj for obj in self.objects if obj.split == TRAIN)

    @property
    def test_objects(self) -> tuple[WorldObject, ...]:
        return tuple(obj for obj in self.objects if obj.split == TEST)

    def object(self, object_id: str) -> WorldObject:
        try:
            return self.objects[self._index[object_id]]
        except KeyError:
            raise InvalidInputError("object_id", f"no object {object_id!r} in world {self.config.name!r}") from None

    def body(self, obj: WorldObject | str) -> ObjectBody:
        """The object's physical body: drawn once from the world seed, the same in every recording."""
        obj = self._own(obj)
        if obj.object_id not in self._bodies:
            rng = _rng(self.seed, _BODY_STREAM, self._index[obj.object_id])
            self._bodies[obj.object_id] = make_body(
                self.config.primitive(obj.noun), obj.adjectives, rng, self.config.difficulty
            )
        return self._bodies[obj.object_id]

    def record(self, obj: WorldObject | str, rng: np.random.Generator | int) -> ObjectRecording:
        """What the robot senses of one object (§II-C): a look plus one interaction per applicable behaviour."""
        obj = self._own(obj)
        return record_object(
            self.body(obj), obj.behaviours, self.config.behaviour_effects, _rng(rng), self.config.difficulty
        )

    def recordings(self, objects: Sequence[WorldObject] | None = None, seed: int = 0) -> dict[str, ObjectRecording]:
        """Recordings of many objects (default all), each from its own stream of ``seed``, so an
        object's recording does not depend on which others are recorded with it."""
        chosen = self.objects if objects is None else tuple(objects)
        _rng(seed)
        return {
            obj.object_id: self.record(obj, _rng(seed, _RECORDING_STREAM, self._index[self._own(obj).object_id]))
            for obj in chosen
        }

    def scenes(self, n_scenes: int, seed: int | np.random.Generator = 0, **options: Any) -> tuple[Scene, ...]:
        """:func:`generate_scenes` over this world's objects."""
        return generate_scenes(self, n_scenes, seed, **options)

    def _own(self, obj: WorldObject | str) -> WorldObject:
        found = self.object(obj if isinstance(obj, str) else obj.object_id)
        if not isinstance(obj, str) and found != obj:
            raise InvalidInputError("object", f"{obj.object_id!r} is not this world's object of that id")
        return found
