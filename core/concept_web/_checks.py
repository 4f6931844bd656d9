"""Input validation for the concept web: every failure is an InvalidInputError naming its field."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from core.errors import InvalidInputError
from core.vocabulary import Vocabulary


def real(
    value: Any, field: str, *, low: float, high: float = np.inf, low_open: bool = False, high_open: bool = False
) -> float:
    """A finite real number inside the interval given."""
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float, np.integer, np.floating))
        or not np.isfinite(value)
    ):
        raise InvalidInputError(field, f"expected a finite number, got {value!r}")
    below = value <= low if low_open else value < low
    above = value >= high if high_open else value > high
    if below or above:
        left, right = "(" if low_open else "[", ")" if high_open else "]"
        raise InvalidInputError(field, f"must lie in {left}{low}, {high}{right}, got {value!r}")
    return float(value)


def count(value: Any, field: str, *, minimum: int) -> int:
    """An integer of at least ``minimum``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise InvalidInputError(field, f"expected an integer >= {minimum}, got {value!r}")
    return int(value)


def numeric_array(value: Any, field: str) -> np.ndarray:
    """``value`` as a float64 array, refusing strings, objects and ragged lists."""
    try:
        array = np.asarray(value)
    except (TypeError, ValueError):
        array = None
    if array is None or array.dtype.kind not in "biuf":
        raise InvalidInputError(field, "expected a numeric array")
    return array.astype(np.float64)


def vocabulary(value: Any) -> Vocabulary:
    if not isinstance(value, Vocabulary):
        raise InvalidInputError("vocabulary", f"expected a Vocabulary, got {type(value).__name__}")
    return value


def probabilities(value: Any, field: str, shape: tuple[int | str, ...]) -> np.ndarray:
    """Perception probabilities of the given shape (a str entry is any length), finite and in [0, 1]."""
    array = numeric_array(value, field)
    if array.ndim != len(shape) or any(isinstance(n, int) and n != m for n, m in zip(shape, array.shape)):
        raise InvalidInputError(field, f"expected shape {shape}, got {array.shape}")
    if not np.isfinite(array).all():
        raise InvalidInputError(field, "probabilities must be finite (no NaN or infinity)")
    if (array < 0.0).any() or (array > 1.0).any():
        raise InvalidInputError(field, "probabilities must lie in [0, 1]")
    return array


def applied_mask(value: Any, shape: tuple[int, ...]) -> np.ndarray:
    """A bool mask of the verbs whose behaviour was applied."""
    mask = np.asarray(value)
    if mask.dtype != np.bool_ or mask.shape != shape:
        raise InvalidInputError(
            "applied", f"expected a bool array of shape {shape} (one entry per verb), got {mask.dtype} {mask.shape}"
        )
    return mask


def configuration_matrix(vocab: Vocabulary, configurations: Any) -> np.ndarray:
    """Training configurations as an (n_objects, n_concepts) bool matrix.

    Every object needs exactly one noun and exactly one adjective of every pair
    (the paper's labelling, §II-A); any set of verbs may be active.
    """
    n_concepts = len(vocab.concepts)
    if isinstance(configurations, np.ndarray):
        if configurations.ndim != 2 or configurations.shape[1] != n_concepts:
            raise InvalidInputError(
                "configurations", f"expected shape (n_objects, {n_concepts}), got {configurations.shape}"
            )
        if not np.isin(configurations, (0, 1)).all():
            raise InvalidInputError("configurations", "array entries must be 0 or 1")
        active = configurations.astype(np.bool_)
    elif isinstance(configurations, Sequence) and not isinstance(configurations, str):
        active = np.zeros((len(configurations), n_concepts), dtype=np.bool_)
        for row, names in enumerate(configurations):
            if isinstance(names, str) or not isinstance(names, Sequence) or not all(isinstance(n, str) for n in names):
                raise InvalidInputError(f"configurations[{row}]", "expected a list of concept names")
            for name in names:
                if name not in vocab:
                    raise InvalidInputError(f"configurations[{row}]", f"unknown concept {name!r}")
                active[row, vocab.index(name)] = True
    else:
        raise InvalidInputError("configurations", "expected a list of concept-name lists or a 0/1 array")
    if active.shape[0] == 0:
        raise InvalidInputError("configurations", "the training set is empty: the web needs at least one object")
    groups = [("noun", vocab.nouns)] + [(f"adjective of {a}/{b}", (a, b)) for a, b in vocab.adjective_pairs]
    for label, names in groups:
        columns = [vocab.index(name) for name in names]
        wrong = np.flatnonzero(active[:, columns].sum(axis=1) != 1)
        if wrong.size:
            row = int(wrong[0])
            found = [name for name, column in zip(names, columns) if active[row, column]]
            raise InvalidInputError(f"configurations[{row}]", f"needs exactly one {label}, found {found}")
    return active


def cooccurrence(value: Any, vocab: Vocabulary, n_objects: int) -> np.ndarray:
    """A symmetric non-negative integer count matrix consistent with ``n_objects``."""
    n_concepts = len(vocab.concepts)
    counts = numeric_array(value, "cooccurrence")
    if counts.shape != (n_concepts, n_concepts):
        raise InvalidInputError("cooccurrence", f"expected shape ({n_concepts}, {n_concepts}), got {counts.shape}")
    if not np.isfinite(counts).all() or (counts < 0).any() or (counts != np.round(counts)).any():
        raise InvalidInputError("cooccurrence", "counts must be non-negative integers")
    if (counts != counts.T).any():
        raise InvalidInputError("cooccurrence", "the co-occurrence matrix must be symmetric")
    diagonal = counts.diagonal()
    # Inclusion-exclusion: every 2x2 joint count of two concepts must be non-negative.
    if (counts > np.minimum.outer(diagonal, diagonal)).any() or (
        diagonal[:, None] + diagonal[None, :] - counts > n_objects
    ).any():
        raise InvalidInputError(
            "cooccurrence",
            f"inconsistent counts: some joint count of two concepts over {n_objects} objects is negative",
        )
    n_nouns, n_adjectives = len(vocab.nouns), len(vocab.adjectives)
    exclusive = [list(range(n_nouns))] + [[n_nouns + 2 * k, n_nouns + 2 * k + 1] for k in range(n_adjectives // 2)]
    if any(np.triu(counts[np.ix_(group, group)], k=1).any() for group in exclusive):
        raise InvalidInputError("cooccurrence", "two nouns, or both adjectives of a pair, cannot co-occur")
    pair_totals = diagonal[n_nouns : n_nouns + n_adjectives].reshape(-1, 2).sum(axis=1)
    if diagonal[:n_nouns].sum() != n_objects or (pair_totals != n_objects).any():
        raise InvalidInputError(
            "cooccurrence", f"every one of the {n_objects} objects must count one noun and one adjective per pair"
        )
    return counts.astype(np.int64)
