"""The prequential loop of the paper's simulations: predict each step, then learn it.

``learn=False`` keeps the library frozen (held-out evaluation); the predictor's adaptive
cells still update from each outcome, as any online order selection would.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from slearn.library import has_room, learn_step
from slearn.predictor import Predictor, collect, rank, select, update_cells
from slearn.stream import Episode


@dataclass(frozen=True)
class OnlineResult:
    """Per step of an episode after the first: what was predicted and whether it was right.

    Attributes:
        predicted: predicted observation token per step, -1 where the predictor abstained.
        actual: the observed token per step.
        matched_length: history tokens matched (see :class:`slearn.predictor.Prediction`;
            -1 when abstaining).
        score: share of the winning context's weight behind the prediction.
        top: ``(n_steps, top_k)`` ranked tokens, -1 padded.
    """

    predicted: np.ndarray
    actual: np.ndarray
    matched_length: np.ndarray
    score: np.ndarray
    top: np.ndarray

    @property
    def correct(self) -> np.ndarray:
        return self.predicted == self.actual

    @property
    def abstained(self) -> np.ndarray:
        return self.predicted < 0

    def top_k_correct(self, k: int) -> np.ndarray:
        """Whether the actual token is among the first ``k`` ranked."""
        return (self.top[:, :k] == self.actual[:, None]).any(axis=1)


def run_online(predictor: Predictor, episode: Episode, learn: bool = True) -> OnlineResult:
    """Predict then (optionally) learn every step of one episode."""
    library = predictor.library
    tokens = library.tokens.tokenize(episode)
    return run_online_tokens(predictor, tokens, learn)


def run_online_tokens(predictor: Predictor, tokens: np.ndarray, learn: bool = True) -> OnlineResult:
    """:func:`run_online` on an episode already tokenized by the library's table."""
    library = predictor.library
    n_steps = max((len(tokens) - 1) // 2, 0)
    out = OnlineResult(np.full(n_steps, -1, np.int32), tokens[2::2].copy(), np.full(n_steps, -1, np.int32),
                       np.zeros(n_steps), np.full((n_steps, predictor.top_k), -1, np.int32))
    if n_steps == 0:
        return out
    library.context_index()
    if learn:
        library.begin_episode(tokens)
    frozen_state = np.array([0, 0, 1], np.int64)  # a frozen library keeps its parse state
    scoring = predictor.scoring
    cand = np.zeros(2 * library.max_length, np.int32)
    while True:
        index = library.context_index()
        args = list(library._kernel_args())
        args[3] = index
        if not learn:
            args[6] = frozen_state
        done = _online_run(*args, tokens, learn, predictor.cells, scoring.code,
                           scoring.buckets, scoring.alpha, cand, out.predicted, out.matched_length,
                           out.score, out.top)
        if done:
            break
        library.make_room()
    if learn:
        library.end_episode()
    return out


@numba.njit(cache=True)
def _online_run(trie, count, last_seen, index, use_index, n_patterns, state, clock, max_len,
                max_patterns, buf, tokens, learn, cells, rule, n_buckets, alpha, cand,
                predicted, matched, score, top):
    n_steps = (len(tokens) - 1) // 2
    step = state[2]
    top_score = np.zeros(top.shape[1])
    while step <= n_steps:
        if learn and not has_room(trie, index, True, n_patterns, max_len, max_patterns):
            break
        action, truth = tokens[2 * step - 1], tokens[2 * step]
        n = collect(index, tokens, 2 * step - 2, action, max_len, cand)
        if n > 0:
            chosen, outcome = select(index, cand, n, cells, rule, n_buckets)
            rank(index, cand, n, chosen, outcome, top[step - 1], top_score)
            predicted[step - 1] = top[step - 1, 0]
            matched[step - 1] = chosen + 1
            score[step - 1] = top_score[0]
            update_cells(index, cand, n, truth, cells, n_buckets, alpha)
        if learn:
            learn_step(trie, count, last_seen, index, True, n_patterns, state, action, truth,
                       clock[0], max_len, buf)
            clock[0] += 1
        step += 1
    state[2] = step
    return step > n_steps
