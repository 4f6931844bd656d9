"""An object's evidence for its concept web: the perception P(c) over the vocabulary, and which
concepts carry evidence (Fig. 6(b), step 1).

- A **named** object (the concept level): a named concept is certain (1.0) and so
  is the absence of its rivals (the other nouns, the opposite adjective); a
  name → probability map is taken as given, the nouns or a pair completed so that
  they sum to 1; concepts not mentioned carry no evidence (0.5; a verb not
  mentioned is a behaviour not applied). Names outside the vocabulary are kept
  apart (``unseen``).
- A **measured** object (features, or raw payloads turned into features): the
  prototypes' perception (Eq. 1, ``core.prototypes.perceive_many``); every noun
  and adjective carries evidence, and the verbs whose behaviour was applied
  (``core.concept_web.active.carries_evidence``).
"""

from __future__ import annotations

import functools
from collections.abc import Collection, Mapping
from dataclasses import dataclass
from typing import Literal

import numpy as np

from core.concept_web.active import carries_evidence
from core.prototypes.perception import NO_EVIDENCE
from core.vocabulary import Vocabulary

#: How an object was given: by its concepts, by Table III's feature vectors, or by raw payloads.
ObjectLevel = Literal["concepts", "features", "raw"]


@dataclass(frozen=True)
class ObjectEvidence:
    """Perception over the vocabulary (``probabilities``), which concepts carry evidence
    (``informed``), which behaviours were applied (``applied``, in ``vocabulary.verbs`` order) and
    the names outside the vocabulary with their probabilities (``unseen``, concept level only)."""

    level: ObjectLevel
    probabilities: np.ndarray
    informed: np.ndarray
    applied: np.ndarray
    unseen: Mapping[str, float]


def measured_evidence(
    vocabulary: Vocabulary, level: ObjectLevel, probabilities: np.ndarray, behaviours: Collection[str]
) -> ObjectEvidence:
    """A measured object's evidence: its perception and the ``behaviours`` applied to it."""
    applied = np.array([verb in behaviours for verb in vocabulary.verbs], dtype=bool)
    return ObjectEvidence(level, probabilities, carries_evidence(vocabulary, applied), applied, {})


@dataclass(frozen=True)
class _Layout:
    """Where each concept sits: its column, and its group (the nouns, one adjective pair; -1 for a verb)."""

    column: dict[str, int]
    group: np.ndarray
    group_size: np.ndarray
    verbs: slice


@functools.lru_cache(maxsize=64)
def _layout(vocabulary: Vocabulary) -> _Layout:
    n_nouns, n_pairs = len(vocabulary.nouns), len(vocabulary.adjective_pairs)
    group = np.concatenate(
        [np.zeros(n_nouns, int), np.repeat(np.arange(1, n_pairs + 1), 2), np.full(len(vocabulary.verbs), -1)]
    )
    return _Layout(
        column={name: i for i, name in enumerate(vocabulary.concepts)},
        group=group,
        group_size=np.bincount(group[group >= 0], minlength=n_pairs + 1),
        verbs=slice(n_nouns + 2 * n_pairs, len(vocabulary)),
    )


@functools.lru_cache(maxsize=4096)
def named_evidence(vocabulary: Vocabulary, named_probabilities: tuple[tuple[str, float], ...]) -> ObjectEvidence:
    """Perception of a named object: the nouns and each pair named in completed to a distribution.

    In a group (the nouns, or one pair) with a name given, the unnamed members
    share what the named ones leave, and a total above 1 is rescaled; the groups
    named carry evidence, and the verbs named are the behaviours applied. A pure
    function of the names (and probabilities) given, which a robot's scenes
    repeat: it is memoised, its arrays read-only.
    """
    given = dict(named_probabilities)
    layout = _layout(vocabulary)
    probabilities = np.full(len(vocabulary), NO_EVIDENCE)
    named = np.zeros(len(vocabulary), dtype=bool)
    unseen: dict[str, float] = {}
    for name, value in given.items():
        column = layout.column.get(name)
        if column is None:
            unseen[name] = float(value)
        else:
            probabilities[column], named[column] = value, True
    group, n_groups = layout.group, len(layout.group_size)
    grouped = group >= 0
    group_named = np.bincount(group[grouped & named], minlength=n_groups) > 0
    informed = np.where(grouped, group_named[np.maximum(group, 0)], named)
    if group_named.any():
        named_mass = np.bincount(group[grouped & named], weights=probabilities[grouped & named], minlength=n_groups)
        unnamed = np.bincount(group[grouped & ~named], minlength=n_groups)
        share = np.maximum(0.0, 1.0 - named_mass) / np.maximum(unnamed, 1)
        filled = grouped & informed & ~named
        probabilities[filled] = share[group[filled]]
        members = grouped & informed
        totals = np.bincount(group[members], weights=probabilities[members], minlength=n_groups)[group[members]]
        uniform = 1.0 / layout.group_size[group[members]]
        probabilities[members] = np.where(
            totals > 0, probabilities[members] / np.where(totals > 0, totals, 1.0), uniform
        )
    evidence = ObjectEvidence("concepts", probabilities, informed, named[layout.verbs].copy(), unseen)
    for array in (evidence.probabilities, evidence.informed, evidence.applied):
        array.flags.writeable = False
    return evidence
