"""Arrays handed to a kernel as one address table come back as the same memory."""

from __future__ import annotations

import numpy as np
import pytest

from slearn.core._jit import kernel
from slearn.core.addresses import ROW, address_table, cube, matrix, vector


@kernel
def _touch(table):
    """Add one to the first value of each array; return their sums."""
    a, b, c = vector(table, 0, np.int32), matrix(table, 1, np.float64), cube(table, 2, np.int64)
    a[0] += 1
    b[0, 0] += 1.0
    c[0, 0, 0] += 1
    return a.sum(), b.sum(), c.sum()


def test_a_table_round_trips_shapes_and_writes_through():
    a = np.arange(5, dtype=np.int32)
    b = np.ones((2, 3))
    c = np.arange(24, dtype=np.int64).reshape(2, 3, 4)
    table = address_table((a, b, c))
    assert table.dtype == np.int64 and len(table) == 3 * ROW
    assert table[ROW + 1:ROW + 4].tolist() == [2, 3, 0] and table[2 * ROW + 1:].tolist() == [2, 3, 4]
    assert _touch(table) == (11, 7.0, 277)
    assert a[0] == 1 and b[0, 0] == 2.0 and c[0, 0, 0] == 1  # the same memory, not a copy


def test_a_table_refuses_what_a_kernel_would_misread():
    with pytest.raises(ValueError, match="C-contiguous"):
        address_table([np.zeros((4, 4))[:, 1]])
    with pytest.raises(ValueError, match="at most 3 dimensions"):
        address_table([np.zeros((1, 1, 1, 1))])


def test_addresses_are_where_the_data_starts_for_every_kind_of_array():
    """Addresses are read through ctypes where it can (writable, non-empty), else through
    the array interface: the same numbers either way, views and read-only arrays included."""
    read_only = np.arange(6, dtype=np.int64)
    read_only.flags.writeable = False
    arrays = [np.zeros(5, np.int32), np.zeros(0, np.int64), np.zeros((3, 4))[1:], read_only,
              np.frombuffer(b"abcd", np.uint8), np.zeros((2, 3, 4), np.int8)[1]]
    table = address_table(arrays)
    assert table[::ROW].tolist() == [a.__array_interface__["data"][0] for a in arrays]
