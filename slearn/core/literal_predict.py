"""Prediction by the paper's literal rule: the longest match wins.

The history's suffix (the current observation and the action just issued, then as many
earlier events as match) is looked up in the containment index of a
:class:`~slearn.core.literal.LiteralLibrary` (:mod:`slearn.core.context_index`). Every suffix found
inside some library pattern is a candidate; the longest one speaks, and its outcomes rank
by weight (the summed counts of the patterns that contain it: frequency), then by
``last_seen`` (recency), then by id. With no candidate the prediction abstains.

:func:`run_literal` is the prequential loop (predict each step, then learn it, or keep
the library frozen) over steps encoded for one joint view (:mod:`slearn.core.views`).
"""

from __future__ import annotations

import numpy as np

from slearn.core._jit import helper, kernel
from slearn.core.context_index import find_entry, ranks_above
from slearn.core.hashtrie import child
from slearn.core.literal import has_room, learn_step
from slearn.core.mixer import FREQUENT
from slearn.core.online import Reports, new_reports
from slearn.core.views import StepCodes, token_stream


def run_literal(library, codes: StepCodes, learn: bool, record: bool, top_k: int) -> Reports:
    """Predict and/or learn encoded steps with the literal rule (one joint view)."""
    out = new_reports(codes.n_reports if record else 0, top_k)
    tokens, report_at = token_stream(codes, library.empty_action, library.empty_observation)
    n_steps = max((len(tokens) - 1) // 2, 0)
    if n_steps == 0:
        return out
    index = library.context_index()
    if learn:
        library.begin_episode(tokens)
    frozen_state = np.array([0, 0, 1], np.int64)
    while True:
        index = library.context_index()
        args = list(library._kernel_args())
        args[3] = index
        if not learn:
            args[6] = frozen_state
        done = _online_run(*args, tokens, learn, record, report_at, out.predicted, out.length,
                           out.score, out.truth_p, out.top, out.top_p, out.context)
        if done:
            break
        library.make_room()
    if learn:
        library.end_episode()
    if record:
        out.kind[out.predicted >= 0] = FREQUENT
    return out


@helper
def collect(index, tokens, obs_pos, action, max_length, cand):
    """Candidate contexts, shortest first: ``cand[h]`` matches ``h + 1`` history tokens."""
    node = child(index.trie, 0, action)
    n = 0
    i = obs_pos
    while node >= 0 and i >= 0 and n < 2 * max_length - 1:
        node = child(index.trie, node, tokens[i])
        if node < 0 or index.head[node] == -1:
            break
        cand[n] = node
        n += 1
        i -= 1
    return n


@helper
def rank(index, node, outcome, top_tok, top_p, top_entry):
    """The top-k outcomes of the chosen context and their shares in it: ``outcome``
    first, then by rank (``top_entry`` is scratch of the same length)."""
    head, nxt, outs = index.head, index.next, index.outcome
    weight, last_seen = index.weight, index.last_seen
    k = len(top_tok)
    top_tok[:] = -1
    top_p[:] = 0.0
    top_tok[0] = outcome
    filled = 1
    e = head[node]
    while e != -1 and k > 1:
        o = outs[e]
        if o != outcome:
            pos = filled
            while pos > 1 and ranks_above(weight, last_seen, outs, e, top_entry[pos - 1]):
                pos -= 1
            if pos < k:
                for i in range(min(filled, k - 1), pos, -1):
                    top_tok[i], top_entry[i] = top_tok[i - 1], top_entry[i - 1]
                top_tok[pos], top_entry[pos] = o, e
                filled = min(filled + 1, k)
        e = nxt[e]
    total = index.total[node]
    for i in range(filled):
        top_p[i] = (index.weight[index.best[node]] if i == 0 else weight[top_entry[i]]) / total


@kernel
def _online_run(trie, count, last_seen, index, use_index, n_patterns, state, clock, max_len,
                max_patterns, buf, tokens, learn, record, report_at, predicted, length, score,
                truth_p, top, top_p, context):
    n_steps = (len(tokens) - 1) // 2
    step = state[2]
    cand = np.zeros(2 * max_len, np.int32)
    top_entry = np.empty(top.shape[1], np.int64)
    while step <= n_steps:
        if learn and not has_room(trie, index, True, n_patterns, max_len, max_patterns):
            break
        action, truth = tokens[2 * step - 1], tokens[2 * step]
        r = report_at[step - 1]
        if record and r >= 0:
            context[r] = True
            n = collect(index, tokens, 2 * step - 2, action, max_len, cand)
            if n > 0:
                node = cand[n - 1]
                b = index.best[node]
                predicted[r] = index.outcome[b]
                length[r] = n + 1
                score[r] = index.weight[b] / index.total[node]
                e = find_entry(index, node, truth)
                truth_p[r] = 0.0 if e == -1 else index.weight[e] / index.total[node]
                rank(index, node, predicted[r], top[r], top_p[r], top_entry)
        if learn:
            learn_step(trie, count, last_seen, index, True, n_patterns, state, action, truth,
                       clock[0], max_len, buf)
            clock[0] += 1
        step += 1
    state[2] = step
    return step > n_steps
