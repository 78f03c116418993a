"""The raw material of the fuzz cases, shared by tests/test_fuzz.py (hypothesis, bounded for
CI) and bench/fuzz.py (10^4 random cases per class): valid logs to mutate, their record
bounds, the spec that reads them, and the paths into a library header."""

from __future__ import annotations

import struct
from typing import Iterator

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
