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

Supported paths: names through nested messages, ending at a primitive, a string, an
array of them, or one element of such an array by index or by ``[key=value]`` over a
sibling array. Anything else (arrays of messages, ``wstring``, ``float128``, empty
messages) has no plan: the channel is decoded whole.
"""

from __future__ import annotations

import struct
from functools import lru_cache
from typing import Any, Callable, cast

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


def field_plan(channel, fields: list[str]) -> Callable[[bytes], list] | None:
    """A reader of the values at ``fields`` (field paths) in one payload of ``channel``,
    or ``None`` when the channel must be decoded whole (see the module docstring).

    The reader returns one value per path (:data:`slearn.io.decode.MISSING` where the
    message lacks the element) and raises :class:`CdrError` when the payload does not
    decode."""
    if channel.schema is None or channel.schema_encoding != "ros2msg":
        return None
    try:
        root, types = _types(channel)
        paths = [parse_field_path(f) for f in fields]
        needs: dict = {}
        for path in paths:
            if not _mark(types, root, path.steps, needs):
                return None
        walk = _message(types, root, needs, set())
    except Exception:  # noqa: BLE001 - any schema this cannot plan is decoded whole
        return None
    if walk is None:
        return None
    getters = [path.get for path in paths]

    def read(data: bytes) -> list:
        if len(data) < 4 or data[:2] not in (b"\x00\x00", b"\x00\x01"):
            raise CdrError("invalid or unsupported CDR encapsulation")
        raw = data[4:]
        try:
            obj, pos = walk(raw, 0, "<" if data[1] else ">")
        except (struct.error, UnicodeDecodeError, ValueError, IndexError) as err:
            raise CdrError(str(err)) from None
        if pos + 4 + 3 < len(data):
            raise CdrError("CDR message size mismatch")
        return [get(obj) for get in getters]
    return read


def _fields(types: dict, name: str) -> list:
    fields = types.get(name)
    if not fields:
        raise KeyError(name)  # unknown or empty message: no plan
    return fields


def _mark(types: dict, name: str, steps: tuple, needs: dict) -> bool:
    """Record in ``needs`` the fields of message ``name`` a path reads; whether it can."""
    fields = dict(_fields(types, name))
    if not steps or steps[0][0] != "attr" or steps[0][1] not in fields:
        return False
    field = steps[0][1]
    kind, args = fields[field]
    rest = steps[1:]
    if kind == NAME:
        sub = needs.setdefault(field, {})
        return isinstance(sub, dict) and bool(rest) and _mark(types, args, rest, sub)
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
    return True


def _base_ok(typename: str) -> bool:
    return typename == "string" or typename in _SIZES


def _message(types: dict, name: str, needs: dict, stack: set):
    """A walker ``(raw, pos, endian) -> (sparse dict, pos)`` of message ``name``."""
    if name in stack:
        raise ValueError("recursive message type")
    steps = [_field(types, fname, desc, needs.get(fname), stack | {name})
             for fname, desc in _fields(types, name)]

    def walk(raw: bytes, pos: int, endian: str):
        out: dict[str, Any] = {}
        for fname, step in steps:
            value, pos = step(raw, pos, endian)
            if value is not _SKIPPED:
                out[fname] = value
        return out, pos
    return walk


_SKIPPED = object()


def _field(types: dict, fname: str, desc, need, stack: set):
    kind, args = desc
    if kind == NAME:
        inner = _message(types, args, need if isinstance(need, dict) else {}, stack)
        if need is None:
            return fname, lambda raw, pos, endian: (_SKIPPED, inner(raw, pos, endian)[1])
        return fname, inner
    if kind == BASE:
        return fname, _base(args[0], need is not None)
    element, count = args
    if element[0] != BASE:
        inner = _message(types, element[1], {}, stack)
        return fname, _message_array(inner, count if kind == ARRAY else None, _align_of(types, element))
    typename = element[1][0]
    if typename == "string":
        return fname, _strings(count if kind == ARRAY else None, need is not None)
    if typename not in _SIZES:
        raise KeyError(typename)
    return fname, _primitives(typename, count if kind == ARRAY else None, need is not None)


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
    def step(raw: bytes, pos: int, endian: str):
        n, pos = _length(raw, pos, endian, count, 1)  # each element takes a byte at least
        for _ in range(n):
            pos = (pos + align - 1) & -align
            _, pos = inner(raw, pos, endian)
        return _SKIPPED, pos
    return step
