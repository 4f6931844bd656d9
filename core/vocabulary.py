"""The concept vocabulary as data (§III: nouns N, adjective pairs A, verbs V).

The names live in a world file (``core/data/*.json``), never in code: later
worlds add concept kinds and concepts. A :class:`Vocabulary` gives every concept
a stable integer index in the order nouns, adjectives (pair by pair, first then
second), verbs, which is the order of the paper's 29 concept-web nodes.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import cached_property
from importlib import resources
from typing import Any

from core.errors import InvalidInputError

NOUN = "noun"
ADJECTIVE = "adjective"
VERB = "verb"
CONCEPT_KINDS: tuple[str, ...] = (NOUN, ADJECTIVE, VERB)


@dataclass(frozen=True)
class Vocabulary:
    """Nouns, dichotomic adjective pairs and verbs of one world."""

    nouns: tuple[str, ...]
    adjective_pairs: tuple[tuple[str, str], ...]
    verbs: tuple[str, ...]
    _index: dict[str, int] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not self.nouns:
            raise InvalidInputError("vocabulary.nouns", "at least one noun is required")
        for pair in self.adjective_pairs:
            if len(pair) != 2 or pair[0] == pair[1]:
                raise InvalidInputError(
                    "vocabulary.adjective_pairs", f"{pair!r} is not a pair of two distinct adjectives"
                )
        names = self.concepts
        duplicates = sorted({name for name in names if names.count(name) > 1})
        if duplicates:
            raise InvalidInputError("vocabulary", f"concept names must be unique, repeated: {duplicates}")
        object.__setattr__(self, "_index", {name: i for i, name in enumerate(names)})

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Vocabulary:
        return cls(
            nouns=tuple(data["nouns"]),
            adjective_pairs=tuple((a, b) for a, b in data["adjective_pairs"]),
            verbs=tuple(data.get("verbs", ())),
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "nouns": list(self.nouns),
            "adjective_pairs": [list(p) for p in self.adjective_pairs],
            "verbs": list(self.verbs),
        }

    @cached_property
    def adjectives(self) -> tuple[str, ...]:
        return tuple(adjective for pair in self.adjective_pairs for adjective in pair)

    @cached_property
    def concepts(self) -> tuple[str, ...]:
        """All concepts, in node order: nouns, adjectives, verbs."""
        return self.nouns + self.adjectives + self.verbs

    @cached_property
    def kinds(self) -> tuple[str, ...]:
        """The kind of each concept, aligned with :attr:`concepts`."""
        return (NOUN,) * len(self.nouns) + (ADJECTIVE,) * len(self.adjectives) + (VERB,) * len(self.verbs)

    def __len__(self) -> int:
        return len(self.concepts)

    def __contains__(self, name: object) -> bool:
        return name in self._index

    def index(self, name: str) -> int:
        """Node index of a concept; unknown names are an :class:`InvalidInputError`."""
        try:
            return self._index[name]
        except KeyError:
            raise InvalidInputError("concept", f"unknown concept {name!r}") from None

    def kind(self, name: str) -> str:
        return self.kinds[self.index(name)]

    def opposite(self, adjective: str) -> str:
        """The other adjective of a dichotomic pair (hard -> soft)."""
        for first, second in self.adjective_pairs:
            if adjective == first:
                return second
            if adjective == second:
                return first
        raise InvalidInputError("adjective", f"{adjective!r} is not an adjective of this vocabulary")


def load_world_file(name: str = "paper") -> dict[str, Any]:
    """The raw dictionary of a world file shipped in ``core/data`` (``paper`` by default)."""
    text = resources.files("core.data").joinpath(f"{name}_world.json").read_text(encoding="utf-8")
    return json.loads(text)


def paper_vocabulary() -> Vocabulary:
    """The paper's 29 concepts: 6 nouns, 5 adjective pairs, 13 verbs."""
    return Vocabulary.from_dict(load_world_file("paper")["vocabulary"])
