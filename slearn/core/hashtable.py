"""One open-addressing hash table for every pair-keyed structure of slearn.

A table maps a pair of non-negative 32-bit ids ``(a, b)`` (a trie edge ``(parent, token)``,
a context's outcome ``(node, outcome)``) to the id of the record that holds it, found from
the pair's hash (:func:`home`) or from one the structure computes (:func:`probe_from`). Slots
hold record ids only (``int32``, -1 empty); a probe compares a slot's record through the
arrays ``a_of``/``b_of`` that store the pair of every record, so the table costs 4 bytes
a slot. A table has twice as many slots as its structure has room for records, so it is
at most half full (linear probing stays short); its size need not be a power of two (the
hash is scaled to it, Lemire's multiply-shift), so a structure may grow by half rather than
double: :func:`grown`. Records are never deleted one by one: a structure that forgets
rebuilds its table with :func:`rebuild` (the context tree's nodes, placed by path hash,
with :func:`slearn.core.context_tree.rebuild_nodes`).
"""

from __future__ import annotations

import numpy as np

from slearn.core._jit import helper, kernel, prefetch

EMPTY = -1
AHEAD = 16
"""Records a table's rebuild looks ahead (the slot it asks the CPU for)."""
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)


def slots_for(capacity: int) -> int:
    """Slots for ``capacity`` records: twice as many."""
    return 2 * max(int(capacity), 8)


def doubled(capacity: int, used: int, more: int) -> int:
    """``capacity`` doubled as often as needed to hold ``more`` records past ``used``."""
    while capacity - used < more:
        capacity *= 2
    return capacity


def grown(capacity: int, used: int, more: int) -> int:
    """``capacity`` grown by half as often as needed to hold ``more`` records past ``used``:
    after growing, the table is a third full, not a quarter (its slots are memory that is
    written whole, unlike the records' room)."""
    while capacity - used < more:
        capacity += max(capacity // 2, 8)
    return capacity


def new_slots(capacity: int) -> np.ndarray:
    """An empty table for ``capacity`` records."""
    return np.full(slots_for(capacity), EMPTY, np.int32)


@helper
def home(slots, a, b):
    """The first slot probed for the pair ``(a, b)``: the high 32 bits of a multiplicative
    hash, scaled to the table's size."""
    return scaled(slots, ((np.uint64(a) << np.uint64(32)) | np.uint64(b)) * _GOLDEN)


@helper
def scaled(slots, h):
    """The slot of a 64-bit hash ``h`` (``uint64``): its high 32 bits, scaled to the table."""
    return np.int64(((h >> np.uint64(32)) * np.uint64(len(slots))) >> np.uint64(32))


@helper
def probe(slots, a_of, b_of, a, b):
    """The slot holding the record of ``(a, b)``, or the empty slot it would take."""
    return probe_from(slots, a_of, b_of, a, b, home(slots, a, b))


@helper
def probe_from(slots, a_of, b_of, a, b, s):
    """:func:`probe` from slot ``s`` on: for a structure that hashes its pairs its own way
    (the context tree hashes a node's whole path, :func:`slearn.core.context_tree.path_hash`)."""
    n = len(slots)
    while True:
        r = slots[s]
        if r == EMPTY or (a_of[r] == a and b_of[r] == b):
            return s
        s += 1
        if s == n:
            s = 0


@helper
def find(slots, a_of, b_of, a, b):
    """The record of ``(a, b)``, or -1."""
    return slots[probe(slots, a_of, b_of, a, b)]


@kernel
def rebuild(slots, a_of, b_of, first, n):
    """Empty ``slots`` and insert records ``first..n-1`` (a root record has ``a_of == -1``).

    Pairs are unique, so a record takes the first empty slot from its home; the home of the
    record ``AHEAD`` places on is asked for meanwhile (:func:`slearn.core._jit.prefetch`)."""
    slots[:] = EMPTY
    for r in range(first, n):
        q = r + AHEAD
        if q < n and a_of[q] >= 0:
            prefetch(slots, home(slots, a_of[q], b_of[q]))
        if a_of[r] >= 0:
            slots[free_from(slots, home(slots, a_of[r], b_of[r]))] = r


@helper
def free_from(slots, s):
    """The first empty slot from slot ``s`` on (inserting a pair known to be absent)."""
    n = len(slots)
    while slots[s] != EMPTY:
        s += 1
        if s == n:
            s = 0
    return s
