"""The ``"scenes"`` K rule: scene-partition evidence, its search, and K found from few scenes."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.special import gammaln

from core.context import IncrementalLDA, LDAState
from core.context._partition_kernels import _block_log_weight, partition_scans
from core.context.scene_partition import SceneBlocks, best_partition, corpus_centred_prior, partition_evidence
from experiments import documents
from sim.world import WorldConfig, generate_scenes


def _blocks(n_scenes: int, seed: int, base_contexts: int = 0) -> tuple[SceneBlocks, np.ndarray, list[str]]:
    scenes = generate_scenes(WorldConfig.paper(), n_scenes, seed)
    tokens = [scene.tokens() for scene in scenes]
    vocabulary = sorted({word for scene in tokens for word in scene})
    index = {word: i for i, word in enumerate(vocabulary)}
    counts = np.array([np.bincount([index[w] for w in scene], minlength=len(vocabulary)) for scene in tokens])
    words = np.concatenate([[index[w] for w in scene] for scene in tokens])
    scene_of_token = np.repeat(np.arange(n_scenes), [len(scene) for scene in tokens])
    base = np.arange(base_contexts * len(vocabulary), dtype=float).reshape(base_contexts, len(vocabulary)) % 4
    blocks = SceneBlocks.from_tokens(words, scene_of_token, n_scenes, len(vocabulary), base)
    return blocks, counts, [scene.object_contexts[0] for scene in scenes]


def _evidence_by_hand(
    counts: np.ndarray, labels: np.ndarray, k: int, prior: np.ndarray, alpha: float, base: np.ndarray
) -> float:
    """The module docstring's S(K), written out term by term."""
    total = 0.0
    for n in counts.sum(axis=1):
        total += gammaln(k * alpha) - gammaln(n + k * alpha) + gammaln(n + alpha) - gammaln(alpha)
    full_base = np.zeros((k, counts.shape[1]))
    full_base[: base.shape[0]] = base
    b = prior.sum()
    for context in range(k):
        before = full_base[context]
        after = before + counts[labels == context].sum(axis=0)
        for c in (after, before):
            sign = 1 if c is after else -1
            total += sign * (gammaln(b) - gammaln(c.sum() + b) + (gammaln(c + prior) - gammaln(prior)).sum())
    empty = full_base.sum(axis=1) == 0
    used = len({int(label) for label in labels if empty[label]})
    return float(total + gammaln(empty.sum() + 1) - gammaln(empty.sum() - used + 1))


@pytest.mark.parametrize("base_contexts", [0, 2])
def test_partition_evidence_is_the_documented_sum(base_contexts: int) -> None:
    blocks, counts, _ = _blocks(6, 3, base_contexts)
    prior = corpus_centred_prior(counts.sum(axis=0).astype(float), 0.1, 1.0)
    labels = np.array([0, 2, 1, 1, 0, 2])
    expected = _evidence_by_hand(counts, labels, 3, prior, 0.1, blocks.base_counts)
    assert partition_evidence(blocks, labels, 3, prior, 0.1) == pytest.approx(expected, rel=1e-12)


def test_corpus_centred_prior_has_the_given_strength_and_the_corpus_shape() -> None:
    prior = corpus_centred_prior(np.array([10.0, 0.0, 30.0]), 0.1, 2.0)
    assert prior.sum() == pytest.approx(2.0 * 3)
    assert prior[2] / prior[0] == pytest.approx(30.1 / 10.1) and prior[1] > 0


@pytest.mark.parametrize("seed", [5, 6])
def test_search_finds_the_best_partition_of_every_labelling(seed: int) -> None:
    """6 scenes into 3 contexts: 729 labellings, and the search reaches the best of them."""
    blocks, counts, _ = _blocks(6, seed)
    prior = corpus_centred_prior(counts.sum(axis=0).astype(float), 0.1, 1.0)
    exhaustive = max(
        partition_evidence(blocks, np.array(labels), 3, prior, 0.1) for labels in itertools.product(range(3), repeat=6)
    )
    found = best_partition(blocks, 3, prior, 0.1, [np.zeros(6, dtype=np.int64)], np.random.default_rng(seed), 2, 25)
    assert found.evidence == pytest.approx(exhaustive, abs=1e-9)
    assert partition_evidence(blocks, found.labels, 3, prior, 0.1) == pytest.approx(found.evidence)


#: Test sets of the stop-K tests: not the report's (its seeds 0–4 give test sets 0–4009).
TEST_SETS = range(100, 110)
#: The perceived world of the stop-K test: recognition's quick objects of the hard world at this seed
#: (≈ 25 s of feature extraction, shared with the other experiment tests of the process).
PERCEIVED_SEED = 7
#: Test sets of 10 in which K must equal the contexts present, by case: bounds that a seed set of 10
#: breaks with probability under 1 % (binomial) at the rate measured on 500 other test sets
#: (1000-1499, 2026-12-06; label documents, and the perceived webs of world 7).
#: The paper's bar is 9 of 10 (Fig. 11); the report judges it over its own seeds (issue 15). Measured
#: per set: labels 0.956 (|D| = 3), 0.894 (5), 0.960 (10); perceived webs of world 7 0.702 (3), 0.568
#: (5), 0.750 (10), 0.980 (20). Other perceived worlds differ: at |D| = 20 world 8 0.88, world 9 0.97,
#: world 10 0.945, world 11 0.68 (200-300 sets each), so "10 of 10 at |D| = 20" is world 7's, not the
#: hard world's in general. Until 2026-12-06 the cases below 9 of 10 were strict xfails on sets 100-109,
#: which other seed sets passed (an unexpected pass) as often as 71 % of the time (labels, |D| = 5).
STOP_K_BOUNDS = {
    ("labels", 3): 8,
    ("labels", 5): 6,
    ("labels", 10): 8,
    ("perceived", 3): 3,
    ("perceived", 5): 2,
    ("perceived", 10): 4,
    ("perceived", 20): 8,
}


@pytest.mark.parametrize(("source", "n_scenes"), list(STOP_K_BOUNDS))
def test_growth_stops_at_the_contexts_present_from_three_scenes(source: str, n_scenes: int) -> None:
    """Fig. 11 / issue 4: with ≥ 3 scenes, K = the contexts the scenes hold, in at least the measured
    share of 10 test sets, on the label documents (``Scene.tokens``) and on the paper's: the active
    concepts of perceived webs."""
    hits = []
    for seed in TEST_SETS:
        if source == "labels":
            scenes = generate_scenes(WorldConfig.paper(), n_scenes, seed)
            tokens = [scene.tokens() for scene in scenes]
        else:
            docs = documents.experiment_documents("hard", PERCEIVED_SEED, documents.PERCEIVED, quick=True)
            scenes = docs.scenes(n_scenes, seed)
            tokens = [docs.scene(scene) for scene in scenes]
        present = len({c for scene in scenes for c in scene.object_contexts})
        found = IncrementalLDA(seed=seed).fit(tokens).n_contexts
        hits.append(found == present)
    assert sum(hits) >= STOP_K_BOUNDS[(source, n_scenes)], hits


@pytest.mark.xfail(strict=True, reason="test set 104 merges the Playroom and the Workshop (issue 15)")
def test_the_found_contexts_are_the_true_ones() -> None:
    """Not only the right K: the scenes of each true context share one learned context."""
    scenes = generate_scenes(WorldConfig.paper(), 10, 104)
    model = IncrementalLDA(seed=104).fit([scene.tokens() for scene in scenes])
    learned = model.lda_state.n_dk.argmax(axis=1)
    pairs = {(scene.object_contexts[0], int(context)) for scene, context in zip(scenes, learned, strict=True)}
    assert len(pairs) == len({truth for truth, _ in pairs}) == len({context for _, context in pairs}) == 3, pairs


def test_a_new_scene_starts_in_one_context_with_consistent_counts() -> None:
    state = LDAState(0.1, 0.1, 4, 2)
    state.append_document(np.array([0, 0, 1, 1]))
    state.assignments[:] = [0, 0, 0, 0]
    state.recount()
    state.append_document(np.array([2, 3, 3]))
    state.assignments[4:] = 1
    state.recount()
    scene = state.append_document(np.array([0, 1, 1, 0]))
    context = state.scene_to_one_context(scene, np.random.default_rng(0))
    assert context == 0 and set(state.assignments[8:].tolist()) == {0}
    assert state.invariant_violations() == []


def test_greedy_scans_leave_every_scene_in_its_best_context_by_the_log_gamma_weights() -> None:
    """The kernel's block weights (products of rising factors) are the log-gamma weights of the
    module docstring: after greedy scans that move nothing, each scene's context is the argmax of
    log Γ(T + B) − log Γ(T + N + B) + Σ_c [log Γ(n_c + x_c + β_c) − log Γ(n_c + β_c)] computed by
    scipy, against what the other scenes and the earlier counts put in each context."""
    rng = np.random.default_rng(3)
    n_contexts, vocab_size, n_scenes = 4, 29, 60
    offsets, words, counts = [0], [], []
    for _ in range(n_scenes):
        room = rng.integers(3)
        concepts = np.unique(rng.choice(np.arange(room * 8, room * 8 + 13) % vocab_size, size=15))
        words += concepts.tolist()
        counts += rng.integers(1, 7, size=len(concepts)).tolist()
        offsets.append(len(words))
    blocks = SceneBlocks(
        offsets=np.array(offsets, dtype=np.int64),
        words=np.array(words, dtype=np.int64),
        counts=np.array(counts, dtype=np.float64),
        totals=np.add.reduceat(np.array(counts, dtype=np.float64), offsets[:-1]),
        base_counts=rng.integers(0, 20, size=(n_contexts, vocab_size)).astype(np.float64),
    )
    prior = rng.uniform(0.05, 2.0, vocab_size)
    labels = rng.integers(0, n_contexts, n_scenes)
    context_counts = blocks.base_counts.copy()
    for scene in range(n_scenes):
        entries = slice(offsets[scene], offsets[scene + 1])
        context_counts[labels[scene], blocks.words[entries]] += blocks.counts[entries]
    context_totals = context_counts.sum(axis=1)
    arguments = (blocks.offsets, blocks.words, blocks.counts, blocks.totals, labels, context_counts, context_totals)
    for _ in range(50):
        if partition_scans(*arguments, prior, float(prior.sum()), rng.permutation(n_scenes), np.zeros(0), 0) == 0:
            break
    else:
        pytest.fail("greedy scans kept moving scenes")
    moved_somewhere = False
    for scene in range(n_scenes):
        entries = slice(offsets[scene], offsets[scene + 1])
        scene_words, scene_counts = blocks.words[entries], blocks.counts[entries]
        without = context_counts.copy()
        without[labels[scene], scene_words] -= scene_counts
        held = without.sum(axis=1) + prior.sum()
        base = without[:, scene_words] + prior[scene_words]
        weights = (
            gammaln(held)
            - gammaln(held + scene_counts.sum())
            + (gammaln(base + scene_counts) - gammaln(base)).sum(axis=1)
        )
        assert labels[scene] == np.argmax(weights), scene
        for context in range(n_contexts):  # and the kernel's own weight is scipy's, to rounding
            kernel = _block_log_weight(
                without, context, blocks.words, blocks.counts, offsets[scene], offsets[scene + 1], held[context], prior
            )
            assert kernel == pytest.approx(weights[context], rel=1e-11, abs=1e-9)
        moved_somewhere |= bool(np.ptp(weights) > 1.0)
    assert moved_somewhere, "the contexts must differ for the check to mean anything"
