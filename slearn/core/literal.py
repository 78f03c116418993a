"""The paper's literal S-learning: its library and learning rule (section II, Fig. 1a).

From the current anchor (an observation), the longest library pattern matching the head
of the stream is found; its count is incremented and its recency reset (``last_seen`` set
to the current step); it is extended by the next step into a new pattern (count 1); the
next parse starts at the boundary, so consecutive patterns share it::

    3 R 4 R 5 L 4 R 5 L 4 L 3 L 2   ->   3 R 4 | 4 R 5 | 5 L 4 | 4 R 5 L 4 | 4 L 3 | 3 L 2

Patterns live in a trie of tokens (see :mod:`slearn.core.tokens`): a pattern of ``m`` steps
is the trie node at depth ``2m + 1`` reached by ``O A O ... O``; its ``count`` is positive.
The library is prefix-closed, so the longest match grows one step at a time. A pattern
that reached ``max_length`` steps is counted but not extended, and the parse restarts at
its last observation. Forgetting (``max_patterns``) drops the rarest, oldest patterns
that have no extensions until the library is back to 90 % of the bound.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator

import numpy as np

from slearn.core import context_index, hashtrie, views
from slearn.core._jit import helper, kernel
from slearn.core.context_index import ContextIndex
from slearn.core.hashtrie import child, child_or_add, path_tokens
from slearn.core.online import Reports
from slearn.core.stream import Episode
from slearn.core.tokens import ACTION, OBSERVATION, TokenTable
from slearn.core.views import StepCodes
from slearn.errors import ParameterError

JOINT = "*"

DEFAULT_MAX_LENGTH = 5
"""Steps per pattern at most: the paper capped patterns at five movement events."""

FORGET_TO = 0.9
_NO_BOUND = np.iinfo(np.int64).max
_TRIE_MARGIN = 8


@dataclass(frozen=True)
class Pattern:
    """One library entry: its tokens ``O A O ... O``, count and the step it was last seen."""

    tokens: tuple[int, ...]
    count: int
    last_seen: int

    @property
    def n_steps(self) -> int:
        """Steps after the anchor observation."""
        return len(self.tokens) // 2


class LiteralLibrary:
    """A growing library of observed patterns with a count and a recency each, counted at
    the parse boundaries of the paper's rule (see the module docstring).

    Args:
        max_length: the longest pattern, in steps after its first observation.
        max_patterns: forgetting bound; ``None`` keeps every pattern.
    """

    def __init__(self, max_length: int = DEFAULT_MAX_LENGTH, max_patterns: int | None = None) -> None:
        if max_length < 1:
            raise ParameterError("max_length must be at least 1")
        if max_patterns is not None and max_patterns < 16:
            raise ParameterError("max_patterns must be at least 16")
        self.max_length = int(max_length)
        self.max_patterns = max_patterns
        self.tokens = TokenTable()
        self.empty_action = self.tokens.intern(ACTION, ())
        self.empty_observation = self.tokens.intern(OBSERVATION, ())
        self.view_names = [JOINT]
        self._clock = np.zeros(1, np.int64)
        self.forgotten = 0
        self._trie = hashtrie.new_trie(1024)
        self._count = np.zeros(len(self._trie.parent), np.int64)
        self._last_seen = np.zeros(len(self._trie.parent), np.int64)
        self._n_patterns = np.zeros(1, np.int64)
        self._index: ContextIndex | None = None
        self._buf = np.zeros(2 * self.max_length + 3, np.int32)
        # parse state: current match node, its length in steps, next step to learn
        self._state = np.zeros(3, np.int64)

    def __len__(self) -> int:
        return int(self._n_patterns[0])

    @property
    def clock(self) -> int:
        """Steps learned so far: the time base of ``last_seen``."""
        return int(self._clock[0])

    factored = False
    has_actions = True

    # learning -------------------------------------------------------------------------
    def encode(self, episode: Episode, intern: bool = True) -> StepCodes:
        """The episode's steps with each step's observations as one token (one view)."""
        return views.encode(self.tokens, episode, views.joint_mapping(episode), intern)

    def learn(self, episode: Episode) -> None:
        """Learn one whole episode (its own parse: episodes are never glued together)."""
        self.learn_tokens(views.token_stream(self.encode(episode), self.empty_action,
                                             self.empty_observation)[0])

    def run(self, codes: StepCodes, *, learn: bool, record: bool = True, top_k: int = 3,
            new_episode: bool = True, streams=None) -> Reports:
        """Predict (``record``) and/or learn encoded steps, longest match first (every run is
        one whole episode; ``streams`` is accepted for the common interface and unused)."""
        from slearn.core.literal_predict import run_literal  # it imports this module's kernels

        return run_literal(self, codes, learn, record, top_k)

    def learn_tokens(self, tokens: np.ndarray) -> None:
        """Learn one episode given as tokens ``O A O ... O`` of this library's table."""
        if len(tokens) == 0:
            return
        self.begin_episode(tokens)
        while not _learn_run(*self._kernel_args(), tokens):
            self.make_room()
        self.end_episode()

    def begin_episode(self, tokens: np.ndarray) -> None:
        """Anchor a new parse at the first observation of an episode."""
        self.make_room()
        self._state[:] = (_anchor(self._trie, tokens[0]), 0, 1)

    def learn_next(self, action_token: int, observation_token: int) -> None:
        """Learn one more step of the episode opened by :meth:`begin_episode` (closed loop)."""
        args = self._kernel_args()
        if not has_room(args[0], args[3], args[4], args[5], self.max_length, args[9]):
            self.make_room()
            args = self._kernel_args()
        learn_step(*args[:7], int(action_token), int(observation_token), self.clock,
                   self.max_length, self._buf)
        self._clock[0] += 1

    def end_episode(self) -> None:
        """Count the match still open at the end of an episode."""
        if self._state[1] > 0:
            _touch(self._trie, self._count, self._last_seen, self._index_or_dummy(),
                   self._index is not None, int(self._state[0]), self.clock - 1, self._buf)
        self._state[1] = 0

    def _kernel_args(self):
        bound = _NO_BOUND if self.max_patterns is None else self.max_patterns
        return (self._trie, self._count, self._last_seen, self._index_or_dummy(),
                self._index is not None, self._n_patterns, self._state, self._clock,
                self.max_length, bound, self._buf)

    def make_room(self) -> None:
        """Grow arrays and forget as needed between kernel calls."""
        if self.max_patterns is not None and len(self) >= self.max_patterns:
            self._forget()
        if hashtrie.free_nodes(self._trie) < 64 * _TRIE_MARGIN:
            self._grow(len(self._trie.parent))
        if self._index is not None and context_index.free_room(self._index) < 64 * self._index_margin():
            self._index = context_index.grow(self._index, len(self._index.outcome))

    def _grow(self, min_free: int) -> None:
        self._trie = hashtrie.grow(self._trie, min_free)
        self._count = _resized(self._count, len(self._trie.parent))
        self._last_seen = _resized(self._last_seen, len(self._trie.parent))

    def _index_margin(self) -> int:
        return 2 * self.max_length + 4

    # prediction support ----------------------------------------------------------------
    def context_index(self) -> ContextIndex:
        """The containment index (built on first use, then kept in step with learning)."""
        if self._index is None:
            n = int(self._trie.size[0])
            self._index = context_index.index_library(self._trie, self._count[:n], self._last_seen[:n],
                                                      self.max_length)
            self.make_room()
        return self._index

    def _index_or_dummy(self) -> ContextIndex:
        if self._index is not None:
            return self._index
        if not hasattr(self, "_dummy_index"):
            self._dummy_index = context_index.new_index(16)
        return self._dummy_index

    # forgetting ----------------------------------------------------------------------
    def _forget(self) -> None:
        self.forget(int((self.max_patterns or 0) * FORGET_TO))  # called only with a bound

    def forget(self, target: int) -> None:
        """Drop the rarest, then oldest patterns until at most ``target`` remain."""
        n = int(self._trie.size[0])
        parent, count = self._trie.parent[:n], self._count[:n]
        keep_anyway = np.zeros(n, bool)
        keep_anyway[int(self._state[0])] = True
        while int(np.count_nonzero(count)) > target:
            grand = parent[np.maximum(parent, 0)]
            has_extension = np.zeros(n, bool)
            extended = (count > 0) & (parent > 0)
            has_extension[grand[extended]] = True
            leaves = np.flatnonzero((count > 0) & ~has_extension & ~keep_anyway)
            if len(leaves) == 0:
                break
            order = np.lexsort((leaves, self._last_seen[leaves], count[leaves]))
            victims = leaves[order[: int(np.count_nonzero(count)) - target]]
            count[victims] = 0
            self.forgotten += len(victims)
        self._compact(keep_anyway)

    def _compact(self, keep_anyway: np.ndarray) -> None:
        n = int(self._trie.size[0])
        keep = (self._count[:n] > 0) | keep_anyway
        keep[0] = True
        _keep_ancestors(self._trie.parent, keep)
        new_id = np.cumsum(keep) - 1
        capacity = len(self._trie.parent)
        parent = np.zeros(capacity, np.int32)
        token = np.full(capacity, -1, np.int32)
        kept = np.flatnonzero(keep)
        parent[: len(kept)] = np.where(kept == 0, -1, new_id[self._trie.parent[kept]])
        token[: len(kept)] = self._trie.token[kept]
        self._trie = hashtrie.rebuilt(parent, token, len(kept))
        self._count = _compacted(self._count, kept, capacity)
        self._last_seen = _compacted(self._last_seen, kept, capacity)
        self._n_patterns[0] = int(np.count_nonzero(self._count))
        self._state[0] = new_id[int(self._state[0])]
        if self._index is not None:
            self._index = None
            self.context_index()

    # inspection and export ----------------------------------------------------------------
    def iter_patterns(self) -> Iterator[Pattern]:
        """Every pattern, in the order it was first recorded."""
        n = int(self._trie.size[0])
        for node in np.flatnonzero(self._count[:n] > 0):
            length = path_tokens(self._trie, int(node), self._buf)
            yield Pattern(tuple(self._buf[:length].tolist()), int(self._count[node]),
                          int(self._last_seen[node]))

    def pattern_nodes(self) -> np.ndarray:
        """Trie node ids of all patterns, in recording order."""
        return np.flatnonzero(self._count[: int(self._trie.size[0])] > 0)

    def max_count(self) -> int:
        """The largest pattern count (0 when empty)."""
        return int(self._count[: int(self._trie.size[0])].max(initial=0))

    def export(self) -> dict[str, np.ndarray]:
        """Patterns as flat arrays: tokens (``token_offsets``/``pattern tokens``), counts, recency."""
        nodes = self.pattern_nodes()
        offsets, flat = _export_paths(self._trie, nodes, 2 * self.max_length + 1)
        return {
            "pattern_offsets": offsets,
            "pattern_tokens": flat,
            "count": self._count[nodes].copy(),
            "last_seen": self._last_seen[nodes].copy(),
        }

    @classmethod
    def from_export(cls, arrays: dict[str, np.ndarray], tokens: TokenTable, clock: int,
                    max_length: int, max_patterns: int | None = None) -> "LiteralLibrary":
        """Rebuild a library from :meth:`export` output and its token table.

        An optional ``arrays["pattern_parent"]`` (:meth:`pattern_parents`) makes this about
        3x faster: a pattern is attached to its prefix pattern instead of walked from the
        root (an entry that does not name an earlier prefix is walked, so it is only a hint).
        """
        library = cls(max_length, max_patterns)
        library.tokens = tokens
        library.empty_action = tokens.intern(ACTION, ())
        library.empty_observation = tokens.intern(OBSERVATION, ())
        library._clock[0] = int(clock)
        offsets, flat = arrays["pattern_offsets"], arrays["pattern_tokens"]
        n = len(offsets) - 1
        parents = np.asarray(arrays.get("pattern_parent", np.full(n, -1)), np.int64)
        library._trie = hashtrie.new_trie(max(1024, _node_estimate(offsets, parents)))
        library._count = np.zeros(len(library._trie.parent), np.int64)
        library._last_seen = np.zeros(len(library._trie.parent), np.int64)
        nodes, done = np.zeros(n, np.int32), 0
        while done < n:
            done = _import_paths(library._trie, library._count, library._last_seen, offsets, flat,
                                 parents, arrays["count"], arrays["last_seen"], nodes, done)
            if done < n:  # a wrong hint made the estimate short
                library._grow(max(len(library._trie.parent), int(offsets[done + 1] - offsets[done])))
        library._n_patterns[0] = n
        library.make_room()
        return library

    def pattern_parents(self) -> np.ndarray:
        """Per pattern (recording order), the index of its prefix one step shorter; -1 for
        one-step patterns. Parents come before their extensions."""
        nodes = self.pattern_nodes()
        if len(nodes) == 0:
            return np.zeros(0, np.int64)
        prefix = self._trie.parent[self._trie.parent[nodes]]
        index = np.minimum(np.searchsorted(nodes, prefix), len(nodes) - 1)
        return np.where(nodes[index] == prefix, index, -1).astype(np.int64)

    def nbytes(self) -> int:
        """Bytes held by the library's arrays (trie, counts, recency; not the index)."""
        trie = self._trie
        return sum(a.nbytes for a in (*trie[:4], self._count, self._last_seen))

    def index_nbytes(self) -> int:
        """Bytes held by the containment index (0 until prediction is used)."""
        return 0 if self._index is None else context_index.nbytes(self._index)


def _resized(array: np.ndarray, size: int) -> np.ndarray:
    out = np.zeros(size, array.dtype)
    out[: len(array)] = array
    return out


def _compacted(array: np.ndarray, kept: np.ndarray, capacity: int) -> np.ndarray:
    out = np.zeros(capacity, array.dtype)
    out[: len(kept)] = array[kept]
    return out


@kernel
def _keep_ancestors(parent, keep):
    for node in range(len(keep) - 1, 0, -1):
        if keep[node]:
            keep[parent[node]] = True


@kernel
def _anchor(trie, obs_token):
    return child_or_add(trie, 0, obs_token)


@helper(python=True)
def _touch(trie, count, last_seen, index, use_index, node, clock, buf):
    count[node] += 1
    last_seen[node] = clock
    if use_index:
        length = path_tokens(trie, node, buf)
        context_index.add_pattern(index, buf, length, 1, clock)


@helper(python=True)
def learn_step(trie, count, last_seen, index, use_index, n_patterns, state, a_tok, o_tok,
               clock, max_len, buf):
    """Learn one step ``(a_tok, o_tok)``; ``state`` holds the match node and its length."""
    while True:
        cur = state[0]
        cur_len = state[1]
        if cur_len < max_len:
            a = child(trie, cur, a_tok)
            if a >= 0:
                o = child(trie, a, o_tok)
                if o >= 0 and count[o] > 0:
                    state[0] = o
                    state[1] = cur_len + 1
                    return
        if cur_len < max_len:
            o = child_or_add(trie, child_or_add(trie, cur, a_tok), o_tok)
            if cur_len > 0:
                count[cur] += 1
                last_seen[cur] = clock
            count[o] = 1
            last_seen[o] = clock
            n_patterns[0] += 1
            if use_index:
                # the match's contexts are credited twice (its count and the new pattern)
                length = path_tokens(trie, o, buf)
                context_index.add_extension(index, buf, length, 2 if cur_len > 0 else 1, 1, clock)
            state[0] = child_or_add(trie, 0, o_tok)
            state[1] = 0
            return
        _touch(trie, count, last_seen, index, use_index, cur, clock, buf)
        state[0] = child_or_add(trie, 0, trie.token[cur])
        state[1] = 0


@helper(python=True)
def has_room(trie, index, use_index, n_patterns, max_len, max_patterns):
    """Whether one more step can be learned without growing or forgetting."""
    if len(trie.parent) - trie.size[0] < _TRIE_MARGIN or n_patterns[0] >= max_patterns:
        return False
    if use_index:
        free = min(len(index.trie.parent) - index.trie.size[0], len(index.outcome) - index.size[0])
        if free < 2 * max_len + 4:
            return False
    return True


@kernel
def _learn_run(trie, count, last_seen, index, use_index, n_patterns, state, clock, max_len,
               max_patterns, buf, tokens):
    n_steps = (len(tokens) - 1) // 2
    step = state[2]
    while step <= n_steps:
        if not has_room(trie, index, use_index, n_patterns, max_len, max_patterns):
            break
        learn_step(trie, count, last_seen, index, use_index, n_patterns, state,
                   tokens[2 * step - 1], tokens[2 * step], clock[0], max_len, buf)
        clock[0] += 1
        step += 1
    state[2] = step
    return step > n_steps


@kernel
def _export_paths(trie, nodes, max_tokens):
    offsets = np.zeros(len(nodes) + 1, np.int64)
    flat = np.empty(len(nodes) * max_tokens, np.int32)
    pos = 0
    for i in range(len(nodes)):
        length = path_tokens(trie, nodes[i], flat[pos:])
        pos += length
        offsets[i + 1] = pos
    return offsets, flat[:pos].copy()


@helper
def _is_prefix(flat, start, end, of_start, of_end):
    if end - start != of_end - of_start:
        return False
    for k in range(end - start):
        if flat[start + k] != flat[of_start + k]:
            return False
    return True


def _node_estimate(offsets: np.ndarray, parents: np.ndarray) -> int:
    """Trie nodes needed: 2 per pattern attached to its parent, else its length (+ margin)."""
    lengths = np.diff(offsets)
    n = len(lengths)
    ok = (parents >= 0) & (parents < np.arange(n))
    ok[ok] = lengths[parents[ok]] == lengths[ok] - 2
    return int(np.where(ok, 2, lengths).sum()) + 64 * _TRIE_MARGIN


@kernel
def _import_paths(trie, count, last_seen, offsets, flat, parents, counts, recency, nodes, first):
    """Insert patterns ``first..`` and return where it stopped (all done, or the trie is full)."""
    for i in range(first, len(offsets) - 1):
        start, end, p = offsets[i], offsets[i + 1], parents[i]
        node = 0
        if 0 <= p < i and _is_prefix(flat, offsets[p], offsets[p + 1], start, end - 2):
            node, start = nodes[p], end - 2
        if trie.size[0] + (end - start) > len(trie.parent):
            return i
        for j in range(start, end):
            node = child_or_add(trie, node, flat[j])
        nodes[i] = node
        count[node] = counts[i]
        last_seen[node] = recency[i]
    return len(offsets) - 1
