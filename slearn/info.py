"""What is in a log: header, duration, channels, counts, rates and decodable scalar fields.

:func:`describe` dispatches on the file: ``.mcap`` logs are profiled here; ``.parquet``
pattern libraries go to :func:`slearn.library_info.describe`. :func:`suggest_spec` turns log profiles into a commented TOML spec skeleton.
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass, field
from typing import Any, Iterable

from slearn.decode import DecodeError, DecoderCache, decode_payload, iter_scalar_fields
from slearn.errors import InputError
from slearn.mcap_read import ChannelInfo, McapLog, ReadReport

EXAMPLE_MESSAGES = 3  # messages decoded per channel for example values
MAX_FIELDS = 40


@dataclass
class FieldInfo:
    """A scalar field of a channel: its path, type name and up to three example values."""

    path: str
    type: str
    examples: list = field(default_factory=list)


@dataclass
class ChannelProfile:
    """One channel of a log: identity, encodings, counts, rate and fields."""

    id: int
    topic: str
    schema: str
    schema_encoding: str
    message_encoding: str
    count: int = 0
    first_ns: int | None = None
    last_ns: int | None = None
    decode_error: str | None = None
    fields: list[FieldInfo] = field(default_factory=list)
    more_fields: int = 0

    @property
    def rate_hz(self) -> float | None:
        """Messages per second between the first and last message, ``None`` if undefined."""
        if self.count < 2 or not self.last_ns or self.last_ns <= (self.first_ns or 0):
            return None
        return (self.count - 1) * 1e9 / (self.last_ns - self.first_ns)

    def to_dict(self) -> dict:
        """Plain JSON-able data."""
        out = asdict(self)
        out["rate_hz"] = self.rate_hz
        out["decodable"] = self.decode_error is None
        return out


@dataclass
class LogProfile:
    """A whole log: header, size, time span, channels in id order and the read report."""

    path: str
    profile: str
    library: str
    size_bytes: int
    n_messages: int
    start_ns: int | None
    end_ns: int | None
    channels: list[ChannelProfile]
    report: ReadReport

    @property
    def duration_s(self) -> float:
        """Seconds between the first and the last message (0 when fewer than two)."""
        return (self.end_ns - self.start_ns) / 1e9 if self.start_ns is not None else 0.0

    def to_dict(self) -> dict:
        """Plain JSON-able data (``kind`` is ``"mcap"``)."""
        return {"kind": "mcap", "path": self.path, "profile": self.profile,
                "library": self.library, "size_bytes": self.size_bytes,
                "n_messages": self.n_messages, "start_ns": self.start_ns, "end_ns": self.end_ns,
                "duration_s": self.duration_s,
                "truncated": None if not self.report.truncated else {
                    "broken_at": self.report.broken_at, "reason": self.report.reason,
                    "message": self.report.describe()},
                "channels": [c.to_dict() for c in self.channels]}


def _profile_of(channel: ChannelInfo) -> ChannelProfile:
    return ChannelProfile(channel.id, channel.topic, channel.schema_name, channel.schema_encoding,
                          channel.message_encoding)


def _add_examples(profile: ChannelProfile, message: Any, max_fields: int) -> None:
    known = {f.path: f for f in profile.fields}
    fields = list(iter_scalar_fields(message))
    for path, value in fields:
        info = known.get(path)
        if info is None:
            if len(known) >= max_fields:
                continue
            info = known[path] = FieldInfo(path, type(value).__name__)
            profile.fields.append(info)
        if value not in info.examples and len(info.examples) < 3:
            info.examples.append(value[:60] if isinstance(value, str) else value)
    profile.more_fields = max(profile.more_fields, len(fields) - len(profile.fields))


def _sample(profile: ChannelProfile, message, cache: DecoderCache, max_fields: int) -> None:
    decoder = cache.get(message.channel)
    if decoder is None:
        profile.decode_error = cache.failures[message.channel.id]
        return
    try:
        _add_examples(profile, decode_payload(decoder, message.channel, message.data), max_fields)
    except DecodeError as err:
        profile.decode_error = str(err)


def describe_log(path: str | os.PathLike, max_fields: int = MAX_FIELDS) -> LogProfile:
    """Profile one MCAP log: one streaming pass; decodes a few messages per channel only.

    Raises:
        InputError: the file cannot be opened or is not MCAP.
    """
    cache = DecoderCache()
    profiles: dict[int, ChannelProfile] = {}
    n, start, end = 0, None, None
    with McapLog(path) as log:
        for message in log.iter_messages():
            p = profiles.get(message.channel.id) or profiles.setdefault(
                message.channel.id, _profile_of(message.channel))
            t = message.log_time_ns
            p.first_ns = t if p.first_ns is None else min(p.first_ns, t)
            p.last_ns = t if p.last_ns is None else max(p.last_ns, t)
            if p.count < EXAMPLE_MESSAGES and p.decode_error is None:
                _sample(p, message, cache, max_fields)
            p.count += 1
            n += 1
            start = t if start is None else min(start, t)
            end = t if end is None else max(end, t)
        for channel in log.channels.values():  # channels without messages
            profiles.setdefault(channel.id, _profile_of(channel))
        return LogProfile(log.path, log.profile, log.library, log.report.size_bytes, n, start, end,
                          [profiles[k] for k in sorted(profiles)], log.report)


def describe(path: str | os.PathLike) -> LogProfile | dict:
    """Describe a log (``.mcap``) or a pattern library (``.parquet``).

    Raises:
        InputError: unreadable file, or library description not available.
    """
    path = os.fspath(path)
    if path.endswith(".parquet"):
        from slearn.library_info import describe as describe_library

        return describe_library(path)
    return describe_log(path)


# --- spec skeleton ------------------------------------------------------------------------

def _symbolizer_lines(info: FieldInfo) -> list[str]:
    if info.type == "float":
        return ["quantiles = 8        # or: range = [low, high] + count = N; width = W; "
                "edges = [...]; wrap = true for angles"]
    if info.type == "int":
        return ["# categorical as is; for numbers use quantiles = 8 or range/count"]
    return ["# categorical as is; optionally values = [...] to fix the symbol order"]


def _entry_lines(channel: ChannelProfile, info: FieldInfo) -> list[str]:
    lines = ["[[channel]]", f"topic = {_toml_str(channel.topic)}",
             f"field = {_toml_str(info.path)}    # e.g. {', '.join(map(repr, info.examples))}",
             'role = "observation"    # or "action"']
    return lines + _symbolizer_lines(info)


def _toml_str(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _channel_block(channel: ChannelProfile) -> list[str]:
    rate = f"{channel.rate_hz:.1f} Hz" if channel.rate_hz else "rate n/a"
    head = [f"# --- {channel.topic}  ({channel.schema or 'schemaless'}, {channel.message_encoding}, "
            f"{channel.count} messages, {rate})"]
    if channel.decode_error:
        return head + [f"# cannot be decoded: {channel.decode_error}", ""]
    if not channel.fields:
        return head + ["# no scalar fields", ""]
    lines = list(head)
    for info in channel.fields:
        lines += ["#"] + ["# " + line for line in _entry_lines(channel, info)]
    return lines + [""]


def suggest_spec(profiles: Iterable[LogProfile]) -> str:
    """A commented TOML spec skeleton listing every decodable scalar field of the logs.

    Every entry is commented out: uncomment the ones to learn, set their roles and bins.
    """
    profiles = list(profiles)
    lines = ["# slearn channel spec, suggested by `slearn info --suggest-spec` from:"]
    lines += [f"#   {p.path}" for p in profiles]
    lines += ["# Uncomment the entries to learn (each [[channel]] block), choose each role",
              "# (action | observation) and how values become symbols.", "",
              'mode = "change"    # "message": every message; "change": when the symbol changes;',
              '                   # "tick": sample and hold every tick_ms (add tick_ms = 100)', ""]
    seen: set[tuple[str, str]] = set()
    for profile in profiles:
        for channel in profile.channels:
            if (channel.topic, channel.schema) not in seen:
                seen.add((channel.topic, channel.schema))
                lines += _channel_block(channel)
    return "\n".join(lines) + "\n"
