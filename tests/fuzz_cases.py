"""The raw material of the fuzz cases, shared by tests/test_fuzz.py (hypothesis, bounded for
CI) and bench/fuzz.py (10^4 random cases per class): valid logs to mutate, their record
bounds, the spec that reads them, and the paths into a library header."""

from __future__ import annotations

import struct
from typing import Iterator, Protocol, Sequence

import mcap_bytes as mb

from slearn.io.spec import Spec

SPEC = Spec.from_dict({"mode": "change", "channel": [
    {"topic": "/a", "field": "v", "role": "observation", "width": 0.5},
    {"topic": "/b", "field": "c", "role": "action"}]})


def base_logs(steps: int = 40, per_chunk: int = 10) -> list[bytes]:
    """Small valid logs in several layouts (chunked zstd / lz4 / none, unchunked)."""
    records = []
    for t in range(steps):
        records.append(mb.message(t, b'{"v": %d.5}' % (t % 7)))
        records.append(mb.message(t, b'{"c": "%s"}' % b"LR"[t % 2:t % 2 + 1], channel_id=2))
    groups = [b"".join(records[i:i + per_chunk]) for i in range(0, len(records), per_chunk)]
    b_channel = mb.channel(2, "/b")
    logs = [mb.log(b_channel, *(mb.chunk(g, c) for g in groups)) for c in ("zstd", "lz4", "")]
    return logs + [mb.log(b_channel, *records)]


def record_bounds(data: bytes) -> list[tuple[int, int]]:
    """Top-level records after the magic, as ``(start, end)``."""
    bounds, pos = [], 8
    while pos + 9 <= len(data):
        end = pos + 9 + struct.unpack_from("<Q", data, pos + 1)[0]
        if end > len(data):
            break
        bounds.append((pos, end))
        pos = end
    return bounds


def json_paths(doc, prefix: tuple = ()) -> Iterator[tuple]:
    """Every path into a JSON document (keys and list indices), the root first."""
    yield prefix
    if isinstance(doc, dict):
        for key, value in doc.items():
            yield from json_paths(value, prefix + (key,))
    elif isinstance(doc, list):
        for i, value in enumerate(doc):
            yield from json_paths(value, prefix + (i,))


MUTATIONS = ("flip", "overwrite", "truncate", "duplicate", "remove", "swap", "length", "opcode", "zeros")
LENGTHS = (0, 1, 8, 2 ** 32, 2 ** 63, 2 ** 64 - 1)


class Picks(Protocol):
    """Where a mutation's choices come from (``random.Random`` in the bench, hypothesis draws
    in the test)."""

    def integer(self, lo: int, hi: int) -> int: ...
    def choice(self, options: Sequence): ...
    def binary(self, most: int) -> bytes: ...


def mutated(data: bytes, pick: Picks, most_zeros: int) -> bytes:
    """``data`` after 1-4 damages: bit flips, overwrites, truncation, whole records
    duplicated, removed or swapped, bad record lengths and opcodes, runs of zeros."""
    out = bytearray(data)
    for _ in range(pick.integer(1, 4)):
        if len(out) < 9:
            break
        bounds = record_bounds(bytes(out)) or [(8, len(out))]
        (a, b), (c, d) = pick.choice(bounds), pick.choice(bounds)
        _damage(out, pick.choice(MUTATIONS), pick, (a, b, c, d), most_zeros)
    return bytes(out)


def _damage(data: bytearray, kind: str, pick: Picks, bounds: tuple, most_zeros: int) -> None:
    a, b, c, d = bounds
    if kind == "flip":
        data[pick.integer(0, len(data) - 1)] ^= 1 << pick.integer(0, 7)
    elif kind == "overwrite":
        k = pick.integer(0, len(data) - 1)
        data[k:k + 8] = pick.binary(8)
    elif kind == "truncate":
        del data[pick.integer(0, len(data)):]
    elif kind == "duplicate":
        data[b:b] = data[a:b]
    elif kind == "remove":
        del data[a:b]
    elif kind == "swap" and b <= c:
        data[a:d] = data[c:d] + data[b:c] + data[a:b]
    elif kind == "length" and a + 9 <= len(data):
        struct.pack_into("<Q", data, a + 1, pick.choice(LENGTHS + (pick.integer(0, 2 ** 20),)))
    elif kind == "opcode":
        data[a] = pick.integer(0, 255)
    elif kind == "zeros":
        data[a:a] = bytes(pick.integer(1, most_zeros))
