"""What is in a log: header, time span, channels, counts, rates and every field's values.

:func:`describe` dispatches on the file: logs (MCAP, rosbag2 folders, ``.db3``, ``.bag``)
are profiled here; ``.parquet`` pattern libraries go to :func:`slearn.io.library_info.describe`.
:func:`suggest_spec` (:mod:`slearn.jobs.suggest`) turns log profiles into a spec.

Every field is listed: all elements of arrays (by name for ROS parallel arrays such as
``JointState.position[name=...]``), with its minimum and maximum, its distinct values up
to :data:`DISTINCT_CAP`, whether it is constant, how often it changes between messages,
and example values sampled across the whole log. The first :data:`DECODE_BUDGET` messages
of a channel are decoded, then every 2nd, 4th, ... (the stride doubles each time another
budget's worth has been decoded), so a long log costs little more than a short one;
``decoded`` says how many messages the statistics come from.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import Any, Iterable

from slearn.errors import DecodeError
from slearn.io.bags import open_log
from slearn.io.decode import DecoderCache, decode_payload, iter_scalar_fields
from slearn.io.mcap_read import ChannelInfo, ReadReport
from slearn.io.slicing import TimeSlice

DECODE_BUDGET = 2000  # messages decoded per channel before the stride doubles
MAX_FIELDS = 2000  # fields listed per channel
MAX_ARRAY_ITEMS = 1000  # elements listed per array
DISTINCT_CAP = 64  # distinct values kept per field
EXAMPLES = 5
_SAMPLE = 64  # values kept per field to draw examples across the log
BURST_NS = 1_000_000  # a channel whose messages span less than this (or 1 % of the log) is a burst


def iso_time(time_ns: int | None) -> str | None:
    """A log time as ISO 8601 UTC with nanoseconds (``2012-05-12T01:02:03.123456789Z``)."""
    if time_ns is None:
        return None
    seconds, nanos = divmod(int(time_ns), 1_000_000_000)
    return datetime.fromtimestamp(seconds, timezone.utc).strftime("%Y-%m-%dT%H:%M:%S") + f".{nanos:09d}Z"


@dataclass
class FieldInfo:
    """A scalar field of a channel and what its values did over the decoded messages."""

    path: str
    type: str
    count: int = 0
    min: float | None = None
    max: float | None = None
    distinct: list = field(default_factory=list)
    more_distinct: bool = False
    changes: int = 0
    examples: list = field(default_factory=list)
    _last: Any = field(default=None, repr=False)
    _sample: list = field(default_factory=list, repr=False)
    _stride: int = field(default=1, repr=False)

    @property
    def constant(self) -> bool:
        """One value in every decoded message."""
        return self.count > 0 and len(self.distinct) == 1 and not self.more_distinct

    @property
    def n_distinct(self) -> int | None:
        """Distinct values seen, ``None`` when more than :data:`DISTINCT_CAP`."""
        return None if self.more_distinct else len(self.distinct)

    def add(self, value: Any) -> None:
        """Count one value."""
        if isinstance(value, str):
            value = value[:60]
        if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value):
            self.min = value if self.min is None else min(self.min, value)
            self.max = value if self.max is None else max(self.max, value)
        if self.count and value != self._last:
            self.changes += 1
        self._last = value
        if not self.more_distinct and value not in self.distinct:
            if len(self.distinct) < DISTINCT_CAP:
                self.distinct.append(value)
            else:
                self.more_distinct = True
        if self.count % self._stride == 0:
            self._sample.append(value)
            if len(self._sample) >= _SAMPLE:
                self._sample, self._stride = self._sample[::2], self._stride * 2
        self.count += 1

    def finish(self) -> None:
        """Choose the examples: the distinct values when few, else values spread over the log."""
        if not self.more_distinct:
            ordered, n = sorted(self.distinct, key=_order), len(self.distinct)
            values = ordered if n <= EXAMPLES else \
                [ordered[round(i * (n - 1) / (EXAMPLES - 1))] for i in range(EXAMPLES)]
        else:
            n = len(self._sample)
            values = [self._sample[round(i * (n - 1) / (EXAMPLES - 1))] for i in range(EXAMPLES)]
        self.examples = list(dict.fromkeys(values))

    def to_dict(self) -> dict:
        """Plain JSON-able data (``distinct`` is ``null`` beyond the cap)."""
        return {"path": self.path, "type": self.type, "count": self.count, "min": self.min,
                "max": self.max, "constant": self.constant, "n_distinct": self.n_distinct,
                "distinct": None if self.more_distinct else sorted(self.distinct, key=_order),
                "changes": self.changes, "examples": self.examples}


def _order(value: Any) -> tuple:
    return (0, value, "") if isinstance(value, (int, float)) else (1, 0, str(value))


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
    decoded: int = 0
    burst: bool = False
    metadata: dict[str, str] = field(default_factory=dict)

    @property
    def span_ns(self) -> int:
        """Time between the first and the last message."""
        if self.first_ns is None or self.last_ns is None:
            return 0
        return self.last_ns - self.first_ns

    @property
    def rate_hz(self) -> float | None:
        """Messages per second between the first and last message; ``None`` for fewer than
        two messages and for bursts (a rate over a few nanoseconds means nothing)."""
        if self.count < 2 or self.burst or self.span_ns <= 0:
            return None
        return (self.count - 1) * 1e9 / self.span_ns

    def to_dict(self) -> dict:
        """Plain JSON-able data."""
        return {"id": self.id, "topic": self.topic, "schema": self.schema,
                "schema_encoding": self.schema_encoding, "message_encoding": self.message_encoding,
                "count": self.count, "first_ns": self.first_ns, "last_ns": self.last_ns,
                "first_time": iso_time(self.first_ns), "last_time": iso_time(self.last_ns),
                "span_s": self.span_ns / 1e9, "rate_hz": self.rate_hz, "burst": self.burst,
                "decodable": self.decode_error is None, "decode_error": self.decode_error,
                "metadata": self.metadata,
                "decoded": self.decoded, "fields": [f.to_dict() for f in self.fields],
                "more_fields": self.more_fields}


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
    window: str | None = None

    @property
    def duration_s(self) -> float:
        """Seconds between the first and the last message (0 when fewer than two)."""
        if self.start_ns is None or self.end_ns is None:
            return 0.0
        return (self.end_ns - self.start_ns) / 1e9

    def to_dict(self) -> dict:
        """Plain JSON-able data (``kind`` is ``"log"``; times in ns, ISO 8601 and seconds)."""
        return {"kind": "log", "path": self.path, "profile": self.profile,
                "library": self.library, "size_bytes": self.size_bytes,
                "n_messages": self.n_messages, "start_ns": self.start_ns, "end_ns": self.end_ns,
                "start_time": iso_time(self.start_ns), "end_time": iso_time(self.end_ns),
                "start_s": None if self.start_ns is None else self.start_ns / 1e9,
                "end_s": None if self.end_ns is None else self.end_ns / 1e9,
                "duration_s": self.duration_s, "window": self.window,
                "truncated": None if not self.report.truncated else {
                    "broken_at": self.report.broken_at, "reason": self.report.reason,
                    "message": self.report.describe()},
                "channels": [c.to_dict() for c in self.channels]}


def _profile_of(channel: ChannelInfo) -> ChannelProfile:
    return ChannelProfile(channel.id, channel.topic, channel.schema_name, channel.schema_encoding,
                          channel.message_encoding, metadata=dict(channel.metadata))


class _Profiler:
    """Accumulates one channel's counts, times and field statistics."""

    def __init__(self, profile: ChannelProfile, max_fields: int) -> None:
        self.profile, self.max_fields = profile, max_fields
        self.known: dict[str, FieldInfo] = {}
        self.stride = 1

    def add(self, message, cache: DecoderCache) -> None:
        p, t = self.profile, message.log_time_ns
        p.first_ns = t if p.first_ns is None else min(p.first_ns, t)
        p.last_ns = t if p.last_ns is None else max(p.last_ns, t)
        if p.decode_error is None and p.count % self.stride == 0:
            self._decode(message, cache)
            if p.decoded >= DECODE_BUDGET * self.stride:
                self.stride *= 2
        p.count += 1

    def _decode(self, message, cache: DecoderCache) -> None:
        decoder = cache.get(message.channel)
        if decoder is None:
            self.profile.decode_error = cache.failures[message.channel.id]
            return
        try:
            decoded = decode_payload(decoder, message.channel, message.data)
        except DecodeError as err:
            self.profile.decode_error = str(err)
            return
        self.profile.decoded += 1
        extra = 0
        for path, value in iter_scalar_fields(decoded, max_items=MAX_ARRAY_ITEMS):
            info = self.known.get(path)
            if info is None:
                if len(self.known) >= self.max_fields:
                    extra += 1
                    continue
                info = self.known[path] = FieldInfo(path, type(value).__name__)
                self.profile.fields.append(info)
            info.add(value)
        self.profile.more_fields = max(self.profile.more_fields, extra)


def describe_log(path: str | os.PathLike, max_fields: int = MAX_FIELDS,
                 topics: Iterable[str] | None = None, window: TimeSlice | None = None) -> LogProfile:
    """Profile one log in one streaming pass (see the module docstring for what is decoded).

    Args:
        topics: only these topics (``None``: all).
        window: only this slice of the log's time.

    Raises:
        InputError: the file cannot be opened or is not a log.
    """
    cache = DecoderCache()
    profilers: dict[int, _Profiler] = {}
    wanted = None if topics is None else set(topics)
    n = 0
    with open_log(path) as log:
        low, high = _time_window(log, window)
        for message in log.iter_messages(wanted):
            if not low <= message.log_time_ns < high:
                continue
            profiler = profilers.get(message.channel.id) or profilers.setdefault(
                message.channel.id, _Profiler(_profile_of(message.channel), max_fields))
            profiler.add(message, cache)
            n += 1
        for channel in log.channels.values():  # channels without messages
            if wanted is None or channel.topic in wanted:
                profilers.setdefault(channel.id, _Profiler(_profile_of(channel), max_fields))
        channels = [profilers[k].profile for k in sorted(profilers)]
        return _finish(LogProfile(log.path, log.profile, log.library, log.report.size_bytes, n,
                                  None, None, channels, log.report,
                                  window.describe() if window else None))


def _time_window(log, window: TimeSlice | None) -> tuple[int, int]:
    span = log.time_range() if window is not None else None
    if window is None or span is None:
        return (0, 1 << 64)
    return window.window(*span)


def _finish(profile: LogProfile) -> LogProfile:
    """Log span, bursts and examples once every message was seen."""
    firsts = [c.first_ns for c in profile.channels if c.first_ns is not None]
    lasts = [c.last_ns for c in profile.channels if c.last_ns is not None]
    profile.start_ns, profile.end_ns = (min(firsts), max(lasts)) if firsts else (None, None)
    log_span = (max(lasts) - min(firsts)) if firsts else 0
    for channel in profile.channels:
        channel.burst = channel.count >= 2 and channel.span_ns < max(BURST_NS, log_span // 100)
        for info in channel.fields:
            info.finish()
    return profile


def describe(path: str | os.PathLike, topics: Iterable[str] | None = None,
             window: TimeSlice | None = None) -> LogProfile | dict:
    """Describe a log (MCAP, rosbag2 folder, ``.db3``, ``.bag``) or a pattern library (``.parquet``).

    ``topics`` and ``window`` select part of a log (see :func:`describe_log`).

    Raises:
        InputError: unreadable file.
    """
    path = os.fspath(path)
    if path.endswith(".parquet"):
        from slearn.io.library_info import describe as describe_library

        return describe_library(path)
    return describe_log(path, topics=topics, window=window)


def suggest_spec(profiles: Iterable[LogProfile]) -> str:
    """A TOML spec for the logs: see :func:`slearn.jobs.suggest.suggest_spec`."""
    from slearn.jobs.suggest import suggest_spec as suggest

    return suggest(profiles)
