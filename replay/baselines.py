"""The two baselines a reviewer asks for, run on the same token stream as the library.

* ``frequency``: the most frequent next observation given the current observation and
  the action just issued (a first-order transition table).
* ``markov``: a variable-order Markov predictor whose contexts reach as far back as the
  library's (``max_length - 1`` whole steps before the current observation) and back off
  to shorter contexts until one has been seen.

Both are one table of counts: a trie over contexts read backwards (the action, the
current observation, the action before it, ...), whose context nodes count the
observations that followed them. ``frequency`` reads the order-0 node, ``markov`` the
deepest node the history reaches. Within a context the most frequent outcome wins; ties
go to the outcome that reached the count first. With no context at all (the current
observation never seen with this action) both abstain. Tokens are the library's
(:mod:`slearn.tokens`), so predictions compare with the library's one for one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from slearn import hashtrie
from slearn.hashtrie import child, child_or_add

FREQUENCY = "frequency"
MARKOV = "markov"
NAMES = (FREQUENCY, MARKOV)


@dataclass(frozen=True)
class BaselinePredictions:
    """Per step after the first, the token each baseline predicted (-1 = abstained)."""

    frequency: np.ndarray
    markov: np.ndarray

    def get(self, name: str) -> np.ndarray:
        """The predictions of the baseline called ``name``."""
        return getattr(self, name)


class Baselines:
    """Both baselines over one shared count table.

    Args:
        max_order: whole steps of history before the current observation the ``markov``
            baseline may use (the library's ``max_length - 1``).
    """

    def __init__(self, max_order: int) -> None:
        if max_order < 0:
            raise ValueError("max_order must be at least 0")
        self.max_order = int(max_order)
        self._trie = hashtrie.new_trie(1024)
        n = len(self._trie.parent)
        self._count = np.zeros(n, np.int64)
        self._best = np.full(n, -1, np.int32)
        self._best_count = np.zeros(n, np.int64)
        self.steps_learned = 0

    def learn_tokens(self, tokens: np.ndarray) -> None:
        """Count every step of one episode (tokens ``O A O ... O``)."""
        self.run_tokens(tokens, learn=True)

    def run_tokens(self, tokens: np.ndarray, learn: bool) -> BaselinePredictions:
        """Predict every step of one episode, counting each step after predicting it if ``learn``."""
        n_steps = max((len(tokens) - 1) // 2, 0)
        frequency = np.full(n_steps, -1, np.int32)
        markov = np.full(n_steps, -1, np.int32)
        step = 1
        while step <= n_steps:
            self._make_room()
            step = _run(self._trie, self._count, self._best, self._best_count, tokens, step,
                        self.max_order, learn, frequency, markov)
        if learn:
            self.steps_learned += n_steps
        return BaselinePredictions(frequency, markov)

    def _make_room(self) -> None:
        if hashtrie.free_nodes(self._trie) >= 64 * _margin(self.max_order):
            return
        self._trie = hashtrie.grow(self._trie, len(self._trie.parent))
        n = len(self._trie.parent)
        self._count = _resized(self._count, n, 0)
        self._best = _resized(self._best, n, -1)
        self._best_count = _resized(self._best_count, n, 0)


def _margin(max_order: int) -> int:
    return 3 * (max_order + 1) + 1


def _resized(array: np.ndarray, size: int, fill: int) -> np.ndarray:
    out = np.full(size, fill, array.dtype)
    out[: len(array)] = array
    return out


@numba.njit(cache=True)
def _run(trie, count, best, best_count, tokens, step, max_order, learn, frequency, markov):
    """Predict (and count) steps from ``step`` on; returns the next step to do.

    Stops early, before counting a step, when the trie could run out of nodes.
    """
    n_steps = (len(tokens) - 1) // 2
    margin = 3 * (max_order + 1) + 1
    while step <= n_steps:
        if learn and len(trie.parent) - trie.size[0] < margin:
            return step
        obs_pos = 2 * step - 2
        action, truth = tokens[obs_pos + 1], tokens[obs_pos + 2]
        first, deepest = _lookup(trie, best_count, tokens, obs_pos, action, max_order)
        frequency[step - 1] = best[first] if first >= 0 else -1
        markov[step - 1] = best[deepest] if deepest >= 0 else -1
        if learn:
            _count_step(trie, count, best, best_count, tokens, obs_pos, action, truth, max_order)
        step += 1
    return step


@numba.njit(cache=True)
def _lookup(trie, best_count, tokens, obs_pos, action, max_order):
    """``(order-0 context node, deepest context node)`` with counts, -1 where none."""
    first, deepest = -1, -1
    node = child(trie, 0, action)
    pos, order = obs_pos, 0
    while node >= 0 and order <= max_order:
        node = child(trie, node, tokens[pos])
        if node < 0 or best_count[node] == 0:
            break
        if order == 0:
            first = node
        deepest = node
        if pos == 0:
            break
        node = child(trie, node, tokens[pos - 1])
        pos -= 2
        order += 1
    return first, deepest


@numba.njit(cache=True)
def _count_step(trie, count, best, best_count, tokens, obs_pos, action, truth, max_order):
    node = child_or_add(trie, 0, action)
    pos, order = obs_pos, 0
    while order <= max_order:
        node = child_or_add(trie, node, tokens[pos])
        outcome = child_or_add(trie, node, truth)
        count[outcome] += 1
        if count[outcome] > best_count[node]:
            best_count[node] = count[outcome]
            best[node] = truth
        if pos == 0:
            break
        node = child_or_add(trie, node, tokens[pos - 1])
        pos -= 2
        order += 1
