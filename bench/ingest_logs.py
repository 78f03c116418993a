"""Large pointer logs written fast (numpy), for the ingest and memory benchmarks.

Every message record of a pointer log has a fixed size (the position is padded to two
digits, ``{"position":  7}`` being valid JSON), so a chunk of trials is one numpy array of
records. Three layouts:

* ``chunked``: chunks of ``chunk_trials`` trials in time order (what a recorder writes);
* ``time0``: the same, but every chunk starts with a latched message at log time 0 on
  ``/static`` (so every chunk's time range starts at 0 and a log-time merge must open all
  of them at once);
* ``one_chunk``: every message in a single chunk.

No summary: slearn scans the data section (the file has a footer and is complete).
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np
import zstandard

MAGIC = b"\x89MCAP0\r\n"
TRIAL_NS = 100_000_000
_COMMAND = b'{"command": "%s"}'
_POSITION = b'{"position": %2d}'
_STATIC = b'{"frame": "world"}'
_CHANNELS = {1: "/pointer/command", 2: "/pointer/position", 3: "/static"}


def _record(op: int, body: bytes) -> bytes:
    return struct.pack("<BQ", op, len(body)) + body


def _string(text: str) -> bytes:
    data = text.encode()
    return struct.pack("<I", len(data)) + data


def _message(channel: int, log_time: int, data: bytes) -> bytes:
    return _record(0x05, struct.pack("<HIQQ", channel, 0, log_time, log_time) + data)


def _template(channel: int, data: bytes) -> np.ndarray:
    return np.frombuffer(_message(channel, 0, data), np.uint8)


def _trial_records(first: int, n: int) -> np.ndarray:
    """Records of trials ``first .. first + n - 1``: command at ``t``, position at ``t + 50 ms``."""
    command = _template(1, _COMMAND % b"L")
    position = _template(2, _POSITION % 1)
    size = len(command) + len(position)
    out = np.empty((n, size), np.uint8)
    out[:, :len(command)] = command
    out[:, len(command):] = position
    i = np.arange(first, first + n, dtype=np.int64)
    t = i * TRIAL_NS
    times = out[:, 15:31].view("<u8")  # log and publish time of the command
    times[:, 0] = times[:, 1] = t
    times = out[:, len(command) + 15:len(command) + 31].view("<u8")
    times[:, 0] = times[:, 1] = t + TRIAL_NS // 2
    out[:, len(command) - 3] = np.where(i % 3 % 2 == 0, ord("L"), ord("R"))
    label = i % 36 + 1
    tens = label // 10
    out[:, size - 3] = np.where(tens > 0, ord("0") + tens, ord(" "))
    out[:, size - 2] = ord("0") + label % 10
    return out.reshape(-1)


def _chunk(records: bytes, start: int, end: int) -> bytes:
    data = zstandard.ZstdCompressor(level=1).compress(records)
    body = (struct.pack("<QQQI", start, end, len(records), zlib.crc32(records)) + _string("zstd")
            + struct.pack("<Q", len(data)) + data)
    return _record(0x06, body)


def _head() -> bytes:
    out = MAGIC + _record(0x01, _string("") + _string("slearn-bench"))
    out += _record(0x03, struct.pack("<H", 1) + _string("Pointer") + _string("jsonschema")
                   + struct.pack("<I", 2) + b"{}")
    for cid, topic in _CHANNELS.items():
        out += _record(0x04, struct.pack("<HH", cid, 1) + _string(topic) + _string("json")
                       + struct.pack("<I", 0))
    return out


def write_pointer_log(path: Path, trials: int, layout: str = "chunked",
                      chunk_trials: int = 20_000) -> int:
    """Write a pointer log of ``trials`` trials (two messages each, plus one ``/static`` per
    chunk in the ``time0`` layout); return the number of messages."""
    if layout == "one_chunk":
        chunk_trials = trials
    n_messages = 0
    with open(path, "wb") as f:
        f.write(_head())
        for first in range(0, trials, chunk_trials):
            n = min(chunk_trials, trials - first)
            records = _trial_records(first, n).tobytes()
            start, end = first * TRIAL_NS, (first + n) * TRIAL_NS
            if layout == "time0":
                records = _message(3, 0, _STATIC) + records
                start = 0
            f.write(_chunk(records, start, end))
            n_messages += 2 * n + (layout == "time0")
        f.write(_record(0x0F, struct.pack("<I", 0)))
        f.write(_record(0x02, struct.pack("<QQI", 0, 0, 0)) + MAGIC)
    return n_messages
