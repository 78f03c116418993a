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
