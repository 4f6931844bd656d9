"""Scene-partition evidence: how many contexts the scenes support (the ``"scenes"`` K rule).

A context is a property of a scene (§V: a scene is drawn from one context), so the
number of contexts is judged on partitions of the scenes: every scene's concepts
go to one context, and a partition with K contexts is scored by its collapsed
evidence

    S(K) = Σ_s log P(z_s = one context | α, K)                       (LDA's θ ~ Dir(α))
         + Σ_χ [log DM(n_χ + x_window,χ | β) − log DM(n_χ | β)]       (the window given the rest)
         + log E! / (E − U)!                                           (label permutations)

where DM is the Dirichlet-multinomial of a context's concept counts, n_χ the
counts a context holds from scenes before the window (none in batch), E the
contexts holding none of those and U how many of them the partition uses (the
sum over labellings counts each partition that many times). The best partition
for K and for K + 1 is searched by a scene-level collapsed Gibbs sampler
(:mod:`core.context._partition_kernels`) from the model's own partition, from it
with a badly explained scene moved to the new context, and from random starts.

The prior β on a context's concepts is centred on the corpus: β_c =
``strength`` · |W| · m_c with m the corpus's concept frequencies (smoothed by ξ).
Under Eq. 5's symmetric ξ a new context must learn every concept afresh,
including the verbs that all contexts share (13 of a box's 19 tokens), and the
evidence prefers merging contexts until ≈ 20 scenes; centred on the corpus, a
context pays only for where it differs. docs/context.md ("Choosing K") has the
measurements.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import gammaln

from core.context import _partition_kernels as kernels
from core.context.metrics import dirichlet_multinomial_log_likelihood

#: Greedy scans closing a search (each scene to its best context; they stop early once none moves).
GREEDY_SCANS = 5


@dataclass(frozen=True)
class SceneBlocks:
    """The concept counts of a window of scenes (CSR), with what the contexts hold before it."""

    offsets: np.ndarray
    """Scene s owns entries ``offsets[s]:offsets[s + 1]``."""
    words: np.ndarray
    counts: np.ndarray
    totals: np.ndarray
    """Tokens per scene."""
    base_counts: np.ndarray
    """K × |W| concept counts of each context from the scenes before the window."""

    @property
    def n_scenes(self) -> int:
        return int(self.totals.shape[0])

    @classmethod
    def from_tokens(
        cls, words: np.ndarray, scene_of_token: np.ndarray, n_scenes: int, vocab_size: int, base_counts: np.ndarray
    ) -> SceneBlocks:
        """Blocks of the tokens ``words`` whose scene (0..n_scenes − 1) is ``scene_of_token``."""
        keys, counts = np.unique(scene_of_token.astype(np.int64) * vocab_size + words, return_counts=True)
        scenes = keys // vocab_size
        offsets = np.zeros(n_scenes + 1, dtype=np.int64)
        np.cumsum(np.bincount(scenes, minlength=n_scenes), out=offsets[1:])
        return cls(
            offsets=offsets,
            words=(keys % vocab_size).astype(np.int64),
            counts=counts.astype(np.float64),
            totals=np.bincount(scenes, weights=counts, minlength=n_scenes),
            base_counts=np.asarray(base_counts, dtype=np.float64),
        )


@dataclass(frozen=True)
class ScenePartition:
    """A partition of a window's scenes into ``n_contexts`` contexts and its evidence S(K)."""

    labels: np.ndarray
    n_contexts: int
    evidence: float


def corpus_centred_prior(concept_counts: np.ndarray, xi: float, strength: float) -> np.ndarray:
    """β_c = strength · |W| · (n_c + ξ) / (N + |W|ξ): a Dirichlet as strong as ``strength``
    pseudo-counts per concept, centred on the corpus's concept frequencies."""
    vocab_size = concept_counts.shape[0]
    frequencies = (concept_counts + xi) / (concept_counts.sum() + vocab_size * xi)
    return strength * vocab_size * frequencies


def partition_evidence(
    blocks: SceneBlocks, labels: np.ndarray, n_contexts: int, prior: np.ndarray, alpha: float
) -> float:
    """S(K) of the module docstring for ``labels`` (one context per scene of ``blocks``)."""
    vocab_size = prior.shape[0]
    base = _context_counts(blocks, None, n_contexts, vocab_size)
    with_scenes = _context_counts(blocks, labels, n_contexts, vocab_size)
    counts = with_scenes - base
    prior_total = float(prior.sum())
    concepts = dirichlet_multinomial_log_likelihood(
        with_scenes, with_scenes.sum(axis=1), prior, vocab_size, prior_total
    ) - dirichlet_multinomial_log_likelihood(base, base.sum(axis=1), prior, vocab_size, prior_total)
    totals = blocks.totals
    scenes = (
        gammaln(n_contexts * alpha) - gammaln(totals + n_contexts * alpha) + gammaln(totals + alpha) - gammaln(alpha)
    )
    empty = base.sum(axis=1) == 0
    used_empty = int(np.count_nonzero(empty & (counts.sum(axis=1) > 0)))
    n_empty = int(np.count_nonzero(empty))
    permutations = gammaln(n_empty + 1) - gammaln(n_empty - used_empty + 1)
    return float(concepts + scenes.sum() + permutations)


def best_partition(
    blocks: SceneBlocks,
    n_contexts: int,
    prior: np.ndarray,
    alpha: float,
    starts: list[np.ndarray],
    rng: np.random.Generator,
    random_starts: int,
    sampled_scans: int,
) -> ScenePartition:
    """The best partition found into ``n_contexts`` contexts by scene-level collapsed Gibbs
    searches (``sampled_scans`` sampled scans, then up to :data:`GREEDY_SCANS` greedy ones)
    from each of ``starts`` and from ``random_starts`` uniform labellings."""
    labelings = [np.asarray(start, dtype=np.int64) for start in starts]
    labelings += [rng.integers(0, n_contexts, blocks.n_scenes) for _ in range(random_starts)]
    best: ScenePartition | None = None
    for labels in labelings:
        labels = _search(blocks, labels.copy(), n_contexts, prior, rng, sampled_scans)
        evidence = partition_evidence(blocks, labels, n_contexts, prior, alpha)
        if best is None or evidence > best.evidence:
            best = ScenePartition(labels, n_contexts, evidence)
    if best is None:
        raise ValueError("best_partition needs at least one start")
    return best


def _search(
    blocks: SceneBlocks, labels: np.ndarray, n_contexts: int, prior: np.ndarray, rng: np.random.Generator, sampled: int
) -> np.ndarray:
    """``sampled`` sampled scans, then greedy scans until none moves a scene (at most :data:`GREEDY_SCANS`)."""
    counts = _context_counts(blocks, labels, n_contexts, prior.shape[0])
    totals = counts.sum(axis=1)
    prior_total = float(prior.sum())
    order = np.concatenate([rng.permutation(blocks.n_scenes) for _ in range(sampled)])
    arguments = (blocks.offsets, blocks.words, blocks.counts, blocks.totals, labels, counts, totals, prior, prior_total)
    kernels.partition_scans(*arguments, order, rng.random(len(order)), len(order))
    for _ in range(GREEDY_SCANS):
        order = rng.permutation(blocks.n_scenes)
        if kernels.partition_scans(*arguments, order, np.zeros(0), 0) == 0:
            break
    return labels


def _context_counts(blocks: SceneBlocks, labels: np.ndarray | None, n_contexts: int, vocab_size: int) -> np.ndarray:
    """K × |W| concept counts: what each context holds before the window, plus (with ``labels``)
    the scenes each label sends it."""
    counts = np.zeros((n_contexts, vocab_size))
    counts[: blocks.base_counts.shape[0]] = blocks.base_counts
    if labels is not None:
        scene_of_entry = np.repeat(np.arange(blocks.n_scenes), np.diff(blocks.offsets))
        np.add.at(counts, (labels[scene_of_entry], blocks.words), blocks.counts)
    return counts
