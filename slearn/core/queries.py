"""A compiled run of frozen queries: each query's history replayed on scratch view
streams, its last step predicted, and what is answered remembered.

:func:`predict_queries` answers the queries of one :class:`Query` in one call, with every
array it reads in one address table (:func:`state_table`): numba wraps every array argument
on every call, which cost more than a small query. :class:`slearn.core.predictor.Predictor`
runs it for one query (flat codes, a table it keeps) and for batches (encoded steps).
Frozen, nothing changes between queries, so answers are kept in a :class:`Memo`: by a
view's context, and rankings by the chosen context and expert.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from slearn.core._jit import helper, kernel
from slearn.core.addresses import address_table, cube, matrix, vector
from slearn.core.context_tree import Tree, child, path_hash, root_path
from slearn.core.mixer import BETA, N_KINDS, Mixer, heaviest_beyond, persists, select
from slearn.core.online import (
    Reports,
    candidates,
    hold_silent,
    new_reports,
    record_hold,
    record_persistence,
    record_prediction,
)
from slearn.core.views import NO_ACTIONS, NO_TOKEN, UNKNOWN, ViewState, new_view_state


class Memo(NamedTuple):
    """Answers a query run remembers, in direct-mapped slots: by a view's context (its last
    tokens, ``window[slot] = (view, tokens...)``, ``depth`` -1 when empty; the answer in
    row ``slot``), and rankings by the chosen context and expert (``rank_key``, -1 when
    empty; the answer in row ``slots + slot``). Frozen, a prediction is a function of the
    view's context alone: it fixes the contexts found, the experts' candidates, the choice
    (the weights do not move) and the ranking (a query's outcome is never known here, so
    no report's ``truth_p`` depends on it)."""

    depth: np.ndarray      # int32 (slots,)
    window: np.ndarray     # int32 (slots, max_context + 1)
    rank_key: np.ndarray   # int64 (slots,)
    predicted: np.ndarray  # the answers, as in Reports (2 * slots rows)
    length: np.ndarray
    kind: np.ndarray
    score: np.ndarray
    top: np.ndarray
    top_p: np.ndarray


def new_memo(slots: int, max_context: int, top_k: int) -> Memo:
    """An empty memo of ``slots`` (a power of two)."""
    said = new_reports(2 * slots, top_k)
    return Memo(np.full(slots, -1, np.int32), np.zeros((slots, max_context + 1), np.int32),
                np.full(slots, -1, np.int64), said.predicted, said.length, said.kind, said.score, said.top,
                said.top_p)


def forget(memo: Memo) -> None:
    """Empty every slot (the library learned)."""
    memo.depth.fill(-1)
    memo.rank_key.fill(-1)


class Query(NamedTuple):
    """What a query run asks: the run's scalars (``has_actions``, ``empty_action``,
    ``empty_observation``, ``hold``: see :class:`slearn.core.online.Reports`; then
    ``N_FLAT`` and ``REUSED``, :func:`predict_queries`' own), then either a single query's
    flat codes (see ``Predictor._codes_of``) or encoded steps and each query's bounds."""

    run: np.ndarray      # int32[6]
    flat: np.ndarray     # int32
    action: np.ndarray   # int32 per step
    scoped: np.ndarray   # int32 (steps, scopes): see StepCodes
    offsets: np.ndarray  # int64 per step + 1
    view: np.ndarray     # int32 per observation
    token: np.ndarray    # int32 per observation
    starts: np.ndarray   # int64 per query
    ends: np.ndarray     # int64 per query


N_FLAT, REUSED = 4, 5  # places in Query.run of predict_queries' two scalars


class Work(NamedTuple):
    """A query run's scratch arrays, kept with its buffers (six allocations were a fifth of
    a single query's compiled call)."""

    nodes: np.ndarray   # int32 (max_context + 1,): the contexts found
    hashes: np.ndarray  # uint64 (max_context + 1,): their path hashes
    cand: np.ndarray    # int32 (max_context + 1, kinds): the experts' outcomes
    beyond: np.ndarray  # float64 (views, 2 * (max_context + 1)): see mixer.heaviest_beyond
    lead: np.ndarray    # int64 (views,)
    ranked: np.ndarray  # int32 (top_k,): see online.record_prediction


class Buffers(NamedTuple):
    """Everything a query run works in besides the library's own state."""

    scratch: ViewState  # streams the history is replayed on
    out: Reports
    memo: Memo
    query: Query
    work: Work


MEMO_BYTES = 1 << 18  # a memo's size at most: beside the tree's hot part, what a core's L2
#   cache holds. Memos are probed at random, so one larger than the cache misses on every
#   probe: 16,384 slots (2.8 MB at 12 tokens of context and top 3) answered batches
#   1.1-1.4x slower than 1,024 slots (170 kB) on every pointer and arm stream measured,
#   though they remembered more (bench_predict.py, issue 12).
_NO_I32, _NO_I64 = np.zeros(0, np.int32), np.zeros(0, np.int64)


def memo_slots(wanted: int, max_context: int, top_k: int) -> int:
    """The power of two at least ``wanted`` (at least one), as long as the memo's bytes stay
    within ``MEMO_BYTES``; the largest power of two that does otherwise."""
    slot = sum(a.nbytes for a in new_memo(1, max_context, top_k))
    cap = 1 << max(0, (MEMO_BYTES // slot).bit_length() - 1)
    return 1 << max(0, min(wanted, cap) - 1).bit_length()


def kept_buffers(library, queries: int, top_k: int) -> Buffers:
    """Buffers a predictor keeps for its runs, with the largest memo within ``MEMO_BYTES``
    (answers stay valid from run to run while the library does not learn)."""
    return new_buffers(library, queries, top_k, slots=1 << 62)


def new_buffers(library, queries: int, top_k: int, slots: int | None = None) -> Buffers:
    """The buffers of ``queries`` queries, with a memo of about ``slots`` (else one per
    query and view), within ``MEMO_BYTES`` (``memo_slots``)."""
    n_views = len(library.view_names)
    n = queries * n_views
    scopes = library.n_scopes
    run = np.array([library.has_actions, library.empty_action, library.empty_observation, library.factored,
                    -1, 0], np.int32)
    top_k = max(top_k, 1)
    slots = memo_slots(n if slots is None else slots, library.max_context, top_k)
    k = library.max_context + 1
    work = Work(np.zeros(k, np.int32), np.zeros(k, np.uint64), np.full((k, N_KINDS), -1, np.int32),
                np.zeros((n_views, 2 * k)), np.zeros(n_views, np.int64), np.zeros(top_k, np.int32))
    return Buffers(new_view_state(n_views, library.max_context, library.streams.root, library.streams.scope),
                   new_reports(n, top_k), new_memo(slots, library.max_context, top_k),
                   Query(run, _NO_I32, _NO_I32, np.zeros((0, scopes), np.int32), _NO_I64, _NO_I32, _NO_I32,
                         _NO_I64, _NO_I64), work)


def single_query(run: np.ndarray, size: int, scopes: int) -> Query:
    """A single query's buffers for ``size`` flat codes at least (capacity doubles): its
    steps take fewer entries than its codes (``scopes``: the library's action scopes)."""
    n = 1 << max(size - 1, 1).bit_length()
    return Query(run, np.zeros(n, np.int32), np.zeros(n, np.int32), np.zeros((n, scopes), np.int32),
                 np.zeros(n + 1, np.int64),
                 np.zeros(n, np.int32), np.zeros(n, np.int32), np.zeros(1, np.int64), np.zeros(1, np.int64))


def state_table(state: tuple, buffers: Buffers) -> np.ndarray:
    """The arrays of a query run as one address table, in the order ``predict_queries``
    reads them: the tree's fields, the mixer's, the scratch streams', the memo's (the
    :func:`kept_rows`), then the reports', the query's and the scratch arrays'. The caller
    keeps them alive."""
    return run_table(kept_rows(state, buffers), buffers.out, buffers.query, buffers.work)


def run_table(kept: np.ndarray, out: Reports, query: Query, work: Work) -> np.ndarray:
    """:func:`state_table` from its :func:`kept_rows` and a run's reports, query and scratch."""
    return np.concatenate((kept, address_table((*out, *query, *work))))


def kept_rows(state: tuple, buffers: Buffers) -> np.ndarray:
    """The rows of :func:`state_table` that stay while the library does not change and the
    buffers' scratch streams and memo are reused: a caller that keeps them makes only the
    reports' and the query's rows per run (an address costs a microsecond in Python)."""
    tree, mixer = state
    return address_table((*tree, *mixer, *buffers.scratch, *buffers.memo))


_TREE, _MIXER, _SCRATCH = 0, len(Tree._fields), len(Tree._fields) + len(Mixer._fields)
_MEMO_AT = _SCRATCH + len(ViewState._fields)
_OUT = _MEMO_AT + len(Memo._fields)
_QUERY_AT = _OUT + len(Reports._fields)
_WORK_AT = _QUERY_AT + len(Query._fields)


@kernel
def predict_queries(table):
    """For query ``i`` of the table's :class:`Query`: replay steps ``starts[i]..ends[i] - 1``
    on fresh scratch streams, as if they were an episode of their own, then predict every view at step ``ends[i]`` (its
    action pushed) as ``run_codes`` does frozen, its outcome unknown: rows ``i * views ..``
    of ``out``. ``run[N_FLAT] >= 0``: one query, the first ``run[N_FLAT]`` flat
    codes. ``out`` holds abstentions (``new_reports``) unless ``run[REUSED]`` (then each
    query's rows are reset first). Answers with an unknown outcome are remembered in the table's
    :class:`Memo`, which stays valid while the library does not learn. Everything comes
    as one address table (``state_table``), scalars included: numba wraps every argument on
    every call, which cost more than a small query; for the same reason the query step is
    walked here, not by a call of ``run_codes``."""
    i32, i64, f64 = np.int32, np.int64, np.float64
    t, m, sc, o = _TREE, _MIXER, _SCRATCH, _OUT
    tree = Tree(vector(table, t, i32), vector(table, t + 1, i32), vector(table, t + 2, i32),
                vector(table, t + 3, i32), vector(table, t + 4, i32), vector(table, t + 5, i32),
                vector(table, t + 6, i32), vector(table, t + 7, i32), vector(table, t + 8, i32),
                vector(table, t + 9, i32), vector(table, t + 10, i64), vector(table, t + 11, i64),
                vector(table, t + 12, i64), vector(table, t + 13, i32), vector(table, t + 14, i32),
                vector(table, t + 15, i64), vector(table, t + 16, i32), vector(table, t + 17, i32))
    mixer = Mixer(cube(table, m, f64), matrix(table, m + 1, f64), vector(table, m + 2, i32),
                  cube(table, m + 3, i64), vector(table, m + 4, i64), matrix(table, m + 5, f64))
    scratch = ViewState(matrix(table, sc, i32), vector(table, sc + 1, i64), vector(table, sc + 2, i32),
                        vector(table, sc + 3, i32), vector(table, sc + 4, i32))
    out = Reports(vector(table, o, i32), vector(table, o + 1, i32), vector(table, o + 2, np.int8),
                  vector(table, o + 3, f64), vector(table, o + 4, f64), matrix(table, o + 5, i32),
                  matrix(table, o + 6, f64), vector(table, o + 7, np.bool_), vector(table, o + 8, i32),
                  vector(table, o + 9, i32), vector(table, o + 10, i32))
    parent, tok_of, first, best, newest = tree.parent, tree.token, tree.first, tree.best, tree.newest
    fresh_best, node_epoch, node_slots = tree.fresh_best, tree.epoch, tree.node_slots
    outcome, count, last_seen, fresh, nxt = tree.outcome, tree.count, tree.last_seen, tree.fresh, tree.next
    weights, epoch, persist = mixer.weight, mixer.epoch, mixer.persist
    recent, filled, held, root, scope = scratch.recent, scratch.filled, scratch.held, scratch.root, scratch.scope
    K = weights.shape[1]  # the longest context, in tokens
    M = recent.shape[1] - 1  # a token's place in its ring: a mask (ViewState)
    n_views = len(filled)
    w = _WORK_AT  # scratch (Work)
    nodes, hashes, cand = vector(table, w, i32), vector(table, w + 1, np.uint64), matrix(table, w + 2, i32)
    beyond, lead, ranked = matrix(table, w + 3, f64), vector(table, w + 4, i64), vector(table, w + 5, i32)
    heaviest_beyond(weights, beyond, lead)  # the weights stay as they are: nothing learns here
    top_k = out.top.shape[1]
    mm = _MEMO_AT  # answers remembered (see Memo)
    memo_depth, memo_window, rank_key = vector(table, mm, i32), matrix(table, mm + 1, i32), vector(table, mm + 2, i64)
    memo_said, memo_length, memo_kind = vector(table, mm + 3, i32), vector(table, mm + 4, i32), \
        vector(table, mm + 5, np.int8)
    memo_score, memo_top, memo_p = vector(table, mm + 6, f64), matrix(table, mm + 7, i32), matrix(table, mm + 8, f64)
    size = len(memo_depth)
    qa = _QUERY_AT
    run = vector(table, qa, i32)
    has_actions, empty_action, empty_observation, hold = run[0] != 0, run[1], run[2], run[3] != 0
    n_flat, reused = run[N_FLAT], run[REUSED] != 0
    action, scoped = vector(table, qa + 2, i32), matrix(table, qa + 3, i32)
    offsets, view, token = vector(table, qa + 4, i64), vector(table, qa + 5, i32), vector(table, qa + 6, i32)
    starts, ends = vector(table, qa + 7, i64), vector(table, qa + 8, i64)
    n_queries = len(starts)
    if n_flat >= 0:  # one query: its steps into the buffers, which hold as many codes
        _steps_of(vector(table, qa + 1, i32), n_flat, action, scoped, offsets, view, token, starts, ends)
        n_queries = 1
    for i in range(n_queries):
        s, e = starts[i], ends[i]
        filled[:] = 0
        held[:] = NO_TOKEN
        for step in range(s, e):  # as run_codes moves the streams, without learning or recording
            a = action[step]  # (written out here: a helper's call per step was a quarter of a batch)
            push_action = has_actions and (step > s or a != empty_action)
            if push_action:
                for v in range(n_views):
                    c = scope[v]
                    if c != NO_ACTIONS:
                        recent[v, filled[v] & M] = a if c < 0 else scoped[step, c]
                        filled[v] += 1
            first_obs, end_obs = offsets[step], offsets[step + 1]
            for r in range(first_obs, end_obs):
                v = view[r]
                recent[v, filled[v] & M] = token[r]
                filled[v] += 1
                held[v] = token[r]
            if push_action and end_obs - first_obs < n_views:  # a view was silent (views are distinct)
                hold_silent(recent, filled, held, view, first_obs, end_obs, empty_observation)
        r0 = i * n_views
        if reused:
            _abstain(out, r0, r0 + n_views)
        a = action[e]
        if has_actions and (e > s or a != empty_action):
            for v in range(n_views):
                c = scope[v]
                if c != NO_ACTIONS:
                    recent[v, filled[v] & M] = a if c < 0 else scoped[e, c]
                    filled[v] += 1
        for v in range(n_views):
            depth = min(filled[v], K)
            if depth == 0:
                continue
            r = r0 + v
            out.context[r] = True
            slot = _window_slot(recent, filled, v, depth, size)
            recalled, keep = -1, -1  # memo rows: the answer's, and a ranking's to keep
            if _claim_window(recent, filled, v, depth, memo_depth, memo_window, slot):
                recalled = slot
            else:
                # The contexts up to the longest with an expert of top weight first; the
                # longer ones only when their experts could outweigh the one chosen.
                nodes[0], hashes[0] = root[v], root_path(root[v])
                reach = min(depth, lead[v])
                n = _descend(node_slots, parent, tok_of, recent, filled, v, nodes, hashes, 0, reach)
                found = candidates(first, best, newest, fresh_best, node_epoch, outcome, nodes, n, epoch[v], cand)
                whole = n < reach or reach == depth or found < n  # no longer context counts
                if found > 0:
                    k_sel, kind, heaviest = select(weights, v, cand, found)
                    if not whole and not (heaviest > beyond[v, n] and heaviest * BETA >= beyond[v, K + 1 + n]):
                        n = _descend(node_slots, parent, tok_of, recent, filled, v, nodes, hashes, n, depth)
                        found = candidates(first, best, newest, fresh_best, node_epoch, outcome, nodes, n,
                                           epoch[v], cand)
                        whole = True
                        k_sel, kind, heaviest = select(weights, v, cand, found)
                    if persists(persist, v, k_sel, held[v]):  # (not remembered: the slot is given up)
                        if not whole:  # the ranking reads every context found, as run_codes' does
                            n = _descend(node_slots, parent, tok_of, recent, filled, v, nodes, hashes, n, depth)
                            found = candidates(first, best, newest, fresh_best, node_epoch, outcome, nodes, n,
                                               epoch[v], cand)
                        record_prediction(out, r, nodes[k_sel], kind, k_sel, held[v], UNKNOWN, first, nxt,
                                          count, fresh, last_seen, outcome, nodes, found, ranked)
                        record_persistence(out, r, persist[v, k_sel - 1], held[v], UNKNOWN, first, nxt, count,
                                           fresh, outcome, nodes, kind, k_sel)
                        memo_depth[slot] = -1
                        continue
                    key = np.int64(nodes[k_sel]) * N_KINDS + kind
                    rank_slot = key & (size - 1)
                    if rank_key[rank_slot] == key:
                        recalled = size + rank_slot
                    else:  # the chosen context and the shorter ones first: they fill the ranking
                        record_prediction(out, r, nodes[k_sel], kind, k_sel, cand[k_sel, kind], UNKNOWN,
                                          first, nxt, count, fresh, last_seen, outcome, nodes, k_sel, ranked)
                        if out.top[r, top_k - 1] >= 0:  # then they alone fix the answer (a longer
                            rank_key[rank_slot] = key  # context's counted outcomes are its suffixes':
                            keep = size + rank_slot  # test_library)
                        else:  # a fresh expert ranks by fresh counts: longer contexts fill it
                            if not whole:
                                n = _descend(node_slots, parent, tok_of, recent, filled, v, nodes, hashes, n,
                                             depth)
                                found = candidates(first, best, newest, fresh_best, node_epoch, outcome, nodes,
                                                   n, epoch[v], cand)
                            if found > k_sel:
                                record_prediction(out, r, nodes[k_sel], kind, k_sel, cand[k_sel, kind], UNKNOWN,
                                                  first, nxt, count, fresh, last_seen, outcome, nodes, found,
                                                  ranked)
                elif hold and held[v] >= 0:  # (not remembered: the window's slot is given up)
                    record_hold(out, r, held[v])
                    memo_depth[slot] = -1
                    continue
            # (the copies are written out: a helper's call with a dozen arrays cost a tenth of a batch)
            if recalled >= 0:
                out.predicted[r], out.length[r], out.kind[r] = memo_said[recalled], memo_length[recalled], \
                    memo_kind[recalled]
                out.score[r] = memo_score[recalled]
                for k in range(top_k):
                    out.top[r, k], out.top_p[r, k] = memo_top[recalled, k], memo_p[recalled, k]
            if recalled != slot:  # the window was claimed: its answer
                for row in (slot, keep):
                    if row >= 0:
                        memo_said[row], memo_length[row], memo_kind[row] = out.predicted[r], out.length[r], \
                            out.kind[r]
                        memo_score[row] = out.score[r]
                        for k in range(top_k):
                            memo_top[row, k], memo_p[row, k] = out.top[r, k], out.top_p[r, k]


@helper
def _descend(node_slots, parent, tok_of, recent, filled, v, nodes, hashes, n, to):
    """View ``v``'s contexts of ``n + 1..to`` tokens, looked up below ``nodes[n]`` (path hash
    ``hashes[n]``) into ``nodes``/``hashes``; returns the longest found (below ``to``: the
    next was never seen)."""
    M = recent.shape[1] - 1
    node, h = nodes[n], hashes[n]
    for k in range(n + 1, to + 1):
        t = recent[v, (filled[v] - k) & M]
        h = path_hash(h, t)
        node = child(node_slots, parent, tok_of, node, t, h)
        if node < 0:
            return k - 1
        nodes[k] = node
        hashes[k] = h
    return to


@helper
def _window_slot(recent, filled, v, depth, size):
    """The memo slot of view ``v``'s last ``depth`` tokens (``size`` a power of two)."""
    M = recent.shape[1] - 1
    h = np.int64(v) * 1000003 + depth
    at = filled[v] - 1  # the newest token, then back
    for _ in range(depth):
        h = h * 1000003 + recent[v, at & M]
        at -= 1
    return (h ^ (h >> 29)) & (size - 1)


@helper
def _claim_window(recent, filled, v, depth, memo_depth, memo_window, slot):
    """Whether ``slot`` holds view ``v``'s last ``depth`` tokens; if not, it does from now
    on (the caller then stores the answer in its row)."""
    M = recent.shape[1] - 1
    same = memo_depth[slot] == depth and memo_window[slot, 0] == v
    at = filled[v] - 1
    for k in range(1, depth + 1):
        t = recent[v, at & M]
        if same and memo_window[slot, k] != t:
            same = False
        memo_window[slot, k] = t
        at -= 1
    memo_depth[slot] = depth
    memo_window[slot, 0] = v
    return same


@helper
def _steps_of(flat, n_flat, action, scoped, offsets, view, token, starts, ends):
    """The first ``n_flat`` flat codes (``Predictor._codes_of``) as the steps of one
    query (actions, scoped actions, offsets, views, tokens) and its bounds: every step but
    the last is its history."""
    j, r, step = 0, 0, 0
    n_scopes = scoped.shape[1]
    offsets[0] = 0
    while j < n_flat:
        action[step] = flat[j]
        for c in range(n_scopes):
            scoped[step, c] = flat[j + 1 + c]
        j += 1 + n_scopes
        for k in range(flat[j]):
            view[r] = flat[j + 1 + 2 * k]
            token[r] = flat[j + 2 + 2 * k]
            r += 1
        offsets[step + 1] = r
        j += 1 + 2 * flat[j]
        step += 1
    starts[0] = 0
    ends[0] = step - 1


@helper
def _abstain(out, r0, r1):
    """Rows ``r0..r1`` of ``out`` as ``new_reports`` makes them (buffers are reused)."""
    for r in range(r0, r1):
        out.predicted[r] = -1
        out.length[r] = -1
        out.kind[r] = -1
        out.score[r] = 0.0
        out.truth_p[r] = 0.0
        out.context[r] = False
        out.markov[r] = -1
        out.frequency[r] = -1
        out.persistence[r] = -1
        for k in range(out.top.shape[1]):
            out.top[r, k] = -1
            out.top_p[r, k] = 0.0
