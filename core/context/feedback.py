"""Context fed back into the concept webs (§IV-D, Eq. 6, Fig. 6(b)).

A scene of several objects is interpreted in a loop until the webs and the
context agree (docs/feedback.md gives the reasons at length):

1. every object's concept web is settled on its perception (§III-B); the MAP
   configurations give the objects' active concepts, together the scene's LDA
   document (Table V);
2. the context posterior θ = P(χ | scene) is folded in against the context model
   (no learning: :meth:`IncrementalLDA.infer_scene`);
3. P(c | χ) = Σ_k θ_k P(c | k): the posterior-weighted mixture of the contexts'
   concept probabilities rather than those of the argmax context, because a
   mixed scene (Table VI) has no single context and a mixture degrades
   gracefully when θ is uncertain, where the argmax would commit to one guess;
4. Eq. 6, P*(c) = σ P(c) + (1 − σ) P(c | χ), with P(c) the MRF-decided
   probability of step 1, gives the in-context probabilities;
5. each web is settled again with P* as its evidence (the "reiteration of the
   concept webs"); its MAP configuration gives the object's new active
   concepts, and the loop goes back to 2 until the scene's document no longer
   changes.

The document holds the MAP concepts that carry evidence: the noun, the
adjectives and the verbs whose behaviour was applied (``applied``; every verb
when it is None), by the one rule of ``core.concept_web.active`` (which says why).

P(c) in Eq. 6 stays the web of step 1, settled on the perception: updating the
web's own output again and again would count its clique evidence at every turn
and drift towards 0 or 1 whatever the context. So the loop runs through the
context only, and a pass that reproduces the previous document is an exact
fixed point: every fold-in of one call uses the same ``seed``, so the same
document always gets the same θ. Otherwise the loop stops when θ moves by less
than ``tolerance``, or after ``max_iterations`` passes (``converged`` false).

P(c | k), one row per context, follows the vocabulary's structure: φ_k
restricted to the nouns and renormalised (an object has one noun), φ_k of each
adjective pair renormalised over the pair, and a verb's probability of being
active is its expected number of tokens per object of context k,
φ_k(verb) / Σ_nouns φ_k(noun) (every object adds exactly one noun token and at
most one token of each verb), clipped to 1. Contexts are normalised first and
then mixed, so that θ weighs contexts, not contexts times their noun mass.

Step 5's settlings are cheaper than step 1's, not different: each starts its
sum-product pass from the previous settling's messages (the evidence moves a
little from one pass to the next) and runs it undamped, which halves its
iterations; the max-product pass, which decides the document, runs exactly as a
plain ``ConceptWeb.infer`` (cold, damped). An object whose passes did not both
converge within ``UNDAMPED_ITERATIONS`` is settled again with the defaults.
The marginals agree with a cold damped settling within 1e-4 (both lie within
≈ 5e-5 of the LBP fixed point at the default tolerance; docs/feedback.md).

Two options trade for speed (docs/feedback.md, "Speed", has the measurements).
``marginals=False`` skips the in-context sum-product passes, whose marginals only
``in_context_web`` reports (None then): the documents, θ and P* do not change.
``warm_map=True`` starts each in-context max-product pass from the previous
settling's max-product messages (step 1's for the first) and runs it undamped:
about 2 iterations instead of 20. A max-product pass started elsewhere than
uniform can settle on another fixed point: on the paper world's service scenes
and the sigma experiment's it never changed a document (5,880 scenes), on the
noise experiment's scenes it changed 7 % of them; it stays deterministic (the
start is step 1's settling, a function of the inputs), and without step 1's
max-product messages every pass runs cold. The defaults keep the experiments'
numbers.

The context has no opinion on a group (the nouns, one adjective pair, the
verbs) of which its model has seen no token (a model that has learned no scene,
or one learned without verbs): there P*(c) is the web's P(c), whatever σ.
"""

from __future__ import annotations

import functools
import itertools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from core.concept_web import ConceptWeb, WebInference
from core.concept_web.active import active_concepts, carries_evidence
from core.context.incremental import IncrementalLDA
from core.context.lda import SeededUniforms
from core.errors import InvalidInputError
from core.vocabulary import Vocabulary

#: σ of Eq. 6 that the paper chooses from Fig. 9's interval [0.4, 0.5].
PAPER_SIGMA = 0.5
#: How P(c) and P(c | χ) are pooled: Eq. 6's weighted sum (``linear``, the paper's), or the
#: weighted geometric mean renormalised within each group (``log``; docs/feedback.md, "The hard world").
POOLING_RULES: tuple[str, ...] = ("linear", "log")
PAPER_POOLING = "linear"
DEFAULT_TOLERANCE = 1e-6
DEFAULT_MAX_ITERATIONS = 10
#: Iterations an in-context sum-product pass may take undamped before the object is settled again with the defaults.
UNDAMPED_ITERATIONS = 30


@dataclass(frozen=True)
class ContextConcepts:
    """P(c | χ = k) per context, (K, n_concepts) in ``vocabulary.concepts`` order, and which
    concepts the context has an opinion on (``informed``, (n_concepts,))."""

    given_context: np.ndarray
    informed: np.ndarray

    def mixture(self, context_posterior: np.ndarray) -> np.ndarray:
        """P(c | χ) = Σ_k θ_k P(c | k) of a scene with context posterior θ."""
        return context_posterior @ self.given_context


@dataclass(frozen=True)
class FeedbackResult:
    """One scene interpreted in context; arrays are (n_objects, n_concepts) in vocabulary order.

    ``web`` is the concept web on the perception alone; ``in_context`` P*(c) of
    Eq. 6 when the loop stopped (σ = 1 gives ``web``, σ = 0 the context's
    P(c | χ)); ``in_context_web`` the webs settled on P*, whose decisions are the
    paper's "in context" recognition (Table VII, Fig. 13), None when the call
    asked for no ``marginals``. ``context_concepts``
    is the scene's P(c | χ) (NaN where the context has no opinion),
    ``active_concepts`` each object's words in the in-context scene document
    (MAP concepts of its in-context web that carry evidence), and
    ``iterations`` counts the passes (in-context settlings of the webs).
    """

    perception: np.ndarray
    web: np.ndarray
    in_context: np.ndarray
    in_context_web: np.ndarray | None
    context_posterior: np.ndarray
    context_concepts: np.ndarray
    active_concepts: tuple[tuple[str, ...], ...]
    iterations: int
    converged: bool


def context_concepts(context_model: IncrementalLDA, vocabulary: Vocabulary) -> ContextConcepts:
    """The context model's P(c | k) over ``vocabulary``, matched by concept name and
    normalised by the vocabulary's structure (module docstring)."""
    if not isinstance(context_model, IncrementalLDA):
        raise InvalidInputError("context_model", f"expected an IncrementalLDA, got {type(context_model).__name__}")
    if not isinstance(vocabulary, Vocabulary):
        raise InvalidInputError("vocabulary", f"expected a Vocabulary, got {type(vocabulary).__name__}")
    state = context_model.lda_state
    if state.n_tokens == 0:
        return ContextConcepts(
            np.zeros((state.n_contexts, len(vocabulary.concepts))), np.zeros(len(vocabulary.concepts), bool)
        )
    counts = state.n_kw[:, _layout(vocabulary, context_model.vocabulary).column]
    return _memoised_context_concepts(
        vocabulary,
        context_model.vocabulary,
        counts.shape,
        counts.dtype.str,
        counts.tobytes(),
        state.n_k.dtype.str,
        state.n_k.tobytes(),
        state.vocab_size,
        state.xi,
    )


@functools.lru_cache(maxsize=256)
def _memoised_context_concepts(
    vocabulary: Vocabulary,
    model_vocabulary: tuple[str, ...],
    shape: tuple[int, int],
    dtype: str,
    counts_bytes: bytes,
    totals_dtype: str,
    totals_bytes: bytes,
    vocab_size: int,
    xi: float,
) -> ContextConcepts:
    """:func:`context_concepts` from everything it reads (the vocabulary's counts, n_k, |W|, ξ),
    memoised on their bytes: the scenes of a serving model ask again and again between two
    learned scenes, and a key made of the counts themselves can never be stale. The arrays are
    read-only, as they are shared between callers."""
    given, informed = _context_concepts(
        _layout(vocabulary, model_vocabulary),
        np.frombuffer(counts_bytes, dtype=dtype).reshape(shape),
        np.frombuffer(totals_bytes, dtype=totals_dtype),
        vocab_size,
        xi,
    )
    given.flags.writeable = False
    informed.flags.writeable = False
    return ContextConcepts(given, informed)


def _context_concepts(
    layout: _ConceptLayout, counts: np.ndarray, n_k: np.ndarray, vocab_size: int, xi: float
) -> tuple[np.ndarray, np.ndarray]:
    """P(c | k) and ``informed`` of a model with tokens, from its counts of the vocabulary's concepts."""
    given = np.zeros(counts.shape)
    informed = np.zeros(counts.shape[1], dtype=bool)
    known = layout.known
    # φ = (n_kw + ξ) / (n_k + |W|ξ) of the vocabulary's concepts; a concept the model never met
    # has the φ of a concept with no token.
    denominator = n_k[:, None] + vocab_size * xi
    phi = (counts + xi) / denominator
    if not layout.all_known:
        phi = np.where(known, phi, xi / denominator)
    seen = known & (counts.sum(axis=0) > 0)
    # The nouns (group 0) and each adjective pair: φ renormalised over the group, where it has a token.
    # Each group's total adds its concepts in vocabulary order (what a bincount over the group does).
    n_nouns, grouped = layout.n_nouns, layout.n_grouped
    noun_total = phi[:, 0].copy()
    for noun in range(1, n_nouns):
        noun_total += phi[:, noun]
    totals = np.concatenate(
        [noun_total[:, None], phi[:, n_nouns:grouped:2] + phi[:, n_nouns + 1 : grouped : 2]], axis=1
    )
    group_seen = np.bincount(layout.grouped_group[seen[:grouped]], minlength=layout.n_groups) > 0
    if group_seen.all():
        given[:, :grouped] = phi[:, :grouped] / totals[:, layout.grouped_group]
        informed[:grouped] = True
    else:
        normalised = layout.grouped & group_seen[layout.group_or_0]
        given[:, normalised] = phi[:, normalised] / totals[:, layout.group[normalised]]
        informed[normalised] = True
    verbs = layout.verbs
    if verbs.size and informed[:n_nouns].any() and seen[verbs].any():
        per_object = phi[:, verbs] / noun_total[:, None]
        given[:, verbs] = np.minimum(per_object, 1.0)
        informed[verbs] = True
    return given, informed


@dataclass(frozen=True)
class _ConceptLayout:
    """Where a vocabulary's concepts sit in a context model's vocabulary, and their groups."""

    known: np.ndarray
    all_known: bool
    column: np.ndarray
    group: np.ndarray
    """0 for a noun, 1 + p for adjective pair p, -1 for a verb."""
    grouped: np.ndarray
    """The concepts of a group (the nouns and adjectives), as a mask."""
    grouped_group: np.ndarray
    """``group[grouped]``."""
    group_or_0: np.ndarray
    """``max(group, 0)``."""
    n_groups: int
    n_nouns: int
    n_grouped: int
    """The nouns and adjectives, which come first, in that order."""
    verbs: np.ndarray


@functools.lru_cache(maxsize=64)
def _layout(vocabulary: Vocabulary, model_vocabulary: tuple[str, ...]) -> _ConceptLayout:
    """Memoised: a context model's vocabulary only grows, so a serving model meets a handful."""
    names = vocabulary.concepts
    position = {name: i for i, name in enumerate(model_vocabulary)}
    columns = np.array([position.get(name, -1) for name in names])
    n_nouns, n_pairs = len(vocabulary.nouns), len(vocabulary.adjective_pairs)
    n_verbs = len(names) - n_nouns - 2 * n_pairs
    group = np.concatenate([np.zeros(n_nouns, int), 1 + np.repeat(np.arange(n_pairs), 2), np.full(n_verbs, -1)])
    layout = _ConceptLayout(
        known=columns >= 0,
        all_known=bool((columns >= 0).all()),
        column=np.maximum(columns, 0),
        group=group,
        grouped=group >= 0,
        grouped_group=group[group >= 0],
        group_or_0=np.maximum(group, 0),
        n_groups=1 + n_pairs,
        n_nouns=n_nouns,
        n_grouped=n_nouns + 2 * n_pairs,
        verbs=np.arange(n_nouns + 2 * n_pairs, len(names)),
    )
    for array in (
        layout.known,
        layout.column,
        layout.group,
        layout.grouped,
        layout.grouped_group,
        layout.group_or_0,
        layout.verbs,
    ):
        array.flags.writeable = False
    return layout


def contextual_feedback(
    web: ConceptWeb,
    context_model: IncrementalLDA,
    perceptions: Any,
    vocabulary: Vocabulary,
    *,
    applied: np.ndarray | None = None,
    sigma: float = PAPER_SIGMA,
    tolerance: float = DEFAULT_TOLERANCE,
    max_iterations: int = DEFAULT_MAX_ITERATIONS,
    seed: int = 0,
    perceived: Sequence[WebInference] | None = None,
    marginals: bool = True,
    warm_map: bool = False,
    pooling: str = PAPER_POOLING,
) -> FeedbackResult:
    """Interpret a scene's objects in context by iterating webs, context and Eq. 6 (§IV-D).

    ``perceptions`` (n_objects, n_concepts) are the objects' perception
    probabilities in ``vocabulary.concepts`` order (as :func:`core.prototypes.perceive`
    gives them); ``applied`` (n_objects, n_verbs) marks the verbs whose behaviour
    was applied (see :meth:`ConceptWeb.infer`). ``sigma`` = 1 is the web alone,
    0 the context alone. ``perceived`` is step 1 when the caller has already run it:
    ``web.infer_many(perceptions, applied=applied)``, one inference per object (a
    service that shows the web on the perception alone need not settle it twice).

    Two options for a caller that wants speed (docs/feedback.md, "Speed"):
    ``marginals`` false skips the in-context webs' sum-product passes, so
    ``in_context_web`` is None (nothing else changes); ``warm_map`` starts each
    in-context max-product pass from the previous settling's max-product messages
    (step 1's ``perceived`` for the first) and runs it undamped, which can settle on
    another fixed point than the default cold start (measured there).

    ``pooling`` = ``linear`` is Eq. 6 as written; ``log`` pools P(c) and P(c | χ) as
    P(c)^σ P(c | χ)^(1-σ), renormalised over each group (:func:`pool`).
    """
    sigma, tolerance, max_iterations, seed = _checked_settings(sigma, tolerance, max_iterations, seed)
    if pooling not in POOLING_RULES:
        raise InvalidInputError("pooling", f"must be one of {POOLING_RULES}, got {pooling!r}")
    for name, flag in (("marginals", marginals), ("warm_map", warm_map)):
        if not isinstance(flag, bool):
            raise InvalidInputError(name, f"expected a bool, got {flag!r}")
    if not isinstance(web, ConceptWeb):
        raise InvalidInputError("web", f"expected a ConceptWeb, got {type(web).__name__}")
    if not isinstance(vocabulary, Vocabulary) or vocabulary.concepts != web.vocabulary.concepts:
        raise InvalidInputError("vocabulary", "must be the Vocabulary the concept web was fitted on")
    perceptions = _checked_perceptions(perceptions, len(vocabulary))
    table = context_concepts(context_model, vocabulary)
    if perceived is None:
        settled = web.infer_many(perceptions, applied=applied)
    elif len(perceived) != len(perceptions) or not all(isinstance(item, WebInference) for item in perceived):
        raise InvalidInputError("perceived", f"expected one WebInference per object ({len(perceptions)})")
    else:
        settled = list(perceived)
    plain = _marginals(settled)
    # Warm max-product passes need step 1's max-product messages; without them the whole loop runs cold.
    warm_map = warm_map and all(inference.max_messages is not None for inference in settled)
    every_verb = np.ones((len(perceptions), len(vocabulary.verbs)), dtype=bool)
    evidence = carries_evidence(vocabulary, every_verb if applied is None else applied)
    fold_in = _FoldIn(context_model, vocabulary, seed)
    document = _document(settled, evidence)
    theta = fold_in(document)
    converged = False
    for iteration in range(1, max_iterations + 1):
        context = table.mixture(theta)
        in_context = pool(plain, context, table.informed, sigma, vocabulary, pooling)
        settled = _settle(web, in_context, applied, settled, marginals=marginals, warm_map=warm_map)
        settled_document = _document(settled, evidence)
        if np.array_equal(settled_document, document):
            converged = True
            break
        settled_theta = fold_in(settled_document)
        if np.abs(settled_theta - theta).max() < tolerance:
            converged = True
            break
        document, theta = settled_document, settled_theta
    concepts = vocabulary.concepts
    return FeedbackResult(
        perception=perceptions,
        web=plain,
        in_context=in_context,
        in_context_web=_marginals(settled) if marginals else None,
        context_posterior=theta,
        context_concepts=np.where(table.informed, context, np.nan),
        active_concepts=tuple(tuple(itertools.compress(concepts, row)) for row in settled_document.tolist()),
        iterations=iteration,
        converged=converged,
    )


def pool(
    web: np.ndarray, context: np.ndarray, informed: np.ndarray, sigma: float, vocabulary: Vocabulary, rule: str
) -> np.ndarray:
    """P*(c) from the web's P(c) and the context's P(c | χ), where the context is ``informed``.

    ``linear`` is Eq. 6, σ P(c) + (1 - σ) P(c | χ). ``log`` is the logarithmic opinion pool
    P(c)^σ P(c | χ)^(1-σ), renormalised over the nouns, over each adjective pair, and over
    each verb's active/inactive: the context then acts as a prior that multiplies the web's
    odds, so a web sure of an in-context noun stays sure, and a noun the context rules out
    is ruled out (docs/feedback.md, "The hard world", has the measurements).
    """
    if rule == "linear":
        return np.where(informed, sigma * web + (1.0 - sigma) * context, web)
    floor = np.finfo(np.float64).tiny
    weights = np.where(informed, (np.maximum(web, floor) ** sigma) * (np.maximum(context, floor) ** (1.0 - sigma)), web)
    off = np.where(
        informed,
        (np.maximum(1.0 - web, floor) ** sigma) * (np.maximum(1.0 - context, floor) ** (1.0 - sigma)),
        1.0 - web,
    )
    pooled = np.empty_like(web)
    n_nouns, n_grouped = len(vocabulary.nouns), len(vocabulary.nouns) + len(vocabulary.adjectives)
    nouns = weights[:, :n_nouns]
    pooled[:, :n_nouns] = nouns / nouns.sum(axis=1, keepdims=True)
    pairs = weights[:, n_nouns:n_grouped].reshape(len(web), -1, 2)
    pooled[:, n_nouns:n_grouped] = (pairs / pairs.sum(axis=2, keepdims=True)).reshape(len(web), -1)
    verbs = weights[:, n_grouped:]
    pooled[:, n_grouped:] = verbs / (verbs + off[:, n_grouped:])
    return np.where(informed, pooled, web)


class _FoldIn:
    """θ of a scene document given as a (n_objects, n_concepts) mask: exactly
    ``context_model.infer_scene(_words(document, vocabulary), seed=seed)``, with the words'
    model ids read off the layout instead of spelt out and looked up one by one, and the
    fold-in's random numbers from :class:`SeededUniforms` (as ``infer_scene`` draws them)."""

    def __init__(self, context_model: IncrementalLDA, vocabulary: Vocabulary, seed: int) -> None:
        self._model, self._uniforms = context_model, SeededUniforms(seed)
        self._layout = _layout(vocabulary, context_model.vocabulary)
        self._n_concepts = len(vocabulary.concepts)

    def __call__(self, document: np.ndarray) -> np.ndarray:
        concepts = np.flatnonzero(document) % self._n_concepts
        ids = self._layout.column[concepts[self._layout.known[concepts]]].astype(np.int32)
        state = self._model.lda_state
        if ids.shape[0] == 0:
            return np.full(state.n_contexts, 1.0 / state.n_contexts)
        settings = self._model.hyperparameters.sampler
        return state.fold_in(ids, self._uniforms, settings.inference_sweeps, settings.inference_burn_in)


def _settle(
    web: ConceptWeb,
    evidence: np.ndarray,
    applied: np.ndarray | None,
    previous: Sequence[WebInference],
    *,
    marginals: bool,
    warm_map: bool,
) -> list[WebInference]:
    """The webs settled on the in-context evidence (module docstring): the sum-product pass
    warm-started from ``previous`` (the last settling) and undamped, or skipped without
    ``marginals``; the max-product pass as :meth:`ConceptWeb.infer` runs it by default, or,
    with ``warm_map`` and every previous settling's max-product messages at hand, started
    from those and undamped. An object whose passes did not both converge is settled again
    with the defaults only."""
    start = previous if marginals and all(item.messages is not None for item in previous) else None
    warm = warm_map and all(item.max_messages is not None for item in previous)
    settled = web.infer_many(
        evidence,
        applied=applied,
        start=start,
        sum_product=(0.0, UNDAMPED_ITERATIONS),
        max_start=previous if warm else None,
        max_product=(0.0, UNDAMPED_ITERATIONS) if warm else None,
        marginals=marginals,
    )
    unsettled = [i for i, inference in enumerate(settled) if not inference.converged]
    if unsettled:
        again = web.infer_many(
            evidence[unsettled],
            applied=None if applied is None else np.asarray(applied)[unsettled],
            marginals=marginals,
        )
        for i, inference in zip(unsettled, again, strict=True):
            settled[i] = inference
    return settled


def _marginals(settled: Sequence[WebInference]) -> np.ndarray:
    return np.array([inference.probabilities for inference in settled])


def _document(settled: Sequence[WebInference], evidence: np.ndarray) -> np.ndarray:
    """Each object's words of the scene's LDA document (Table V) as a (n_objects, n_concepts) mask:
    its MAP concepts that carry evidence."""
    return active_concepts(np.array([inference.map_configuration for inference in settled]), evidence)


def _words(document: np.ndarray, vocabulary: Vocabulary) -> list[str]:
    """The document's words, object by object, in vocabulary order (what :class:`_FoldIn` folds in)."""
    concepts = vocabulary.concepts
    return [concepts[i] for i in np.flatnonzero(document) % len(concepts)]


def _checked_settings(sigma: Any, tolerance: Any, max_iterations: Any, seed: Any) -> tuple[float, float, int, int]:
    def is_real(value: Any) -> bool:
        return (
            not isinstance(value, bool)
            and isinstance(value, (int, float, np.integer, np.floating))
            and bool(np.isfinite(value))
        )

    def is_integer(value: Any) -> bool:
        return not isinstance(value, bool) and isinstance(value, (int, np.integer))

    if not (is_real(sigma) and 0.0 <= sigma <= 1.0):
        raise InvalidInputError("sigma", f"σ of Eq. 6 must lie in [0, 1], got {sigma!r}")
    if not (is_real(tolerance) and tolerance > 0.0):
        raise InvalidInputError("tolerance", f"must be a positive number, got {tolerance!r}")
    if not (is_integer(max_iterations) and max_iterations >= 1):
        raise InvalidInputError("max_iterations", f"must be an integer >= 1, got {max_iterations!r}")
    if not (is_integer(seed) and seed >= 0):
        raise InvalidInputError("seed", f"must be an integer >= 0, got {seed!r}")
    return float(sigma), float(tolerance), int(max_iterations), int(seed)


def _checked_perceptions(perceptions: Any, n_concepts: int) -> np.ndarray:
    try:
        array = np.array(perceptions, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidInputError("perceptions", "must be a numeric (n_objects, n_concepts) array") from None
    if array.ndim != 2 or array.shape[0] < 1 or array.shape[1] != n_concepts:
        raise InvalidInputError("perceptions", f"expected shape (n_objects >= 1, {n_concepts}), got {array.shape}")
    if not (0.0 <= array.min() and array.max() <= 1.0):  # NaN fails both comparisons
        raise InvalidInputError("perceptions", "probabilities must be finite and lie in [0, 1]")
    return array
