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


@numba.njit(cache=True, nogil=True, inline="always")
def _inverse_totals(n_k: np.ndarray, n_contexts: int, v_xi: float, shift: int = 0) -> np.ndarray:
    """``1 / ((n_k + shift) + |W|ξ)`` per context (``shift = -1``: with one token taken out)."""
    inverse = np.empty(n_contexts)
    for k in range(n_contexts):
        inverse[k] = 1.0 / ((n_k[k] + shift) + v_xi)
    return inverse


# The sweeps below compute Eq. 5's conditional of token i from the full counts: the counts
# without token i (the ¬i of Eq. 5) differ from them only in i's own context z_i, by one, so
# only that context's term is written with n − 1 (``below[k] = 1 / ((n_k − 1) + |W|ξ)`` is kept
# beside ``inverse``). The counts are then written only when the token moves, which in a
# mixed chain is the exception: a token that stays costs no count update and no division.
# Every weight is the same floating-point expression, on the same values, as taking the token
# out, sampling and putting it back, so the draws are those of that textbook form bit for bit
# (tests/test_context_sweep_reference.py compares with it). error_model="numpy": ``below`` of an
# empty context may divide by zero (|W|ξ = 1); that entry is never read, since a token's own
# context holds at least that token.


@numba.njit(cache=True, nogil=True, error_model="numpy")
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
    """One Gibbs sweep over the tokens of documents ``first_doc:stop_doc`` (Algorithm 1, Eq. 5):
    K weights, one running cumulative sum, a linear search for ``u · Σ``.

    Counts are written only when a token moves (the comment above; the move is
    :func:`_move_token`). The weights and the draw are written out here rather than shared:
    this is the hot loop, and a helper for that step halved its throughput (measured, also with
    numba's ``inline="always"``).
    """
    v_xi = vocab_size * xi
    inverse = _inverse_totals(n_k, n_contexts, v_xi)
    below = _inverse_totals(n_k, n_contexts, v_xi, -1)
    cumulative = np.empty(n_contexts)
    u_index = 0
    for d in range(first_doc, stop_doc):
        for i in range(doc_offsets[d], doc_offsets[d + 1]):
            w = words[i]
            old = z[i]
            total = 0.0
            for k in range(old):
                total += (n_wk[w, k] + xi) * inverse[k] * (n_dk[d, k] + alpha)
                cumulative[k] = total
            total += ((n_wk[w, old] - 1) + xi) * below[old] * ((n_dk[d, old] - 1) + alpha)
            cumulative[old] = total
            for k in range(old + 1, n_contexts):
                total += (n_wk[w, k] + xi) * inverse[k] * (n_dk[d, k] + alpha)
                cumulative[k] = total
            new = _draw(cumulative, n_contexts, uniforms[u_index])
            u_index += 1
            if new != old:
                z[i] = new
                _move_token(w, d, old, new, n_wk, n_k, n_dk, inverse, below, v_xi)


@numba.njit(cache=True, nogil=True, inline="always")
def _move_token(
    w: int, d: int, old: int, new: int, n_wk: np.ndarray, n_k: np.ndarray, n_dk: np.ndarray,
    inverse: np.ndarray, below: np.ndarray, v_xi: float,
) -> None:  # fmt: skip
    """Move one token of concept ``w`` in scene ``d`` from context ``old`` to ``new``: its counts,
    and ``inverse``/``below`` of both contexts (each keeps ``1 / ((n_k [− 1]) + |W|ξ)``)."""
    n_wk[w, old] -= 1
    n_k[old] -= 1
    n_dk[d, old] -= 1
    inverse[old] = below[old]
    below[old] = 1.0 / ((n_k[old] - 1) + v_xi)
    n_wk[w, new] += 1
    n_k[new] += 1
    n_dk[d, new] += 1
    below[new] = inverse[new]
    inverse[new] = 1.0 / (n_k[new] + v_xi)


LANES = 8
"""Contexts k, k + 8, k + 16, ... form one lane of :func:`sweep_documents_by_lanes`."""


@numba.njit(cache=True, nogil=True, error_model="numpy")
def sweep_documents_by_lanes(
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
    """:func:`sweep_documents` for many contexts: the same Eq. 5 conditional, its cumulative
    sum taken in :data:`LANES` interleaved lanes instead of one running sum.

    Context k's weight is ``(n_wk + ξ) · c_k`` with ``c_k = (n_dk + α) / (n_k + |W|ξ)`` kept
    per scene (two entries change per move). The weights are computed in one pass the
    compiler vectorises, then the token's own context's entry is rewritten with its counts
    less one (the comment above :func:`sweep_documents`); the eight lane sums grow
    independently (one running sum chains K additions, each waiting for the one before); the
    draw ``u · Σ_k`` picks a lane, then a context within it. Same distribution as
    :func:`sweep_documents` (the order in which the contexts are laid out on [0, 1) differs,
    so the same ``u`` can give another context), one uniform per token.
    """
    v_xi = vocab_size * xi
    depth = (n_contexts + LANES - 1) // LANES
    padded = (depth + 1) // 2 * 2 * LANES  # an even number of rows
    last_lane = min(LANES, n_contexts) - 1
    inverse = _inverse_totals(n_k, n_contexts, v_xi)
    below = _inverse_totals(n_k, n_contexts, v_xi, -1)
    weights = np.zeros(padded)  # entries from n_contexts on stay 0
    coefficient = np.empty(n_contexts)
    u_index = 0
    for d in range(first_doc, stop_doc):
        for k in range(n_contexts):
            coefficient[k] = (n_dk[d, k] + alpha) * inverse[k]
        # The two coefficients a move changes are held here and written back only after the next
        # token's weights have been read in one vector pass, whose two stale entries are then
        # rewritten: a wide load of ``coefficient`` right after a narrow store into it waits for
        # that store (no store-to-load forwarding), which cost 10-25 % of a sweep while most
        # tokens move (docs/benchmarks.md). The weights are the same numbers.
        pending = False
        pending_old = pending_new = 0
        value_old = value_new = 0.0
        for i in range(doc_offsets[d], doc_offsets[d + 1]):
            w = words[i]
            old = z[i]
            for k in range(n_contexts):
                weights[k] = (n_wk[w, k] + xi) * coefficient[k]
            if pending:
                coefficient[pending_old] = value_old
                coefficient[pending_new] = value_new
                weights[pending_old] = (n_wk[w, pending_old] + xi) * value_old
                weights[pending_new] = (n_wk[w, pending_new] + xi) * value_new
                pending = False
            weights[old] = ((n_wk[w, old] - 1) + xi) * (((n_dk[d, old] - 1) + alpha) * below[old])
            # Lane sums in two sets (even and odd rows of eight), then the lane boundaries as a tree
            # of sums: three dependent additions each instead of ``depth`` and seven.
            a_0 = a_1 = a_2 = a_3 = a_4 = a_5 = a_6 = a_7 = 0.0
            b_0 = b_1 = b_2 = b_3 = b_4 = b_5 = b_6 = b_7 = 0.0
            for j in range(0, padded, 2 * LANES):
                a_0 += weights[j]
                a_1 += weights[j + 1]
                a_2 += weights[j + 2]
                a_3 += weights[j + 3]
                a_4 += weights[j + 4]
                a_5 += weights[j + 5]
                a_6 += weights[j + 6]
                a_7 += weights[j + 7]
                b_0 += weights[j + 8]
                b_1 += weights[j + 9]
                b_2 += weights[j + 10]
                b_3 += weights[j + 11]
                b_4 += weights[j + 12]
                b_5 += weights[j + 13]
                b_6 += weights[j + 14]
                b_7 += weights[j + 15]
            mass_0, mass_1, mass_2, mass_3 = a_0 + b_0, a_1 + b_1, a_2 + b_2, a_3 + b_3
            mass_4, mass_5, mass_6, mass_7 = a_4 + b_4, a_5 + b_5, a_6 + b_6, a_7 + b_7
            edge_2 = mass_0 + mass_1  # edge_m: the mass of lanes 0..m-1, non-decreasing in m
            edge_4 = edge_2 + (mass_2 + mass_3)
            edge_6 = edge_4 + (mass_4 + mass_5)
            total = edge_4 + ((mass_4 + mass_5) + (mass_6 + mass_7))
            edge_3, edge_5, edge_7 = edge_2 + mass_2, edge_4 + mass_4, edge_6 + mass_6
            target = uniforms[u_index] * total
            u_index += 1
            # Branch-free: count the lane boundaries ``target`` passes, then the lane's steps.
            lane = 0
            lower = 0.0
            for boundary in (mass_0, edge_2, edge_3, edge_4, edge_5, edge_6, edge_7):
                passed = boundary <= target
                lane += passed
                lower = boundary if passed else lower
            lane = min(lane, last_lane)
            target -= lower
            steps = 0
            cumulative = 0.0
            for m in range(depth - 1):
                cumulative += weights[lane + m * LANES]
                steps += cumulative <= target
            new = lane + min(steps, (n_contexts - 1 - lane) // LANES) * LANES  # rounding never lands past K
            if new != old:
                z[i] = new
                _move_token(w, d, old, new, n_wk, n_k, n_dk, inverse, below, v_xi)
                pending_old, value_old = old, (n_dk[d, old] + alpha) * inverse[old]
                pending_new, value_new = new, (n_dk[d, new] + alpha) * inverse[new]
                pending = True


@numba.njit(cache=True, nogil=True, error_model="numpy")
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
    and gets its first context from the counts of everything sampled before it.

    Eq. 5's document denominator ``N_d + Kα`` is the same for every context and cancels. As in
    :func:`sweep_documents` (the comment above it, which gives the reasons and error_model): the
    token's own context's term is written with its counts less one, ``inverse`` and ``below`` are
    kept up to date, and the counts are written only when the token moves. Written out like
    :func:`sweep_documents` (a helper per token halves the speed).
    """
    v_xi = vocab_size * xi
    inverse = _inverse_totals(n_k, n_contexts, v_xi)
    below = _inverse_totals(n_k, n_contexts, v_xi, -1)
    cumulative = np.empty(n_contexts)
    for j in range(tokens.shape[0]):
        i = tokens[j]
        d = token_docs[j]
        w = words[i]
        old = z[i]
        total = 0.0
        for k in range(n_contexts):
            if k == old:
                total += ((n_wk[w, k] - 1) + xi) * below[k] * ((n_dk[d, k] - 1) + alpha)
            else:
                total += (n_wk[w, k] + xi) * inverse[k] * (n_dk[d, k] + alpha)
            cumulative[k] = total
        new = _draw(cumulative, n_contexts, uniforms[j])
        if new == old:
            continue
        z[i] = new
        if old >= 0:
            _move_token(w, d, old, new, n_wk, n_k, n_dk, inverse, below, v_xi)
        else:
            n_wk[w, new] += 1
            n_k[new] += 1
            n_dk[d, new] += 1
            below[new] = inverse[new]
            inverse[new] = 1.0 / (n_k[new] + v_xi)


@numba.njit(cache=True, nogil=True, error_model="numpy")
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
    sweeps (``uniforms`` holds one number per token per sweep). error_model="numpy" for the
    reason the sweeps give: ``below_total`` of an empty context may divide by zero, and is never read.
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
    # Eq. 5's three factors kept as floats, updated as the document's tokens move: its concepts'
    # counts plus ξ (the model's, with its own tokens added), the reciprocal of each context's
    # total plus |W|ξ (two divisions a token instead of K), and n_dk + α.
    concept_weight = np.empty((n_distinct, n_contexts))
    for u in range(n_distinct):
        for k in range(n_contexts):
            concept_weight[u, k] = n_wk[distinct[u], k] + xi
    context_total = np.empty(n_contexts)
    inverse_total = np.empty(n_contexts)
    for k in range(n_contexts):
        context_total[k] = n_k[k] + v_xi
        inverse_total[k] = 1.0 / context_total[k]
    document_weight = np.full(n_contexts, alpha)
    n_dk = np.zeros(n_contexts, dtype=np.int64)  # θ sums n_dk + α as before: bit for bit the same θ
    z = np.full(n_tokens, -1, dtype=np.int64)
    cumulative = np.empty(n_contexts)
    theta = np.zeros(n_contexts)
    u_index = 0
    below_total = np.empty(n_contexts)  # the reciprocal totals with one token taken out
    for k in range(n_contexts):
        below_total[k] = 1.0 / (context_total[k] - 1.0)
    for sweep in range(sweeps):
        for i in range(n_tokens):
            # As in the sweeps (the comment above sweep_documents): the token's own context's term
            # with it taken out, and the factors written only when it moves. Taking 1 off a factor
            # that holds the token and adding it back is exact, so θ is that of taking every token
            # out and putting it back, bit for bit.
            u = local_words[i]
            old = z[i]
            total = 0.0
            for k in range(n_contexts):
                if k == old:
                    total += (concept_weight[u, k] - 1.0) * below_total[k] * (document_weight[k] - 1.0)
                else:
                    total += concept_weight[u, k] * inverse_total[k] * document_weight[k]
                cumulative[k] = total
            new = _draw(cumulative, n_contexts, uniforms[u_index])
            u_index += 1
            if new == old:
                continue
            if old >= 0:
                concept_weight[u, old] -= 1.0
                context_total[old] -= 1.0
                inverse_total[old] = 1.0 / context_total[old]
                below_total[old] = 1.0 / (context_total[old] - 1.0)
                document_weight[old] -= 1.0
                n_dk[old] -= 1
            z[i] = new
            concept_weight[u, new] += 1.0
            context_total[new] += 1.0
            inverse_total[new] = 1.0 / context_total[new]
            below_total[new] = 1.0 / (context_total[new] - 1.0)
            document_weight[new] += 1.0
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


@numba.njit(cache=True, nogil=True)
def sample_new_scene(
    words: np.ndarray,
    z: np.ndarray,
    token_scene: np.ndarray,
    doc_offsets: np.ndarray,
    word_ids: np.ndarray,
    d: int,
    sweeps: int,
    rejuvenated: np.ndarray,
    n_wk: np.ndarray,
    n_k: np.ndarray,
    n_dk: np.ndarray,
    n_contexts: int,
    alpha: float,
    xi: float,
    vocab_size: int,
    u_scene: float,
    uniforms: np.ndarray,
) -> np.ndarray:
    """One online update's sampling (Algorithm 2's loop body): write scene ``d`` (``word_ids``) after
    the corpus with z = -1 (the arrays must have room for it), put it in one context as a block
    (:func:`scene_to_one_context`, with ``u_scene``), then ``sweeps`` Eq. 5 sweeps
    (:func:`sample_tokens`), each over the scene's tokens followed by its share of the
    ``rejuvenated`` earlier tokens (sweep after sweep; one number of ``uniforms`` per token).

    Returns the contexts of the rejuvenated tokens before sampling.
    """
    start = doc_offsets[d]
    stop = start + word_ids.shape[0]
    for i in range(start, stop):
        words[i] = word_ids[i - start]
        z[i] = -1
        token_scene[i] = d
    doc_offsets[d + 1] = stop
    scene_to_one_context(words, z, start, stop, d, n_wk, n_k, n_dk, n_contexts, alpha, xi, vocab_size, u_scene)
    # The rejuvenated tokens are read in one pass before any is sampled. Their loads do not depend
    # on each other here, so on a corpus larger than the cache their misses overlap; the sampling
    # below, whose steps do depend on each other, then finds them in cache (1.17x a whole update at
    # 1,000 scenes, 1.26x at 100,000, docs/benchmarks.md). The concept and the scene's first count
    # are read for that alone: their sum, checked, keeps the compiler from dropping the reads.
    previous = np.empty(rejuvenated.shape[0], dtype=np.int32)
    rejuvenated_docs = np.empty(rejuvenated.shape[0], dtype=np.int64)
    warmed = 0
    for j in range(rejuvenated.shape[0]):
        i = rejuvenated[j]
        previous[j] = z[i]
        rejuvenated_docs[j] = token_scene[i]
        warmed += words[i] + n_dk[rejuvenated_docs[j], 0]
    if warmed < 0:
        raise AssertionError("negative concept ids or counts")
    per_sweep = rejuvenated.shape[0] // sweeps
    tokens = np.empty(sweeps * (stop - start + per_sweep), dtype=np.int64)
    token_docs = np.empty(tokens.shape[0], dtype=np.int64)
    j = 0
    for s in range(sweeps):
        for i in range(start, stop):
            tokens[j] = i
            token_docs[j] = d
            j += 1
        for r in range(s * per_sweep, (s + 1) * per_sweep):
            tokens[j] = rejuvenated[r]
            token_docs[j] = rejuvenated_docs[r]
            j += 1
    sample_tokens(tokens, token_docs, words, z, n_wk, n_k, n_dk, n_contexts, alpha, xi, vocab_size, uniforms)
    return previous


#: :func:`scene_changes` sums net count changes in a dense table when the key space (concepts ×
#: context capacity) is at most this many times the number of keys, and sorts the keys otherwise.
_DENSE_KEYS_PER_KEY = 4


@numba.njit(cache=True, nogil=True)
def scene_changes(
    touched: np.ndarray,
    previous: np.ndarray,
    d: int,
    doc_offsets: np.ndarray,
    words: np.ndarray,
    z: np.ndarray,
    n_wk: np.ndarray,
    n_dk: np.ndarray,
    n_contexts: int,
    alpha: float,
    k_capacity: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """What an online update of scene ``d`` (the last one) changed, from the earlier tokens it may
    have moved (``touched``, with their contexts before, ``previous``; a token listed more than
    once counts with its first entry).

    Returns the earlier tokens whose context differs from their first ``previous`` (ascending,
    int64), their contexts now and before (int32, what undoes the update); the n_kw entries with a nonzero net change, as rows
    (context, concept, count now) ordered by concept × ``k_capacity`` + context (int64, m × 3; the
    scene's tokens count as new); the scene's contexts (int32); and its θ = (n_dk + α) / (N_d + Kα).

    Only a token with some entry differing from its context now can have changed, and those are
    few: they alone are sorted, then each one's first entry is found by binary search. (Sorting
    every entry instead, stably so that a token's first entry leads, took 6 µs of numba's
    mergesort for an update's 320 entries; this path takes the whole kernel under 4 µs:
    docs/benchmarks.md.)
    """
    n_touched = touched.shape[0]
    candidates = np.empty(n_touched, dtype=np.int64)
    n_candidates = 0
    for j in range(n_touched):
        if z[touched[j]] != previous[j]:
            candidates[n_candidates] = touched[j]
            n_candidates += 1
    candidates = np.sort(candidates[:n_candidates])
    n_distinct = 0
    for j in range(n_candidates):
        if n_distinct == 0 or candidates[j] != candidates[n_distinct - 1]:
            candidates[n_distinct] = candidates[j]
            n_distinct += 1
    candidates = candidates[:n_distinct]
    first = np.empty(n_distinct, dtype=np.int32)
    found = np.zeros(n_distinct, dtype=np.bool_)
    if n_distinct:
        for j in range(n_touched):
            c = np.searchsorted(candidates, touched[j])
            if c < n_distinct and candidates[c] == touched[j] and not found[c]:
                first[c] = previous[j]
                found[c] = True
    reassigned = np.empty(n_distinct, dtype=np.int64)
    contexts = np.empty(n_distinct, dtype=np.int32)
    old = np.empty(n_distinct, dtype=np.int32)
    n_reassigned = 0
    for c in range(n_distinct):
        i = candidates[c]
        if z[i] != first[c]:
            reassigned[n_reassigned] = i
            contexts[n_reassigned] = z[i]
            old[n_reassigned] = first[c]
            n_reassigned += 1
    # Net count changes: each key (concept × k_capacity + context) doubled, plus 1 for a token
    # joining, so that one plain sort groups the keys and says which way each entry counts.
    start, stop = doc_offsets[d], doc_offsets[d + 1]
    keys = np.empty(2 * n_reassigned + stop - start, dtype=np.int64)
    n_keys = 0
    for j in range(n_reassigned):
        w = np.int64(words[reassigned[j]])
        if old[j] >= 0:
            keys[n_keys] = 2 * (w * k_capacity + old[j])
            n_keys += 1
        keys[n_keys] = 2 * (w * k_capacity + contexts[j]) + 1
        n_keys += 1
    for i in range(start, stop):
        keys[n_keys] = 2 * (np.int64(words[i]) * k_capacity + z[i]) + 1
        n_keys += 1
    rows = np.empty((n_keys, 3), dtype=np.int64)
    n_rows = 0
    key_space = np.int64(n_wk.shape[0]) * k_capacity
    if key_space <= _DENSE_KEYS_PER_KEY * n_keys:
        # A small key space (a vocabulary of tens of concepts): net changes summed in a dense
        # table and read back in key order, which is the sorted order without the sort.
        net_by_key = np.zeros(key_space, dtype=np.int64)
        for j in range(n_keys):
            net_by_key[keys[j] // 2] += 1 if keys[j] % 2 else -1
        for key in range(key_space):
            if net_by_key[key] != 0:
                concept, context = key // k_capacity, key % k_capacity
                rows[n_rows, 0] = context
                rows[n_rows, 1] = concept
                rows[n_rows, 2] = n_wk[concept, context]
                n_rows += 1
    else:
        keys = np.sort(keys[:n_keys])
        j = 0
        while j < n_keys:
            key = keys[j] // 2
            net = 0
            while j < n_keys and keys[j] // 2 == key:
                net += 1 if keys[j] % 2 else -1
                j += 1
            if net != 0:
                concept, context = key // k_capacity, key % k_capacity
                rows[n_rows, 0] = context
                rows[n_rows, 1] = concept
                rows[n_rows, 2] = n_wk[concept, context]
                n_rows += 1
    assignments = z[start:stop].copy()
    theta = np.empty(n_contexts)
    denominator = (stop - start) + n_contexts * alpha
    for k in range(n_contexts):
        theta[k] = (n_dk[d, k] + alpha) / denominator
    return (
        reassigned[:n_reassigned].copy(),
        contexts[:n_reassigned].copy(),
        old[:n_reassigned].copy(),
        rows[:n_rows].copy(),
        assignments,
        theta,
    )
