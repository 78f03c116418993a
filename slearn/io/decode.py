"""Decoding message payloads per channel, and reaching into decoded messages by field path.

Decoders: JSON (``jsonschema`` or schemaless, ``json.loads``), ROS 2 CDR
(``mcap_ros2``), ROS 1 (``mcap_ros1``) and protobuf (``mcap_protobuf``). A decoder is
built once per channel; a channel that has none keeps the reason. Whatever the decoder
libraries print while building (the vendored ROS 2 parser prints on failure) is captured
and never reaches stdout, and the ROS 1 decoder's log line for strings that are not UTF-8
("Characters replaced ...", logger ``rosout``) is silenced: the value keeps U+FFFD
characters, and slearn's output stays one line per error.

Field paths: ``pose.pose.position.x``, ``position[3]`` (negative indexes count from the
end), ``position[name=r_shoulder_pan_joint]`` (ROS parallel arrays: the element of
``position`` at the index where the sibling array ``name`` holds that value; when there is
no sibling ``name``, the first element of ``position`` whose own ``name`` field matches),
``position["r_shoulder_pan_joint"]`` (short for ``[name=...]``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import logging
import re
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator, cast

import numpy as np

from slearn.errors import DecodeError, FieldPathError
from slearn.io.mcap_read import ChannelInfo, SchemaInfo

Decoder = Callable[[bytes], Any]

MISSING = object()
"""Returned by :meth:`FieldPath.get` when a message lacks that element (skip it)."""


# --- decoders -------------------------------------------------------------------------

def _factory_for(message_encoding: str):
    """The mcap decoder factory for an encoding, or ``None``."""
    if message_encoding == "cdr":
        from mcap_ros2.decoder import DecoderFactory as Ros2Factory
        return Ros2Factory()
    if message_encoding == "ros1":
        from mcap_ros1.decoder import DecoderFactory as Ros1Factory
        _silence_rosout()
        return Ros1Factory()
    if message_encoding == "protobuf":
        from mcap_protobuf.decoder import DecoderFactory as ProtobufFactory
        return ProtobufFactory()
    return None


def _silence_rosout() -> None:
    """Keep genpy's per-message log lines (logger ``rosout``) off stderr."""
    logger = logging.getLogger("rosout")
    if not any(isinstance(h, logging.NullHandler) for h in logger.handlers):
        logger.addHandler(logging.NullHandler())
    logger.propagate = False


def _first_line(text: str) -> str:
    lines = [line.strip() for line in text.strip().splitlines() if line.strip()]
    return lines[0] if lines else ""


_MSG_SEPARATOR = re.compile(r"^={40,}\s*$", re.M)


def _ros2_type_name(name: str) -> str:
    parts = name.strip().split("/")
    return f"{parts[0]}/msg/{parts[-1]}" if len(parts) == 2 else name.strip()


def ros2_message_types(schema_name: str, data: bytes) -> tuple[str, dict]:
    """The full type name of a ROS 2 ``ros2msg`` schema and the rosbags definitions of its
    message type and every type it embeds.

    Raises:
        ValueError: a section of the schema is not a ``MSG:`` definition.
    """
    from rosbags.typesys import get_types_from_msg

    parts = _MSG_SEPARATOR.split(data.decode("utf-8"))
    name = _ros2_type_name(schema_name)
    types = dict(get_types_from_msg(parts[0], name))
    for part in parts[1:]:
        head, _, body = part.strip("\n").partition("\n")
        if not head.startswith("MSG:"):
            raise ValueError(f"unexpected schema section {head!r}")
        types.update(get_types_from_msg(body, _ros2_type_name(head[4:])))
    return name, types


def _rosbags_cdr_decoder(channel: ChannelInfo) -> Decoder:
    """A ROS 2 CDR decoder from ``rosbags`` (1.5-2x faster than mcap-ros2-support)."""
    from rosbags.typesys import Stores, get_typestore

    schema = cast(SchemaInfo, channel.schema)  # a CDR channel always has its schema
    name, types = ros2_message_types(schema.name, schema.data)
    store = get_typestore(Stores.EMPTY)  # one store per channel: type versions cannot clash
    store.register(types)
    deserialize = store.deserialize_cdr
    return lambda data: deserialize(data, name)


def make_decoder(channel: ChannelInfo) -> Decoder:
    """Build the payload decoder of one channel.

    ROS 2 ``ros2msg`` channels use ``rosbags`` when it parses the schema, else
    mcap-ros2-support (whose error is the one reported when both fail).

    Raises:
        DecodeError: no decoder exists for the channel's encodings, or building it failed;
            the message says why.
    """
    if channel.message_encoding == "json":
        return json.loads
    if channel.message_encoding == "cdr" and channel.schema_encoding == "ros2msg":
        try:
            with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
                return _rosbags_cdr_decoder(channel)
        except Exception:  # noqa: BLE001 - fall back to mcap-ros2-support below
            pass
    factory = _factory_for(channel.message_encoding)
    if factory is None:
        raise DecodeError(f"no decoder for message encoding {channel.message_encoding!r} "
                          f"(schema encoding {channel.schema_encoding!r})")
    from mcap.records import Schema
    schema = None
    if channel.schema is not None:
        s = channel.schema
        schema = Schema(id=s.id, name=s.name, encoding=s.encoding, data=s.data)
    chatter = io.StringIO()
    try:
        with contextlib.redirect_stdout(chatter), contextlib.redirect_stderr(chatter):
            decoder = factory.decoder_for(channel.message_encoding, schema)
    except Exception as err:  # the decoder libraries raise many unrelated types
        raise DecodeError(_schema_failure(channel, err)) from err
    if decoder is None:
        raise DecodeError(f"no decoder for message encoding {channel.message_encoding!r} "
                          f"with schema encoding {channel.schema_encoding!r}")
    return decoder


def _schema_failure(channel: ChannelInfo, err: Exception) -> str:
    detail = f"{type(err).__name__}: {_first_line(str(err))}"
    text = channel.schema.data.decode("utf-8", "replace") if channel.schema else ""
    if "\n---" in text and "/srv/" in channel.schema_name:
        detail += (" (a raw .srv service definition, request --- response: "
                   "ROS 2 service events cannot be decoded by mcap-ros2-support)")
    return f"schema {channel.schema_name!r} ({channel.schema_encoding}) cannot be parsed: {detail}"


@dataclass
class DecoderCache:
    """One decoder per channel id, built on first use; failures are kept with their reason."""

    decoders: dict[int, Decoder] = field(default_factory=dict)
    failures: dict[int, str] = field(default_factory=dict)

    def get(self, channel: ChannelInfo) -> Decoder | None:
        """The channel's decoder, or ``None`` when it has none (see ``failures``)."""
        decoder = self.decoders.get(channel.id)
        if decoder is not None or channel.id in self.failures:
            return decoder
        try:
            decoder = self.decoders[channel.id] = make_decoder(channel)
        except DecodeError as err:
            self.failures[channel.id] = str(err)
        return decoder

    def require(self, channel: ChannelInfo) -> Decoder:
        """The channel's decoder; raise :class:`DecodeError` naming the channel if none."""
        decoder = self.get(channel)
        if decoder is None:
            raise DecodeError(f"channel {channel.topic!r} (id {channel.id}) cannot be decoded: "
                              f"{self.failures[channel.id]}")
        return decoder


def decode_payload(decoder: Decoder, channel: ChannelInfo, data: bytes) -> Any:
    """Decode one payload; raise :class:`DecodeError` naming the channel when it fails."""
    try:
        return decoder(data)
    except Exception as err:  # corrupt payloads raise struct, unicode, json, ... errors
        raise DecodeError(f"channel {channel.topic!r}: a message does not decode: "
                          f"{_first_line(str(err)) or type(err).__name__}") from err


# --- field paths ----------------------------------------------------------------------

_SEGMENT = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)?((?:\[[^\]]*\])*)$")
_SELECTOR = re.compile(r"\[([^\]]*)\]")


def split_outside_brackets(text: str, sep: str, max_splits: int = -1) -> list[str]:
    """Split ``text`` on ``sep`` where it is not inside ``[...]``, at most ``max_splits``
    times (all when negative), as ``str.split`` does."""
    parts: list[str] = []
    depth = start = 0
    for i, ch in enumerate(text):
        depth += (ch == "[") - (ch == "]")
        if ch == sep and depth == 0 and len(parts) != max_splits:
            parts.append(text[start:i])
            start = i + 1
    return parts + [text[start:]]


def _parse_selector(raw: str, path: str) -> tuple:
    raw = raw.strip()
    if re.fullmatch(r"-?\d+", raw):
        return ("index", int(raw))
    if len(raw) >= 2 and raw[0] == raw[-1] and raw[0] in "'\"":
        return ("match", "name", raw[1:-1])
    key, eq, value = raw.partition("=")
    if not eq or not key.strip():
        raise FieldPathError(f"field {path!r}: selector [{raw}] must be an index [3], "
                             f"a lookup [name=value] or a quoted name [\"value\"]")
    return ("match", key.strip(), value.strip().strip("'\""))


def parse_field_path(path: str) -> "FieldPath":
    """Parse a field path such as ``position[name=r_shoulder_pan_joint]``.

    Raises:
        FieldPathError: the path is malformed.
    """
    steps: list[tuple] = []
    if not path.strip():
        return FieldPath(path, ())
    for part in split_outside_brackets(path.strip(), "."):
        m = _SEGMENT.match(part)
        if m is None or (not m.group(1) and not m.group(2)):
            raise FieldPathError(f"field {path!r}: cannot parse {part!r}")
        if m.group(1):
            steps.append(("attr", m.group(1)))
        for raw in _SELECTOR.findall(m.group(2)):
            steps.append(_parse_selector(raw, path))
    return FieldPath(path, tuple(steps))


def field_names(obj: Any) -> list[str]:
    """The field names of a decoded message (dict, ROS 1/2 object, protobuf)."""
    if isinstance(obj, dict):
        return [str(k) for k in obj]
    descriptor = getattr(obj, "DESCRIPTOR", None)
    if descriptor is not None and hasattr(descriptor, "fields"):
        return [f.name for f in descriptor.fields]
    if dataclasses.is_dataclass(obj):  # rosbags messages; skip its type tag and constants
        return [f.name for f in dataclasses.fields(obj)
                if not f.name.startswith("_") and not f.name.isupper()]
    slots = getattr(type(obj), "__slots__", None)
    if slots:
        return list(slots)
    return [k for k in getattr(obj, "__dict__", {}) if not k.startswith("_")]


def _child(obj: Any, name: str, path: str) -> Any:
    try:
        return obj[name] if isinstance(obj, dict) else getattr(obj, name)
    except (KeyError, AttributeError, TypeError):
        known = ", ".join(field_names(obj)[:20]) or "none"
        raise FieldPathError(f"field {path!r}: no field {name!r} here (fields: {known})") from None


def _is_sequence(obj: Any) -> bool:
    return hasattr(obj, "__len__") and hasattr(obj, "__getitem__") and not isinstance(
        obj, (str, bytes, bytearray, dict))


@dataclass(frozen=True)
class FieldPath:
    """A parsed field path; :meth:`get` reads it from a decoded message."""

    text: str
    steps: tuple

    def get(self, message: Any) -> Any:
        """The value at this path, or :data:`MISSING` when this message lacks the element.

        Raises:
            FieldPathError: the message type has no such field (a spec error, not data).
        """
        parent, value = None, message
        for kind, *args in self.steps:
            if kind == "attr":
                parent, value = value, _child(value, args[0], self.text)
            elif kind == "index":
                if not _is_sequence(value) or not -len(value) <= args[0] < len(value):
                    return MISSING
                parent, value = None, value[args[0]]
            else:
                found = self._match(parent, value, args[0], args[1])
                if found is MISSING:
                    return MISSING
                parent, value = None, found
        if isinstance(value, np.generic):
            return value.item()
        return value.tolist() if isinstance(value, np.ndarray) else value

    def _match(self, parent: Any, seq: Any, key: str, wanted: str) -> Any:
        if not _is_sequence(seq):
            return MISSING
        keys = None
        if parent is not None:
            try:
                keys = parent[key] if isinstance(parent, dict) else getattr(parent, key)
            except (KeyError, AttributeError, TypeError):
                keys = None
        if keys is not None and _is_sequence(keys):
            for i, k in enumerate(keys):
                if str(k) == wanted:
                    return seq[i] if i < len(seq) else MISSING
            return MISSING
        for element in seq:
            k = element.get(key) if isinstance(element, dict) else getattr(element, key, None)
            if k is not None and str(k) == wanted:
                return element
        return MISSING


# --- scalar fields (for ``slearn info``) ----------------------------------------------

def _is_scalar(value: Any) -> bool:
    return isinstance(value, (bool, int, float, str, np.generic))


def _plain(value: Any) -> Any:
    return value.item() if isinstance(value, np.generic) else value


def _sequence_fields(obj: Any, name: str, seq: Any, path: str, depth: int,
                     max_items: int) -> Iterator[tuple[str, Any]]:
    if not len(seq):
        return
    if _is_scalar(seq[0]):
        keys = None if name == "name" else (obj.get("name") if isinstance(obj, dict)
                                            else getattr(obj, "name", None))
        if keys is not None and _is_sequence(keys) and len(keys) == len(seq) and len(keys):
            for key, value in list(zip(keys, seq))[:max_items]:
                yield f"{path}[name={key}]", _plain(value)
        else:
            for i in range(min(len(seq), max_items)):
                yield f"{path}[{i}]", _plain(seq[i])
    elif not isinstance(seq[0], (bytes, bytearray)):
        for i in range(min(len(seq), max_items)):
            yield from iter_scalar_fields(seq[i], f"{path}[{i}]", depth + 1, max_items)


def iter_scalar_fields(obj: Any, prefix: str = "", depth: int = 0,
                       max_items: int = 4) -> Iterator[tuple[str, Any]]:
    """``(field path, value)`` for the scalar leaves of a decoded message.

    Arrays show their first ``max_items`` elements: scalars by name when a sibling
    ``name`` array makes them parallel, else by index; messages by index.
    """
    if depth > 8:
        return
    if _is_scalar(obj):
        yield prefix, _plain(obj)
        return
    for name in field_names(obj):
        try:
            value = obj[name] if isinstance(obj, dict) else getattr(obj, name)
        except (AttributeError, KeyError):
            continue
        path = f"{prefix}.{name}" if prefix else name
        if _is_scalar(value):
            yield path, _plain(value)
        elif isinstance(value, np.ndarray) and value.dtype == np.uint8:
            continue  # raw bytes (images, blobs), as mcap-ros2-support returns them
        elif _is_sequence(value):
            yield from _sequence_fields(obj, name, value, path, depth, max_items)
        elif value is not None and not isinstance(value, (bytes, bytearray)):
            yield from iter_scalar_fields(value, path, depth + 1, max_items)
