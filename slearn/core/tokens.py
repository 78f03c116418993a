"""Tokens: the observations of one step, or the actions of one step, as one interned id.

A pattern alternates observation and action tokens, ``O A O A ... O``: for the pointer,
``3 R 4 R 5`` is the five tokens ``(3,) (R,) (4,) (R,) (5,)``. Interning whole tuples
keeps step boundaries explicit (a step without actions is the empty action token) and
keeps tries shallow when many channels fire at one tick.
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np

from slearn.core._jit import helper, kernel
from slearn.core.hashtable import doubled
from slearn.core.stream import Episode

OBSERVATION = 0
ACTION = 1

TokenArrays = namedtuple("TokenArrays", "offsets symbols kinds hashes slots size")
"""Token ``t`` is ``symbols[offsets[t]:offsets[t + 1]]`` of kind ``kinds[t]``; ``slots`` is
the hash table (token id or -1); ``size`` int64[1] counts tokens."""

_FNV_PRIME = np.uint64(0x100000001B3)
_FNV_BASIS = np.uint64(0xCBF29CE484222325)


def _new_arrays(capacity: int, symbol_capacity: int) -> TokenArrays:
    slots = 1 << int(2 * capacity - 1).bit_length()
    return TokenArrays(np.zeros(capacity + 1, np.int64), np.zeros(symbol_capacity, np.int32),
                       np.zeros(capacity, np.int8), np.zeros(capacity, np.int64),
                       np.full(slots, -1, np.int32), np.zeros(1, np.int64))


class TokenTable:
    """Interns ``(kind, symbols)`` tuples as dense token ids, in order of first sight."""

    def __init__(self, capacity: int = 256) -> None:
        self.arrays = _new_arrays(capacity, 4 * capacity)

    def __len__(self) -> int:
        return int(self.arrays.size[0])

    def reserve(self, tokens: int, symbols: int) -> None:
        """Make room for ``tokens`` more tokens holding ``symbols`` more symbols."""
        a = self.arrays
        n = len(self)
        used = int(a.offsets[n])
        capacity, symbol_capacity = len(a.kinds), len(a.symbols)
        capacity, symbol_capacity = doubled(capacity, n, tokens), doubled(symbol_capacity, used, symbols)
        if capacity == len(a.kinds) and symbol_capacity == len(a.symbols):
            return
        fresh = _new_arrays(capacity, symbol_capacity)
        fresh.offsets[: n + 1] = a.offsets[: n + 1]
        fresh.symbols[:used] = a.symbols[:used]
        fresh.kinds[:n] = a.kinds[:n]
        fresh.hashes[:n] = a.hashes[:n]
        fresh.size[0] = n
        _rehash(fresh)
        self.arrays = fresh

    def tokenize(self, episode: Episode) -> np.ndarray:
        """The episode as ``O A O A ... O`` tokens (int32), interning new tuples.

        The first step contributes its observations only; if it carries actions, the
        sequence starts with the empty observation token so that nothing is dropped.
        """
        self.reserve(2 * len(episode) + 2, episode.n_events)
        return _tokenize(self.arrays, episode.symbols, episode.step_offsets, episode.n_actions)

    def intern(self, kind: int, symbols) -> int:
        """The token of one ``(kind, symbols)`` tuple."""
        values = np.asarray(symbols, dtype=np.int32)
        self.reserve(1, len(values))
        return int(_intern(self.arrays, kind, values, 0, len(values)))

    def find(self, kind: int, symbols) -> int:
        """The token of a tuple, or -1 when it was never interned."""
        values = np.asarray(symbols, dtype=np.int32)
        return int(_find(self.arrays, kind, values, 0, len(values), _hash(kind, values, 0, len(values))))

    def find_all(self, kinds: np.ndarray, symbols: np.ndarray, offsets: np.ndarray) -> np.ndarray:
        """Tokens of many tuples at once (compiled): tuple ``i`` is ``(kinds[i],
        symbols[offsets[i]:offsets[i + 1]])``; -1 where a tuple was never interned."""
        return _find_all(self.arrays, np.asarray(kinds, np.int8), np.asarray(symbols, np.int32),
                         np.asarray(offsets, np.int64))

    def symbols(self, token: int) -> tuple[int, ...]:
        """The symbols of a token."""
        a = self.arrays
        return tuple(a.symbols[a.offsets[token]:a.offsets[token + 1]].tolist())

    def kind(self, token: int) -> int:
        """``OBSERVATION`` or ``ACTION``."""
        return int(self.arrays.kinds[token])

    def export(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(offsets, symbols, kinds)`` of all tokens, copies."""
        a, n = self.arrays, len(self)
        return a.offsets[: n + 1].copy(), a.symbols[: a.offsets[n]].copy(), a.kinds[:n].copy()

    @classmethod
    def from_export(cls, offsets: np.ndarray, symbols: np.ndarray, kinds: np.ndarray) -> "TokenTable":
        """Rebuild a table from :meth:`export` output (same ids)."""
        n = len(kinds)
        table = cls(max(n, 16))
        table.reserve(0, len(symbols))
        a = table.arrays
        a.offsets[: n + 1] = offsets
        a.symbols[: len(symbols)] = symbols
        a.kinds[:n] = kinds
        a.size[0] = n
        _hash_all(a)
        return table


@helper(python=True)
def _hash(kind, values, start, end):
    h = _FNV_BASIS ^ np.uint64(kind + 1)
    for i in range(start, end):
        h = (h ^ np.uint64(values[i] + 0x9E37)) * _FNV_PRIME
    h = h ^ np.uint64(end - start)
    return np.int64(h >> np.uint64(1))


@helper(python=True)
def _find(a, kind, values, start, end, h):
    mask = len(a.slots) - 1
    s = h & mask
    while True:
        t = a.slots[s]
        if t == -1:
            return -1
        if a.hashes[t] == h and a.kinds[t] == kind and a.offsets[t + 1] - a.offsets[t] == end - start:
            o = a.offsets[t]
            same = True
            for i in range(end - start):
                if a.symbols[o + i] != values[start + i]:
                    same = False
                    break
            if same:
                return t
        s = (s + 1) & mask


@kernel
def _find_all(a, kinds, symbols, offsets):
    out = np.empty(len(kinds), np.int32)
    for i in range(len(kinds)):
        start, end = offsets[i], offsets[i + 1]
        out[i] = _find(a, kinds[i], symbols, start, end, _hash(kinds[i], symbols, start, end))
    return out


@helper
def _place(a, t):
    mask = len(a.slots) - 1
    s = a.hashes[t] & mask
    while a.slots[s] != -1:
        s = (s + 1) & mask
    a.slots[s] = t


@helper(python=True)
def _intern(a, kind, values, start, end):
    h = _hash(kind, values, start, end)
    t = _find(a, kind, values, start, end, h)
    if t >= 0:
        return t
    t = a.size[0]
    o = a.offsets[t]
    for i in range(end - start):
        a.symbols[o + i] = values[start + i]
    a.offsets[t + 1] = o + end - start
    a.kinds[t] = kind
    a.hashes[t] = h
    _place(a, t)
    a.size[0] = t + 1
    return t


@kernel
def _rehash(a):
    for t in range(a.size[0]):
        _place(a, t)


@kernel
def _hash_all(a):
    for t in range(a.size[0]):
        a.hashes[t] = _hash(a.kinds[t], a.symbols, a.offsets[t], a.offsets[t + 1])
        _place(a, t)


@kernel
def _tokenize(a, symbols, step_offsets, n_actions):
    n_steps = len(n_actions)
    if n_steps == 0:
        return np.zeros(0, np.int32)
    lead = 2 if n_actions[0] > 0 else 0
    out = np.empty(lead + 2 * n_steps - 1, np.int32)
    pos = 0
    if lead:
        out[0] = _intern(a, OBSERVATION, symbols, 0, 0)
        pos = 1
    for step in range(n_steps):
        start = step_offsets[step]
        split = start + n_actions[step]
        if step > 0 or lead:
            out[pos] = _intern(a, ACTION, symbols, start, split)
            pos += 1
        out[pos] = _intern(a, OBSERVATION, symbols, split, step_offsets[step + 1])
        pos += 1
    return out


@kernel
def join_steps(table, lib, offsets, tokens, use, buf):
    """Per step (reports ``offsets[s]..offsets[s + 1]``), the observation token in ``table``
    of the symbols, in ``lib``, of its used reports' ``tokens`` joined: -2 with none used,
    -1 when every used report abstained, so a partial prediction joins what was said.
    ``buf`` holds a step's symbols. (Replay's per-step outcomes; compiled at install, as the
    core's kernels are.)"""
    out = np.full(len(offsets) - 1, -2, np.int32)
    for s in range(len(offsets) - 1):
        m = 0
        used = 0
        said = 0
        for r in range(offsets[s], offsets[s + 1]):
            if not use[r]:
                continue
            used += 1
            t = tokens[r]
            if t < 0:
                continue
            said += 1
            for i in range(lib.offsets[t], lib.offsets[t + 1]):
                buf[m] = lib.symbols[i]
                m += 1
        if used == 0:
            continue
        out[s] = -1 if said == 0 else _intern(table, OBSERVATION, buf, 0, m)
    return out
