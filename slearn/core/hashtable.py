"""One open-addressing hash table for every pair-keyed structure of slearn.

A table maps a pair of non-negative 32-bit ids ``(a, b)`` (a trie edge ``(parent, token)``,
a context's outcome ``(node, outcome)``) to the id of the record that holds it. Slots
hold record ids only (``int32``, -1 empty); a probe compares a slot's record through the
arrays ``a_of``/``b_of`` that store the pair of every record, so the table costs 4 bytes
a slot. Tables are powers of two kept at most half full (linear probing stays short);
records are never deleted one by one: a structure that forgets rebuilds its table with
:func:`rebuild`.
"""

from __future__ import annotations

import numpy as np

from slearn.core._jit import helper, kernel

EMPTY = -1
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)


def slots_for(capacity: int) -> int:
    """Slots for ``capacity`` records: a power of two at least twice as large."""
    return 1 << int(2 * max(int(capacity), 8) - 1).bit_length()


def doubled(capacity: int, used: int, more: int) -> int:
    """``capacity`` doubled as often as needed to hold ``more`` records past ``used``."""
    while capacity - used < more:
        capacity *= 2
    return capacity


def new_slots(capacity: int) -> np.ndarray:
    """An empty table for ``capacity`` records."""
    return np.full(slots_for(capacity), EMPTY, np.int32)


@helper
def home(slots, a, b):
    """The first slot probed for the pair ``(a, b)``."""
    key = (np.uint64(a) << np.uint64(32)) | np.uint64(b)
    return np.int64((key * _GOLDEN) >> np.uint64(32)) & (len(slots) - 1)


@helper
def probe(slots, a_of, b_of, a, b):
    """The slot holding the record of ``(a, b)``, or the empty slot it would take."""
    mask = len(slots) - 1
    s = home(slots, a, b)
    while True:
        r = slots[s]
        if r == EMPTY or (a_of[r] == a and b_of[r] == b):
            return s
        s = (s + 1) & mask


@helper
def find(slots, a_of, b_of, a, b):
    """The record of ``(a, b)``, or -1."""
    return slots[probe(slots, a_of, b_of, a, b)]


@kernel
def rebuild(slots, a_of, b_of, first, n):
    """Empty ``slots`` and insert records ``first..n-1`` (a root record has ``a_of == -1``)."""
    slots[:] = EMPTY
    mask = len(slots) - 1
    for r in range(first, n):
        if a_of[r] < 0:
            continue
        s = home(slots, a_of[r], b_of[r])
        while slots[s] != EMPTY:
            s = (s + 1) & mask
        slots[s] = r
