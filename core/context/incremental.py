"""Incremental-LDA (§IV-C, Algorithm 2): contexts of scenes, learned online with K grown on demand.

A K rule decides when K grows (:mod:`core.context.k_selection`, one strategy object per rule;
docs/context.md, "Choosing K", has the measurements behind the choice): ``"scenes"`` (the
default, scene-partition evidence) or ``"paper"`` (Algorithm 2 as written, C_low ≠ ∅). The model
holds the corpus and the sampler (Eq. 5) and runs Algorithm 2's loop; the rule gives the evidence
for a candidate K, the decision and the new context's start.

Online (:meth:`IncrementalLDA.learn_scene`) the model never re-learns: a new scene
first joins one context as a whole (drawn from the exact collapsed probabilities
of Eq. 5's model), then its tokens are sampled for ``scene_sweeps`` sweeps, each together with
``rejuvenation_tokens`` earlier tokens drawn uniformly (Canini, Shi & Griffiths
2009), and growth is checked only on a window of the last scenes, scoring the
window given the scenes before it: on the last ``birth_window`` scenes after each
of the first ``birth_check_interval`` scenes and after 2, 4, 8, ... times that many;
on the recent scenes from the earliest novel one after a scene that a fresh context explains
better than every existing one (novelty, :meth:`LDAState.scene_novelty`), so that a
new context is found within a few scenes of its first (docs/context.md, "When
growth is checked online"; :meth:`core.context.k_selection.KRule.growth_window`). So an update
costs O(scene + rejuvenation) and a growth check O(window), whatever the number of scenes learned.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np

from core.context.hyperparameters import Hyperparameters
from core.context.k_selection import PAPER_TAU, KRule, low_confidence_concepts
from core.context.lda import LDAState, SeededUniforms, layout_problems
from core.context.metrics import PAPER_RHO, RELEVANCE_WEIGHT, concept_relevance, contextual_entropy
from core.errors import InvalidInputError
from core.vocabulary import Vocabulary


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
    previous_contexts: np.ndarray
    """Their contexts before the update (int32): with ``rng_state_before``, what
    :meth:`IncrementalLDA.undo_scene` needs to take the update back."""
    changed_counts: np.ndarray
    """One row (context, concept, new n_kw) per count entry that changed (int64, m × 3)."""
    contexts_before: int
    contexts_after: int
    vocabulary_additions: tuple[str, ...]
    """Concepts first seen in this scene; they got ids |W|_before, |W|_before + 1, ..."""
    rng_state: dict[str, Any]
    """The model's random generator state after the update."""
    rng_state_before: dict[str, Any]
    """Its state before the update."""
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
    n_kw: np.ndarray | None
    """Concept counts per context, K × |W| (int32): redundant with the assignments, checked on
    restore; None when the caller checks the restored counts itself (a server's start checks them
    against the stored count rows: a count over the whole corpus less at a million scenes)."""
    rng_state: dict[str, Any] = field(default_factory=dict)


class IncrementalLDA:
    """Incremental-LDA over scenes given as bags of concept names (Algorithms 1–3)."""

    def __init__(
        self,
        vocabulary: Iterable[str] | Vocabulary = (),
        *,
        seed: int = 0,
        hyperparameters: Hyperparameters | None = None,
        **settings: Any,
    ) -> None:
        """``hyperparameters`` in full, or ``settings`` in the flat form
        (:meth:`Hyperparameters.from_flat`: ``sweeps=10, k_selection="paper", tau=0.05``)."""
        if hyperparameters is not None and settings:
            raise InvalidInputError("hyperparameters", "give the hyperparameters or flat settings, not both")
        self.hyperparameters = hyperparameters if hyperparameters is not None else Hyperparameters.from_flat(**settings)
        self._k_rule: KRule = self.hyperparameters.k_rule.make_rule()
        self._rng = np.random.default_rng(_validated_seed(seed))
        self._vocabulary: list[str] = []
        self._index: dict[str, int] = {}
        self._state = LDAState(self.hyperparameters.priors.alpha, self.hyperparameters.priors.xi)
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
        return self.n_contexts >= self.hyperparameters.k_rule.max_contexts

    @property
    def lda_state(self) -> LDAState:
        """The underlying sampler state, for reading (changing it bypasses the model)."""
        return self._state

    # Learning.

    def fit(self, scenes: Sequence[Sequence[str]], n_contexts: int | None = None) -> IncrementalLDA:
        """Learn these scenes as a batch, replacing what was learned (the vocabulary stays).

        Without ``n_contexts``, Algorithm 2: K starts at 1 and grows by the
        K rule, each growth step over the whole corpus. With it, Algorithm 1:
        that many contexts, assignments drawn uniformly, then ``sweeps`` Gibbs sweeps.
        """
        if len(scenes) == 0:
            raise InvalidInputError("scenes", "needs at least one scene")
        h = self.hyperparameters
        max_contexts = h.k_rule.max_contexts
        if n_contexts is not None and not (isinstance(n_contexts, int) and 1 <= n_contexts <= max_contexts):
            raise InvalidInputError(
                "n_contexts", f"must be an integer in 1..max_contexts ({max_contexts}), got {n_contexts!r}"
            )
        checked = [_validated_words(scene, f"scenes[{i}]") for i, scene in enumerate(scenes)]
        self._state = LDAState(h.priors.alpha, h.priors.xi, len(self._vocabulary), n_contexts or 1)
        for words in checked:
            self._add_concepts(words)
            self._state.append_document(self._ids(words))
        if n_contexts is None:
            self._state.assignments[:] = 0
            self._state.recount()
            self._grow_contexts(0, online=False)
        else:
            self._state.initialize_randomly(self._rng)
            self._state.sweep(self._rng, h.sampler.sweeps)
        return self

    def grow_context(self) -> None:
        """Algorithm 3's start, whatever the K rule would decide: open context K + 1
        with the low-confidence tokens (and each other token with probability δ). Those are
        the tokens of C_low under the ``paper`` rule, the tokens of the scene explained worst
        (then ``split_scans`` scene-level split passes) under ``scenes``
        (:meth:`core.context.k_selection.KRule.open_context`). For experiments that force
        K (Figs. 10 and 11); follow it with :meth:`sweep`."""
        if self.context_cap_reached:
            max_contexts = self.hyperparameters.k_rule.max_contexts
            raise InvalidInputError("max_contexts", f"the model already has max_contexts = {max_contexts} contexts")
        if self.n_scenes == 0:
            raise InvalidInputError("scenes", "the model has learned no scene yet")
        self._k_rule.open_context(self._state, self._rng)

    def sweep(self, sweeps: int = 1) -> None:
        """Gibbs sweeps over every learned scene (Eq. 5) with the current K."""
        if isinstance(sweeps, bool) or not isinstance(sweeps, int) or sweeps < 0:
            raise InvalidInputError("sweeps", f"must be an integer >= 0, got {sweeps!r}")
        self._state.sweep(self._rng, sweeps)

    def learn_scene(self, words: Sequence[str]) -> SceneUpdate:
        """Add one scene online (Algorithm 2's loop body) and report what changed.

        The sampling is one kernel call (:meth:`LDAState.add_scene_online`) and so is the report
        (:meth:`LDAState.scene_changes`): at ~64 tokens a scene, numpy calls spread over the
        bookkeeping would cost more than the sampling, so it is fused.
        """
        ids, additions = self._scene_ids(words)
        state, h = self._state, self.hyperparameters
        rng_state_before = dict(self._rng.bit_generator.state)
        contexts_before = state.n_contexts
        earlier = state.n_tokens
        first_doc = self._k_rule.growth_window(state, ids)
        scene, touched, previous = state.add_scene_online(
            ids, self._rng, h.sampler.scene_sweeps, h.sampler.rejuvenation_tokens
        )
        growth_checked = first_doc is not None
        if first_doc is not None:
            window = np.arange(state.doc_offsets[first_doc], earlier, dtype=np.int64)
            touched = np.concatenate([touched, window])
            previous = np.concatenate([previous, state.assignments[window]])
            self._grow_contexts(first_doc, online=True)
        reassigned, contexts, previous_contexts, changed_counts, assignments, theta = state.scene_changes(
            scene, touched, previous, h.k_rule.max_contexts + 1
        )
        return SceneUpdate(
            scene_index=scene,
            word_ids=ids,
            assignments=assignments,
            reassigned_tokens=reassigned,
            reassigned_contexts=contexts,
            previous_contexts=previous_contexts,
            changed_counts=changed_counts,
            contexts_before=contexts_before,
            contexts_after=state.n_contexts,
            vocabulary_additions=tuple(additions),
            rng_state=dict(self._rng.bit_generator.state),
            rng_state_before=rng_state_before,
            context_posterior=theta,
            growth_checked=growth_checked,
        )

    def undo_scene(self, update: SceneUpdate) -> None:
        """Take back ``update``, the last :meth:`learn_scene` (its write to storage failed): the
        model is then exactly as before it, assignments, counts, vocabulary and random state (a
        retry of the scene learns it as the first try would have). Raises ValueError when
        ``update`` is not the model's last change; the model must then be rebuilt from storage.
        """
        state = self._state
        vocab_size = len(self._vocabulary) - len(update.vocabulary_additions)
        if (
            update.scene_index != state.n_documents - 1
            or update.contexts_after != state.n_contexts
            or tuple(self._vocabulary[vocab_size:]) != update.vocabulary_additions
            or not np.array_equal(state.assignments[state.doc_offsets[-2] :], update.assignments)
        ):
            raise ValueError(f"scene {update.scene_index} is not the model's last change")
        state.remove_last_scene(update.reassigned_tokens, update.previous_contexts, update.contexts_before, vocab_size)
        for word in update.vocabulary_additions:
            del self._index[word]
        del self._vocabulary[vocab_size:]
        self._rng.bit_generator.state = update.rng_state_before

    def _grow_contexts(self, first_doc: int, online: bool) -> None:
        """Algorithm 2's inner loop on scenes ``first_doc:`` (all of them in batch, the window
        online): the K rule opens contexts one at a time until it declines or K reaches the cap."""
        state, h = self._state, self.hyperparameters
        while state.n_contexts < h.k_rule.max_contexts:
            if not self._k_rule.grow(state, self._rng, first_doc, online=online, sweeps=h.sampler.sweeps):
                return

    # Using the model.

    def infer_scene(self, words: Sequence[str], *, seed: int = 0) -> np.ndarray:
        """Context posterior θ (K,) of an unseen scene, by fold-in Gibbs sampling against the
        current counts (the model, including its random state, is left unchanged), with the random
        numbers of ``np.random.default_rng(seed)``, memoised per seed (:class:`SeededUniforms`).

        Concepts the model has never seen carry no evidence and are ignored; a scene of
        only such concepts gets the uniform prior.
        """
        uniforms = SeededUniforms(_validated_seed(seed))
        known = self._known_ids(words)
        if known.shape[0] == 0:
            return np.full(self.n_contexts, 1.0 / self.n_contexts)
        sampler = self.hyperparameters.sampler
        return self._state.fold_in(known, uniforms, sampler.inference_sweeps, sampler.inference_burn_in)

    def _known_ids(self, words: Any) -> np.ndarray:
        """The model ids of the scene ``words`` in order, leaving out the words it has never seen,
        after validating the scene (``_scene_words``; in one pass when it knows them all,
        :meth:`_ids_if_all_known`)."""
        ids = self._ids_if_all_known(words)
        if ids is not None:
            return ids
        index = self._index
        return np.fromiter((index[w] for w in _scene_words(words) if w in index), dtype=np.int32)

    def _ids_if_all_known(self, words: Any) -> np.ndarray | None:
        """The ids (int32) of ``words`` when they are a non-empty list or tuple of concepts the
        model knows, else None. Every key is a non-empty ``str``, so this one pass of dict lookups
        in C also validates the scene: the common case needs no separate check (a fold-in of a
        5-object scene spent 2.7 of its 24 µs on it) and costs half a filter."""
        if type(words) not in (list, tuple) or not words:
            return None
        try:
            return np.fromiter(map(self._index.__getitem__, words), dtype=np.int32, count=len(words))
        except (KeyError, TypeError):  # an unknown word, or an entry that is not a valid name at all
            return None

    def context_posterior(self, scene: Sequence[str] | int, *, seed: int = 0) -> np.ndarray:
        """P(χ | scene), (K,): a learned scene by index (its θ), or an unseen one by its concepts."""
        if isinstance(scene, int | np.integer) and not isinstance(scene, bool):
            if not 0 <= scene < self.n_scenes:
                raise InvalidInputError("scene", f"no learned scene {scene} (there are {self.n_scenes})")
            return self._state.context_given_scene(int(scene), int(scene) + 1)[0]
        # Concept names; a bool lands here too, and infer_scene's validation refuses it by name.
        return self.infer_scene(cast(Sequence[str], scene), seed=seed)

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
            [(self._vocabulary[w], float(phi[c, w]), float(relevance[c, w])) for w in row]
            for c, row in enumerate(order)
        ]

    def entropy(self, rho: float = PAPER_RHO) -> float:
        """H̃ of Eq. 8 over the learned scenes (see :func:`metrics.contextual_entropy`)."""
        if self.n_scenes == 0:
            raise InvalidInputError("scenes", "the model has learned no scene yet")
        return contextual_entropy(self.concept_given_context(), self._state.context_given_scene(), rho)

    def low_confidence_concepts(self, tau: float | None = None) -> list[str]:
        """C_low under τ (the ``paper`` rule's set), by name; τ by default the model's own under
        the ``paper`` rule, else the paper rule's default :data:`PAPER_TAU` (Fig. 11 measures
        |C_low| under every rule)."""
        if tau is None:
            tau = getattr(self.hyperparameters.k_rule, "tau", PAPER_TAU)
        mask = low_confidence_concepts(self._state, tau)
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
            rng_state=dict(self._rng.bit_generator.state),
        )

    @classmethod
    def from_state(cls, saved: ContextModelState) -> IncrementalLDA:
        """The model exactly as exported: it continues as the original would have."""
        try:
            hyperparameters = Hyperparameters.from_dict(saved.hyperparameters)
        except InvalidInputError as error:
            raise InvalidInputError(f"state.hyperparameters.{error.field}", error.problem) from None
        model = cls(saved.vocabulary, hyperparameters=hyperparameters)
        words = _state_array(saved.words, "state.words")
        assignments = _state_array(saved.assignments, "state.assignments")
        offsets = _state_array(saved.doc_offsets, "state.doc_offsets")
        h = model.hyperparameters
        n_contexts = saved.n_contexts
        if isinstance(n_contexts, bool) or not (
            isinstance(n_contexts, int | np.integer) and 1 <= n_contexts <= h.k_rule.max_contexts
        ):
            raise InvalidInputError("state.n_contexts", f"must be in 1..max_contexts, got {n_contexts!r}")
        problems = layout_problems(words, assignments, offsets, len(model._vocabulary), int(n_contexts))
        if problems:
            raise InvalidInputError("state", "; ".join(problems))
        state = LDAState.from_arrays(
            h.priors.alpha, h.priors.xi, len(model._vocabulary), int(n_contexts), words, assignments, offsets
        )
        if saved.n_kw is not None and not np.array_equal(np.asarray(saved.n_kw), state.n_kw):
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
        moved: np.ndarray,
        added: np.ndarray,
        count_entries: np.ndarray,
        scene_count: int,
        rng_state: dict[str, Any],
    ) -> None:
        """Bring the model to a later stored state from what changed since it (docs/scaling.md).

        ``moved`` holds (id, context) rows of earlier tokens and their new contexts; ``added``
        (scene, concept, context) rows of the new tokens, which continue the corpus as whole new
        scenes; ``count_entries`` the (context, concept, count) n_kw entries that changed, checked
        against the counts the tokens give. Raises InvalidInputError (nothing proven, the caller
        must reload) when the changes do not fit this model.
        """
        state = self._state
        if n_contexts < state.n_contexts or n_contexts > self.hyperparameters.k_rule.max_contexts:
            raise InvalidInputError("state.n_contexts", f"{n_contexts} does not follow {state.n_contexts}")
        moved = np.asarray(moved, dtype=np.int64).reshape(-1, 2)
        added = np.asarray(added, dtype=np.int64).reshape(-1, 3)
        self._add_concepts(list(new_words))
        if (added.size and (added[:, 1].max() >= state.vocab_size or added[:, 2].max() >= n_contexts)) or (
            moved.size and moved[:, 1].max() >= n_contexts
        ):
            raise InvalidInputError("state.tokens", "a changed token names an unknown concept or context")
        while state.n_contexts < n_contexts:
            state.add_context()
        if moved.size:
            if moved[:, 0].min() < 0 or moved[:, 0].max() >= state.n_tokens:
                raise InvalidInputError("state.tokens", "a reassigned token is not in memory")
            state.reassign(moved[:, 0], moved[:, 1].astype(np.int32))
        if added.size:
            scenes, lengths = np.unique(added[:, 0], return_counts=True)
            expected_scenes = np.arange(state.n_documents, state.n_documents + scenes.shape[0])
            if not np.array_equal(scenes, expected_scenes):
                raise InvalidInputError("state.tokens", "the new tokens do not form whole scenes after the last one")
            if np.any(np.diff(added[:, 0]) < 0):
                raise InvalidInputError("state.tokens", "the new tokens' scenes are out of order")
            state.append_assigned_scenes(
                added[:, 1].astype(np.int32), added[:, 2].astype(np.int32), lengths.astype(np.int32)
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

    def _scene_ids(self, words: Any) -> tuple[np.ndarray, list[str]]:
        """The scene's concept ids (int32) and the concepts it adds to the vocabulary, in order,
        after validating the scene (``_scene_words``; in one pass when every concept is known,
        :meth:`_ids_if_all_known`) and checking that the model has room for it (:meth:`LDAState.check_room`)."""
        ids = self._ids_if_all_known(words)
        if ids is not None:
            self._state.check_room(ids.shape[0])
            return ids, []
        words = _scene_words(words)
        self._state.check_room(len(words))  # before the vocabulary grows: a refused scene changes nothing
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
    """``values`` as an integer array that int32 holds, without a copy when its type is int32 or
    narrower (a start at a million scenes holds ~78 million tokens: a copy of one of their arrays
    is 312 MB; ``LDAState.from_arrays`` widens them as it copies them into the model's own).
    Values of a wider type are refused when int32 cannot hold them, not wrapped into range."""
    array = np.asarray(values)
    if array.ndim != 1 or (array.size and not np.issubdtype(array.dtype, np.integer)):
        raise InvalidInputError(field_name, "must be a one-dimensional integer array")
    if np.can_cast(array.dtype, np.int32):
        return array
    bounds = np.iinfo(np.int32)
    if array.size and (array.min() < bounds.min or array.max() > bounds.max):
        raise InvalidInputError(field_name, "holds values outside the 32-bit integer range")
    return array.astype(np.int32)
