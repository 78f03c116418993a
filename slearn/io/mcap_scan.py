"""The record walk of an MCAP block as a compiled kernel (for blocks of many records).

:func:`slearn.io.mcap_read._parse_messages` walks records one at a time in Python; for a
large block this kernel finds the same message rows. It stops at the first record that
is cut, made of zero bytes or too short for a message header, holds a log time past
int64, or when the block would not fit in memory; the caller then takes the Python walk, which says why exactly.
"""

from __future__ import annotations

import numpy as np

from slearn.core._jit import helper, kernel

OK = 0
STOPPED = 1
_OP_MESSAGE = 0x05
_OP_SCHEMA = 0x03
_OP_CHANNEL = 0x04
_LAST_TIME_NS = 2**63 - 1  # as mcap_read: later log times mark a block damaged


@helper
def _u64(buf, at, size):
    value = np.uint64(0)
    for k in range(size - 1, -1, -1):
        value = (value << np.uint64(8)) | np.uint64(buf[at + k])
    return value


@kernel
def scan(buf, room, check_every, record_cost):
    """``(status, rows, others)``: ``rows`` of every message ``(log_time, publish_time,
    sequence, channel_id, start, end)`` in file order; ``others`` ``(op, body, end)`` of the
    schema and channel records; ``status`` :data:`OK`, or :data:`STOPPED` (nothing returned)."""
    end = len(buf)
    n_messages, n_others, n_records, pos = 0, 0, 0, 0
    while pos + 9 <= end:  # pass 1: count, and check as the Python walk does
        op = buf[pos]
        length = _u64(buf, pos + 1, 8)
        if length > np.uint64(end - pos - 9) or op == 0 or (op == _OP_MESSAGE and pos + 9 + 22 > end):
            return STOPPED, np.zeros((0, 6), np.uint64), np.zeros((0, 3), np.int64)
        n_records += 1
        if n_records % check_every == 0 and end + record_cost * n_records > room:
            return STOPPED, np.zeros((0, 6), np.uint64), np.zeros((0, 3), np.int64)
        if op == _OP_MESSAGE:
            if _u64(buf, pos + 9 + 6, 8) > np.uint64(_LAST_TIME_NS):
                return STOPPED, np.zeros((0, 6), np.uint64), np.zeros((0, 3), np.int64)
            n_messages += 1
        elif op == _OP_SCHEMA or op == _OP_CHANNEL:
            n_others += 1
        pos += 9 + int(length)
    rows = np.empty((n_messages, 6), np.uint64)
    others = np.empty((n_others, 3), np.int64)
    i, j, pos = 0, 0, 0
    while pos + 9 <= end:
        op = buf[pos]
        body = pos + 9
        nxt = body + int(_u64(buf, pos + 1, 8))
        if op == _OP_MESSAGE:
            rows[i, 0] = _u64(buf, body + 6, 8)
            rows[i, 1] = _u64(buf, body + 14, 8)
            rows[i, 2] = _u64(buf, body + 2, 4)
            rows[i, 3] = _u64(buf, body, 2)
            rows[i, 4] = min(body + 22, nxt)
            rows[i, 5] = nxt
            i += 1
        elif op == _OP_SCHEMA or op == _OP_CHANNEL:
            others[j, 0], others[j, 1], others[j, 2] = op, body, nxt
            j += 1
        pos = nxt
    return OK, rows, others
