"""Numba kernels of the collapsed Gibbs sampler for LDA (Eq. 5).

The corpus is flat: ``words[i]`` is the concept id of token ``i``, ``z[i]`` its
context, and document ``d`` owns tokens ``doc_offsets[d]:doc_offsets[d + 1]``.
Counts are ``n_wk`` (word × context: a word's counts over contexts are
contiguous, which is what Eq. 5 reads for every token), ``n_k`` and ``n_dk``;
only the first ``n_contexts`` columns are live (the arrays keep spare capacity).

Randomness comes in as ``uniforms`` drawn by the caller's
``np.random.Generator``, one per sampled token, so a kernel never touches global
random state and a model restored with its generator state continues
bit-identically.
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True, nogil=True, inline="always")
def _draw(cumulative: np.ndarray, n_contexts: int, u: float) -> int:
    target = u * cumulative[n_contexts - 1]
    k = 0
    while k < n_contexts - 1 and cumulative[k] <= target:
        k += 1
    return k


@numba.njit(cache=True, nogil=True)
def _resample(
    i: int,
    d: int,
    words: np.ndarray,
    z: np.ndarray,
    n_wk: np.ndarray,
    n_k: np.ndarray,
    n_dk: np.ndarray,
    n_contexts: int,
    alpha: float,
    xi: float,
    v_xi: float,
    inverse: np.ndarray,
    cumulative: np.ndarray,
    u: float,
) -> None:
    """One draw of Eq. 5 for token ``i`` of document ``d`` (z < 0: not yet assigned).

    Eq. 5's document denominator ``N_d + Kα`` is the same for every context and
    cancels; ``inverse[k] = 1 / (n_k + |W|ξ)`` is kept up to date for the two
    contexts the token leaves and joins.
    """
    w = words[i]
    old = z[i]
    if old >= 0:
        n_wk[w, old] -= 1
        n_k[old] -= 1
        n_dk[d, old] -= 1
        inverse[old] = 1.0 / (n_k[old] + v_xi)
    total = 0.0
    for k in range(n_contexts):
        total += (n_wk[w, k] + xi) * inverse[k] * (n_dk[d, k] + alpha)
        cumulative[k] = total
    new = _draw(cumulative, n_contexts, u)
    z[i] = new
    n_wk[w, new] += 1
    n_k[new] += 1
    n_dk[d, new] += 1
    inverse[new] = 1.0 / (n_k[new] + v_xi)


@numba.njit(cache=True, nogil=True, inline="always")
def _inverse_totals(n_k: np.ndarray, n_contexts: int, v_xi: float) -> np.ndarray:
    inverse = np.empty(n_contexts)
    for k in range(n_contexts):
        inverse[k] = 1.0 / (n_k[k] + v_xi)
    return inverse


@numba.njit(cache=True, nogil=True)
def sweep_documents(
    words: np.ndarray,
    z: np.ndarray,
    doc_offsets: np.ndarray,
    first_doc: int,
    stop_doc: int,
    n_wk: np.ndarray,
    n_k: np.ndarray,
    n_dk: np.ndarray,
    n_contexts: int,
    alpha: float,
    xi: float,
    vocab_size: int,
    uniforms: np.ndarray,
) -> None:
    """One Gibbs sweep over the tokens of documents ``first_doc:stop_doc`` (Algorithm 1, Eq. 5).

    The step of :func:`_resample` is written out here: this is the hot loop, and
    calling the helper halves its throughput (measured).
    """
    v_xi = vocab_size * xi
    inverse = _inverse_totals(n_k, n_contexts, v_xi)
    cumulative = np.empty(n_contexts)
    u_index = 0
    for d in range(first_doc, stop_doc):
        for i in range(doc_offsets[d], doc_offsets[d + 1]):
            w = words[i]
            old = z[i]
            n_wk[w, old] -= 1
            n_k[old] -= 1
            n_dk[d, old] -= 1
            inverse[old] = 1.0 / (n_k[old] + v_xi)
            total = 0.0
            for k in range(n_contexts):
                total += (n_wk[w, k] + xi) * inverse[k] * (n_dk[d, k] + alpha)
                cumulative[k] = total
            new = _draw(cumulative, n_contexts, uniforms[u_index])
            u_index += 1
            z[i] = new
            n_wk[w, new] += 1
            n_k[new] += 1
            n_dk[d, new] += 1
            inverse[new] = 1.0 / (n_k[new] + v_xi)


@numba.njit(cache=True, nogil=True)
def sample_tokens(
    tokens: np.ndarray,
    token_docs: np.ndarray,
    words: np.ndarray,
    z: np.ndarray,
    n_wk: np.ndarray,
    n_k: np.ndarray,
    n_dk: np.ndarray,
    n_contexts: int,
    alpha: float,
    xi: float,
    vocab_size: int,
    uniforms: np.ndarray,
) -> None:
    """Resample the listed tokens in order (Eq. 5); a token with ``z < 0`` is unassigned
    and gets its first context from the counts of everything sampled before it."""
    v_xi = vocab_size * xi
    inverse = _inverse_totals(n_k, n_contexts, v_xi)
    cumulative = np.empty(n_contexts)
    for j in range(tokens.shape[0]):
        _resample(
            tokens[j],
            token_docs[j],
            words,
            z,
            n_wk,
            n_k,
            n_dk,
            n_contexts,
            alpha,
            xi,
            v_xi,
            inverse,
            cumulative,
            uniforms[j],
        )


@numba.njit(cache=True, nogil=True)
def fold_in(
    word_ids: np.ndarray,
    n_wk: np.ndarray,
    n_k: np.ndarray,
    n_contexts: int,
    alpha: float,
    xi: float,
    vocab_size: int,
    burn_in: int,
    uniforms: np.ndarray,
) -> np.ndarray:
    """Context posterior θ of one unseen document, without touching the model's counts.

    The document's own tokens are counted in a local table over its distinct
    concepts, added to the model's ``n_wk`` on the fly, so the result equals
    sampling the document into a copy of the model. The first ``burn_in`` sweeps
    are discarded; θ = (n_dk + α) / (N_d + Kα) is averaged over the remaining
    sweeps (``uniforms`` holds one number per token per sweep).
    """
    n_tokens = word_ids.shape[0]
    order = np.argsort(word_ids)
    local_words = np.empty(n_tokens, dtype=np.int64)
    distinct = np.empty(n_tokens, dtype=np.int64)
    n_distinct = 0
    for j in range(n_tokens):
        i = order[j]
        if n_distinct == 0 or distinct[n_distinct - 1] != word_ids[i]:
            distinct[n_distinct] = word_ids[i]
            n_distinct += 1
        local_words[i] = n_distinct - 1
    sweeps = uniforms.shape[0] // n_tokens
    v_xi = vocab_size * xi
    local_wk = np.zeros((n_distinct, n_contexts), dtype=np.int64)
    local_k = np.zeros(n_contexts, dtype=np.int64)
    n_dk = np.zeros(n_contexts, dtype=np.int64)
    z = np.full(n_tokens, -1, dtype=np.int64)
    cumulative = np.empty(n_contexts)
    theta = np.zeros(n_contexts)
    u_index = 0
    for sweep in range(sweeps):
        for i in range(n_tokens):
            u = local_words[i]
            w = word_ids[i]
            old = z[i]
            if old >= 0:
                local_wk[u, old] -= 1
                local_k[old] -= 1
                n_dk[old] -= 1
            total = 0.0
            for k in range(n_contexts):
                total += (n_wk[w, k] + local_wk[u, k] + xi) / (n_k[k] + local_k[k] + v_xi) * (n_dk[k] + alpha)
                cumulative[k] = total
            new = _draw(cumulative, n_contexts, uniforms[u_index])
            u_index += 1
            z[i] = new
            local_wk[u, new] += 1
            local_k[new] += 1
            n_dk[new] += 1
        if sweep >= burn_in:
            for k in range(n_contexts):
                theta[k] += n_dk[k] + alpha
    return theta / theta.sum()


@numba.njit(cache=True, nogil=True)
def conditional_entropy(
    words: np.ndarray,
    z: np.ndarray,
    doc_offsets: np.ndarray,
    first_doc: int,
    stop_doc: int,
    n_wk: np.ndarray,
    n_k: np.ndarray,
    n_dk: np.ndarray,
    n_contexts: int,
    alpha: float,
    xi: float,
    vocab_size: int,
) -> float:
    """Σ_i H(z_i | z_¬i, w): the entropies of Eq. 5's conditionals, summed over the
    tokens of documents ``first_doc:stop_doc`` (read-only: nothing is resampled)."""
    v_xi = vocab_size * xi
    p = np.empty(n_contexts)
    entropy = 0.0
    for d in range(first_doc, stop_doc):
        for i in range(doc_offsets[d], doc_offsets[d + 1]):
            w = words[i]
            own = z[i]
            total = 0.0
            for k in range(n_contexts):
                mine = 1 if k == own else 0
                p[k] = (n_wk[w, k] - mine + xi) / (n_k[k] - mine + v_xi) * (n_dk[d, k] - mine + alpha)
                total += p[k]
            for k in range(n_contexts):
                if p[k] > 0.0:
                    q = p[k] / total
                    entropy -= q * math.log(q)
    return entropy


@numba.njit(cache=True, nogil=True)
def reassign_tokens(
    tokens: np.ndarray,
    token_docs: np.ndarray,
    new_contexts: np.ndarray,
    words: np.ndarray,
    z: np.ndarray,
    n_wk: np.ndarray,
    n_k: np.ndarray,
    n_dk: np.ndarray,
) -> None:
    """Set ``z[tokens] = new_contexts`` and move their counts along (assigned tokens only)."""
    for j in range(tokens.shape[0]):
        i = tokens[j]
        d = token_docs[j]
        w = words[i]
        old = z[i]
        new = new_contexts[j]
        if old == new:
            continue
        n_wk[w, old] -= 1
        n_k[old] -= 1
        n_dk[d, old] -= 1
        z[i] = new
        n_wk[w, new] += 1
        n_k[new] += 1
        n_dk[d, new] += 1


@numba.njit(cache=True, nogil=True, inline="always")
def _count_block(
    block: np.ndarray, n_block: int, d: int, k: int, change: int,
    words: np.ndarray, n_wk: np.ndarray, n_k: np.ndarray, n_dk: np.ndarray,
) -> None:  # fmt: skip
    """Add ``change`` to the counts of the first ``n_block`` tokens of ``block`` in context k."""
    for j in range(n_block):
        w = words[block[j]]
        n_wk[w, k] += change
        n_k[k] += change
        n_dk[d, k] += change


@numba.njit(cache=True, nogil=True, inline="always")
def _block_log_weight(
    block: np.ndarray, n_block: int, d: int, k: int,
    words: np.ndarray, n_wk: np.ndarray, n_k: np.ndarray, n_dk: np.ndarray,
    alpha: float, xi: float, v_xi: float,
) -> float:  # fmt: skip
    """log P(whole block in context k | every other token), up to a term common to every k:
    the block's tokens, uncounted, join k one by one and Eq. 5's numerators multiply up
    (the collapsed Dirichlet-multinomial terms of k and of scene d). The tokens stay counted in k."""
    log_weight = 0.0
    weight = 1.0  # a running product, moved into the log before it can under- or overflow: few logs
    for j in range(n_block):
        w = words[block[j]]
        weight *= (n_wk[w, k] + xi) / (n_k[k] + v_xi) * (n_dk[d, k] + alpha)
        if not 1e-200 < weight < 1e200:
            log_weight += math.log(weight)
            weight = 1.0
        n_wk[w, k] += 1
        n_k[k] += 1
        n_dk[d, k] += 1
    return log_weight + math.log(weight)


@numba.njit(cache=True, nogil=True)
def split_scenes(
    words: np.ndarray,
    z: np.ndarray,
    doc_offsets: np.ndarray,
    scene_order: np.ndarray,
    previous_context: np.ndarray,
    anchored: np.ndarray,
    n_wk: np.ndarray,
    n_k: np.ndarray,
    n_dk: np.ndarray,
    new_context: int,
    alpha: float,
    xi: float,
    vocab_size: int,
    uniforms: np.ndarray,
) -> None:
    """Restricted blocked Gibbs scans between each scene's previous context and the new one.

    At every visit of a scene ``d`` (``scene_order`` lists one visit per scene per scan),
    its block is its tokens in ``previous_context[d]`` or in ``new_context`` that are not
    ``anchored`` (one flag per token of the corpus). The whole block goes to one of the two
    contexts, drawn from their exact collapsed probabilities given every other token
    (``uniforms``: one number per visit); the scene's other tokens stay where they are.
    """
    v_xi = vocab_size * xi
    longest = 0
    for d in range(doc_offsets.shape[0] - 1):
        longest = max(longest, doc_offsets[d + 1] - doc_offsets[d])
    block = np.empty(longest, dtype=np.int64)
    for visit in range(scene_order.shape[0]):
        d = scene_order[visit]
        previous = previous_context[d]
        n_block = 0
        for i in range(doc_offsets[d], doc_offsets[d + 1]):
            k = z[i]
            if not anchored[i] and (k == previous or k == new_context):
                block[n_block] = i
                n_block += 1
                n_wk[words[i], k] -= 1
                n_k[k] -= 1
                n_dk[d, k] -= 1
        if n_block == 0:
            continue
        stay = _block_log_weight(block, n_block, d, previous, words, n_wk, n_k, n_dk, alpha, xi, v_xi)
        _count_block(block, n_block, d, previous, -1, words, n_wk, n_k, n_dk)
        move = _block_log_weight(block, n_block, d, new_context, words, n_wk, n_k, n_dk, alpha, xi, v_xi)
        # P(move) = 1 / (1 + exp(stay - move)), in the form that stays finite for any difference.
        difference = stay - move
        if difference > 0.0:
            p_move = math.exp(-difference) / (1.0 + math.exp(-difference))
        else:
            p_move = 1.0 / (1.0 + math.exp(difference))
        target = new_context
        if uniforms[visit] >= p_move:
            target = previous
            _count_block(block, n_block, d, new_context, -1, words, n_wk, n_k, n_dk)
            _count_block(block, n_block, d, previous, 1, words, n_wk, n_k, n_dk)
        for j in range(n_block):
            z[block[j]] = target


@numba.njit(cache=True, nogil=True)
def scene_to_one_context(
    words: np.ndarray,
    z: np.ndarray,
    start: int,
    stop: int,
    d: int,
    n_wk: np.ndarray,
    n_k: np.ndarray,
    n_dk: np.ndarray,
    n_contexts: int,
    alpha: float,
    xi: float,
    vocab_size: int,
    u: float,
) -> int:
    """Put the tokens ``start:stop`` of scene ``d`` (all of it) into one context, drawn from the
    exact collapsed probability of the whole block joining each context given every other
    token (Eq. 5's numerators multiplied up, :func:`_block_log_weight`); returns the context.
    Tokens with z = -1 are new; the others leave their contexts first."""
    v_xi = vocab_size * xi
    n_block = stop - start
    block = np.arange(start, stop)
    for i in range(start, stop):
        if z[i] >= 0:
            n_wk[words[i], z[i]] -= 1
            n_k[z[i]] -= 1
            n_dk[d, z[i]] -= 1
    log_weights = np.empty(n_contexts)
    best = -np.inf
    for k in range(n_contexts):
        log_weights[k] = _block_log_weight(block, n_block, d, k, words, n_wk, n_k, n_dk, alpha, xi, v_xi)
        _count_block(block, n_block, d, k, -1, words, n_wk, n_k, n_dk)
        best = max(best, log_weights[k])
    total = 0.0
    for k in range(n_contexts):
        total += math.exp(log_weights[k] - best)
        log_weights[k] = total  # now cumulative
    target = _draw(log_weights, n_contexts, u)
    _count_block(block, n_block, d, target, 1, words, n_wk, n_k, n_dk)
    for i in range(start, stop):
        z[i] = target
    return target
