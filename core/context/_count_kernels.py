"""Numba kernels that rebuild the Incremental-LDA count tables from the assignments, or take
the last online update back out of them.

A start of a long-lived model rebuilds n_wk, n_k and n_dk (Eq. 5's counts) from the
checkpointed assignments of every token. ``np.bincount`` over ``words * K + z`` does it too,
but builds int64 temporaries of the corpus's length (about 600 MB each at a million scenes of
78 tokens): these single passes write straight into the count tables.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def fill_token_scenes(offsets: np.ndarray, token_scene: np.ndarray) -> None:
    """``token_scene[i] = d`` for every token i of scene d (``offsets``: CSR scene offsets)."""
    for scene in range(offsets.shape[0] - 1):
        for token in range(offsets[scene], offsets[scene + 1]):
            token_scene[token] = scene


@numba.njit(cache=True, nogil=True)
def count_assignments(
    words: np.ndarray,
    assignments: np.ndarray,
    token_scene: np.ndarray,
    n_wk: np.ndarray,
    n_k: np.ndarray,
    n_dk: np.ndarray,
) -> None:
    """Add every assigned token (context ≥ 0) to n_wk[w, k], n_k[k] and n_dk[d, k]; the tables
    must be zero where the counts go. Unassigned tokens (context −1) are skipped."""
    for token in range(words.shape[0]):
        context = assignments[token]
        if context < 0:
            continue
        n_wk[words[token], context] += 1
        n_k[context] += 1
        n_dk[token_scene[token], context] += 1


@numba.njit(cache=True, nogil=True)
def remove_scene(
    moved: np.ndarray,
    contexts_before: np.ndarray,
    scene: int,
    offsets: np.ndarray,
    words: np.ndarray,
    z: np.ndarray,
    token_scene: np.ndarray,
    n_wk: np.ndarray,
    n_k: np.ndarray,
    n_dk: np.ndarray,
) -> None:
    """The inverse of an online update of the last ``scene``: each earlier token ``moved[j]``
    returns to context ``contexts_before[j]`` (−1: unassigned), then the scene's own tokens leave
    n_wk, n_k and n_dk (their z and words stay as garbage past the corpus's end)."""
    for j in range(moved.shape[0]):
        token = moved[j]
        word, document, now, before = words[token], token_scene[token], z[token], contexts_before[j]
        if now >= 0:
            n_wk[word, now] -= 1
            n_k[now] -= 1
            n_dk[document, now] -= 1
        if before >= 0:
            n_wk[word, before] += 1
            n_k[before] += 1
            n_dk[document, before] += 1
        z[token] = before
    for token in range(offsets[scene], offsets[scene + 1]):
        context = z[token]
        if context >= 0:
            n_wk[words[token], context] -= 1
            n_k[context] -= 1
            n_dk[scene, context] -= 1
