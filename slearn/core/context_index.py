"""The containment index: which observation followed each context inside library patterns.

Prediction needs the patterns that *contain* the recent history, anywhere inside them,
not only as a prefix. The index is a trie over contexts read backwards (the action just
issued, the observation before it, the action before that, ...). Every context of at least
one observation and the action after it -- starting at an observation or at an action, as
a match over the event stream may -- holds entries ``(outcome, weight, last_seen)``:
``weight`` is the sum of the counts of all library patterns in which the context is
followed by ``outcome``, ``last_seen`` the newest ``last_seen`` among them. A pattern of
``m`` steps touches ``m^2`` entries, and a new pattern creates at most ``2m - 1`` of them
(its other contexts are already there from its prefix), so the index grows linearly with
the library, not with the square of pattern length.
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np

from slearn.core import hashtable, hashtrie
from slearn.core._jit import helper, kernel
from slearn.core.context_tree import ranks_above
from slearn.core.hashtable import EMPTY, doubled, probe
from slearn.core.hashtrie import child_or_add, path_tokens

ContextIndex = namedtuple(
    "ContextIndex", "trie head best newest total outcome owner weight last_seen next size entry_slots")
"""Per context node: ``head`` (first entry or -1; entries are linked through ``next``),
``best`` (the entry of largest weight, then newest, then smallest outcome), ``newest``
(the entry seen last) and ``total`` (summed weight), all kept up to date in O(1) because
weights and recency only grow. Per entry: ``outcome``, its context node ``owner``,
``weight``, ``last_seen``. ``entry_slots`` hash ``(owner, outcome)`` to the entry (slearn's
one hash table); ``size`` int64[1] counts entries."""


def new_index(capacity: int = 1024) -> ContextIndex:
    """An empty index with room for ``capacity`` nodes and entries."""
    trie = hashtrie.new_trie(capacity)
    nodes = len(trie.parent)
    return ContextIndex(trie, np.full(nodes, -1, np.int32), np.full(nodes, -1, np.int32),
                        np.full(nodes, -1, np.int32), np.zeros(nodes, np.int64),
                        np.zeros(capacity, np.int32), np.full(capacity, -1, np.int32),
                        np.zeros(capacity, np.int64), np.zeros(capacity, np.int64),
                        np.full(capacity, -1, np.int32), np.zeros(1, np.int64), hashtable.new_slots(capacity))


def free_room(index: ContextIndex) -> int:
    """How many nodes and entries can both still be added."""
    return min(hashtrie.free_nodes(index.trie), len(index.outcome) - int(index.size[0]))


def grow(index: ContextIndex, min_free: int) -> ContextIndex:
    """A copy with room for at least ``min_free`` more nodes and entries."""
    trie = hashtrie.grow(index.trie, min_free)
    per_node = [_extended(a, len(trie.parent), fill)
                for a, fill in ((index.head, -1), (index.best, -1), (index.newest, -1), (index.total, 0))]
    n = int(index.size[0])
    capacity = doubled(len(index.outcome), n, min_free)
    if capacity == len(index.outcome):
        return index._replace(trie=trie, head=per_node[0], best=per_node[1], newest=per_node[2],
                              total=per_node[3])
    outcome, owner, weight, last_seen, nxt = (
        _extended(a, capacity, fill) for a, fill in
        ((index.outcome, 0), (index.owner, -1), (index.weight, 0), (index.last_seen, 0), (index.next, -1)))
    slots = hashtable.new_slots(capacity)
    hashtable.rebuild(slots, owner, outcome, 0, n)
    return ContextIndex(trie, *per_node, outcome, owner, weight,  # type: ignore[call-arg]
                        last_seen, nxt, index.size, slots)


def _extended(array: np.ndarray, size: int, fill) -> np.ndarray:
    if len(array) == size:
        return array
    out = np.full(size, fill, array.dtype)
    out[: len(array)] = array
    return out


def nbytes(index: ContextIndex) -> int:
    """Bytes held by the index arrays (the trie's included)."""
    return sum(a.nbytes for a in (*index.trie, *index[1:]))


@helper
def find_entry(index, node, outcome):
    """The entry of ``outcome`` after the context at ``node``, or -1."""
    return index.entry_slots[probe(index.entry_slots, index.owner, index.outcome, node, outcome)]


@helper
def _entry(index, node, outcome):
    """The entry of ``outcome`` after ``node``, created (at the head of its list) if missing."""
    s = probe(index.entry_slots, index.owner, index.outcome, node, outcome)
    found = index.entry_slots[s]
    if found != EMPTY:
        return found
    e = index.size[0]
    index.entry_slots[s] = e
    index.outcome[e] = outcome
    index.owner[e] = node
    index.next[e] = index.head[node]
    index.head[node] = e
    index.size[0] = e + 1
    return e


@helper
def _credit(index, weight, seen, outcome_of, total, best, newest, node, outcome, delta, last_seen):
    """Add ``delta`` to the weight of ``outcome`` after the context at ``node``.

    The arrays come in as locals: reading them off the tuple inside a hot loop is costly.
    """
    e = _entry(index, node, outcome)
    weight[e] += delta
    if last_seen > seen[e]:
        seen[e] = last_seen
    total[node] += delta
    b = best[node]
    if b == -1 or (b != e and ranks_above(weight, seen, outcome_of, e, b)):
        best[node] = e
    w = newest[node]
    if w == -1 or seen[e] > seen[w] or (seen[e] == seen[w] and outcome < outcome_of[w]):
        newest[node] = e


@helper
def add_pattern(index, tokens, length, delta, last_seen):
    """Credit every (context, outcome) inside the pattern ``tokens[:length]``."""
    add_extension(index, tokens, length, delta, delta, last_seen)


@helper
def add_extension(index, tokens, length, prefix_delta, last_delta, last_seen):
    """Credit the pattern ``tokens[:length]``: ``prefix_delta`` to the contexts inside its
    prefix (one step shorter), ``last_delta`` to those ending at its last step. A new
    pattern whose prefix was counted in the same parse credits its prefix twice."""
    trie, weight, seen, outcome_of = index.trie, index.weight, index.last_seen, index.outcome
    total, best, newest = index.total, index.best, index.newest
    for j in range(1, length - 1, 2):
        outcome = tokens[j + 1]
        step_delta = last_delta if j == length - 2 else prefix_delta
        node = 0
        for i in range(j, -1, -1):
            node = child_or_add(trie, node, tokens[i])
            if i < j:
                _credit(index, weight, seen, outcome_of, total, best, newest, node, outcome,
                        step_delta, last_seen)


@kernel
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
