"""ROS 2 CDR: read only the fields a spec names, and step over the rest.

A payload is walked field by field as the schema lays it out (CDR alignment, relative
to the end of the 4-byte encapsulation header). Fields the spec's paths need are read
into a sparse message (nested dicts, arrays as numpy arrays, exactly as rosbags gives
them), everything else is skipped by its size: strings and sequences by their length
prefixes. The walk checks what rosbags checks (lengths in bounds, string terminators,
UTF-8, the message size), so a payload reads here exactly when it decodes there; a
payload that fails here is handed to the full decoder, which gives its own verdict. A
run of strings equal to the previous message's (the joint names of every JointState)
is recognized by comparing bytes, not walked again.

Many payloads at once (:meth:`FieldPlan.many`): the first is walked once more to *locate*
its values (where each leaf the paths read lies in its bytes) and to find the bytes that
are not values: the encapsulation header, length prefixes, strings and padding. A payload
of the same size whose every such byte equals the first one's has the same layout, so
each path's value is at the same offset in it, and the payloads' values are read as
columns with numpy; the others are walked one by one.

Supported paths: names through nested messages, ending at a primitive, a string, an
array of them, or one element of such an array by index or by ``[key=value]`` over a
sibling array. Anything else (arrays of messages, ``wstring``, ``float128``, empty
messages) has no plan: the channel is decoded whole.
"""

from __future__ import annotations

import struct
from functools import lru_cache
from typing import Any, cast

import numpy as np

from slearn.io.decode import parse_field_path, ros2_message_types

_SIZES = {"bool": 1, "byte": 1, "char": 1, "int8": 1, "uint8": 1, "int16": 2, "uint16": 2,
          "int32": 4, "uint32": 4, "float32": 4, "int64": 8, "uint64": 8, "float64": 8}
_FORMATS = {"bool": "?", "byte": "b", "char": "B", "int8": "b", "uint8": "B", "int16": "h",
            "uint16": "H", "int32": "i", "uint32": "I", "float32": "f", "int64": "q",
            "uint64": "Q", "float64": "d"}
_DTYPES = {"bool": "bool", "byte": "int8", "char": "uint8"}
BASE, NAME, ARRAY, SEQUENCE = 1, 2, 3, 4
LEAF = "leaf"


class CdrError(ValueError):
    """A payload does not decode."""


def _types(channel) -> tuple[str, dict]:
    return _parsed(channel.schema.name, channel.schema.data)


@lru_cache(maxsize=64)
def _parsed(schema_name: str, data: bytes) -> tuple[str, dict]:
    """The message types of a schema (parsed once per schema; never changed after)."""
    name, types = ros2_message_types(schema_name, data)
    return name, {key: list(fields) for key, (_, fields) in types.items()}


class FieldPlan:
    """Reads the values at some field paths from payloads of one channel: called with one
    payload, or :meth:`many` for many (see the module docstring)."""

    def __init__(self, walk, locate, getters: list, keyed_by_numbers: bool) -> None:
        self._walk, self._locate, self._getters = walk, locate, getters
        self._columns = not keyed_by_numbers  # (a numeric key's values decide the element)

    def __call__(self, data: bytes) -> list:
        """One value per path (:data:`slearn.io.decode.MISSING` where the message lacks
        the element); raises :class:`CdrError` when the payload does not decode."""
        obj, _ = self._walked(self._walk, data)
        return [get(obj) for get in self._getters]

    def many(self, buf: bytes, starts: np.ndarray, ends: np.ndarray) -> tuple[list[list], np.ndarray]:
        """Per path, the values of the payloads ``buf[starts[i]:ends[i]]`` laid out as the
        first one is, and which payloads those are; the others are left to the caller."""
        sizes = ends - starts
        alike = np.zeros(len(starts), bool)
        empty: list[list] = [[] for _ in self._getters]
        if not self._columns or not len(starts):
            return empty, alike
        first = buf[int(starts[0]):int(ends[0])]
        regions: list = []
        leaves: list = []
        try:
            where, _ = self._walked(self._locate, first, regions, leaves)
        except CdrError:
            return empty, alike
        at = [get(where) for get in self._getters]  # a leaf's number, a string, or MISSING
        if any(isinstance(x, list) for x in at):
            return empty, alike  # (whole arrays: values that are lists, read one by one)
        located = {x: _leaf(leaves, x) for x in at if type(x) is int}
        size = len(first)
        fixed = np.ones(size, bool)  # the bytes that are not values
        for start, length in regions:
            fixed[4 + start:4 + start + length] = False
        template = np.frombuffer(first, np.uint8)[fixed]
        same = np.flatnonzero(sizes == size)
        parts: list[list] = [[] for _ in at]
        step = max(1, _ROWS_BYTES // size)
        for lo in range(0, len(same), step):  # (rows of a few MB at a time)
            chunk = same[lo:lo + step]
            rows = _rows(buf, starts[chunk], size)
            ok = (rows[:, fixed] == template).all(axis=1)
            alike[chunk[ok]] = True
            rows = rows[ok]
            for part, x in zip(parts, at):
                if type(x) is int:
                    offset, dtype = located[x]
                    part += rows[:, 4 + offset:4 + offset + dtype.itemsize].copy().view(dtype)[:, 0].tolist()
                else:  # a string, the same in every payload alike, or MISSING
                    part += [x] * len(rows)
        return parts, alike

    @staticmethod
    def _walked(walk, data: bytes, *locating) -> tuple[Any, int]:
        if len(data) < 4 or data[:2] not in (b"\x00\x00", b"\x00\x01"):
            raise CdrError("invalid or unsupported CDR encapsulation")
        raw = data[4:]
        try:
            obj, pos = walk(raw, 0, "<" if data[1] else ">", *locating)
        except (struct.error, UnicodeDecodeError, ValueError, IndexError) as err:
            raise CdrError(str(err)) from None
        if pos + 4 + 3 < len(data):
            raise CdrError("CDR message size mismatch")
        return obj, pos


_ROWS_BYTES = 1 << 21  # payload bytes compared at once by FieldPlan.many


def _leaf(leaves: list, number: int) -> tuple[int, np.dtype]:
    """Leaf ``number``'s offset in the payload after its header, and its dtype."""
    for first, n, start, dtype in leaves:
        if first <= number < first + n:
            return start + (number - first) * dtype.itemsize, dtype
    raise CdrError(f"no leaf {number}")  # (not reached: numbers come from the walk)


def _rows(buf: bytes, starts: np.ndarray, size: int) -> np.ndarray:
    """The ``size`` bytes at each of ``starts`` in ``buf``, one row each."""
    if not len(starts):
        return np.zeros((0, size), np.uint8)
    return np.frombuffer(buf, np.uint8)[starts[:, None] + np.arange(size)]


def field_plan(channel, fields: list[str]) -> FieldPlan | None:
    """A :class:`FieldPlan` of the values at ``fields`` (field paths) in payloads of
    ``channel``, or ``None`` when the channel must be decoded whole (see the module
    docstring)."""
    if channel.schema is None or channel.schema_encoding != "ros2msg":
        return None
    try:
        root, types = _types(channel)
        paths = [parse_field_path(f) for f in fields]
        needs: dict = {}
        numeric_keys: list = []
        for path in paths:
            if not _mark(types, root, path.steps, needs, numeric_keys):
                return None
        walk = _message(types, root, needs, set())
        locate = _message(types, root, needs, set(), locating=True)
    except Exception:  # noqa: BLE001 - any schema this cannot plan is decoded whole
        return None
    if walk is None:
        return None
    return FieldPlan(walk, locate, [path.get for path in paths], bool(numeric_keys))


def _fields(types: dict, name: str) -> list:
    fields = types.get(name)
    if not fields:
        raise KeyError(name)  # unknown or empty message: no plan
    return fields


def _mark(types: dict, name: str, steps: tuple, needs: dict, numeric_keys: list) -> bool:
    """Record in ``needs`` the fields of message ``name`` a path reads; whether it can.
    Keys of ``[key=value]`` that are numbers are added to ``numeric_keys``."""
    fields = dict(_fields(types, name))
    if not steps or steps[0][0] != "attr" or steps[0][1] not in fields:
        return False
    field = steps[0][1]
    kind, args = fields[field]
    rest = steps[1:]
    if kind == NAME:
        sub = needs.setdefault(field, {})
        return isinstance(sub, dict) and bool(rest) and _mark(types, args, rest, sub, numeric_keys)
    if kind == BASE:
        needs[field] = LEAF
        return not rest and _base_ok(args[0])
    element = args[0]
    if element[0] != BASE or not _base_ok(element[1][0]) or len(rest) > 1:
        return False
    needs[field] = LEAF
    if rest and rest[0][0] == "match":
        key = rest[0][1]
        if key not in fields or fields[key][0] not in (ARRAY, SEQUENCE):
            return False  # matching inside arrays of messages: decoded whole
        sibling = fields[key][1][0]
        if sibling[0] != BASE or sibling[1][0] not in ("string", *_SIZES) or sibling[1][0] in (
                "float32", "float64", "bool"):
            return False
        needs[key] = LEAF
        if sibling[1][0] != "string":
            numeric_keys.append(key)
    return True


def _base_ok(typename: str) -> bool:
    return typename == "string" or typename in _SIZES


def _message(types: dict, name: str, needs: dict, stack: set, locating: bool = False):
    """A walker ``(raw, pos, endian) -> (sparse dict, pos)`` of message ``name``.

    ``locating``: a walker ``(raw, pos, endian, regions, leaves)`` that gives, in place of
    each value read, its leaf's number (leaves are numbered in walk order; ``leaves`` gets
    ``(first number, count, offset in raw, dtype)`` per field read), and adds every value's
    bytes, read or not, to ``regions`` (``(offset, size)``).
    """
    if name in stack:
        raise ValueError("recursive message type")
    steps = [_field(types, fname, desc, needs.get(fname), stack | {name}, locating)
             for fname, desc in _fields(types, name)]

    def walk(raw: bytes, pos: int, endian: str, *locating):
        out: dict[str, Any] = {}
        for fname, step in steps:
            value, pos = step(raw, pos, endian, *locating)
            if value is not _SKIPPED:
                out[fname] = value
        return out, pos
    return walk


_SKIPPED = object()


def _field(types: dict, fname: str, desc, need, stack: set, locating: bool):
    kind, args = desc
    if kind == NAME:
        inner = _message(types, args, need if isinstance(need, dict) else {}, stack, locating)
        if need is None:
            return fname, lambda raw, pos, endian, *located: (_SKIPPED, inner(raw, pos, endian, *located)[1])
        return fname, inner
    if kind == BASE:
        if args[0] == "string":
            return fname, _passing(_string(need is not None), locating)
        return fname, _located(_base(args[0], need is not None), args[0], _SCALAR, need is not None, locating)
    element, count = args
    if element[0] != BASE:
        inner = _message(types, element[1], {}, stack, locating)
        return fname, _message_array(inner, count if kind == ARRAY else None, _align_of(types, element))
    typename = element[1][0]
    if typename == "string":
        return fname, _passing(_strings(count if kind == ARRAY else None, need is not None), locating)
    if typename not in _SIZES:
        raise KeyError(typename)
    count = count if kind == ARRAY else None
    return fname, _located(_primitives(typename, count, need is not None), typename, count, need is not None, locating)


def _passing(step, locating: bool):
    """``step`` for a locating walker: strings are not values (their bytes fix the layout)."""
    if not locating:
        return step
    return lambda raw, pos, endian, regions, leaves: step(raw, pos, endian)


_SCALAR = -1  # the count of a primitive that is not in an array


def _located(step, typename: str, count: int | None, read: bool, locating: bool):
    """``step`` of a primitive (``count`` ``_SCALAR``), a fixed array of ``count`` of them or
    a sequence of them (``count`` None), for a locating walker: see :func:`_message`."""
    if not locating:
        return step
    size = _SIZES[typename]
    dtype = np.dtype(_DTYPES.get(typename, typename))

    def locate(raw: bytes, pos: int, endian: str, regions: list, leaves: list):
        value, end = step(raw, pos, endian)  # (checks everything first)
        n = 1 if count == _SCALAR else _length(raw, pos, endian, count, size)[0]
        start = end - size * n
        if n:
            regions.append((start, size * n))
        if not read:
            return _SKIPPED, end
        first = leaves[-1][0] + leaves[-1][1] if leaves else 0
        leaves.append((first, n, start, dtype.newbyteorder(cast(Any, endian))))
        return (first if count == _SCALAR else np.arange(first, first + n)), end
    return locate


def _align_of(types: dict, desc) -> int:
    """CDR alignment of a field's first primitive (as rosbags aligns array elements)."""
    kind, args = desc
    if kind == BASE:
        return 4 if args[0] == "string" else _SIZES[args[0]]
    if kind == NAME:
        return _align_of(types, _fields(types, args)[0][1])
    if kind == SEQUENCE:
        return 4
    return _align_of(types, args[0])


def _base(typename: str, read: bool):
    if typename == "string":
        return _string(read)
    if typename not in _SIZES:
        raise KeyError(typename)
    size = _SIZES[typename]
    formats = {e: struct.Struct(e + _FORMATS[typename]).unpack_from for e in "<>"}

    def step(raw: bytes, pos: int, endian: str):
        pos = (pos + size - 1) & -size
        value = formats[endian](raw, pos)[0]  # read even when skipped: checks the bounds
        return (value if read else _SKIPPED), pos + size
    return step


_U32 = {e: struct.Struct(e + "I").unpack_from for e in "<>"}


def _one_string(raw: bytes, pos: int, endian: str) -> tuple[str, int]:
    """A string at ``pos`` (aligned to 4), checked as rosbags checks it."""
    pos = (pos + 3) & -4
    (length,) = _U32[endian](raw, pos)
    end = pos + 4 + length
    if length < 1 or end > len(raw):
        raise ValueError(f"invalid string length {length} at offset {pos}")
    if raw[end - 1] != 0:
        raise ValueError(f"missing string terminator at offset {end - 1}")
    return raw[pos + 4:end - 1].decode(), end


def _string(read: bool):
    def step(raw: bytes, pos: int, endian: str):
        value, pos = _one_string(raw, pos, endian)
        return (value if read else _SKIPPED), pos
    return step


def _strings(count: int | None, read: bool):
    """A sequence (``count`` None) or fixed array of strings; a run of bytes equal to the
    previous message's at the same place is not walked again."""
    seen: list = [None]  # (pos, bytes of the run, value, end)

    def step(raw: bytes, pos: int, endian: str):
        start = pos
        last = seen[0]
        if last is not None and last[0] == start and raw.startswith(last[1], start):
            return (last[2] if read else _SKIPPED), last[3]
        n, pos = _length(raw, pos, endian, count, 5)  # a string takes 5 bytes at least
        values = []
        for _ in range(n):
            value, pos = _one_string(raw, pos, endian)
            values.append(value)
        seen[0] = (start, raw[start:pos], values, pos)
        return (values if read else _SKIPPED), pos
    return step


def _length(raw: bytes, pos: int, endian: str, count: int | None, item_size: int) -> tuple[int, int]:
    """``(items, position after the length)``: ``count`` for a fixed array, else the
    sequence's uint32 length prefix (aligned to 4), checked against the bytes left."""
    if count is not None:
        return count, pos
    pos = (pos + 3) & -4
    (n,) = _U32[endian](raw, pos)
    pos += 4
    if pos + item_size * n > len(raw):
        raise ValueError(f"invalid sequence length {n} at offset {pos}")
    return n, pos


def _primitives(typename: str, count: int | None, read: bool):
    size = _SIZES[typename]
    dtype = np.dtype(_DTYPES.get(typename, typename))

    def step(raw: bytes, pos: int, endian: str):
        n, pos = _length(raw, pos, endian, count, size)
        if n:
            pos = (pos + size - 1) & -size
        end = pos + size * n
        if end > len(raw):
            raise ValueError("array runs past the end of the message")
        if not read:
            return _SKIPPED, end
        value = np.frombuffer(raw, dtype.newbyteorder(cast(Any, endian)), n, pos)  # '<' or '>'
        if value.dtype.byteorder not in ("=", "|") and not value.dtype.isnative:
            value = value.byteswap().view(value.dtype.newbyteorder())
        return value, end
    return step


def _message_array(inner, count: int | None, align: int):
    def step(raw: bytes, pos: int, endian: str, *locating):
        n, pos = _length(raw, pos, endian, count, 1)  # each element takes a byte at least
        for _ in range(n):
            pos = (pos + align - 1) & -align
            _, pos = inner(raw, pos, endian, *locating)
        return _SKIPPED, pos
    return step
