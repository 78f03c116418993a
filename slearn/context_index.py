"""The containment index: which observation followed each context inside library patterns.

Prediction needs the patterns that *contain* the recent history, anywhere inside them,
not only as a prefix. The index is a trie over contexts read backwards (the action just
issued, the observation before it, the action before that, ...). A node whose context
starts at an observation holds entries ``(outcome, weight, last_seen)``: ``weight`` is the
sum of the counts of all library patterns in which the context is followed by
``outcome``, ``last_seen`` the newest ``last_seen`` among them. A pattern of ``m`` steps
touches ``m (m + 1) / 2`` entries, and a new pattern creates at most ``m`` of them (its
other contexts are already there from its prefix), so the index grows linearly with the
library, not with the square of pattern length.
"""

from __future__ import annotations

from collections import namedtuple

import numba
import numpy as np

from slearn import hashtrie
from slearn.hashtrie import child_or_add, path_tokens

ContextIndex = namedtuple("ContextIndex", "trie head outcome weight last_seen next size")
"""``head`` int32 per trie node (first entry or -1); entries are linked lists through
``next``; ``size`` int64[1] counts entries."""


def new_index(capacity: int = 1024) -> ContextIndex:
    """An empty index with room for ``capacity`` nodes and entries."""
    trie = hashtrie.new_trie(capacity)
    return ContextIndex(trie, np.full(len(trie.parent), -1, np.int32), np.zeros(capacity, np.int32),
                        np.zeros(capacity, np.int64), np.zeros(capacity, np.int64),
                        np.full(capacity, -1, np.int32), np.zeros(1, np.int64))


def free_room(index: ContextIndex) -> int:
    """How many nodes and entries can both still be added."""
    return min(hashtrie.free_nodes(index.trie), len(index.outcome) - int(index.size[0]))


def grow(index: ContextIndex, min_free: int) -> ContextIndex:
    """A copy with room for at least ``min_free`` more nodes and entries."""
    trie = hashtrie.grow(index.trie, min_free)
    head = np.full(len(trie.parent), -1, np.int32)
    head[: len(index.head)] = index.head
    n = int(index.size[0])
    capacity = len(index.outcome)
    while capacity - n < min_free:
        capacity *= 2
    arrays = [index.outcome, index.weight, index.last_seen, index.next]
    if capacity != len(index.outcome):
        fresh = [np.zeros(capacity, a.dtype) for a in arrays]
        for new, old in zip(fresh, arrays):
            new[:n] = old[:n]
        arrays = fresh
    return ContextIndex(trie, head, *arrays, index.size)


def nbytes(index: ContextIndex) -> int:
    """Bytes held by the index arrays."""
    arrays = (*index.trie[:4], index.head, index.outcome, index.weight, index.last_seen, index.next)
    return sum(a.nbytes for a in arrays)


@numba.njit(cache=True)
def add_entry(index, node, outcome, delta, last_seen):
    """Add ``delta`` to the weight of ``outcome`` after the context at ``node``."""
    e = index.head[node]
    while e != -1:
        if index.outcome[e] == outcome:
            index.weight[e] += delta
            if last_seen > index.last_seen[e]:
                index.last_seen[e] = last_seen
            return
        e = index.next[e]
    e = index.size[0]
    index.outcome[e] = outcome
    index.weight[e] = delta
    index.last_seen[e] = last_seen
    index.next[e] = index.head[node]
    index.head[node] = e
    index.size[0] = e + 1


@numba.njit(cache=True)
def add_pattern(index, tokens, length, delta, last_seen):
    """Credit every (context, outcome) inside the pattern ``tokens[:length]``."""
    for j in range(1, length - 1, 2):
        outcome = tokens[j + 1]
        node = 0
        for i in range(j, -1, -1):
            node = child_or_add(index.trie, node, tokens[i])
            if (i & 1) == 0:
                add_entry(index, node, outcome, delta, last_seen)


@numba.njit(cache=True)
def _add_library(index, trie, count, last_seen, buf, start, margin):
    """Index patterns from node ``start`` on; return where it stopped for lack of room."""
    for node in range(start, trie.size[0]):
        if min(len(index.trie.parent) - index.trie.size[0], len(index.outcome) - index.size[0]) < margin:
            return node
        if count[node] > 0:
            length = path_tokens(trie, node, buf)
            add_pattern(index, buf, length, count[node], last_seen[node])
    return trie.size[0]


def index_library(trie, count, last_seen, max_length: int) -> ContextIndex:
    """A fresh index over a whole library (every node with a positive count), in node order."""
    margin = 2 * max_length + 2
    index = new_index(max(1024, int(trie.size[0])))
    buf = np.zeros(2 * max_length + 3, np.int32)
    node = 1
    while node < int(trie.size[0]):
        node = _add_library(index, trie, count, last_seen, buf, node, margin)
        if node < int(trie.size[0]):
            index = grow(index, margin + free_room(index) + 1)
    return index
