"""Prediction: what the library says comes next, given the history and the action issued.

The history's suffix (the current observation and the action just issued, then as many
earlier events as match: the action before, the observation before that, ...) is looked
up in the containment index (:mod:`slearn.context_index`). Every suffix that occurs
inside some library pattern is a *candidate context*, identified by how many history
tokens it matches; matches are over events, so a context may begin at an action. Within
a context, outcomes rank by weight (the summed counts of the patterns that contain it:
frequency), then by ``last_seen`` (recency), then by id.

Which context speaks is the scoring rule:

* ``literal`` -- the paper read literally: the longest match wins.
* ``adaptive`` (default) -- every candidate offers two answers, its most frequent
  outcome and its most recent one. Each answer belongs to a *cell*: (context length,
  support bucket, confidence bucket, frequent-or-recent), where support buckets are powers of
  two of the context's total weight and confidence buckets the share of its best
  outcome. A cell keeps an exponential moving average of its hits (rate ``alpha``), and
  the answer from the best cell speaks. So a context seen once cannot outvote a short
  one seen a hundred times unless contexts like it have earned that trust (pointer
  ``error``), yet after a change of dynamics (``reversal``, ``scramble``) the recent
  outcome and the fresh long contexts take over as soon as they prove right. Ties go to
  the longer context and to frequency, so with no record yet it behaves like
  ``literal``.

With no candidate at all (the action or current observation never seen in any pattern)
the predictor abstains.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numba
import numpy as np

from slearn.context_index import find_entry, ranks_above
from slearn.hashtrie import child
from slearn.library import PatternLibrary
from slearn.tokens import ACTION, OBSERVATION

SCORINGS = ("adaptive", "literal")


@dataclass(frozen=True)
class Scoring:
    """How candidate contexts are weighed (see the module docstring).

    Args:
        rule: ``"adaptive"`` or ``"literal"``.
        alpha: learning rate of the adaptive cells' hit records.
        buckets: support buckets per order (powers of two of the context weight).
        prior: the hit record a cell starts from.
    """

    rule: str = "adaptive"
    alpha: float = 0.01
    buckets: int = 8
    prior: float = 0.5

    def __post_init__(self) -> None:
        if self.rule not in SCORINGS:
            raise ValueError(f"scoring must be one of {SCORINGS}, not {self.rule!r}")

    @property
    def code(self) -> int:
        return SCORINGS.index(self.rule)


@dataclass(frozen=True)
class Prediction:
    """A prediction of the next observations.

    Attributes:
        observations: the predicted observation symbols, ``None`` when abstaining.
        score: the share of the winning context's weight that backs the prediction.
        matched_length: history tokens matched before the action just issued: 1 = the
            current observation, 2 = also the action before it, 3 = also the observation
            before that (one whole step), ...; -1 when abstaining.
        ranked: ``(observations, score)`` best first, up to ``top_k``.
    """

    observations: tuple[int, ...] | None
    score: float
    matched_length: int
    ranked: list[tuple[tuple[int, ...], float]] = field(default_factory=list)

    @property
    def abstained(self) -> bool:
        return self.observations is None


class Predictor:
    """Predicts next observations from a :class:`PatternLibrary` (online or frozen)."""

    def __init__(self, library: PatternLibrary, scoring: Scoring | str = "adaptive", top_k: int = 3) -> None:
        self.library = library
        self.scoring = Scoring(scoring) if isinstance(scoring, str) else scoring
        self.top_k = int(top_k)
        self.cells = np.full(2 * N_CONFIDENCE * 2 * library.max_length * self.scoring.buckets, self.scoring.prior)

    def predict(self, history: list[tuple[tuple[int, ...], tuple[int, ...]]],
                actions: tuple[int, ...]) -> Prediction:
        """Predict the observations that follow ``actions`` after the steps in ``history``.

        ``history`` is a list of ``(actions, observations)`` steps, oldest first; its last
        step's observations are the current ones.
        """
        tokens = self._context_tokens(history, actions)
        if tokens is None:
            return Prediction(None, 0.0, -1)
        index = self.library.context_index()
        k = self.top_k
        cand = np.zeros(2 * self.library.max_length, np.int32)
        top_tok = np.full(k, -1, np.int32)
        top_score = np.zeros(k)
        chosen = _predict(index, tokens, len(tokens) - 2, tokens[-1], self.library.max_length, cand,
                          self.cells, self.scoring.code, self.scoring.buckets, top_tok, top_score)
        if chosen < 0:
            return Prediction(None, 0.0, -1)
        ranked = [(self.library.tokens.symbols(int(t)), float(s)) for t, s in zip(top_tok, top_score) if t >= 0]
        return Prediction(ranked[0][0], ranked[0][1], int(chosen) + 1, ranked)

    def _context_tokens(self, history, actions) -> np.ndarray | None:
        table = self.library.tokens
        action = table.find(ACTION, actions)
        if action < 0 or not history:
            return None
        tokens = [action]
        for i in range(len(history) - 1, -1, -1):
            step_actions, step_observations = history[i]
            obs = table.find(OBSERVATION, step_observations)
            if obs < 0:
                break
            tokens.append(obs)
            act = table.find(ACTION, step_actions) if i > 0 else -1
            if act < 0:
                break
            tokens.append(act)
        if len(tokens) % 2 == 1:  # a dangling action before an unknown observation
            tokens.pop()
        if len(tokens) < 2:
            return None
        return np.asarray(tokens[::-1], np.int32)


@numba.njit(cache=True)
def collect(index, tokens, obs_pos, action, max_length, cand):
    """Candidate contexts, shortest first: ``cand[h]`` matches ``h + 1`` history tokens.

    ``tokens[obs_pos]`` is the current observation; candidate 0 is it and ``action``,
    candidate 1 adds the action before it, candidate 2 the observation before that, and so
    on while the context occurs inside a pattern (at most ``2 * max_length - 1``).
    """
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


@numba.njit(cache=True)
def collect_steps(index, tokens, obs_pos, action, max_orders, cand):
    """Candidate contexts that start at an observation, order 0 (no earlier step) first."""
    node = child(index.trie, 0, action)
    n = 0
    i = obs_pos
    while node >= 0 and i >= 0 and n < max_orders:
        node = child(index.trie, node, tokens[i])
        if node < 0 or index.head[node] == -1:
            break
        cand[n] = node
        n += 1
        if i == 0:
            break
        node = child(index.trie, node, tokens[i - 1])
        i -= 2
    return n


N_CONFIDENCE = 4


@numba.njit(cache=True, inline="always")
def _cell(order, total, best_w, n_buckets):
    bucket = 0
    t = total
    while t > 1 and bucket < n_buckets - 1:
        t >>= 1
        bucket += 1
    share = best_w / total
    conf = 0 if share < 0.5 else (1 if share < 0.7 else (2 if share < 0.9 else 3))
    return 2 * ((order * n_buckets + bucket) * N_CONFIDENCE + conf)


@numba.njit(cache=True)
def select(index, cand, n, cells, rule, n_buckets):
    """The outcome of the candidate and ranking (weight or recency) that speaks.

    Returns ``(candidate index, outcome)``.
    """
    best, newest, outcome_of = index.best, index.newest, index.outcome
    weight, total = index.weight, index.total
    if rule == 1:
        return n - 1, outcome_of[best[cand[n - 1]]]
    chosen, outcome, chosen_acc = n - 1, -1, -1.0
    for k in range(n - 1, -1, -1):
        node = cand[k]
        b = best[node]
        c = _cell(k, total[node], weight[b], n_buckets)
        if cells[c] > chosen_acc:
            chosen, outcome, chosen_acc = k, outcome_of[b], cells[c]
        if cells[c + 1] > chosen_acc:
            chosen, outcome, chosen_acc = k, outcome_of[newest[node]], cells[c + 1]
    return chosen, outcome


@numba.njit(cache=True)
def update_cells(index, cand, n, truth, cells, n_buckets, alpha):
    """Record, for every candidate's cells, whether its outcomes were ``truth``."""
    best, newest, outcome_of = index.best, index.newest, index.outcome
    weight, total = index.weight, index.total
    for k in range(n):
        node = cand[k]
        b = best[node]
        c = _cell(k, total[node], weight[b], n_buckets)
        cells[c] += alpha * ((1.0 if outcome_of[b] == truth else 0.0) - cells[c])
        cells[c + 1] += alpha * ((1.0 if outcome_of[newest[node]] == truth else 0.0) - cells[c + 1])


@numba.njit(cache=True)
def rank(index, cand, n, chosen, outcome, top_tok, top_score):
    """Fill the top-k outcomes: ``outcome``, the chosen context's ranking, then the others'.

    Within one context outcomes keep its rank order; the index's arrays are read into
    locals once, which keeps this loop cheap in compiled code.
    """
    head, nxt, outs = index.head, index.next, index.outcome
    weight, last_seen, total = index.weight, index.last_seen, index.total
    k = len(top_tok)
    top_entry = np.empty(k, np.int64)
    for i in range(k):
        top_tok[i] = -1
        top_score[i] = 0.0
    node = cand[chosen]
    top_tok[0] = outcome
    e0 = find_entry(index, node, outcome)
    top_score[0] = 0.0 if e0 == -1 else weight[e0] / total[node]
    filled = 1
    for pass_ in range(n + 1):
        if filled >= k:
            break
        if pass_ > 0:
            j = n - pass_
            if j == chosen:
                continue
            node = cand[j]
        start = filled
        e = head[node]
        while e != -1:
            o = outs[e]
            taken = False
            for i in range(filled):
                if top_tok[i] == o:
                    taken = True
                    break
            if not taken:
                pos = filled
                while pos > start and ranks_above(weight, last_seen, outs, e, top_entry[pos - 1]):
                    pos -= 1
                if pos < k:
                    for i in range(min(filled, k - 1), pos, -1):
                        top_tok[i], top_score[i], top_entry[i] = top_tok[i - 1], top_score[i - 1], top_entry[i - 1]
                    top_tok[pos], top_score[pos], top_entry[pos] = o, weight[e] / total[node], e
                    filled = min(filled + 1, k)
            e = nxt[e]


@numba.njit(cache=True)
def _predict(index, tokens, obs_pos, action, max_orders, cand, cells, rule, n_buckets, top_tok, top_score):
    n = collect(index, tokens, obs_pos, action, max_orders, cand)
    if n == 0:
        top_tok[:] = -1
        return -1
    chosen, outcome = select(index, cand, n, cells, rule, n_buckets)
    rank(index, cand, n, chosen, outcome, top_tok, top_score)
    return chosen
