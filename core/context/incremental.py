"""Incremental-LDA (§IV-C, Algorithm 2): contexts of scenes, learned online with K grown on demand.

Three rules decide when K grows (``k_selection``; docs/context.md, "Choosing K",
has the measurements behind the choice):

- ``"scenes"`` (default), scene-partition evidence: a context belongs to a scene
  (§V draws each scene from one context), so K + 1 is kept when the best partition
  of the scenes into K + 1 contexts has more evidence than the best into K, each
  context's concepts under a Dirichlet centred on the corpus's concept frequencies
  (:mod:`core.context.scene_partition`). The new context then starts from that
  partition (Algorithm 3's start with the low-confidence tokens being those of the
  scenes that move), followed by Eq. 5's Gibbs sweeps. It finds the contexts
  present from 3 scenes on; the two rules below do not.
- ``"likelihood"``, a token-level birth move: propose K + 1 by a K-incremental
  start (Algorithm 3) and keep it only if it explains the scenes better. The score
  is the collapsed joint log-likelihood log P(w, z | K) (Griffiths & Steyvers 2004)
  plus the entropy of the sampler's conditionals Σ_i H(z_i | z_¬i, w), at a few
  Gibbs samples. The sum is a lower bound on the evidence log P(w | K)
  (log P(w) = E[log P(w, z)] + H(z | w), and H(z | w) ≥ Σ_i H(z_i | z_¬i, w)); the
  joint alone leaves out the entropy term, which grows with K, and undercounts
  contexts. The low-confidence tokens that start the new context are those of
  the scene the model explains worst (lowest mean log P(w | s)); every other token
  keeps its context or moves with probability δ. ``birth_proposals`` such starts
  (the worst, second worst... scene) are tried and the best kept; K + 1 wins when
  its mean score beats K's by more than ``growth_z`` standard errors (0 in batch,
  3 online, where a test runs every ``birth_check_interval`` scenes).
- ``"paper"``: Algorithm 2 as written, K grows while C_low ≠ ∅, C_low being the
  concepts whose confidence is below τ, and Algorithm 3 starts the new context
  with the tokens of C_low. The paper does not define the confidence of a
  concept's contextual assignment; here it is P(c | χ) under the concept's best
  context, max_χ φ_χc (a measure normalised over contexts would be 1 for every
  concept at K = 1, and K would never grow).

Online (:meth:`IncrementalLDA.learn_scene`) the model never re-learns: a new scene
first joins one context as a whole (drawn from the exact collapsed probabilities
of Eq. 5's model), then its tokens are sampled for ``scene_sweeps`` sweeps, each together with
``rejuvenation_tokens`` earlier tokens drawn uniformly (Canini, Shi & Griffiths
2009), and growth is checked only on a window of the last scenes, scoring the
window given the scenes before it: on the last ``birth_window`` scenes after each
of the first ``birth_check_interval`` scenes and after 2, 4, 8, ... times that many;
on the last ``novelty_window`` scenes after a scene that a fresh context explains
better than every existing one (novelty, :meth:`LDAState.scene_novelty`), so that a
new context is found within a few scenes of its first (docs/context.md, "When
growth is checked online"). So an update costs O(scene + rejuvenation) and a
growth check O(window), whatever the number of scenes learned.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import Any, Literal

import numpy as np

from core.context.lda import LDAState, SeededUniforms, layout_problems
from core.context.metrics import PAPER_RHO, RELEVANCE_WEIGHT, concept_relevance, contextual_entropy
from core.context.scene_partition import SceneBlocks, best_partition, corpus_centred_prior
from core.errors import InvalidInputError
from core.vocabulary import Vocabulary

KSelection = Literal["scenes", "likelihood", "paper"]
K_SELECTIONS: tuple[str, ...] = ("scenes", "likelihood", "paper")


@dataclass(frozen=True)
class Hyperparameters:
    """Everything that configures an :class:`IncrementalLDA` (the paper's symbols where it has them)."""

    alpha: float = 0.1
    """α: symmetric Dirichlet prior on a scene's contexts (Eq. 5; §V-B uses 0.1)."""
    xi: float = 0.1
    """ξ: symmetric Dirichlet prior on a context's concepts (Eq. 5; §V-B uses 0.1)."""
    k_selection: KSelection = "scenes"
    """How K grows: ``"scenes"`` (scene-partition evidence), ``"likelihood"`` (token-level
    birth move) or ``"paper"`` (C_low ≠ ∅)."""
    tau: float = 0.03
    """τ: a concept is in C_low when its confidence max_χ φ_χc is below τ (docs/context.md
    has the τ scan behind 0.03)."""
    delta: float = 0.05
    """δ: probability that a confident token moves to the new context (Algorithm 3)."""
    max_contexts: int = 10
    """K never exceeds this; at the cap growth is simply not proposed any more."""
    sweeps: int = 200
    """Gibbs sweeps after each K-incremental start (batch, or over the growth window)."""
    likelihood_samples: int = 10
    """Samples averaged by the birth move's score."""
    scene_prior_strength: float = 1.0
    """``"scenes"``: pseudo-counts per concept of the corpus-centred Dirichlet on a context's
    concepts (:func:`core.context.scene_partition.corpus_centred_prior`)."""
    partition_scans: int = 25
    """``"scenes"``: sampled scans of each partition search in :meth:`IncrementalLDA.fit`."""
    online_partition_scans: int = 10
    """``"scenes"``: the same online, where searches start from the model's own partition."""
    partition_random_starts: int = 4
    """``"scenes"``, in :meth:`IncrementalLDA.fit`: searches from random partitions, besides
    those from the model's own (online, where the model's partition is already a good
    start, only the latter: a check then costs milliseconds)."""
    birth_margin: float = 0.0
    """``"scenes"``: :meth:`IncrementalLDA.fit` keeps K + 1 if its evidence exceeds K's by more
    than this many nats."""
    online_birth_margin: float = 3.0
    """``"scenes"``: the same margin online, where a test runs every ``birth_check_interval``
    scenes (3 nats: a Bayes factor of 20, "strong" on Kass & Raftery's scale)."""
    growth_z: float = 0.0
    """:meth:`IncrementalLDA.fit` keeps K + 1 only if the mean score rises by more than
    this many standard errors (of the difference of the two sample means)."""
    online_growth_z: float = 3.0
    """The same margin online: a long-lived model runs a test every
    ``birth_check_interval`` scenes, so each test must rarely accept by chance."""
    birth_proposals: int = 2
    """Proposals per birth move, seeded with the worst-explained scenes in turn."""
    split_scans: int = 3
    """Scene-level split passes after a birth move's K-incremental start (docs/context.md,
    "K-incremental starts and Fig. 10": 3 passes put the scenes in their true contexts in
    10 of 10 test sets); the ``paper`` rule's C_low start stays Algorithm 3 as written."""
    sample_lag: int = 5
    """Sweeps between two of those samples."""
    scene_sweeps: int = 5
    """Online: sweeps over a new scene's tokens."""
    rejuvenation_tokens: int = 64
    """Online: earlier tokens resampled with each of those sweeps."""
    birth_window: int = 100
    """Online: growth is decided on the last this-many scenes."""
    birth_check_interval: int = 25
    """Online: growth is checked on the last ``birth_window`` scenes after each of the first
    this-many scenes, then after scenes 2, 4, 8, ... times this many (a safety net for contexts
    merged while young, which no single scene announces); besides, novelty triggers checks
    (``novelty_window``; docs/context.md, "When growth is checked online")."""
    novelty_window: int = 20
    """Online: a scene that a fresh context explains better than every existing context held
    before the last this-many scenes (``LDAState.scene_novelty`` > 0) triggers a growth check on
    the last this-many scenes, itself included (docs/context.md, "When growth is checked online")."""
    inference_sweeps: int = 30
    """Fold-in sweeps of :meth:`IncrementalLDA.infer_scene`."""
    inference_burn_in: int = 10
    """Of those, the first ones not averaged."""

    def __post_init__(self) -> None:
        for name in ("alpha", "xi", "scene_prior_strength"):
            value = getattr(self, name)
            if isinstance(value, bool) or not (isinstance(value, int | float) and np.isfinite(value) and value > 0):
                raise InvalidInputError(name, f"must be a positive number, got {value!r}")
        if self.k_selection not in K_SELECTIONS:
            raise InvalidInputError("k_selection", f"must be one of {K_SELECTIONS}, got {self.k_selection!r}")
        if not (isinstance(self.tau, int | float) and 0.0 < self.tau < 1.0):
            raise InvalidInputError("tau", f"must lie in (0, 1), got {self.tau!r}")
        if not (isinstance(self.delta, int | float) and 0.0 <= self.delta <= 1.0):
            raise InvalidInputError("delta", f"must lie in [0, 1], got {self.delta!r}")
        for name in ("growth_z", "online_growth_z", "birth_margin", "online_birth_margin"):
            value = getattr(self, name)
            if isinstance(value, bool) or not (isinstance(value, int | float) and np.isfinite(value) and value >= 0):
                raise InvalidInputError(name, f"must be a number >= 0, got {value!r}")
        if not (isinstance(self.likelihood_samples, int) and self.likelihood_samples >= 2):
            raise InvalidInputError("likelihood_samples", f"must be an integer >= 2, got {self.likelihood_samples!r}")
        for name in (
            "max_contexts",
            "sweeps",
            "sample_lag",
            "scene_sweeps",
            "birth_proposals",
            "partition_scans",
            "online_partition_scans",
            "birth_window",
            "birth_check_interval",
            "novelty_window",
            "inference_sweeps",
        ):
            value = getattr(self, name)
            if not (isinstance(value, int) and not isinstance(value, bool) and value >= 1):
                raise InvalidInputError(name, f"must be an integer >= 1, got {value!r}")
        for name in ("rejuvenation_tokens", "inference_burn_in", "split_scans", "partition_random_starts"):
            value = getattr(self, name)
            if not (isinstance(value, int) and not isinstance(value, bool) and value >= 0):
                raise InvalidInputError(name, f"must be an integer >= 0, got {value!r}")
        if self.inference_burn_in >= self.inference_sweeps:
            raise InvalidInputError("inference_burn_in", "must be smaller than inference_sweeps")

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


@dataclass(frozen=True)
class SceneUpdate:
    """Exactly what one :meth:`IncrementalLDA.learn_scene` changed (for incremental persistence)."""

    scene_index: int
    word_ids: np.ndarray
    """The scene's tokens (concept ids, int32), in the order given."""
    assignments: np.ndarray
    """Their contexts after the update (int32)."""
    reassigned_tokens: np.ndarray
    """Earlier tokens whose context changed (rejuvenation, growth), as global token indices (int64)."""
    reassigned_contexts: np.ndarray
    """Their new contexts (int32)."""
    reassigned_scenes: np.ndarray
    """Their scenes (int32): with ``reassigned_words``, a store can write each moved token's whole row."""
    reassigned_words: np.ndarray
    """Their concept ids (int32)."""
    changed_counts: np.ndarray
    """One row (context, concept, new n_kw) per count entry that changed (int64, m × 3)."""
    contexts_before: int
    contexts_after: int
    vocabulary_additions: tuple[str, ...]
    """Concepts first seen in this scene; they got ids |W|_before, |W|_before + 1, ..."""
    rng_state: dict[str, Any]
    """The model's random generator state after the update."""
    context_posterior: np.ndarray
    """θ of the scene after the update, (contexts_after,)."""
    growth_checked: bool
    """Whether this update ran a growth check on the window."""


@dataclass
class ContextModelState:
    """A model as plain arrays and numbers; :meth:`IncrementalLDA.from_state` restores it exactly."""

    hyperparameters: dict[str, Any]
    vocabulary: list[str]
    n_contexts: int
    words: np.ndarray
    """Concept id of every token, scene after scene (int32)."""
    assignments: np.ndarray
    """Context of every token (int32)."""
    doc_offsets: np.ndarray
    """Scene d owns tokens doc_offsets[d]:doc_offsets[d + 1] (int32, |D| + 1 entries)."""
    n_kw: np.ndarray
    """Concept counts per context, K × |W| (int32): redundant with the assignments, checked on restore."""
    rng_state: dict[str, Any] = field(default_factory=dict)


def concept_confidence(state: LDAState) -> np.ndarray:
    """Confidence of each concept's contextual assignment: max_χ P(c | χ) (the ``paper`` rule)."""
    return state.concept_given_context().max(axis=0)


def low_confidence_concepts(state: LDAState, tau: float, first_doc: int = 0) -> np.ndarray:
    """C_low as a mask over the vocabulary: concepts seen in scenes ``first_doc:`` whose
    confidence is below τ."""
    seen = np.zeros(state.vocab_size, dtype=bool)
    seen[state.words[state.window_tokens(first_doc)]] = True
    return seen & (concept_confidence(state) < tau)


class IncrementalLDA:
    """Incremental-LDA over scenes given as bags of concept names (Algorithms 1–3)."""

    def __init__(self, vocabulary: Iterable[str] | Vocabulary = (), *, seed: int = 0, **hyperparameters: Any) -> None:
        self.hyperparameters = Hyperparameters(**hyperparameters)
        self._rng = np.random.default_rng(_validated_seed(seed))
        self._vocabulary: list[str] = []
        self._index: dict[str, int] = {}
        self._state = LDAState(self.hyperparameters.alpha, self.hyperparameters.xi)
        concepts = vocabulary.concepts if isinstance(vocabulary, Vocabulary) else vocabulary
        names = _validated_words(concepts, "vocabulary", allow_empty=True)
        if len(set(names)) != len(names):
            raise InvalidInputError("vocabulary", "concept names must be unique")
        self._add_concepts(names)

    # Read-only views.

    @property
    def vocabulary(self) -> tuple[str, ...]:
        return tuple(self._vocabulary)

    def unseen_words(self, words: Iterable[str]) -> list[str]:
        """The distinct ``words`` not in the vocabulary, in first-seen order: what learning them would add."""
        return [word for word in dict.fromkeys(words) if word not in self._index]

    @property
    def n_contexts(self) -> int:
        return self._state.n_contexts

    @property
    def n_scenes(self) -> int:
        return self._state.n_documents

    @property
    def context_cap_reached(self) -> bool:
        """K = max_contexts: no further context will be proposed."""
        return self.n_contexts >= self.hyperparameters.max_contexts

    @property
    def lda_state(self) -> LDAState:
        """The underlying sampler state, for reading (changing it bypasses the model)."""
        return self._state

    # Learning.

    def fit(self, scenes: Sequence[Sequence[str]], n_contexts: int | None = None) -> IncrementalLDA:
        """Learn these scenes as a batch, replacing what was learned (the vocabulary stays).

        Without ``n_contexts``, Algorithm 2: K starts at 1 and grows by the
        ``k_selection`` rule, each growth step over the whole corpus. With it, Algorithm 1:
        that many contexts, assignments drawn uniformly, then ``sweeps`` Gibbs sweeps.
        """
        if len(scenes) == 0:
            raise InvalidInputError("scenes", "needs at least one scene")
        h = self.hyperparameters
        if n_contexts is not None and not (isinstance(n_contexts, int) and 1 <= n_contexts <= h.max_contexts):
            raise InvalidInputError(
                "n_contexts", f"must be an integer in 1..max_contexts ({h.max_contexts}), got {n_contexts!r}"
            )
        checked = [_validated_words(scene, f"scenes[{i}]") for i, scene in enumerate(scenes)]
        self._state = LDAState(h.alpha, h.xi, len(self._vocabulary), n_contexts or 1)
        for words in checked:
            self._add_concepts(words)
            self._state.append_document(self._ids(words))
        if n_contexts is None:
            self._state.assignments[:] = 0
            self._state.recount()
            self._grow_contexts(0, online=False)
        else:
            self._state.initialize_randomly(self._rng)
            self._state.sweep(self._rng, h.sweeps)
        return self

    def grow_context(self) -> None:
        """Algorithm 3's start, whatever the K-selection rule would decide: open context K + 1
        with the low-confidence tokens (and each other token with probability δ). Those are
        the tokens of C_low under the ``paper`` rule, the tokens of the scene explained worst
        (the birth move's first proposal, then ``split_scans`` scene-level split passes) under
        ``likelihood`` and ``scenes``. For experiments that force
        K (Figs. 10 and 11); follow it with :meth:`sweep`."""
        h = self.hyperparameters
        if self.context_cap_reached:
            raise InvalidInputError("max_contexts", f"the model already has max_contexts = {h.max_contexts} contexts")
        if self.n_scenes == 0:
            raise InvalidInputError("scenes", "the model has learned no scene yet")
        if h.k_selection == "paper":
            low, split_scans = low_confidence_concepts(self._state, h.tau)[self._state.words], 0
        else:
            low, split_scans = self._scene_tokens(0, int(np.argmin(self._state.scene_fit(0)))), h.split_scans
        self._state.grow_k_incrementally(low, h.delta, self._rng, split_scans=split_scans)

    def sweep(self, sweeps: int = 1) -> None:
        """Gibbs sweeps over every learned scene (Eq. 5) with the current K."""
        if isinstance(sweeps, bool) or not isinstance(sweeps, int) or sweeps < 0:
            raise InvalidInputError("sweeps", f"must be an integer >= 0, got {sweeps!r}")
        self._state.sweep(self._rng, sweeps)

    def learn_scene(self, words: Sequence[str]) -> SceneUpdate:
        """Add one scene online (Algorithm 2's loop body) and report what changed.

        The sampling is one kernel call (:meth:`LDAState.add_scene_online`) and so is the report
        (:meth:`LDAState.scene_changes`): at ~80 tokens an update is dominated by per-call
        overhead, so the bookkeeping is fused rather than spread over numpy calls.
        """
        words = _scene_words(words)
        state, h = self._state, self.hyperparameters
        contexts_before = state.n_contexts
        ids, additions = self._scene_ids(words)
        earlier = state.n_tokens
        first_doc = self._growth_window(ids)
        scene, touched, previous = state.add_scene_online(ids, self._rng, h.scene_sweeps, h.rejuvenation_tokens)
        growth_checked = first_doc is not None
        if first_doc is not None:
            window = np.arange(state.doc_offsets[first_doc], earlier, dtype=np.int64)
            touched = np.concatenate([touched, window])
            previous = np.concatenate([previous, state.assignments[window]])
            self._grow_contexts(first_doc, online=True)
        reassigned, contexts, changed_counts, assignments, theta = state.scene_changes(
            scene, touched, previous, h.max_contexts + 1
        )
        return SceneUpdate(
            scene_index=scene,
            word_ids=ids,
            assignments=assignments,
            reassigned_tokens=reassigned,
            reassigned_contexts=contexts,
            reassigned_scenes=state.scene_of(reassigned),
            reassigned_words=state.words[reassigned],
            changed_counts=changed_counts,
            contexts_before=contexts_before,
            contexts_after=state.n_contexts,
            vocabulary_additions=tuple(additions),
            rng_state=self._rng.bit_generator.state,
            context_posterior=theta,
            growth_checked=growth_checked,
        )

    def _growth_window(self, word_ids: np.ndarray) -> int | None:
        """The first scene of the window that a growth check after learning ``word_ids`` runs on,
        or None for no check (docs/context.md, "When growth is checked online"). Scheduled: after
        each of the first ``birth_check_interval`` scenes and after scenes 2, 4, 8, ... times
        ``birth_check_interval``, on the last ``birth_window`` scenes. On novelty: when a fresh
        context explains the scene better than every context held before the last
        ``novelty_window`` scenes (the ``"scenes"`` rule's block evidence,
        :meth:`LDAState.scene_novelty` > 0), on the last ``novelty_window`` scenes. Decided before
        the scene joins: its own tokens must not count for the contexts."""
        h, state = self.hyperparameters, self._state
        if self.context_cap_reached:
            return None
        seen = state.n_documents + 1
        periods, rest = divmod(seen, h.birth_check_interval)
        if seen <= h.birth_check_interval or (rest == 0 and periods & (periods - 1) == 0):
            return max(0, seen - h.birth_window)
        first_doc = max(0, seen - h.novelty_window)
        if state.scene_novelty(word_ids, first_doc, h.scene_prior_strength) > 0.0:
            return first_doc
        return None

    def _grow_contexts(self, first_doc: int, online: bool) -> None:
        """Algorithm 2's inner loop on scenes ``first_doc:`` (all of them in batch, the window online)."""
        state, h = self._state, self.hyperparameters
        while state.n_contexts < h.max_contexts:
            if h.k_selection == "scenes":
                if not self._scene_birth(first_doc, online):
                    return
            elif h.k_selection == "paper":
                low = low_confidence_concepts(state, h.tau, first_doc)
                if not low.any():
                    return
                state.grow_k_incrementally(
                    low[state.words[state.window_tokens(first_doc)]], h.delta, self._rng, first_doc
                )
                state.sweep(self._rng, h.sweeps, first_doc)
            elif not self._birth_move(first_doc, h.online_growth_z if online else h.growth_z):
                return

    def _scene_birth(self, first_doc: int, online: bool) -> bool:
        """The ``"scenes"`` rule's test on scenes ``first_doc:``: open context K + 1 if the best
        partition of the scenes into K + 1 contexts has more evidence than the best into K,
        by more than ``birth_margin`` (``online_birth_margin``) nats
        (:mod:`core.context.scene_partition`).

        The searches for K start from the model's own partition (each scene's dominant
        context); those for K + 1 from the best K partition and from it with each of the
        ``birth_proposals`` worst-explained scenes moved to the new context; in batch both
        also from ``partition_random_starts`` random partitions. A new context starts from
        the winning partition (every token in its scene's context); in batch ``sweeps``
        Gibbs sweeps of Eq. 5 follow, online the updates' rejuvenation takes over
        (docs/context.md, "Choosing K").
        """
        state, h = self._state, self.hyperparameters
        n_contexts = state.n_contexts
        blocks = self._scene_blocks(first_doc)
        prior = corpus_centred_prior(state.n_wk.sum(axis=1).astype(np.float64), h.xi, h.scene_prior_strength)
        own = state.n_dk[first_doc:].argmax(axis=1)
        search = partial(
            best_partition, blocks, prior=prior, alpha=h.alpha, rng=self._rng,
            random_starts=0 if online else h.partition_random_starts,
            sampled_scans=h.online_partition_scans if online else h.partition_scans,
        )  # fmt: skip
        current = search(n_contexts, starts=[own])
        worst_first = np.argsort(state.scene_fit(first_doc), kind="stable")[: h.birth_proposals]
        scenes = np.arange(blocks.n_scenes)
        starts = [current.labels] + [np.where(scenes == worst, n_contexts, current.labels) for worst in worst_first]
        proposed = search(n_contexts + 1, starts=starts)
        if proposed.evidence - current.evidence <= (h.online_birth_margin if online else h.birth_margin):
            return False
        state.add_context()
        tokens = state.window_tokens(first_doc)
        state.reassign(tokens, proposed.labels[state.scene_of(tokens) - first_doc].astype(np.int32))
        if not online:
            state.sweep(self._rng, h.sweeps, first_doc)
        return True

    def _scene_blocks(self, first_doc: int) -> SceneBlocks:
        """Concept counts of scenes ``first_doc:``, with what each context holds from the scenes before."""
        state = self._state
        tokens = state.window_tokens(first_doc)
        words = state.words[tokens].astype(np.int64)
        window_counts = np.zeros((state.n_contexts, state.vocab_size))
        np.add.at(window_counts, (state.assignments[tokens], words), 1.0)
        return SceneBlocks.from_tokens(
            words, state.scene_of(tokens) - first_doc, state.n_documents - first_doc, state.vocab_size,
            state.n_kw - window_counts,
        )  # fmt: skip

    def _birth_move(self, first_doc: int, growth_z: float) -> bool:
        """Propose context K + 1 on scenes ``first_doc:``; keep it if their score improves
        by more than ``growth_z`` standard errors.

        Both sides get the same Gibbs budget: the current K is sampled ``sweeps``
        sweeps before it is scored, like each proposal after its K-incremental start.
        Each of the ``birth_proposals`` proposals seeds the new context with one of the
        scenes explained worst; the best-scoring one is compared with the current K.
        """
        state, h = self._state, self.hyperparameters
        state.sweep(self._rng, h.sweeps, first_doc)
        current = self.growth_score(first_doc)
        tokens = state.window_tokens(first_doc)
        saved = state.assignments[tokens].copy()
        worst_first = first_doc + np.argsort(state.scene_fit(first_doc), kind="stable")
        best_score, best_assignments = None, saved
        for seed_scene in worst_first[: h.birth_proposals]:
            state.grow_k_incrementally(
                self._scene_tokens(first_doc, seed_scene), h.delta, self._rng, first_doc, split_scans=h.split_scans
            )
            state.sweep(self._rng, h.sweeps, first_doc)
            score = self.growth_score(first_doc)
            if best_score is None or score.mean() > best_score.mean():
                best_score, best_assignments = score, state.assignments[tokens].copy()
            state.reassign(tokens, saved)
            state.remove_last_context()
        if best_score is None or _improvement_in_standard_errors(best_score, current) <= growth_z:
            return False
        state.add_context()
        state.reassign(tokens, best_assignments)
        return True

    def _scene_tokens(self, first_doc: int, scene: int) -> np.ndarray:
        """Mask over the tokens of scenes ``first_doc:`` marking those of ``scene``."""
        tokens = self._state.window_tokens(first_doc)
        offsets = self._state.doc_offsets
        return (tokens >= offsets[scene]) & (tokens < offsets[scene + 1])

    def growth_score(self, first_doc: int = 0) -> np.ndarray:
        """The birth move's score of scenes ``first_doc:`` (given the earlier ones),
        log P(w, z | K) + Σ_i H(z_i | z_¬i, w), at ``likelihood_samples`` Gibbs samples
        ``sample_lag`` sweeps apart. Sampling moves the model on."""
        state, h = self._state, self.hyperparameters
        scores = np.empty(h.likelihood_samples)
        for i in range(h.likelihood_samples):
            state.sweep(self._rng, h.sample_lag, first_doc)
            scores[i] = state.joint_log_likelihood(first_doc) + state.conditional_entropy(first_doc)
        return scores

    # Using the model.

    def infer_scene(self, words: Sequence[str], *, seed: int = 0) -> np.ndarray:
        """Context posterior θ (K,) of an unseen scene, by fold-in Gibbs sampling against the
        current counts (the model, including its random state, is left unchanged), with the random
        numbers of ``np.random.default_rng(seed)``, memoised per seed (:class:`SeededUniforms`).

        Concepts the model has never seen carry no evidence and are ignored; a scene of
        only such concepts gets the uniform prior.
        """
        words = _scene_words(words)
        uniforms = SeededUniforms(_validated_seed(seed))
        index = self._index
        known = np.fromiter((index[w] for w in words if w in index), dtype=np.int32)
        if known.shape[0] == 0:
            return np.full(self.n_contexts, 1.0 / self.n_contexts)
        h = self.hyperparameters
        return self._state.fold_in(known, uniforms, h.inference_sweeps, h.inference_burn_in)

    def context_posterior(self, scene: Sequence[str] | int, *, seed: int = 0) -> np.ndarray:
        """P(χ | scene), (K,): a learned scene by index (its θ), or an unseen one by its concepts."""
        if isinstance(scene, int | np.integer) and not isinstance(scene, bool):
            if not 0 <= scene < self.n_scenes:
                raise InvalidInputError("scene", f"no learned scene {scene} (there are {self.n_scenes})")
            return self._state.context_given_scene(int(scene), int(scene) + 1)[0]
        return self.infer_scene(scene, seed=seed)

    def concept_given_context(self) -> np.ndarray:
        """P(c | χ), K × |W|, rows in context order, columns in :attr:`vocabulary` order."""
        return self._state.concept_given_context()

    def top_concepts(self, k: int) -> list[list[tuple[str, float]]]:
        """The ``k`` most probable concepts of each context, with P(c | χ)."""
        if not (isinstance(k, int) and k >= 1):
            raise InvalidInputError("k", f"must be an integer >= 1, got {k!r}")
        phi = self.concept_given_context()
        order = np.argsort(-phi, axis=1, kind="stable")[:, :k]
        return [[(self._vocabulary[w], float(phi[c, w])) for w in row] for c, row in enumerate(order)]

    def distinctive_concepts(self, k: int, weight: float = RELEVANCE_WEIGHT) -> list[list[tuple[str, float, float]]]:
        """The ``k`` concepts of each context with the highest relevance (λ = ``weight``,
        :func:`metrics.concept_relevance`), as (name, P(c | χ), relevance); contexts weighted
        by their token counts n_k (equally before any scene)."""
        if not (isinstance(k, int) and k >= 1):
            raise InvalidInputError("k", f"must be an integer >= 1, got {k!r}")
        phi = self.concept_given_context()
        tokens = self._state.n_k[: phi.shape[0]].astype(float)
        relevance = concept_relevance(phi, tokens if tokens.sum() > 0 else np.ones_like(tokens), weight)
        order = np.argsort(-relevance, axis=1, kind="stable")[:, :k]
        return [
            [(self._vocabulary[w], float(phi[c, w]), float(relevance[c, w])) for w in row] for c, row in enumerate(order)
        ]

    def entropy(self, rho: float = PAPER_RHO) -> float:
        """H̃ of Eq. 8 over the learned scenes (see :func:`metrics.contextual_entropy`)."""
        if self.n_scenes == 0:
            raise InvalidInputError("scenes", "the model has learned no scene yet")
        return contextual_entropy(self.concept_given_context(), self._state.context_given_scene(), rho)

    def low_confidence_concepts(self) -> list[str]:
        """C_low under τ (the ``paper`` rule's set), by name."""
        mask = low_confidence_concepts(self._state, self.hyperparameters.tau)
        return [self._vocabulary[w] for w in np.flatnonzero(mask)]

    def joint_log_likelihood(self) -> float:
        """Collapsed log P(w, z | K) of all learned scenes."""
        return self._state.joint_log_likelihood()

    # State.

    def to_state(self) -> ContextModelState:
        state = self._state
        return ContextModelState(
            hyperparameters=self.hyperparameters.to_dict(),
            vocabulary=list(self._vocabulary),
            n_contexts=state.n_contexts,
            words=state.words.copy(),
            assignments=state.assignments.copy(),
            doc_offsets=state.doc_offsets.copy(),
            n_kw=np.ascontiguousarray(state.n_kw),
            rng_state=self._rng.bit_generator.state,
        )

    @classmethod
    def from_state(cls, saved: ContextModelState) -> IncrementalLDA:
        """The model exactly as exported: it continues as the original would have."""
        try:
            model = cls(saved.vocabulary, **saved.hyperparameters)
        except TypeError as error:
            raise InvalidInputError("state.hyperparameters", str(error)) from None
        words = _state_array(saved.words, "state.words")
        assignments = _state_array(saved.assignments, "state.assignments")
        offsets = _state_array(saved.doc_offsets, "state.doc_offsets")
        h = model.hyperparameters
        n_contexts = saved.n_contexts
        if isinstance(n_contexts, bool) or not (
            isinstance(n_contexts, int | np.integer) and 1 <= n_contexts <= h.max_contexts
        ):
            raise InvalidInputError("state.n_contexts", f"must be in 1..max_contexts, got {n_contexts!r}")
        problems = layout_problems(words, assignments, offsets, len(model._vocabulary), int(n_contexts))
        if problems:
            raise InvalidInputError("state", "; ".join(problems))
        state = LDAState.from_arrays(
            h.alpha, h.xi, len(model._vocabulary), int(n_contexts), words, assignments, offsets
        )
        if not np.array_equal(np.asarray(saved.n_kw), state.n_kw):
            raise InvalidInputError("state.n_kw", "differs from the counts of the stored assignments")
        model._state = state
        try:
            model._rng.bit_generator.state = saved.rng_state
        except (TypeError, ValueError, KeyError) as error:
            raise InvalidInputError("state.rng_state", f"not a PCG64 generator state ({error})") from None
        return model

    def catch_up(
        self,
        *,
        new_words: Sequence[str],
        n_contexts: int,
        tokens: np.ndarray,
        count_entries: np.ndarray,
        scene_count: int,
        rng_state: dict[str, Any],
    ) -> None:
        """Bring the model to a later stored state from what changed since it (docs/scaling.md).

        ``tokens`` holds (id, scene, concept, context) rows of every token inserted or reassigned
        since: earlier tokens move to their new context, new ones form whole new scenes;
        ``count_entries`` the (context, concept, count) n_kw entries that changed, checked
        against the counts the tokens give. Raises InvalidInputError (nothing proven, the caller
        must reload) when the changes do not fit this model.
        """
        state = self._state
        if n_contexts < state.n_contexts or n_contexts > self.hyperparameters.max_contexts:
            raise InvalidInputError("state.n_contexts", f"{n_contexts} does not follow {state.n_contexts}")
        tokens = np.asarray(tokens, dtype=np.int64).reshape(-1, 4)
        self._add_concepts(list(new_words))
        if tokens.size and (tokens[:, 2].max() >= state.vocab_size or tokens[:, 3].max() >= n_contexts):
            raise InvalidInputError("state.tokens", "a changed token names an unknown concept or context")
        while state.n_contexts < n_contexts:
            state.add_context()
        earlier = tokens[tokens[:, 0] < state.n_tokens]
        if earlier.size:
            if not np.array_equal(state.words[earlier[:, 0]], earlier[:, 2]):
                raise InvalidInputError("state.tokens", "a reassigned token has another concept than in memory")
            state.reassign(earlier[:, 0], earlier[:, 3].astype(np.int32))
        added = tokens[tokens[:, 0] >= state.n_tokens]
        if added.size:
            expected_ids = np.arange(state.n_tokens, state.n_tokens + added.shape[0])
            scenes, lengths = np.unique(added[:, 1], return_counts=True)
            expected_scenes = np.arange(state.n_documents, state.n_documents + scenes.shape[0])
            if not np.array_equal(added[:, 0], expected_ids) or not np.array_equal(scenes, expected_scenes):
                raise InvalidInputError("state.tokens", "the new tokens do not form whole scenes after the last one")
            if np.any(np.diff(added[:, 1]) < 0):
                raise InvalidInputError("state.tokens", "the new tokens' scenes are out of order")
            state.append_assigned_scenes(
                added[:, 2].astype(np.int32), added[:, 3].astype(np.int32), lengths.astype(np.int32)
            )
        if state.n_documents != scene_count:
            raise InvalidInputError("state.scene_count", f"{scene_count} stored, {state.n_documents} after catching up")
        entries = np.asarray(count_entries, dtype=np.int64).reshape(-1, 3)
        if entries.size:
            inside = (entries[:, 0] < state.n_contexts) & (entries[:, 1] < state.vocab_size)
            counts = np.zeros(entries.shape[0], dtype=np.int64)
            counts[inside] = state.n_kw[entries[inside, 0], entries[inside, 1]]
            if not np.array_equal(counts, entries[:, 2]):
                raise InvalidInputError("state.n_kw", "differs from the counts of the stored assignments")
        try:
            self._rng.bit_generator.state = rng_state
        except (TypeError, ValueError, KeyError) as error:
            raise InvalidInputError("state.rng_state", f"not a PCG64 generator state ({error})") from None

    def check_invariants(self) -> None:
        """Raise AssertionError when the counts differ from those of the stored assignments."""
        problems = self._state.invariant_violations()
        if len(self._vocabulary) != self._state.vocab_size:
            problems.append("vocabulary size differs from the count matrices")
        if problems:
            raise AssertionError("; ".join(problems))

    # Vocabulary.

    def _add_concepts(self, words: Sequence[str]) -> list[str]:
        added = []
        for word in words:
            if word not in self._index:
                self._index[word] = len(self._vocabulary)
                self._vocabulary.append(word)
                added.append(word)
        if added:
            self._state.add_words(len(added))
        return added

    def _ids(self, words: Sequence[str]) -> np.ndarray:
        return np.fromiter((self._index[w] for w in words), dtype=np.int32, count=len(words))

    def _scene_ids(self, words: Sequence[str]) -> tuple[np.ndarray, list[str]]:
        """The scene's concept ids (int32) and the concepts it adds to the vocabulary, in order."""
        try:  # the common case, every concept known: one pass of dict lookups
            return np.fromiter(map(self._index.__getitem__, words), dtype=np.int32, count=len(words)), []
        except KeyError:
            additions = self._add_concepts(words)
            return self._ids(words), additions


def _validated_words(words: Any, field_name: str, allow_empty: bool = False) -> list[str]:
    if isinstance(words, str) or not isinstance(words, Sequence | Iterable):
        raise InvalidInputError(field_name, "must be a sequence of concept names")
    words = list(words)
    if not words and not allow_empty:
        raise InvalidInputError(field_name, "a scene needs at least one concept")
    for word in words:
        if not isinstance(word, str) or not word:
            raise InvalidInputError(field_name, f"concept names must be non-empty strings, got {word!r}")
    return words


def _scene_words(words: Any) -> Sequence[str]:
    """``_validated_words(words, "words")``; a list or tuple of non-empty ``str`` (what the
    service passes) is accepted as it is, after checks that run in C, not per word in Python."""
    if type(words) in (list, tuple) and words and set(map(type, words)) == {str} and "" not in words:
        return words
    return _validated_words(words, "words")


def _validated_seed(seed: Any) -> int:
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise InvalidInputError("seed", f"must be an integer >= 0, got {seed!r}")
    return int(seed)


def _state_array(values: Any, field_name: str) -> np.ndarray:
    array = np.asarray(values)
    if array.ndim != 1 or (array.size and not np.issubdtype(array.dtype, np.integer)):
        raise InvalidInputError(field_name, "must be a one-dimensional integer array")
    return array.astype(np.int32)


def _improvement_in_standard_errors(proposed: np.ndarray, current: np.ndarray) -> float:
    """(mean proposed − mean current) / standard error of that difference."""
    difference = proposed.mean() - current.mean()
    error = np.sqrt(proposed.var(ddof=1) / proposed.shape[0] + current.var(ddof=1) / current.shape[0])
    if error > 0:
        return float(difference / error)
    return np.inf if difference > 0 else -np.inf
