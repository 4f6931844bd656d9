"""The state of collapsed-Gibbs LDA and its two samplers (§IV-A, Algorithms 1 and 3).

:class:`LDAState` holds a corpus of scenes (documents) as flat ``int32`` arrays
plus the count matrices of Eq. 5. Every array keeps spare capacity that doubles
when full, so appending a scene, a concept (vocabulary growth) or a context costs
amortised O(its own size), never a copy of the corpus per scene.

Layout (the ``_gibbs_kernels`` docstring has the details):

- ``words[i]``, ``assignments[i]`` (z): concept id and context of token ``i``;
- ``doc_offsets[d]:doc_offsets[d + 1]``: the tokens of scene ``d``; the scene of each
  token is also kept per token, so that rejuvenating a random earlier token finds
  its scene in O(1);
- ``n_wk`` (|W| × K) counts word-context pairs; :attr:`LDAState.n_kw` is its K × |W|
  view, the orientation the paper and the storage layer use; ``n_k`` and ``n_dk``
  count per context and per scene-context.

Symmetric Dirichlet priors: α on a scene's contexts, ξ on a context's concepts.
"""

from __future__ import annotations

import threading

import numpy as np

from core.context import _count_kernels as count_kernels
from core.context import _gibbs_kernels as kernels
from core.context import _partition_kernels as partition_kernels
from core.context import _sparse_kernels as sparse_kernels
from core.context.metrics import dirichlet_multinomial_log_likelihood
from core.errors import InvalidInputError

_INITIAL_TOKENS = 256
MAX_TOKENS = int(np.iinfo(np.int32).max)
"""The most tokens one model holds: token indices are int32 in memory (the scene offsets, which the
kernels write) and in storage (a scene's ``first_token``, the checkpoint's ``token_count``). At
80 tokens a scene every 2 s that is about two years; :meth:`LDAState.check_room` refuses a scene
that would pass it, where the kernels would otherwise wrap an offset around and corrupt the model."""
_INITIAL_DOCUMENTS = 16
_INITIAL_WORDS = 32
_INITIAL_CONTEXTS = 4

SWEEP_KERNELS = {
    "dense": kernels.sweep_documents,
    "lanes": kernels.sweep_documents_by_lanes,
    "sparse": sparse_kernels.sweep_documents_sparse,
}
"""Gibbs sweeps of Eq. 5 with the same arguments and one uniform per token; same stationary
distribution, but each maps a given uniform to its own context (docs/context.md, "Sweep kernels")."""

#: What :meth:`LDAState._window_arguments` passes to a kernel over a window of scenes: words, z,
#: scene offsets, first and stop scene, n_wk, n_k, n_dk, K, α, ξ, |W|.
_WindowArguments = tuple[
    np.ndarray, np.ndarray, np.ndarray, int, int, np.ndarray, np.ndarray, np.ndarray, int, float, float, int
]

LANES_FROM_CONTEXTS = 12
"""K from which :func:`sweep_kernel` picks ``"lanes"``: above the service's default ``max_contexts``
(10), so every default model keeps the dense chain, and where ``"lanes"`` is measurably faster
(docs/context.md, "Sweep kernels")."""

SPARSE_FROM_CONTEXTS = 512
"""K from which :func:`sweep_kernel` picks ``"sparse"`` (measured crossover with ``"lanes"``, between
400 and 600 on the bench's shape; the service caps K at 100, so its models never reach it)."""


def sweep_kernel(n_contexts: int) -> str:
    """The fastest sweep kernel for K contexts, measured: ``"dense"`` below :data:`LANES_FROM_CONTEXTS`
    (every model of the paper's experiments and of the service's default ``max_contexts`` = 10
    lives there, so their chains are those of the dense sweep), ``"lanes"`` from it, ``"sparse"``
    from :data:`SPARSE_FROM_CONTEXTS`. A function of K alone, so a restored model sweeps with the
    kernel it had and continues bit-identically."""
    if n_contexts >= SPARSE_FROM_CONTEXTS:
        return "sparse"
    return "lanes" if n_contexts >= LANES_FROM_CONTEXTS else "dense"


class SeededUniforms:
    """What ``np.random.default_rng(seed).random(size)`` gives, from a memoised draw per seed: a
    generator's doubles come one after another, so a shorter draw is a prefix of a longer one.
    Creating and seeding a generator, and drawing, cost about as much as folding a 5-object scene
    in (≈ 7 µs each), and the service folds in with one seed per model
    (:meth:`core.context.IncrementalLDA.infer_scene`, and Eq. 6's fold-ins in
    ``core.context.feedback``)."""

    def __init__(self, seed: int) -> None:
        self._seed = seed

    def random(self, size: int) -> np.ndarray:
        """The first ``size`` doubles of the seed's generator (read-only)."""
        if size > _DRAWN_SIZE:
            return np.random.default_rng(self._seed).random(size)
        drawn = _DRAWN.get(self._seed)
        if drawn is None or len(drawn) < size:
            with _DRAWN_LOCK:
                drawn = _DRAWN.get(self._seed)
                if drawn is None or len(drawn) < size:
                    longer = max(size, min(2 * (0 if drawn is None else len(drawn)), _DRAWN_SIZE))
                    drawn = np.random.default_rng(self._seed).random(longer)
                    drawn.flags.writeable = False
                    if len(_DRAWN) >= _DRAWN_SEEDS:
                        del _DRAWN[next(iter(_DRAWN))]
                    _DRAWN[self._seed] = drawn
        return drawn[:size]


#: Memoised draws of :class:`SeededUniforms`, by seed: at most ``_DRAWN_SEEDS`` seeds (the first ones
#: are dropped) of at most ``_DRAWN_SIZE`` numbers (30 sweeps of 2,000 tokens; longer draws are not
#: kept): 8 MB.
_DRAWN: dict[int, np.ndarray] = {}
_DRAWN_SEEDS = 16
_DRAWN_SIZE = 60_000
_DRAWN_LOCK = threading.Lock()


def _with_capacity(array: np.ndarray, rows: int, columns: int | None = None) -> np.ndarray:
    """``array`` itself if it has room for ``rows`` (and ``columns``), else a zero-padded
    copy whose capacity at least doubles (amortised O(1) growth)."""
    has_rows = array.shape[0] >= rows
    has_columns = columns is None or array.shape[1] >= columns
    if has_rows and has_columns:
        return array
    new_rows = array.shape[0] if has_rows else max(rows, 2 * array.shape[0])
    shape: tuple[int, ...] = (new_rows,)
    if columns is not None:
        shape = (new_rows, array.shape[1] if has_columns else max(columns, 2 * array.shape[1]))
    grown = np.zeros(shape, dtype=array.dtype)
    grown[tuple(slice(0, n) for n in array.shape)] = array
    return grown


def layout_problems(
    words: np.ndarray, assignments: np.ndarray, doc_offsets: np.ndarray, vocab_size: int, n_contexts: int
) -> list[str]:
    """What makes these flat arrays an invalid corpus (empty when they are valid)."""
    problems = []
    if words.shape != assignments.shape:
        problems.append("words and assignments differ in length")
    elif words.size and (words.min() < 0 or words.max() >= vocab_size):
        problems.append(f"word ids outside 0..{vocab_size - 1}")
    elif assignments.size and (assignments.min() < 0 or assignments.max() >= n_contexts):
        problems.append(f"assignments outside 0..{n_contexts - 1}")
    if (
        doc_offsets.size == 0
        or doc_offsets[0] != 0
        or doc_offsets[-1] != words.shape[0]
        or np.any(doc_offsets[1:] <= doc_offsets[:-1])  # not np.diff: it wraps for unsigned types
    ):
        problems.append("document offsets must start at 0, end at the token count and give every scene a token")
    return problems


class LDAState:
    """Scenes, context assignments and counts of collapsed LDA (Eq. 5)."""

    def __init__(self, alpha: float, xi: float, vocab_size: int = 0, n_contexts: int = 1) -> None:
        self.alpha = float(alpha)
        self.xi = float(xi)
        self.vocab_size = int(vocab_size)
        self.n_contexts = int(n_contexts)
        self.n_tokens = 0
        self.n_documents = 0
        self._words = np.zeros(_INITIAL_TOKENS, dtype=np.int32)
        self._z = np.zeros(_INITIAL_TOKENS, dtype=np.int32)
        self._token_scene = np.zeros(_INITIAL_TOKENS, dtype=np.int32)
        self._offsets = np.zeros(_INITIAL_DOCUMENTS + 1, dtype=np.int32)
        context_capacity = max(self.n_contexts, _INITIAL_CONTEXTS)
        self._n_wk = np.zeros((max(self.vocab_size, _INITIAL_WORDS), context_capacity), dtype=np.int32)
        self._n_k = np.zeros(context_capacity, dtype=np.int32)
        self._n_dk = np.zeros((_INITIAL_DOCUMENTS, context_capacity), dtype=np.int32)
        self._uniforms = np.zeros(0)

    @classmethod
    def from_arrays(
        cls,
        alpha: float,
        xi: float,
        vocab_size: int,
        n_contexts: int,
        words: np.ndarray,
        assignments: np.ndarray,
        doc_offsets: np.ndarray,
    ) -> LDAState:
        """A state holding exactly these scenes and assignments, with counts recomputed."""
        state = cls(alpha, xi, vocab_size, n_contexts)
        state.n_tokens = int(words.shape[0])
        state.n_documents = int(doc_offsets.shape[0]) - 1
        state._words = _with_capacity(state._words, state.n_tokens)
        state._z = _with_capacity(state._z, state.n_tokens)
        state._token_scene = _with_capacity(state._token_scene, state.n_tokens)
        state._offsets = _with_capacity(state._offsets, state.n_documents + 1)
        state._n_dk = _with_capacity(state._n_dk, state.n_documents, state._n_dk.shape[1])
        state._words[: state.n_tokens] = words
        state._z[: state.n_tokens] = assignments
        state._offsets[: state.n_documents + 1] = doc_offsets
        count_kernels.fill_token_scenes(state.doc_offsets, state._token_scene)
        state.recount()
        return state

    # Views of the live part of the arrays.

    @property
    def words(self) -> np.ndarray:
        return self._words[: self.n_tokens]

    @property
    def assignments(self) -> np.ndarray:
        return self._z[: self.n_tokens]

    @property
    def doc_offsets(self) -> np.ndarray:
        return self._offsets[: self.n_documents + 1]

    @property
    def doc_lengths(self) -> np.ndarray:
        return self.scene_lengths()

    def scene_lengths(self, first_doc: int = 0, stop_doc: int | None = None) -> np.ndarray:
        """N_d of scenes ``first_doc:stop_doc`` (O(their number), not O(|D|))."""
        stop = self.n_documents if stop_doc is None else stop_doc
        return self._offsets[first_doc + 1 : stop + 1] - self._offsets[first_doc:stop]

    @property
    def n_wk(self) -> np.ndarray:
        return self._n_wk[: self.vocab_size, : self.n_contexts]

    @property
    def n_kw(self) -> np.ndarray:
        """Counts of concept w assigned to context k, K × |W| (a view)."""
        return self.n_wk.T

    @property
    def n_k(self) -> np.ndarray:
        return self._n_k[: self.n_contexts]

    @property
    def n_dk(self) -> np.ndarray:
        return self._n_dk[: self.n_documents, : self.n_contexts]

    # Growth.

    def add_words(self, count: int) -> None:
        """Extend the vocabulary by ``count`` concepts (new zero rows of ``n_wk``)."""
        self.vocab_size += count
        self._n_wk = _with_capacity(self._n_wk, self.vocab_size, self._n_wk.shape[1])

    def add_context(self) -> int:
        """Open context K + 1 with zero counts; returns its index."""
        self.n_contexts += 1
        columns = self.n_contexts
        self._n_wk = _with_capacity(self._n_wk, self._n_wk.shape[0], columns)
        self._n_k = _with_capacity(self._n_k, columns)
        self._n_dk = _with_capacity(self._n_dk, self._n_dk.shape[0], columns)
        return self.n_contexts - 1

    def append_document(self, word_ids: np.ndarray) -> int:
        """Append a scene with unassigned tokens (z = -1); returns its index.

        The counts do not include it until its tokens are sampled
        (:meth:`sample_tokens` assigns ``z < 0`` tokens).
        """
        start, stop = self.n_tokens, self.n_tokens + word_ids.shape[0]
        self._reserve_scene(stop)
        self._words[start:stop] = word_ids
        self._z[start:stop] = -1
        self._token_scene[start:stop] = self.n_documents
        self.n_documents += 1
        self._offsets[self.n_documents] = stop
        self.n_tokens = stop
        return self.n_documents - 1

    def append_assigned_scenes(self, word_ids: np.ndarray, contexts: np.ndarray, scene_lengths: np.ndarray) -> None:
        """Append whole scenes whose tokens are already assigned (a catch-up from storage), counts included.

        ``word_ids`` and ``contexts`` hold the tokens of the new scenes one after the other,
        ``scene_lengths`` how many tokens each scene has; contexts must be < ``n_contexts``.
        """
        start, stop = self.n_tokens, self.n_tokens + word_ids.shape[0]
        first_doc, new_docs = self.n_documents, scene_lengths.shape[0]
        self._words = _with_capacity(self._words, stop)
        self._z = _with_capacity(self._z, stop)
        self._token_scene = _with_capacity(self._token_scene, stop)
        self._offsets = _with_capacity(self._offsets, first_doc + new_docs + 2)
        self._n_dk = _with_capacity(self._n_dk, first_doc + new_docs + 1, self._n_dk.shape[1])
        docs = np.repeat(np.arange(first_doc, first_doc + new_docs, dtype=np.int32), scene_lengths)
        self._words[start:stop] = word_ids
        self._z[start:stop] = contexts
        self._token_scene[start:stop] = docs
        self._offsets[first_doc + 1 : first_doc + new_docs + 1] = start + np.cumsum(scene_lengths)
        self.n_documents += new_docs
        self.n_tokens = stop
        # One pass of the count kernel: ``np.add.at`` took 99 ms of a 467 ms catch-up of 10,000 scenes.
        count_kernels.count_assignments(word_ids, contexts, docs, self._n_wk, self._n_k, self._n_dk)

    def check_room(self, new_tokens: int) -> None:
        """Raise :class:`InvalidInputError` on ``words`` if ``new_tokens`` more would pass :data:`MAX_TOKENS`."""
        if self.n_tokens + new_tokens > MAX_TOKENS:
            raise InvalidInputError(
                "words",
                f"the model holds {self.n_tokens:,} tokens and a scene of {new_tokens} would take it past "
                f"{MAX_TOKENS:,}, the most one model holds (int32 token indices): learn into a new model",
            )

    def _reserve_scene(self, stop: int) -> None:
        """Room for one more scene whose tokens end at ``stop`` (each check is one comparison in
        the common case: this runs for every online update)."""
        if stop > self._words.shape[0]:  # the three token arrays always grow together
            self._words = _with_capacity(self._words, stop)
            self._z = _with_capacity(self._z, stop)
            self._token_scene = _with_capacity(self._token_scene, stop)
        if self.n_documents + 2 > self._offsets.shape[0]:
            self._offsets = _with_capacity(self._offsets, self.n_documents + 2)
        if self.n_documents + 1 > self._n_dk.shape[0]:
            self._n_dk = _with_capacity(self._n_dk, self.n_documents + 1, self._n_dk.shape[1])

    # Sampling.

    def _draw_uniforms(self, rng: np.random.Generator, count: int) -> np.ndarray:
        if self._uniforms.shape[0] < count:
            self._uniforms = np.empty(max(count, 2 * self._uniforms.shape[0]))
        out = self._uniforms[:count]
        rng.random(out=out)
        return out

    def initialize_randomly(self, rng: np.random.Generator) -> None:
        """Algorithm 1's start: every z drawn uniformly from the K contexts."""
        self.assignments[:] = rng.integers(0, self.n_contexts, size=self.n_tokens, dtype=np.int32)
        self.recount()

    def sweep(self, rng: np.random.Generator, sweeps: int = 1, first_doc: int = 0, kernel: str | None = None) -> None:
        """``sweeps`` Gibbs sweeps over every token of scenes ``first_doc:``, scene by scene (Eq. 5),
        with ``kernel`` (a key of :data:`SWEEP_KERNELS`; by default :func:`sweep_kernel` of K)."""
        chosen = sweep_kernel(self.n_contexts) if kernel is None else kernel
        if chosen not in SWEEP_KERNELS:
            raise InvalidInputError("kernel", f"must be one of {sorted(SWEEP_KERNELS)}, got {kernel!r}")
        n_uniforms = self.n_tokens - int(self._offsets[first_doc])
        for _ in range(sweeps):
            SWEEP_KERNELS[chosen](*self._window_arguments(first_doc), self._draw_uniforms(rng, n_uniforms))

    def _window_arguments(self, first_doc: int) -> _WindowArguments:
        """What a kernel over scenes ``first_doc:`` takes: corpus, scene range, counts, K, α, ξ, |W|."""
        return (
            self._words, self._z, self._offsets, first_doc, self.n_documents,
            self._n_wk, self._n_k, self._n_dk, self.n_contexts, self.alpha, self.xi, self.vocab_size,
        )  # fmt: skip

    def scene_of(self, tokens: np.ndarray) -> np.ndarray:
        """Index of the scene holding each token."""
        return self._token_scene[tokens]

    def sample_tokens(self, tokens: np.ndarray, rng: np.random.Generator, token_docs: np.ndarray | None = None) -> None:
        """Resample the given tokens in order (assigning those with z = -1); ``token_docs``,
        their scenes, is looked up when not given."""
        kernels.sample_tokens(
            tokens,
            self.scene_of(tokens) if token_docs is None else token_docs,
            self._words,
            self._z,
            self._n_wk,
            self._n_k,
            self._n_dk,
            self.n_contexts,
            self.alpha,
            self.xi,
            self.vocab_size,
            self._draw_uniforms(rng, tokens.shape[0]),
        )

    def scene_to_one_context(self, scene: int, rng: np.random.Generator) -> int:
        """Assign every token of ``scene`` as one block: the whole scene joins one context, drawn
        from the exact collapsed probabilities of Eq. 5's model given every other token (a
        scene comes from one context, §V); returns the context."""
        start, stop = int(self._offsets[scene]), int(self._offsets[scene + 1])
        return int(
            kernels.scene_to_one_context(
                self._words, self._z, start, stop, scene, self._n_wk, self._n_k, self._n_dk,
                self.n_contexts, self.alpha, self.xi, self.vocab_size, float(rng.random()),
            )
        )  # fmt: skip

    def scene_novelty(self, word_ids: np.ndarray, first_doc: int, strength: float) -> float:
        """How much better a fresh context explains the scene ``word_ids`` (not yet added) than
        the best existing context without scenes ``first_doc:``, in nats, under the corpus-centred
        prior of ``strength`` pseudo-counts per concept (``partition_kernels.scene_novelty``)."""
        return float(
            partition_kernels.scene_novelty(
                word_ids, self._words, self._z, int(self._offsets[first_doc]), self.n_tokens,
                self._n_wk, self._n_k, self.n_contexts, self.vocab_size, self.xi, strength,
            )
        )  # fmt: skip

    def first_novel_scene(self, first_doc: int, strength: float, stop: int | None = None) -> int | None:
        """The earliest of scenes ``first_doc:stop`` (``stop`` None: to the last) that is novel by
        :meth:`scene_novelty` against the contexts without scenes ``first_doc:`` (its own tokens
        among them), or None. Where a novelty-triggered growth check starts (:meth:`KRule.growth_window`)."""
        offsets = self._offsets
        for scene in range(first_doc, self.n_documents if stop is None else min(stop, self.n_documents)):
            if self.scene_novelty(self._words[offsets[scene] : offsets[scene + 1]], first_doc, strength) > 0.0:
                return scene
        return None

    def add_scene_online(
        self, word_ids: np.ndarray, rng: np.random.Generator, sweeps: int, rejuvenation_tokens: int
    ) -> tuple[int, np.ndarray, np.ndarray]:
        """Append a scene and sample it online: the whole scene joins one context
        (:meth:`scene_to_one_context`), then ``sweeps`` Eq. 5 sweeps, each over its tokens followed
        by ``rejuvenation_tokens`` earlier tokens drawn uniformly (Canini, Shi & Griffiths 2009).

        Returns the scene's index, the rejuvenated tokens (sweep after sweep, int64) and their
        contexts before the update (int32). The same as :meth:`append_document`,
        :meth:`scene_to_one_context` and :meth:`sample_tokens` one after the other, with the same
        random draws in the same order (the scene's context, the earlier tokens, one uniform per
        sampled token), in one kernel call (``kernels.sample_new_scene``). What an update costs is
        mostly the cache misses of its randomly drawn earlier tokens (docs/benchmarks.md), so the
        kernel reads them all before it samples any.
        """
        earlier = self.n_tokens
        self._reserve_scene(earlier + word_ids.shape[0])
        u_scene = rng.random()
        per_sweep = rejuvenation_tokens if earlier else 0
        # Flat: the same draws as size=(sweeps, per_sweep), which costs microseconds more.
        rejuvenated = rng.integers(0, earlier, sweeps * per_sweep)
        uniforms = self._draw_uniforms(rng, sweeps * (word_ids.shape[0] + per_sweep))
        scene = self.n_documents
        previous = kernels.sample_new_scene(
            self._words, self._z, self._token_scene, self._offsets, word_ids, scene, sweeps, rejuvenated,
            self._n_wk, self._n_k, self._n_dk, self.n_contexts, self.alpha, self.xi, self.vocab_size,
            u_scene, uniforms,
        )  # fmt: skip
        self.n_documents += 1
        self.n_tokens = earlier + word_ids.shape[0]
        return scene, rejuvenated, previous

    def scene_changes(
        self, scene: int, touched: np.ndarray, previous: np.ndarray, k_capacity: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """What the online update of the last ``scene`` changed, given the earlier tokens it may
        have moved (``touched``) and their contexts before (``previous``; a token listed twice
        counts with its first entry): the moved tokens (ascending), their contexts now and before, the
        changed n_kw entries as (context, concept, count) rows ordered by concept × ``k_capacity``
        + context, the scene's contexts and its θ (``kernels.scene_changes``)."""
        return kernels.scene_changes(
            touched, previous, scene, self._offsets, self._words, self._z, self._n_wk, self._n_dk,
            self.n_contexts, self.alpha, k_capacity,
        )  # fmt: skip

    def remove_last_scene(
        self, moved: np.ndarray, contexts_before: np.ndarray, n_contexts: int, vocab_size: int
    ) -> None:
        """Take the last scene's online update back out (:meth:`add_scene_online`, then any growth):
        the earlier tokens ``moved`` return to ``contexts_before``, the scene leaves the corpus and
        the counts, and the contexts and concepts it opened close, back to ``n_contexts`` and
        ``vocab_size``. The counts are then those of the state before the update, entry for entry
        (``count_kernels.remove_scene``). Raises ValueError when the arguments cannot describe the
        last update (checked first: nothing changed) or what is left is not a state before it (a
        context or concept to close still holds tokens): then only a reload restores the state."""
        if self.n_documents == 0 or not (1 <= n_contexts <= self.n_contexts) or not 0 <= vocab_size <= self.vocab_size:
            raise ValueError("not the last online update of this state")
        if moved.shape != contexts_before.shape or (
            moved.size and (moved.min() < 0 or moved.max() >= self._offsets[self.n_documents - 1])
        ):
            raise ValueError("the moved tokens are not earlier tokens of this state")
        if contexts_before.size and contexts_before.max() >= n_contexts:
            raise ValueError("a moved token's context before is not an open context")
        scene = self.n_documents - 1
        count_kernels.remove_scene(
            moved, contexts_before, scene, self._offsets, self._words, self._z, self._token_scene,
            self._n_wk, self._n_k, self._n_dk,
        )  # fmt: skip
        self.n_documents = scene
        self.n_tokens = int(self._offsets[scene])
        while self.n_contexts > n_contexts:
            self.remove_last_context()
        if self._n_wk[vocab_size : self.vocab_size].any():
            raise ValueError("a concept the update added still has tokens")
        self.vocab_size = vocab_size

    def reassign(self, tokens: np.ndarray, contexts: np.ndarray) -> None:
        """Set the contexts of assigned ``tokens`` to ``contexts``, keeping the counts consistent."""
        kernels.reassign_tokens(
            tokens,
            self.scene_of(tokens),
            contexts.astype(np.int32),
            self._words,
            self._z,
            self._n_wk,
            self._n_k,
            self._n_dk,
        )

    def grow_k_incrementally(
        self,
        low_confidence: np.ndarray,
        delta: float,
        rng: np.random.Generator,
        first_doc: int = 0,
        *,
        split_scans: int = 0,
    ) -> None:
        """Algorithm 3's start: open context K from the K − 1 solution.

        Among the tokens of scenes ``first_doc:``, those flagged in ``low_confidence``
        (one flag per such token) move to the new context; every other one keeps its
        context, except that it moves too with probability δ (to escape local optima).

        With ``split_scans`` > 0, that many restricted blocked Gibbs scans over the
        scenes follow (a split move's launch, Jain & Neal 2004): each scene in turn
        sends its unflagged tokens that sit in its K − 1 context or in K, as one block,
        to one of those two contexts, drawn from their exact collapsed probabilities;
        the flagged tokens stay in K as the split's anchor. Scenes of a merged context
        thus move whole instead of one token at a time against α (docs/context.md,
        "Fig. 10").
        """
        if isinstance(split_scans, bool) or not isinstance(split_scans, int | np.integer) or split_scans < 0:
            raise InvalidInputError("split_scans", f"must be an integer >= 0, got {split_scans!r}")
        previous_context = self.n_dk[first_doc:].argmax(axis=1)
        new_context = self.add_context()
        tokens = np.arange(self._offsets[first_doc], self.n_tokens, dtype=np.int64)
        moved = low_confidence | (rng.random(tokens.shape[0]) < delta)
        self.reassign(tokens[moved], np.full(int(moved.sum()), new_context, dtype=np.int32))
        if split_scans:
            self._split_scenes(low_confidence, previous_context, int(split_scans), rng, first_doc)

    def _split_scenes(
        self,
        anchored: np.ndarray,
        previous_context: np.ndarray,
        scans: int,
        rng: np.random.Generator,
        first_doc: int,
    ) -> None:
        """``scans`` restricted blocked scans of scenes ``first_doc:`` between each scene's
        ``previous_context`` (its dominant context before K opened) and the last context,
        scenes in a fresh random order per scan; ``anchored`` flags tokens that stay put."""
        n_scenes = self.n_documents - first_doc
        order = np.concatenate([first_doc + rng.permutation(n_scenes) for _ in range(scans)])
        previous = np.zeros(self.n_documents, dtype=np.int64)
        previous[first_doc:] = previous_context
        flags = np.zeros(self.n_tokens, dtype=np.bool_)
        flags[self._offsets[first_doc] :] = anchored
        kernels.split_scenes(
            self._words, self._z, self._offsets[: self.n_documents + 1], order, previous, flags,
            self._n_wk, self._n_k, self._n_dk, self.n_contexts - 1, self.alpha, self.xi, self.vocab_size,
            rng.random(len(order)),
        )  # fmt: skip

    def remove_last_context(self) -> None:
        """Close context K, which must hold no token."""
        if self.n_k[-1] != 0:
            raise ValueError("the last context still holds tokens")
        self.n_contexts -= 1

    # Counts and scores.

    def recount(self) -> None:
        """Recompute n_wk, n_k, n_dk from the assignments."""
        k, v, d = self.n_contexts, self.vocab_size, self.n_documents
        self._n_wk[:] = 0
        self._n_k[:] = 0
        self._n_dk[:] = 0
        token_scene = self._token_scene[: self.n_tokens]
        count_kernels.count_assignments(
            self.words, self.assignments, token_scene, self._n_wk[:v, :k], self._n_k[:k], self._n_dk[:d, :k]
        )

    def invariant_violations(self) -> list[str]:
        """What is inconsistent between the assignments and the counts (empty when sound)."""
        words, z, offsets = self.words, self.assignments, self.doc_offsets
        problems = layout_problems(words, z, offsets, self.vocab_size, self.n_contexts)
        if problems:
            return problems
        reference = LDAState.from_arrays(self.alpha, self.xi, self.vocab_size, self.n_contexts, words, z, offsets)
        for name in ("n_wk", "n_k", "n_dk"):
            if not np.array_equal(getattr(self, name), getattr(reference, name)):
                problems.append(f"{name} differs from the counts of the stored assignments")
        return problems

    def window_tokens(self, first_doc: int) -> np.ndarray:
        """Indices of the tokens of scenes ``first_doc:`` (the last scenes form a window)."""
        return np.arange(self._offsets[first_doc], self.n_tokens, dtype=np.int64)

    def joint_log_likelihood(self, first_doc: int = 0) -> float:
        """Collapsed log P(w, z | K) (Griffiths & Steyvers 2004) of scenes ``first_doc:``
        given the earlier ones; with ``first_doc = 0``, of the whole corpus.

        log P(w, z) = log P(w | z) + log P(z): Dirichlet-multinomial terms of the
        concepts of each context (prior ξ) and of the contexts of each scene (prior α).
        For a window, log P(w_win, z_win | rest) = log P(w, z) − log P(w_rest, z_rest):
        the scene terms of the window, and the concept terms with all counts minus
        those with the window's counts removed — only the window's concepts differ.
        """
        tokens = self.window_tokens(first_doc)
        k, v = self.n_contexts, self.vocab_size
        window_wk = np.bincount(self.words[tokens] * k + self.assignments[tokens], minlength=v * k).reshape(v, k)
        present = np.flatnonzero(window_wk.sum(axis=1))
        all_counts = self.n_wk[present].T
        rest_counts = all_counts - window_wk[present].T
        rest_totals = self.n_k - window_wk.sum(axis=0)
        concepts = dirichlet_multinomial_log_likelihood(
            all_counts, self.n_k, self.xi, v
        ) - dirichlet_multinomial_log_likelihood(rest_counts, rest_totals, self.xi, v)
        scenes = dirichlet_multinomial_log_likelihood(
            self._n_dk[first_doc : self.n_documents, :k], self.scene_lengths(first_doc), self.alpha, k
        )
        return concepts + scenes

    def conditional_entropy(self, first_doc: int = 0) -> float:
        """Σ_i H(z_i | z_¬i, w) over the tokens of scenes ``first_doc:``, from Eq. 5's conditionals."""
        return float(kernels.conditional_entropy(*self._window_arguments(first_doc)))

    def scene_fit(self, first_doc: int = 0) -> np.ndarray:
        """Mean per-token log P(w | s) = log Σ_χ θ_sχ φ_χw of each scene ``first_doc:``."""
        tokens = self.window_tokens(first_doc)
        lengths = self.scene_lengths(first_doc)
        docs = np.repeat(np.arange(lengths.shape[0]), lengths)
        theta = self.context_given_scene(first_doc)
        phi = self.concept_given_context()
        log_p = np.log(np.einsum("ik,ki->i", theta[docs], phi[:, self.words[tokens]]))
        return np.bincount(docs, weights=log_p, minlength=lengths.shape[0]) / lengths

    def concept_given_context(self) -> np.ndarray:
        """φ = P(c | χ) = (n_kw + ξ) / (n_k + |W|ξ), K × |W|."""
        return (self.n_kw + self.xi) / (self.n_k[:, None] + self.vocab_size * self.xi)

    def context_given_scene(self, first_doc: int = 0, stop_doc: int | None = None) -> np.ndarray:
        """θ = P(χ | s) = (n_dk + α) / (N_d + Kα), one row per scene of ``first_doc:stop_doc``."""
        stop = self.n_documents if stop_doc is None else stop_doc
        lengths = self.scene_lengths(first_doc, stop)
        return (self._n_dk[first_doc:stop, : self.n_contexts] + self.alpha) / (
            lengths[:, None] + self.n_contexts * self.alpha
        )

    def fold_in(
        self, word_ids: np.ndarray, rng: np.random.Generator | SeededUniforms, sweeps: int, burn_in: int
    ) -> np.ndarray:
        """θ of an unseen scene sampled against the current counts, which stay unchanged;
        the mean over the ``sweeps - burn_in`` last of ``sweeps`` sweeps (uniform for no token)."""
        if not 0 <= burn_in < sweeps:
            raise InvalidInputError("burn_in", f"must be in 0..sweeps - 1 ({sweeps - 1}), got {burn_in}")
        if word_ids.shape[0] == 0:
            return np.full(self.n_contexts, 1.0 / self.n_contexts)
        uniforms = rng.random(sweeps * word_ids.shape[0])
        return kernels.fold_in(
            word_ids, self._n_wk, self._n_k, self.n_contexts, self.alpha, self.xi, self.vocab_size, burn_in, uniforms
        )

    def document_tokens(self, documents: np.ndarray) -> np.ndarray:
        """Indices of all tokens of the given scenes, scene by scene."""
        offsets = self.doc_offsets
        return np.concatenate([np.arange(offsets[d], offsets[d + 1]) for d in documents]).astype(np.int64)

    def subset(self, documents: np.ndarray) -> LDAState:
        """A separate state holding only these scenes (same vocabulary and K), counts recomputed."""
        tokens = self.document_tokens(documents)
        lengths = self.doc_lengths[documents]
        offsets = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int32)
        return LDAState.from_arrays(
            self.alpha, self.xi, self.vocab_size, self.n_contexts, self.words[tokens], self.assignments[tokens], offsets
        )
