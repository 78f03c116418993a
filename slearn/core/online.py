"""The step loop: predict each observation from its contexts, then learn it.

One compiled kernel, :func:`run_codes`, walks an encoded episode (:mod:`slearn.core.views`)
step by step. At each step the action is appended to every view's stream (a view of an
action scope gets the step's actions in its scope); for every view that reports, its
contexts are looked up in the context tree, the experts of :mod:`slearn.core.mixer`
propose outcomes and the best-weighted one is recorded; when
learning, the experts' weights and the change detector are updated from the outcome
and every context of the observation counts one more occurrence of it. ``learn=False``
is a frozen library (held-out evaluation): nothing changes, not even the weights.
Learning is this same loop, so a library learned offline carries the weights its
predictions need.

The kernel reads its state (tree, mixer, view streams) into locals once per call and
stops early, before a step, when the tree could run out of room or the library reached
its pattern bound; :class:`slearn.core.library.PatternLibrary` makes room and calls again.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from slearn.core._jit import helper, kernel
from slearn.core.context_tree import (
    FETCH_SLOTS,
    child,
    child_or_add,
    credit,
    credit_fresh,
    entry_or_add,
    fetch_entries,
    fetch_entry_slots,
    fetch_nodes,
    fresh_sums,
    path_hash,
    ranks_above,
    refresh,
    root_path,
    weight_sums,
)
from slearn.core.hashtable import EMPTY, probe
from slearn.core.mixer import (
    CUSUM,
    FREQUENT,
    FRESH,
    KINDS,
    N_KINDS,
    RECENT,
    detect,
    persists,
    select,
    trusted_length,
    update,
    update_persist,
)
from slearn.core.views import NO_ACTIONS, NO_TOKEN


class Reports(NamedTuple):
    """Per report (a view's observation at a step): what was predicted.

    ``predicted`` is the predicted observation token (-1: abstained, or no context yet),
    ``length`` the chosen context's length in tokens (-1), ``kind`` the expert kind
    (:data:`REPORT_KINDS`; :data:`PERSIST` when the view's persistence specialist said
    its last observation instead of the chosen context's expert), ``score`` the chosen
    context's share behind the prediction, ``truth_p`` its share
    behind what happened, ``top`` the ranked tokens (-1 padded) and ``top_p`` the
    probability of each (``record_prediction``: PPM's method C from the chosen context
    down; they sum to at most 1), ``context`` whether the view had any history
    at all (the first observation of an episode has none). With ``Run.baselines``, the
    same walk also records what three simple rules would say: ``markov`` (a
    variable-order Markov model: the most frequent outcome of the longest context seen),
    ``frequency`` (the most frequent outcome after the view's last observation and the
    action, or after the last observation alone in a stream without actions) and
    ``persistence`` (the last observation again).

    A report whose view found no context with outcomes (a reading or a command the library
    never met with what came before) abstains, unless ``Run.hold``: then it predicts the
    view's last observation again (``kind`` :data:`HOLD`, ``length`` 0, no share). A
    channel of a spec is sampled and held between its events, so when no pattern of the
    present was ever seen, the reading held is the one thing known; a plain sequence has
    no held reading, and abstains.
    """

    predicted: np.ndarray  # int32
    length: np.ndarray     # int32
    kind: np.ndarray       # int8
    score: np.ndarray      # float64
    truth_p: np.ndarray    # float64
    top: np.ndarray        # int32 (reports, top_k)
    top_p: np.ndarray      # float64 (reports, top_k)
    context: np.ndarray    # bool
    markov: np.ndarray     # int32: the most frequent outcome of the longest context seen
    frequency: np.ndarray  # int32: the most frequent outcome after (last observation, action)
    persistence: np.ndarray  # int32: the view's last observation


def new_reports(n: int, top_k: int) -> Reports:
    """Output arrays for ``n`` reports, all abstentions."""
    return Reports(np.full(n, -1, np.int32), np.full(n, -1, np.int32), np.full(n, -1, np.int8),
                   np.zeros(n), np.zeros(n), np.full((n, max(top_k, 1)), -1, np.int32),
                   np.zeros((n, max(top_k, 1))), np.zeros(n, np.bool_), np.full(n, -1, np.int32),
                   np.full(n, -1, np.int32), np.full(n, -1, np.int32))


HOLD = N_KINDS
"""The ``kind`` of a report that holds the view's last observation (no expert spoke)."""
PERSIST = N_KINDS + 1
"""The ``kind`` of a report where the view's persistence specialist spoke
(:func:`slearn.core.mixer.persists`): the last observation again, by its record."""
REPORT_KINDS = (*KINDS, "hold", "persist")
"""Names of a report's ``kind``: the experts of :mod:`slearn.core.mixer`, :data:`HOLD`,
:data:`PERSIST`."""


class Run(NamedTuple):
    """Scalars of one kernel call."""

    has_actions: bool
    empty_action: int       # the token of a step without actions
    empty_observation: int  # a view's token before its first observation
    max_entries: int        # stop when the tree holds this many entries (forgetting)
    learn: bool
    record: bool
    baselines: bool = False
    episode_start: bool = True  # step 0 of the codes is the first step of an episode
    hold: bool = False  # with no context found, predict the view's last observation again


PAST = 256
"""Reports a view keeps to count again into a new epoch (:class:`Past`)."""


class Past(NamedTuple):
    """Each view's latest learned reports in the current episode, so that an alarm can date
    its epoch from the change it detected, not from the alarm.

    Page's CUSUM estimates that a change began just after its statistic was last zero
    (``since[v]``: the view's reports since then). An alarm comes some reports later; the
    reports in between already showed the new dynamics, and an empty library started at the
    change would have counted them. So the alarm counts them again as fresh counts of the
    new epoch: ``node[v]`` (a ring of ``PAST``) holds the deepest context each report
    learned (its shorter contexts are the node's ancestors), ``outcome[v]`` what it saw,
    ``filled[v]`` how many were pushed. The ring restarts with each episode and after
    forgetting (node numbers change), and at most ``PAST`` reports are counted again.
    """

    node: np.ndarray     # int32 (views, PAST)
    outcome: np.ndarray  # int32 (views, PAST)
    filled: np.ndarray   # int64 (views,)
    since: np.ndarray    # int64 (views,)


def new_past(views: int) -> Past:
    """No reports yet."""
    return Past(np.zeros((views, PAST), np.int32), np.zeros((views, PAST), np.int32),
                np.zeros(views, np.int64), np.zeros(views, np.int64))


@kernel
def run_codes(tree, mixer, views, past, action, scoped, offsets, view, token, step, clock, run, out):
    """Run steps ``step..`` of an encoded episode; return the step it stopped before.

    ``clock`` is ``int64[1]``, advanced by one per learned step; ``scoped`` holds the
    steps' tokens per action scope (``StepCodes``), which views of a scope see.
    """
    parent, tok_of, first, best, newest = tree.parent, tree.token, tree.first, tree.best, tree.newest
    fresh_best, node_epoch, node_slots = tree.fresh_best, tree.epoch, tree.node_slots
    owner, outcome, count, last_seen = tree.owner, tree.outcome, tree.count, tree.last_seen
    fresh, nxt, entry_slots, size = tree.fresh, tree.next, tree.entry_slots, tree.size
    fresh_total, fresh_outcomes = tree.fresh_total, tree.fresh_outcomes
    weights, detector, epoch, calibration, rounds, persist = mixer
    recent, filled, held, root, scope = views.recent, views.filled, views.held, views.root, views.scope
    past_node, past_outcome, past_filled, since = past.node, past.outcome, past.filled, past.since
    K = weights.shape[1]  # the longest context, in tokens
    M = recent.shape[1] - 1  # a token's place in its ring: a mask (ViewState)
    n_views = len(filled)
    nodes = np.empty(K + 1, np.int32)
    hashes = np.empty(K + 1, np.uint64)
    cand = np.full((K + 1, N_KINDS), -1, np.int32)
    ranked = np.empty(out.top.shape[1], np.int32)  # the entry behind each place of a ranking
    learn = run.learn
    fetch_node = len(node_slots) > FETCH_SLOTS  # tables past the CPU's caches
    fetch_entry = len(entry_slots) > FETCH_SLOTS
    while step < len(action):
        r0, r1 = offsets[step], offsets[step + 1]
        need = K * (r1 - r0)
        if learn and (len(parent) - size[0] < need or len(owner) - size[1] < need
                      or size[1] >= run.max_entries):
            return step
        a = action[step]
        push_action = run.has_actions and (step > 0 or a != run.empty_action
                                           or not run.episode_start)
        if push_action:
            for v in range(n_views):
                c = scope[v]
                if c != NO_ACTIONS:
                    recent[v, filled[v] & M] = a if c < 0 else scoped[step, c]
                    filled[v] += 1
        for r in range(r0, r1):
            v, x = view[r], token[r]
            depth = min(filled[v], K)
            if depth > 0:
                if run.record or run.baselines:
                    out.context[r] = True
                ep = epoch[v]
                node, n = root[v], 0
                h = root_path(node)
                for k in range(1, depth + 1):
                    h = path_hash(h, recent[v, (filled[v] - k) & M])
                    hashes[k] = h
                if fetch_node:
                    fetch_nodes(node_slots, parent, tok_of, first, best, hashes, depth)
                for k in range(1, depth + 1):
                    t = recent[v, (filled[v] - k) & M]
                    h = hashes[k]
                    node = child_or_add(node_slots, parent, tok_of, first, best, newest, fresh_best, node_epoch,
                                        size, node, t, h) if learn \
                        else child(node_slots, parent, tok_of, node, t, h)
                    if node < 0:
                        break
                    nodes[k] = node
                    n = k
                m = candidates(first, best, newest, fresh_best, node_epoch, outcome, nodes, n, ep, cand)
                if run.baselines:
                    out.persistence[r] = held[v]
                    if m > 0:
                        out.markov[r] = cand[m, FREQUENT]
                    order = 2 if run.has_actions else 1
                    if m >= order:
                        out.frequency[r] = cand[order, FREQUENT]
                k_sel, kind = 0, 0
                if m > 0 and (run.record or learn):
                    k_sel, kind, _ = select(weights, v, cand, m)
                if run.record and m > 0:
                    persisting = persists(persist, v, k_sel, held[v])
                    said = held[v] if persisting else cand[k_sel, kind]
                    record_prediction(out, r, nodes[k_sel], kind, k_sel, said, x, first, nxt,
                                      count, fresh, last_seen, outcome, nodes, m, ranked)
                    if persisting:
                        record_persistence(out, r, persist[v, k_sel - 1], said, x, first, nxt, count, fresh,
                                           outcome, nodes, kind, k_sel)
                elif run.record and run.hold and held[v] >= 0:
                    record_hold(out, r, held[v])
                if learn:
                    if fetch_entry:
                        fetch_entry_slots(entry_slots, nodes, n, x)
                    update(weights, rounds, v, cand, m, x)
                    if m > 0:
                        update_persist(persist, rounds, v, k_sel, cand[k_sel, kind], held[v], x)
                    kt = trusted_length(weights, v, cand, m, ep)
                    alarm = False
                    if kt > 0:
                        nd = nodes[kt]
                        b = fresh_best[nd] if ep > 0 else best[nd]  # fresh counts are all-time in epoch 0
                        total, distinct = fresh_sums(first, nxt, fresh, fresh_total, fresh_outcomes, nd)
                        alarm = detect(weights, detector, calibration, v, outcome[b] == x, fresh[b], total, distinct)
                    if alarm:
                        epoch[v] += 1
                        recount(first, nxt, fresh, fresh_best, fresh_total, fresh_outcomes, node_epoch, parent,
                                entry_slots, owner, outcome, past_node, past_outcome, past_filled, since, v, epoch[v])
                    elif detector[v, CUSUM] == 0.0:
                        since[v] = 0
                    else:
                        since[v] += 1
                    ep = epoch[v]
                    if fetch_entry:
                        fetch_entries(entry_slots, owner, outcome, count, last_seen, fresh, nodes, n, x)
                    for k in range(1, n + 1):
                        nd = nodes[k]
                        refresh(first, nxt, fresh, fresh_best, fresh_total, fresh_outcomes, node_epoch, nd, ep)
                        e = entry_or_add(entry_slots, owner, outcome, count, last_seen, fresh, nxt, first, size, nd, x)
                        credit(count, last_seen, fresh, best, newest, fresh_best, fresh_total, fresh_outcomes, e, nd,
                               clock[0])
                    if n > 0:
                        past_node[v, past_filled[v] % PAST] = nodes[n]
                        past_outcome[v, past_filled[v] % PAST] = x
                        past_filled[v] += 1
            recent[v, filled[v] & M] = x
            filled[v] += 1
            held[v] = x
        if push_action:
            hold_silent(recent, filled, held, view, r0, r1, run.empty_observation)
        if learn:
            clock[0] += 1
        step += 1
    return step


@helper
def recount(first, nxt, fresh, fresh_best, fresh_total, fresh_outcomes, node_epoch, parent, entry_slots, owner,
            outcome, past_node, past_outcome, past_filled, since, v, ep):
    """At an alarm of view ``v`` (its epoch now ``ep``): the reports since the change its test
    dates (:class:`Past`), oldest first, counted as fresh counts of the new epoch."""
    n = min(since[v], past_filled[v], PAST)
    for i in range(past_filled[v] - n, past_filled[v]):
        nd, x = past_node[v, i % PAST], past_outcome[v, i % PAST]
        while parent[nd] >= 0:  # the report's contexts, longest first (the root is none)
            refresh(first, nxt, fresh, fresh_best, fresh_total, fresh_outcomes, node_epoch, nd, ep)
            e = entry_slots[probe(entry_slots, owner, outcome, nd, x)]
            if e != EMPTY:
                credit_fresh(fresh, fresh_best, fresh_total, fresh_outcomes, e, nd)
            nd = parent[nd]
    since[v] = 0


@helper
def candidates(first, best, newest, fresh_best, node_epoch, outcome, nodes, n, ep, cand):
    """The experts' outcomes of the contexts ``nodes[1..n]`` found (``cand[k, kind]``, -1:
    asleep), up to the first context with no outcome yet; returns how many contexts have
    outcomes. ``ep`` is the view's epoch (fresh counts of other epochs sleep)."""
    m = 0
    for k in range(1, n + 1):
        nd = nodes[k]
        if first[nd] == -1:
            break
        cand[k, FREQUENT] = outcome[best[nd]]
        cand[k, RECENT] = outcome[newest[nd]]
        fb = fresh_best[nd]
        fresh_ok = ep > 0 and node_epoch[nd] == ep and fb != -1
        cand[k, FRESH] = outcome[fb] if fresh_ok else -1
        m = k
    return m


@helper
def hold_silent(recent, filled, held, view, r0, r1, empty_observation):
    """Views that did not report after an action show their last observation again."""
    M = recent.shape[1] - 1
    r = r0
    for v in range(len(filled)):
        if r < r1 and view[r] == v:
            r += 1
            continue
        recent[v, filled[v] & M] = held[v] if held[v] != NO_TOKEN else empty_observation
        filled[v] += 1


@helper
def record_prediction(out, r, node, kind, length, said, truth, first, nxt, count, fresh, last_seen,
                      outcome, nodes, m, ranked):
    """Store the prediction of report ``r``: the outcome, its share, and the ranking.

    The ranking is the predicted outcome, then the other outcomes of the chosen context
    and of shorter contexts (longer ones when those leave room), each with its
    probability by PPM's method C: a context of total weight ``n`` and ``d`` distinct
    outcomes gives an outcome of weight ``w`` the mass left to it times ``w / (n + d)``
    and passes ``d / (n + d)`` of that mass on to outcomes it never saw (the mass starts
    at 1, so the probabilities sum to at most 1). After the prediction, outcomes are
    ordered by probability. ``ranked`` is scratch of ``top_k`` entries (see ``_rank_into``)."""
    weight = fresh if kind == FRESH else count
    total, distinct = weight_sums(first, nxt, weight, node)
    out.predicted[r] = said
    out.length[r] = length
    out.kind[r] = kind
    out.score[r] = _share(first, nxt, weight, outcome, node, said, total)
    out.truth_p[r] = _share(first, nxt, weight, outcome, node, truth, total)
    top, top_p = out.top, out.top_p
    top[r, 0] = said
    top_p[r, 0] = out.score[r] * total / (total + distinct) if total > 0 else 0.0  # (w / (n + d))
    filled = 1
    mass = 1.0
    for k in range(length, 0, -1):  # the chosen context's ranking, then shorter contexts'
        if filled >= top.shape[1]:
            break
        w = fresh if (kind == FRESH and k == length) else count
        filled, mass = _rank_into(top, top_p, r, filled, mass, first, nodes[k], nxt, w, last_seen, outcome,
                                  ranked)
    for k in range(length + 1, m + 1):
        if filled >= top.shape[1]:
            break
        filled, mass = _rank_into(top, top_p, r, filled, mass, first, nodes[k], nxt, count, last_seen,
                                  outcome, ranked)
    for i in range(2, filled):  # by probability after the prediction (stable: ties keep their rank)
        t, p = top[r, i], top_p[r, i]
        j = i
        while j > 1 and top_p[r, j - 1] < p:
            top[r, j], top_p[r, j] = top[r, j - 1], top_p[r, j - 1]
            j -= 1
        top[r, j], top_p[r, j] = t, p


@helper
def record_persistence(out, r, odds, last, truth, first, nxt, count, fresh, outcome, nodes, kind, length):
    """Turn report ``r``, recorded by :func:`record_prediction` with the view's last
    observation ``last`` as what it says, into the persistence specialist's: the two
    experts' mixture, ``q = odds / (1 + odds)`` on ``last`` (``odds`` the specialist's
    weight over the answer's) and ``1 - q`` on the ranking of the chosen context down, in
    which ``last`` has what PPM's method C gives it along the chain (:func:`record_prediction`)."""
    q = odds / (1.0 + odds)
    mass, p_last = 1.0, 0.0
    for k in range(length, 0, -1):
        w = fresh if (kind == FRESH and k == length) else count
        total, distinct = weight_sums(first, nxt, w, nodes[k])
        if total <= 0:
            continue
        share = _share(first, nxt, w, outcome, nodes[k], last, total)
        if share > 0.0:
            p_last = mass * share * total / (total + distinct)
            break
        mass *= distinct / (total + distinct)
    out.top_p[r, 0] = q + (1.0 - q) * p_last
    for i in range(1, out.top.shape[1]):
        out.top_p[r, i] *= 1.0 - q
    out.score[r] = out.top_p[r, 0]
    out.truth_p[r] = (q if truth == last else 0.0) + (1.0 - q) * out.truth_p[r]
    out.kind[r] = PERSIST


@helper
def record_hold(out, r, said):
    """Store report ``r`` as a hold of observation ``said`` (see :class:`Reports`)."""
    out.predicted[r] = said
    out.length[r] = 0
    out.kind[r] = HOLD
    out.top[r, 0] = said


@helper
def _share(first, nxt, weight, outcome, node, token, total):
    if total <= 0:
        return 0.0
    e = first[node]
    while e != -1:
        if outcome[e] == token:
            return weight[e] / total
        e = nxt[e]
    return 0.0


@helper
def _rank_into(top, top_p, r, filled, mass, first, node, nxt, weight, last_seen, outcome, ranked):
    """Append ``node``'s outcomes to row ``r`` of ``top`` in rank order, skipping those
    already there, each with ``mass`` times its weight over the node's total plus its
    distinct outcomes (PPM's method C, see ``record_prediction``); return the entries
    filled and the mass the node passes on. ``ranked[i]`` remembers the entry placed at
    ``top[r, i]`` (from ``filled`` on), so placing an entry compares it with entries, not
    outcomes: O(outcomes x top_k)."""
    start = filled
    k = top.shape[1]
    total, distinct = weight_sums(first, nxt, weight, node)
    if total <= 0:
        return filled, mass
    scale = mass / (total + distinct)
    e = first[node]
    while e != -1:
        o = outcome[e]
        taken = False
        for i in range(filled):
            if top[r, i] == o:
                taken = True
                break
        if not taken and weight[e] > 0:
            pos = filled
            while pos > start and ranks_above(weight, last_seen, outcome, e, ranked[pos - 1]):
                pos -= 1
            if pos < k:
                for i in range(min(filled, k - 1), pos, -1):
                    top[r, i] = top[r, i - 1]
                    top_p[r, i] = top_p[r, i - 1]
                    ranked[i] = ranked[i - 1]
                top[r, pos] = o
                top_p[r, pos] = weight[e] * scale
                ranked[pos] = e
                filled = min(filled + 1, k)
        e = nxt[e]
    return filled, mass * distinct / (total + distinct)
