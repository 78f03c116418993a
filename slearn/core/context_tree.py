"""The context tree: every context of a stream, read backwards, with what followed it.

A *context* is a run of tokens just before an outcome, up to a maximum length. The tree
stores contexts backwards from a root per view (the token just before the outcome first,
then the one before it, ...), so the contexts of one prediction lie on one path and a
context of ``k`` tokens is the node at depth ``k``. Each node holds *entries*
``(outcome, count, last_seen, fresh)``: how often the outcome followed the context, the
clock of its last occurrence, and how often since the current epoch of its view began
(see :mod:`slearn.core.mixer`). Together, a context and one of its outcomes are a pattern of
the library: an observed run of events with its count and recency.

Per node, ``best`` (most occurrences, ties to the newest), ``newest`` (seen last) and
``fresh_best`` (most occurrences this epoch) are kept in O(1) per occurrence, because
counts only grow: the entry just counted is the newest, so it takes over on a tie.
``fresh_total`` and ``fresh_outcomes`` (a node's fresh counts summed, and how many of its
outcomes have one) are kept the same way, so the probability PPM's method C gives an
outcome (:func:`fresh_sums`, asked once per learned observation) costs O(1), not a
walk of the node's outcomes (a context followed by 1,000 different items made learning
100 us per item). In a view's first epoch fresh counts are the all-time counts.
Fresh counts belong to the epoch written in the node and are reset lazily, when a node
of an older epoch is next counted. Nodes and entries are found through
:mod:`slearn.core.hashtable`; a node's slot follows from its *path hash*, a hash of its
root and the tokens on the way to it (:func:`path_hash`), not from its parent's id, so the
lookups of one prediction's contexts (depth 1, 2, ...) are computed from the tokens alone
and run at the same time, where each waited for the node above it. Nodes are numbered
after their parents (every way a tree is built adds a parent first), so a table is rebuilt
in one pass (:func:`rebuild_nodes`). The arrays never move inside a compiled call: callers
check :func:`room` and :func:`grow` between calls.
"""

from __future__ import annotations

import mmap
from typing import NamedTuple

import numpy as np

from slearn.core import hashtable
from slearn.core._jit import helper, kernel, prefetch
from slearn.core.hashtable import EMPTY, grown, home, probe, probe_from, scaled

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_SEED = np.uint64(0x243F6A8885A308D3)


class Tree(NamedTuple):
    """All arrays of a context tree; ``size`` is ``[nodes, entries]`` in use."""

    parent: np.ndarray      # int32 per node, -1 for a view root
    token: np.ndarray       # int32 per node; a root holds its view
    first: np.ndarray       # int32 per node: its newest-added entry, -1
    best: np.ndarray        # int32 per node
    newest: np.ndarray      # int32 per node
    fresh_best: np.ndarray  # int32 per node
    epoch: np.ndarray       # int32 per node: the epoch its fresh counts belong to
    node_slots: np.ndarray  # int32 hash slots of (parent, token), placed by path hash
    owner: np.ndarray       # int32 per entry: its context node
    outcome: np.ndarray     # int32 per entry
    count: np.ndarray  # type: ignore[assignment]  # int64 per entry (shadows tuple.count)
    last_seen: np.ndarray   # int64 per entry
    fresh: np.ndarray       # int64 per entry
    next: np.ndarray        # int32 per entry: the next entry of the same node, -1
    entry_slots: np.ndarray  # int32 hash slots of (owner, outcome)
    size: np.ndarray        # int64[2]
    fresh_total: np.ndarray     # int32 per node: its entries' fresh counts summed, SATURATED past int32
    fresh_outcomes: np.ndarray  # int32 per node: its entries with a fresh count


_NODE_FILL = {"parent": -1, "token": -1, "first": -1, "best": -1, "newest": -1,
              "fresh_best": -1, "epoch": 0, "fresh_total": 0, "fresh_outcomes": 0}
_ENTRY_FILL = {"owner": -1, "outcome": -1, "count": 0, "last_seen": 0, "fresh": 0, "next": -1}
_NODE_TYPES = {"epoch": np.int32}
_ENTRY_TYPES = {"count": np.int64, "last_seen": np.int64, "fresh": np.int64}
SATURATED = np.iinfo(np.int32).max
"""``fresh_total`` of a node whose fresh counts sum to this or more: it is summed by a walk."""


def new_tree(nodes: int = 1024, entries: int = 1024) -> Tree:
    """An empty tree with room for ``nodes`` nodes and ``entries`` entries.

    Only the hash slots are written now. A node or entry is written whole when it is
    added (:func:`add_root`, :func:`child_or_add`, :func:`entry_or_add`), and the arrays are
    anonymous memory maps (:func:`reserved`), so the room not yet used is memory the system
    has promised but not given: a tree's resident size follows what it holds, not its
    capacity, and an array left behind by :func:`grow` goes back to the system at once.
    """
    node_arrays = {name: reserved(nodes, _NODE_TYPES.get(name, np.int32)) for name in _NODE_FILL}
    entry_arrays = {name: reserved(entries, _ENTRY_TYPES.get(name, np.int32)) for name in _ENTRY_FILL}
    return Tree(**node_arrays, node_slots=_empty_slots(nodes), **entry_arrays,
                entry_slots=_empty_slots(entries), size=np.zeros(2, np.int64))


def reserved(n: int, dtype) -> np.ndarray:
    """A writable array of ``n`` values in a private anonymous memory map: zero pages until
    written (C's allocator would keep a freed array's memory for later use, resident).
    Private, not shared (Python's default): a shared map lives in the kernel's shmem, whose
    page faults were a quarter of learning's time, and a forked process would write into it."""
    return np.frombuffer(mmap.mmap(-1, max(n * np.dtype(dtype).itemsize, 1), flags=mmap.MAP_PRIVATE), dtype, count=n)


def _empty_slots(capacity: int) -> np.ndarray:
    slots = reserved(hashtable.slots_for(capacity), np.int32)
    slots.fill(EMPTY)
    return slots


def room(tree: Tree) -> tuple[int, int]:
    """``(nodes, entries)`` that can still be added without :func:`grow`."""
    return len(tree.parent) - int(tree.size[0]), len(tree.owner) - int(tree.size[1])


def grow(tree: Tree, nodes: int, entries: int) -> Tree:
    """A tree with room for at least ``nodes`` more nodes and ``entries`` more entries: the
    side that has the room keeps its arrays and hash slots; the other is copied into larger
    arrays and its slots rebuilt."""
    n, m = int(tree.size[0]), int(tree.size[1])
    node_cap, entry_cap = grown(len(tree.parent), n, nodes), grown(len(tree.owner), m, entries)
    replaced: dict[str, np.ndarray] = {}
    if node_cap != len(tree.parent):
        for name in _NODE_FILL:
            replaced[name] = reserved(node_cap, _NODE_TYPES.get(name, np.int32))
            replaced[name][:n] = getattr(tree, name)[:n]
        replaced["node_slots"] = _empty_slots(node_cap)
        rebuild_nodes(replaced["node_slots"], replaced["parent"], replaced["token"], n)
    if entry_cap != len(tree.owner):
        for name in _ENTRY_FILL:
            replaced[name] = reserved(entry_cap, _ENTRY_TYPES.get(name, np.int32))
            replaced[name][:m] = getattr(tree, name)[:m]
        replaced["entry_slots"] = _empty_slots(entry_cap)
        hashtable.rebuild(replaced["entry_slots"], replaced["owner"], replaced["outcome"], 0, m)
    return tree._replace(**replaced) if replaced else tree


def ensure_room(tree: Tree, nodes: int, entries: int) -> Tree:
    """``tree`` itself when it has the room, else a grown copy (by half, or more)."""
    free_nodes, free_entries = room(tree)
    if free_nodes >= nodes and free_entries >= entries:
        return tree
    return grow(tree, nodes, entries)


def add_root(tree: Tree, view: int) -> int:
    """A new root node for ``view`` (call with room for one node)."""
    node = int(tree.size[0])
    for name, fill in _NODE_FILL.items():
        getattr(tree, name)[node] = fill
    tree.token[node] = view
    tree.size[0] = node + 1
    return node


def nbytes(tree: Tree) -> int:
    """Bytes held by the tree's arrays."""
    return sum(a.nbytes for a in tree)


# --- compiled helpers on raw arrays (inlined into the kernels that read a Tree) ----------

@helper
def root_path(root):
    """The path hash of the root node ``root`` (a view's: :func:`add_root`)."""
    return path_hash(_SEED, root)


@helper
def path_hash(h, tok):
    """The path hash of the child along ``tok`` of a node whose path hash is ``h``
    (``uint64``): a multiplicative hash of both, its high half folded into the low one."""
    x = (h ^ (np.uint64(tok) + np.uint64(1))) * _GOLDEN
    return x ^ (x >> np.uint64(32))


@kernel
def rebuild_nodes(node_slots, parent, token, n):
    """Empty ``node_slots`` and insert nodes ``0..n-1`` (roots are not in the table)."""
    node_slots[:] = EMPTY
    h = np.empty(max(n, 1), np.uint64)
    for r in range(n):
        p = parent[r]
        if p < 0:
            h[r] = root_path(r)
        elif p >= r:
            raise ValueError("a context tree's node is numbered before its parent")
        else:
            h[r] = path_hash(h[p], token[r])
    for r in range(n):  # nodes are unique: each takes the first empty slot from its own
        q = r + hashtable.AHEAD
        if q < n:
            prefetch(node_slots, scaled(node_slots, h[q]))
        if parent[r] >= 0:
            node_slots[hashtable.free_from(node_slots, scaled(node_slots, h[r]))] = r


@helper
def child(node_slots, parent, token, node, tok, h):
    """The child of ``node`` along ``tok``, or -1; ``h`` is the child's path hash."""
    return node_slots[probe_from(node_slots, parent, token, node, tok, scaled(node_slots, h))]


@helper
def child_or_add(node_slots, parent, token, first, best, newest, fresh_best, epoch, size, node, tok, h):
    """The child of ``node`` along ``tok``, added when missing (room is the caller's);
    ``h`` is the child's path hash."""
    s = probe_from(node_slots, parent, token, node, tok, scaled(node_slots, h))
    found = node_slots[s]
    if found != EMPTY:
        return found
    new = np.int32(size[0])
    parent[new] = node
    token[new] = tok
    first[new] = -1
    best[new] = -1
    newest[new] = -1
    fresh_best[new] = -1
    epoch[new] = 0  # its fresh_total and fresh_outcomes are 0: never written (reserved), as no
    node_slots[s] = new  # node number is used twice in one tree
    size[0] = new + 1
    return new


FETCH_SLOTS = 1 << 18
"""Hash tables of more slots than this (1 MiB) are prefetched (:func:`fetch_nodes`); smaller
ones stay in the CPU's caches, where asking ahead costs more than it saves (5 % of online
learning on a library of 9,000 contexts; 15-25 % saved on one of 650,000)."""


@helper
def fetch_nodes(node_slots, parent, token, first, best, hashes, depth):
    """Ask the CPU for what looking up the contexts ``1..depth`` of a view will read: the
    slot of each path hash ``hashes[k]``, then the node each slot holds (the node sought
    when it exists). Each lookup then finds its memory on the way, instead of waiting for
    it after the lookup before it (:func:`slearn.core._jit.prefetch`)."""
    for k in range(1, depth + 1):
        prefetch(node_slots, scaled(node_slots, hashes[k]))
    for k in range(1, depth + 1):
        found = node_slots[scaled(node_slots, hashes[k])]
        if found >= 0:
            prefetch(parent, found)
            prefetch(token, found)
            prefetch(first, found)
            prefetch(best, found)


@helper
def fetch_entry_slots(entry_slots, nodes, n, out):
    """Ask the CPU for the home slot of the entry ``(nodes[k], out)`` of each context
    ``1..n`` (counting the outcome ``out`` will probe them; see :func:`fetch_nodes`)."""
    for k in range(1, n + 1):
        prefetch(entry_slots, home(entry_slots, nodes[k], out))


@helper
def fetch_entries(entry_slots, owner, outcome, count, last_seen, fresh, nodes, n, out):
    """After :func:`fetch_entry_slots` (and some work between): the entries those slots
    hold, which counting ``out`` reads and writes."""
    for k in range(1, n + 1):
        e = entry_slots[home(entry_slots, nodes[k], out)]
        if e >= 0:
            prefetch(owner, e)
            prefetch(outcome, e)
            prefetch(count, e)
            prefetch(last_seen, e)
            prefetch(fresh, e)


@helper
def entry_or_add(entry_slots, owner, outcome, count, last_seen, fresh, nxt, first, size, node, out):
    """The entry of ``out`` after ``node``, added when missing (room is the caller's)."""
    s = probe(entry_slots, owner, outcome, node, out)
    found = entry_slots[s]
    if found != EMPTY:
        return found
    e = np.int32(size[1])
    owner[e] = node
    outcome[e] = out
    count[e] = 0
    last_seen[e] = 0
    fresh[e] = 0
    nxt[e] = first[node]
    first[node] = e
    entry_slots[s] = e
    size[1] = e + 1
    return e


@helper
def refresh(first, nxt, fresh, fresh_best, fresh_total, fresh_outcomes, epoch, node, current):
    """Bring a node's fresh counts into epoch ``current`` (zero them if older)."""
    if epoch[node] != current:
        e = first[node]
        while e != -1:
            fresh[e] = 0
            e = nxt[e]
        fresh_best[node] = -1
        fresh_total[node] = 0
        fresh_outcomes[node] = 0
        epoch[node] = current


@helper
def credit(count, last_seen, fresh, best, newest, fresh_best, fresh_total, fresh_outcomes, e, node, clock):
    """Count one occurrence of entry ``e`` (of ``node``) at ``clock``."""
    count[e] += 1
    last_seen[e] = clock
    b = best[node]
    if b == -1 or count[e] >= count[b]:
        best[node] = e
    newest[node] = e
    credit_fresh(fresh, fresh_best, fresh_total, fresh_outcomes, e, node)


@helper
def credit_fresh(fresh, fresh_best, fresh_total, fresh_outcomes, e, node):
    """Count one occurrence of entry ``e`` (of ``node``) in the fresh counts alone."""
    fresh[e] += 1
    if fresh[e] == 1:
        fresh_outcomes[node] += 1
    if fresh_total[node] < SATURATED:
        fresh_total[node] += 1
    b = fresh_best[node]
    if b == -1 or fresh[e] >= fresh[b]:
        fresh_best[node] = e


@helper
def weight_sums(first, nxt, weight, node):
    """A node's summed ``weight`` (count or fresh) and how many of its outcomes have any:
    PPM's ``n`` and ``d``, in one walk."""
    total, distinct = 0, 0
    e = first[node]
    while e != -1:
        total += weight[e]
        if weight[e] > 0:
            distinct += 1
        e = nxt[e]
    return total, distinct


@helper
def fresh_sums(first, nxt, fresh, fresh_total, fresh_outcomes, node):
    """A node's fresh counts summed and how many of its outcomes have one (the all-time
    counts in a view's first epoch): PPM's ``n`` and ``d``, from the node's sums, or by a
    walk when they saturated."""
    total, distinct = fresh_total[node], fresh_outcomes[node]
    if total >= SATURATED:
        total, distinct = weight_sums(first, nxt, fresh, node)
    return total, distinct


@helper
def ranks_above(weight, last_seen, outcome, a, b):
    """Whether entry ``a`` ranks above ``b``: weight, then recency, then smaller outcome."""
    if weight[a] != weight[b]:
        return weight[a] > weight[b]
    if last_seen[a] != last_seen[b]:
        return last_seen[a] > last_seen[b]
    return outcome[a] < outcome[b]
