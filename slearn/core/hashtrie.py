"""A growable trie of integer tokens, stored in flat numpy arrays, with compiled lookups.

Node ``n`` has a ``parent`` and a ``token``; the edge ``(parent, token) -> child`` lives in
slearn's one hash table (:mod:`slearn.core.hashtable`: slots of node ids, the pair read
from ``parent``/``token``). Node 0 is the root. The arrays never move inside a compiled
call: kernels stop when ``free_nodes`` gets low, and :func:`grow` (plain Python)
reallocates between calls.
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np

from slearn.core import hashtable
from slearn.core._jit import helper
from slearn.core.hashtable import EMPTY, doubled, find, probe

Trie = namedtuple("Trie", "parent token slots size")
"""``parent``/``token``: int32 per node; ``slots``: the hash table of node ids (int32, -1
empty); ``size``: int64[1], the number of nodes in use."""


def new_trie(capacity: int = 1024) -> Trie:
    """An empty trie holding only the root, with room for ``capacity`` nodes."""
    capacity = max(int(capacity), 16)
    trie = Trie(np.zeros(capacity, np.int32), np.full(capacity, -1, np.int32),
                hashtable.new_slots(capacity), np.ones(1, np.int64))
    trie.parent[0] = -1
    return trie


def free_nodes(trie: Trie) -> int:
    """How many nodes can still be added without :func:`grow`."""
    return len(trie.parent) - int(trie.size[0])


def grow(trie: Trie, min_free: int) -> Trie:
    """A copy of ``trie`` with room for at least ``min_free`` more nodes (doubling)."""
    capacity = doubled(len(trie.parent), int(trie.size[0]), min_free)
    if capacity == len(trie.parent):
        return trie
    n = int(trie.size[0])
    parent = np.zeros(capacity, np.int32)
    token = np.full(capacity, -1, np.int32)
    parent[:n] = trie.parent[:n]
    token[:n] = trie.token[:n]
    return rebuilt(parent, token, n)


def rebuilt(parent: np.ndarray, token: np.ndarray, n: int) -> Trie:
    """A trie over the first ``n`` nodes of ``parent``/``token`` with a fresh hash table."""
    trie = Trie(parent, token, hashtable.new_slots(len(parent)), np.array([n], np.int64))
    hashtable.rebuild(trie.slots, trie.parent, trie.token, 1, n)
    return trie


def clear(trie: Trie) -> None:
    """Drop every node but the root (the arrays stay)."""
    trie.slots.fill(EMPTY)
    trie.size[0] = 1


@helper
def child(trie, node, tok):
    """The child of ``node`` along ``tok``, or -1."""
    return find(trie.slots, trie.parent, trie.token, node, tok)


@helper
def child_or_add(trie, node, tok):
    """The child of ``node`` along ``tok``, created when missing (capacity is the caller's)."""
    s = probe(trie.slots, trie.parent, trie.token, node, tok)
    found = trie.slots[s]
    if found != EMPTY:
        return found
    new = np.int32(trie.size[0])
    trie.parent[new] = node
    trie.token[new] = tok
    trie.slots[s] = new
    trie.size[0] = new + 1
    return new


@helper(python=True)
def path_tokens(trie, node, out):
    """Write the tokens from the root to ``node`` into ``out``; return their number."""
    depth = 0
    n = node
    while n > 0:
        depth += 1
        n = trie.parent[n]
    n = node
    for i in range(depth - 1, -1, -1):
        out[i] = trie.token[n]
        n = trie.parent[n]
    return depth
