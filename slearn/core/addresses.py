"""Many arrays handed to a kernel as one table of addresses.

Numba checks the type of every array argument and wraps it on every call: about 0.1 µs
per array, 5 µs for the 40-odd arrays of a library's tree, weights and buffers, which is
most of the cost of one small query. :func:`address_table` writes each array's address
and shape into one ``int64`` table; inside a kernel, :func:`vector`, :func:`matrix` and
:func:`cube` turn a row of it back into an array (``numba.carray``), with no copy and
no reference counting. So a query passes one table for its state.

The table does not keep its arrays alive: whoever makes it must hold the arrays for as
long as it is used, and make it again when any of them is replaced (a tree that grew).
Only C-contiguous arrays are accepted, in a fixed order each kernel knows.
"""

from __future__ import annotations

import ctypes
from typing import Iterable

import numba
import numpy as np
from numba.core import types
from numba.extending import intrinsic

from slearn.core._jit import kernel

ROW = 4
"""Table entries per array: its address, then up to three dimensions."""


def address_table(arrays: Iterable[np.ndarray]) -> np.ndarray:
    """One row per array: address and shape (zero-padded to three dimensions).

    Raises:
        ValueError: an array is not C-contiguous or has more than three dimensions.
    """
    rows: list[int] = []
    for array in arrays:
        if not array.flags.c_contiguous or array.ndim > 3:
            raise ValueError(f"a kernel table needs C-contiguous arrays of at most 3 dimensions, "
                             f"not {array.ndim}-D with strides {array.strides}")
        rows.extend((_address(array), *array.shape, *(0,) * (3 - array.ndim)))
    return np.array(rows, np.int64)


def _address(array: np.ndarray) -> int:
    """Where ``array``'s data starts: through ctypes (0.5 us), or for an array that is
    read-only or empty (ctypes refuses those) through its array interface (1.4 us)."""
    try:
        return ctypes.addressof(ctypes.c_char.from_buffer(array.data))
    except (TypeError, ValueError):
        return array.__array_interface__["data"][0]


@intrinsic
def _pointer(typingctx, address, dtype):
    """``address`` (an integer) as a pointer to ``dtype`` values."""
    signature = types.CPointer(dtype.instance_type)(types.int64, dtype)

    def codegen(context, builder, sig, args):
        return builder.inttoptr(args[0], context.get_value_type(sig.return_type))

    return signature, codegen


@kernel
def vector(table, i, dtype):
    """Array ``i`` of ``table``, one-dimensional, of ``dtype`` (a NumPy scalar type)."""
    r = ROW * i
    return numba.carray(_pointer(table[r], dtype), (table[r + 1],))


@kernel
def matrix(table, i, dtype):
    """Array ``i`` of ``table``, two-dimensional."""
    r = ROW * i
    return numba.carray(_pointer(table[r], dtype), (table[r + 1], table[r + 2]))


@kernel
def cube(table, i, dtype):
    """Array ``i`` of ``table``, three-dimensional."""
    r = ROW * i
    return numba.carray(_pointer(table[r], dtype), (table[r + 1], table[r + 2], table[r + 3]))
