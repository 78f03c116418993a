"""A growable trie of integer tokens, stored in flat numpy arrays, with compiled lookups.

Node ``n`` has a ``parent`` and a ``token``; the edge ``(parent, token) -> child`` lives in
an open-addressing hash table keyed by ``parent << 32 | token``. Node 0 is the root.
The arrays never move inside a compiled call: kernels stop when ``free_nodes`` gets low,
and :func:`grow` (plain Python) reallocates between calls. The table is kept at most
half full, so probes stay short.
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np
from slearn.core.hashtable import doubled
from slearn.core._jit import helper, kernel

Trie = namedtuple("Trie", "parent token keys vals size")
"""``parent``/``token``: int32 per node; ``keys`` int64 and ``vals`` int32 per hash slot
(key -1 is empty); ``size``: int64[1], the number of nodes in use."""

_EMPTY = -1
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)


def new_trie(capacity: int = 1024) -> Trie:
    """An empty trie holding only the root, with room for ``capacity`` nodes."""
    capacity = max(int(capacity), 16)
    slots = table_size(capacity)
    trie = Trie(
        np.zeros(capacity, np.int32),
        np.full(capacity, -1, np.int32),
        np.full(slots, _EMPTY, np.int64),
        np.zeros(slots, np.int32),
        np.ones(1, np.int64),
    )
    trie.parent[0] = -1
    return trie


def table_size(capacity: int) -> int:
    return 1 << int(2 * capacity - 1).bit_length()


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
    slots = table_size(len(parent))
    trie = Trie(parent, token, np.full(slots, _EMPTY, np.int64), np.zeros(slots, np.int32),
                np.array([n], np.int64))
    _index_all(trie.parent, trie.token, trie.keys, trie.vals, n)
    return trie


@helper
def pair_key(high, low):
    """The 64-bit key of a pair of non-negative 32-bit ids."""
    return (np.int64(high) << 32) | np.int64(low)


@helper
def probe(keys, key):
    """The slot holding ``key`` in an open-addressing table, or the empty slot it would take."""
    mask = len(keys) - 1
    s = np.int64((np.uint64(key) * _GOLDEN) >> np.uint64(32)) & mask
    while keys[s] != key and keys[s] != -1:
        s = (s + 1) & mask
    return s


@kernel
def _index_all(parent, token, keys, vals, n):
    for node in range(1, n):
        key = pair_key(parent[node], token[node])
        s = probe(keys, key)
        keys[s] = key
        vals[s] = node


@helper
def child(trie, node, tok):
    """The child of ``node`` along ``tok``, or -1."""
    key = pair_key(node, tok)
    s = probe(trie.keys, key)
    return trie.vals[s] if trie.keys[s] == key else -1


@helper
def child_or_add(trie, node, tok):
    """The child of ``node`` along ``tok``, created when missing (capacity is the caller's)."""
    key = pair_key(node, tok)
    s = probe(trie.keys, key)
    if trie.keys[s] == key:
        return trie.vals[s]
    new = trie.size[0]
    trie.parent[new] = node
    trie.token[new] = tok
    trie.keys[s] = key
    trie.vals[s] = new
    trie.size[0] = new + 1
    return np.int32(new)


@helper
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
