"""Context-dependent pruning of behaviours (§V-E, Fig. 15).

In context χ the planner refrains from expanding behaviours that are
inappropriate there. Which ones is learned, not listed: it comes from
P(verb | χ), the verb part of the context's concept distribution, which the
context model learns from scenes whose objects carry the behaviours applied to
them (Table II's applicability shows through as verb tokens).

**Rule.** A behaviour is pruned in χ when

    P(v | χ) < θ · max_v' P(v' | χ),        θ = :data:`PRUNING_THRESHOLD` = 0.75.

Why relative to the context's most probable verb: an absolute probability
depends on how many verbs the context has (13 applicable verbs share the mass
more thinly than 5), while the ratio reads as "the share of the context's
objects this behaviour is safe for", the behaviours applicable to every object
of the context having ratio 1. Why θ = 0.75: pushes are applicable to boxes but
not to balls, so in the Playroom their ratio is the boxes' share of the
context's objects (≈ 0.5 when both are equally frequent, 16/26 ≈ 0.62 with
Table I's counts); the planner should refrain from a behaviour that is unsafe
for a substantial part of the context ("pushing a ball causes it to roll down
from the table"), yet keep, in the Workshop, behaviours whose learned
probabilities differ a little from the maximum by sampling noise. Any θ in
(0.62, ~0.9) gives the paper's 5 / 9 / 13 behaviours; 0.75 sits in the middle.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from core.errors import InvalidInputError
from core.vocabulary import load_world_file

#: θ of the pruning rule (module docstring).
PRUNING_THRESHOLD = 0.75


@dataclass(frozen=True)
class Pruning:
    """Kept and pruned behaviours of one context, with each verb's P(v | χ) / max P(· | χ)."""

    kept: tuple[str, ...]
    pruned: tuple[str, ...]
    relative: dict[str, float]
    threshold: float


def _as_distribution(
    verb_given_context: Mapping[str, float] | np.ndarray, behaviours: Sequence[str] | None
) -> dict[str, float]:
    if isinstance(verb_given_context, Mapping):
        names, values = list(verb_given_context), list(verb_given_context.values())
    else:
        if behaviours is None:
            raise InvalidInputError(
                "behaviours", "an array of P(verb | context) needs the behaviour names it is aligned with"
            )
        names, values = list(behaviours), list(np.asarray(verb_given_context, dtype=float).ravel())
        if len(names) != len(values):
            raise InvalidInputError("behaviours", f"{len(names)} names for {len(values)} probabilities")
    if not names:
        raise InvalidInputError("verb_given_context", "is empty")
    probabilities = np.asarray(values, dtype=float)
    if not np.all(np.isfinite(probabilities)) or np.any(probabilities < 0):
        raise InvalidInputError("verb_given_context", "probabilities must be finite and non-negative")
    if probabilities.max() <= 0:
        raise InvalidInputError(
            "verb_given_context", "every verb has probability 0; the context says nothing about its verbs"
        )
    return dict(zip(names, probabilities.tolist(), strict=True))


def prune_behaviours(
    verb_given_context: Mapping[str, float] | np.ndarray,
    threshold: float = PRUNING_THRESHOLD,
    *,
    behaviours: Sequence[str] | None = None,
) -> Pruning:
    """Split behaviours into kept and pruned by P(v | χ) ≥ θ · max P(· | χ) (module docstring).

    ``verb_given_context`` is a verb → probability mapping, or an array aligned
    with ``behaviours``; it need not be normalised (only ratios matter).
    """
    if not (np.isfinite(threshold) and 0 < threshold <= 1):
        raise InvalidInputError("threshold", f"must be in (0, 1], got {threshold!r}")
    distribution = _as_distribution(verb_given_context, behaviours)
    peak = max(distribution.values())
    relative = {verb: p / peak for verb, p in distribution.items()}
    kept = tuple(verb for verb, r in relative.items() if r >= threshold)
    pruned = tuple(verb for verb, r in relative.items() if r < threshold)
    return Pruning(kept, pruned, relative, float(threshold))


def verb_given_context_from_model(
    concept_given_context: np.ndarray, concepts: Sequence[str], verbs: Sequence[str]
) -> np.ndarray:
    """P(verb | χ) (K, |verbs|) from the context model's P(concept | χ) (K, V) over ``concepts``.

    The verb columns, renormalised within each context.
    """
    phi = np.asarray(concept_given_context, dtype=float)
    names = list(concepts)
    if phi.ndim != 2 or phi.shape[1] != len(names):
        raise InvalidInputError("concept_given_context", f"must have shape (K, {len(names)}), got {phi.shape}")
    missing = [verb for verb in verbs if verb not in names]
    if missing:
        raise InvalidInputError("verbs", f"not among the model's concepts: {missing}")
    columns = phi[:, [names.index(verb) for verb in verbs]]
    totals = columns.sum(axis=1, keepdims=True)
    if np.any(totals <= 0):
        raise InvalidInputError("concept_given_context", "a context gives its verbs no probability at all")
    return columns / totals


def verb_given_context_from_scenes(
    scenes: Sequence[Sequence[str]],
    context_labels: Sequence[str],
    verbs: Sequence[str],
    *,
    applicability: Mapping[str, Sequence[str]] | None = None,
) -> dict[str, dict[str, float]]:
    """P(verb | χ) as relative frequencies of verb tokens in the scenes labelled χ.

    Scenes are concept-token lists. Without ``applicability`` the verb tokens are
    counted; with it (noun → applicable verbs), each noun token stands for its
    applicable verbs, for scenes whose tokens carry no verbs.
    """
    if len(scenes) != len(context_labels):
        raise InvalidInputError(
            "context_labels", f"needs one label per scene: {len(context_labels)} labels, {len(scenes)} scenes"
        )
    verb_index = {verb: j for j, verb in enumerate(verbs)}
    counts: dict[str, np.ndarray] = {}
    for tokens, label in zip(scenes, context_labels, strict=True):
        row = counts.setdefault(label, np.zeros(len(verb_index)))
        for token in tokens:
            if applicability is not None:
                for verb in applicability.get(token, ()):
                    if verb not in verb_index:
                        raise InvalidInputError("applicability", f"{token!r} lists unknown verb {verb!r}")
                    row[verb_index[verb]] += 1
            elif token in verb_index:
                row[verb_index[token]] += 1
    empty = [label for label, row in counts.items() if row.sum() == 0]
    if empty:
        raise InvalidInputError("scenes", f"no verb evidence in the scenes of context(s) {empty}")
    return {label: dict(zip(verbs, (row / row.sum()).tolist(), strict=True)) for label, row in counts.items()}


def verb_given_context_from_world(
    world: dict[str, Any] | None = None,
    noun_weights: Mapping[str, float] | None = None,
) -> dict[str, dict[str, float]]:
    """P(verb | χ) ∝ Σ_n P(n | χ) [verb applicable to n] over each context's prevalent nouns.

    The world file's applicability (Table II) and contexts; nouns are equally
    likely within a context unless ``noun_weights`` says otherwise.
    """
    world = load_world_file("paper") if world is None else world
    verbs = list(world["vocabulary"]["verbs"])
    applicability = world["applicability"]
    out: dict[str, dict[str, float]] = {}
    for context, spec in world["contexts"].items():
        weights = {noun: 1.0 if noun_weights is None else float(noun_weights.get(noun, 0.0)) for noun in spec["nouns"]}
        row = np.zeros(len(verbs))
        for noun, weight in weights.items():
            for verb in applicability[noun]:
                row[verbs.index(verb)] += weight
        if row.sum() <= 0:
            raise InvalidInputError("noun_weights", f"context {context!r} has no weighted noun")
        out[context] = dict(zip(verbs, (row / row.sum()).tolist(), strict=True))
    return out
