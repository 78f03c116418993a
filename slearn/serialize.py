"""Serialization: the messages of MCAP files become episodes of steps of symbols.

One file is one episode (several files are several episodes, never glued together);
all episodes share one :class:`~slearn.vocabulary.Vocabulary`.

Event order (stable, the same for every layout of the same recording): log time; at
equal log time observations before actions (what a controller read at ``t`` precedes
what it did at ``t``); then spec order; then file position.

Steps (modes ``message`` and ``change``): a step is the actions of a tick followed by the
observations that came after them. A new step starts at an action that follows
observations or has another log time than the step's actions, and at an observation
whose log time differs from that of the step's observations (so streams without actions
get one step per observation time).
For the pointer, ``pos@0 R@0 pos@50ms L@100ms pos@150ms`` becomes
``([], [pos]), ([R], [pos]), ([L], [pos])``.

Modes: ``message``: every message of a spec entry is an event; ``change``: an event only
when the entry's symbol differs from its previous one; ``tick``: every ``tick_ns`` from
the first event, each entry's latest symbol is sampled and held; step 0 holds the
observations at tick 0, step ``k`` the actions held at tick ``k - 1`` then the
observations held at tick ``k``.

Vocabulary: :func:`prepare_vocabulary` registers the channels in spec order, each followed
by its declared values (``values``, or every bin of bounded bins) in declared order;
other values get symbols in first-seen order.
"""

from __future__ import annotations

import os
import sys
import time
from array import array
from collections import Counter
from dataclasses import dataclass, replace
from typing import Any, Iterable, Iterator

import numpy as np

from slearn.decode import MISSING, DecodeError, DecoderCache, FieldPath, FieldPathError, decode_payload
from slearn.errors import InputError, SpecError
from slearn.mcap_read import McapLog, ReadReport
from slearn.spec import POINTER_COMMAND, POINTER_POSITION, Bins, ChannelSpec, Spec, pointer_spec
from slearn.stream import Episode
from slearn.vocabulary import ACTION, Vocabulary

MAX_TICKS = 10_000_000
_QUANTILE_SAMPLE = 1 << 20  # values kept per entry when fitting quantiles


def prepare_vocabulary(spec: Spec, vocabulary: Vocabulary) -> Vocabulary:
    """Register the spec's channels (spec order) and declared values; return ``vocabulary``."""
    for entry in spec.channels:
        vocabulary.add_channel(entry.name, entry.role)
        for value in entry.symbolizer.declared_values() or ():
            vocabulary.symbol(entry.name, value)
    return vocabulary


# --- reading field values ---------------------------------------------------------------

@dataclass
class _Entry:
    index: int
    spec: ChannelSpec
    path: FieldPath
    is_action: bool
    n_values: int = 0


def _where(path: str, entry: _Entry) -> str:
    return f"{path}: spec entry {entry.index + 1} ({entry.spec.name!r}, field {entry.spec.field!r})"


def _entries_by_topic(spec: Spec) -> dict[str, list[_Entry]]:
    by_topic: dict[str, list[_Entry]] = {}
    for i, c in enumerate(spec.channels):
        by_topic.setdefault(c.topic, []).append(_Entry(i, c, c.path, c.role == ACTION))
    return by_topic


def _decoded(message, cache: DecoderCache, path: str, report: ReadReport) -> Any:
    """The decoded message; :data:`MISSING` (counted in ``report``) when its payload does not decode."""
    try:
        decoder = cache.require(message.channel)
    except DecodeError as err:
        raise SpecError(f"{path}: the spec selects topic {message.topic!r}, but {err}") from err
    try:
        return decode_payload(decoder, message.channel, message.data)
    except DecodeError as err:
        report.note_undecodable(message.topic, message.offset, str(err))
        return MISSING


def _field_value(obj: Any, entry: _Entry, path: str) -> Any:
    try:
        return entry.path.get(obj)
    except FieldPathError as err:
        raise SpecError(f"{_where(path, entry)}: {err}") from err


def iter_field_values(path: str | os.PathLike, spec: Spec, report: ReadReport | None = None,
                      progress: bool = False) -> Iterator[tuple[int, int, Any]]:
    """Yield ``(log_time_ns, entry index, field value)`` for every spec entry of every message.

    Messages come in log-time order (ties in file order); entries of one message in spec
    order. Only the spec's topics are decoded. A message whose payload does not decode is
    skipped and counted in the report (per topic), like a damaged chunk.

    Raises:
        SpecError: a selected channel cannot be decoded, a field does not exist, a topic is
            missing from the file, or a field never matched; the message names file and entry.
    """
    path = os.fspath(path)
    by_topic = _entries_by_topic(spec)
    cache = DecoderCache()
    seen: dict[str, int] = {}
    with McapLog(path) as log, _Progress(path, progress) as bar:
        for message in log.iter_messages(by_topic, on_progress=bar.update):
            seen[message.topic] = seen.get(message.topic, 0) + 1
            obj = _decoded(message, cache, path, log.report)
            if obj is MISSING:
                continue
            for entry in by_topic[message.topic]:
                value = _field_value(obj, entry, path)
                if value is not MISSING:
                    entry.n_values += 1
                    yield message.log_time_ns, entry.index, value
        if report is not None:
            vars(report).update(vars(log.report))
        _check_coverage(path, by_topic, seen, log)


def _check_coverage(path: str, by_topic: dict[str, list[_Entry]], seen: dict[str, int],
                    log: McapLog) -> None:
    if log.report.truncated:
        return  # a salvaged file may simply have lost the topic
    for topic, entries in by_topic.items():
        if topic not in seen and topic not in {c.topic for c in log.channels.values()}:
            topics = ", ".join(sorted({c.topic for c in log.channels.values()})[:12])
            raise SpecError(f"{path}: the spec's topic {topic!r} is not in this log "
                            f"(topics: {topics or 'none'})")
        for entry in entries:
            if seen.get(topic) and not entry.n_values:
                raise SpecError(f"{_where(path, entry)}: matched none of the {seen[topic]} "
                                f"messages on {topic!r} (check names and indexes)")


# --- events -----------------------------------------------------------------------------

def _symbolize(values: Iterable[tuple[int, int, Any]], spec: Spec, vocabulary: Vocabulary,
               path: str) -> Iterator[tuple[int, int, int, bool]]:
    """``(log_time_ns, entry index, symbol, is_action)`` in the documented event order."""
    entries = spec.channels
    is_action = [c.role == ACTION for c in entries]
    group: list[tuple] = []
    group_time = None
    known, per_channel = len(vocabulary), Counter(channel for _, channel, _ in vocabulary.items())
    for position, (log_time, index, value) in enumerate(values):
        value = entries[index].symbolizer.symbol_value(value)
        if value is None:
            continue
        try:
            symbol = vocabulary.symbol(entries[index].name, value)
        except TypeError:
            raise SpecError(f"{path}: spec entry {index + 1} ({entries[index].name!r}): field "
                            f"{entries[index].field!r} is a message, not a value; pick a field "
                            f"inside it (see `slearn info`)") from None
        if symbol >= known:  # a new value: count it against the channel's limit
            known += 1
            _check_symbols(per_channel, entries[index], path)
        if log_time != group_time and group:
            yield from _ordered(group)
            group = []
        group_time = log_time
        group.append((log_time, is_action[index], index, position, symbol))
    yield from _ordered(group)


def _check_symbols(per_channel: Counter, entry: ChannelSpec, path: str) -> None:
    per_channel[entry.name] += 1
    if per_channel[entry.name] > entry.symbol_limit:
        raise SpecError(f"{path}: channel {entry.name!r} has more than {entry.symbol_limit:,} "
                        f"distinct values: use coarser bins, or raise the entry's max_symbols")


def _ordered(group: list[tuple]) -> Iterator[tuple[int, int, int, bool]]:
    group.sort(key=lambda e: (e[1], e[2], e[3]))  # observations first, spec order, file order
    for log_time, action, index, _, symbol in group:
        yield log_time, index, symbol, action


def _only_changes(events: Iterable[tuple[int, int, int, bool]]) -> Iterator[tuple[int, int, int, bool]]:
    last: dict[int, int] = {}
    for event in events:
        if last.get(event[1]) != event[2]:
            last[event[1]] = event[2]
            yield event


# --- steps ------------------------------------------------------------------------------

class _StepBuilder:
    """Accumulates steps into the flat arrays of an :class:`Episode`."""

    def __init__(self) -> None:
        self.symbols = array("i")
        self.offsets = array("q", [0])
        self.n_actions = array("i")
        self.actions = self.observations = 0
        self.open = False
        self.obs_time: int | None = None
        self.action_time: int | None = None

    def close(self) -> None:
        if self.open:
            self.offsets.append(len(self.symbols))
            self.n_actions.append(self.actions)
        self.open, self.actions, self.observations = True, 0, 0
        self.obs_time = self.action_time = None

    def add(self, log_time: int, symbol: int, action: bool) -> None:
        if action:
            if not self.open or self.observations or (self.actions and log_time != self.action_time):
                self.close()
            self.actions += 1
            self.action_time = log_time
        else:
            if not self.open or (self.observations and log_time != self.obs_time):
                self.close()
            self.observations += 1
            self.obs_time = log_time
        self.symbols.append(symbol)

    def add_step(self, actions: list[int], observations: list[int]) -> None:
        self.symbols.extend(actions)
        self.symbols.extend(observations)
        self.offsets.append(len(self.symbols))
        self.n_actions.append(len(actions))

    def build(self) -> Episode:
        if self.open:
            self.close()
            self.open = False
        return Episode(np.frombuffer(self.symbols, dtype=np.int32).copy(),
                       np.frombuffer(self.offsets, dtype=np.int64).copy(),
                       np.frombuffer(self.n_actions, dtype=np.int32).copy())


def _event_steps(events: Iterable[tuple[int, int, int, bool]]) -> Episode:
    builder = _StepBuilder()
    for log_time, _, symbol, action in events:
        builder.add(log_time, symbol, action)
    return builder.build()


def _held(held: dict[int, int], n: int, is_action: list[bool], want_action: bool) -> list[int]:
    return [held[i] for i in range(n) if i in held and is_action[i] == want_action]


def _tick_steps(events: Iterable[tuple[int, int, int, bool]], spec: Spec, path: str) -> Episode:
    """Sample and hold every ``spec.tick_ns``; see the module docstring for the step layout."""
    tick_ns, n = spec.tick_ns, len(spec.channels)
    is_action = [c.role == ACTION for c in spec.channels]
    builder, held = _StepBuilder(), {}
    start = next_tick = None
    previous_actions: list[int] | None = None
    for log_time, index, symbol, _ in events:
        if start is None:
            start = next_tick = log_time
        if (log_time - start) // tick_ns > MAX_TICKS:
            raise InputError(f"{path}: more than {MAX_TICKS} ticks of {tick_ns} ns: the log spans "
                             f"{(log_time - start) / 1e9:.0f} s (messages at log time 0?)")
        while next_tick < log_time:
            previous_actions = _emit_tick(builder, held, n, is_action, previous_actions)
            next_tick += tick_ns
        held[index] = symbol
    if start is not None:
        _emit_tick(builder, held, n, is_action, previous_actions)
    return builder.build()


def _emit_tick(builder: _StepBuilder, held: dict[int, int], n: int, is_action: list[bool],
               previous_actions: list[int] | None) -> list[int]:
    builder.add_step(previous_actions or [], _held(held, n, is_action, False))
    return _held(held, n, is_action, True)


def episode_from_values(values: Iterable[tuple[int, int, Any]], spec: Spec, vocabulary: Vocabulary,
                        path: str = "<values>") -> Episode:
    """Serialize ``(log_time_ns, entry index, value)`` triples (see :func:`iter_field_values`)."""
    events = _symbolize(values, spec, vocabulary, path)
    if spec.mode == "tick":
        return _tick_steps(events, spec, path)
    if spec.mode == "change":
        events = _only_changes(events)
    return _event_steps(events)


def read_episodes(paths: Iterable[str | os.PathLike], spec: Spec, vocabulary: Vocabulary,
                  progress: bool = False) -> Iterator[tuple[str, Episode, ReadReport]]:
    """Read each MCAP file into one episode, in the order given.

    Args:
        paths: MCAP files; each becomes its own episode.
        spec: the channel spec (quantile bins must be fitted: :func:`fit_spec`).
        vocabulary: shared by all episodes and grown as values are first seen;
            :func:`prepare_vocabulary` is applied to it first.
        progress: show progress on stderr.

    Yields:
        ``(path, episode, report)``; the report says how many messages were read and, for
        a truncated file, where it broke (a ``TruncatedLogWarning`` is also issued).

    Raises:
        SpecError: the spec does not fit a log (names the file, entry and field).
        InputError: a file cannot be read as MCAP.
    """
    if not spec.fitted:
        raise SpecError(f"{spec.source}: quantile bins are not fitted: fit them on the training "
                        f"logs first (fit_spec)")
    prepare_vocabulary(spec, vocabulary)
    for path in paths:
        path = os.fspath(path)
        report = ReadReport(path)
        episode = episode_from_values(iter_field_values(path, spec, report, progress), spec,
                                      vocabulary, path)
        _warn_if_truncated(report)
        yield path, episode, report


def _warn_if_truncated(report: ReadReport) -> None:
    if report.truncated:
        import warnings

        from slearn.errors import TruncatedLogWarning
        warnings.warn(TruncatedLogWarning(report.describe()), stacklevel=3)


def _log_topics(path: str | os.PathLike, wanted: set[str]) -> set[str]:
    with McapLog(path) as log:
        topics = {c.topic for c in log.channels.values()}
        for message in log.iter_messages():  # channels defined inside chunks only
            if wanted <= topics:
                break
            topics.add(message.topic)
    return topics


def default_spec(paths: Iterable[str | os.PathLike]) -> Spec:
    """The spec to use when none was given: :func:`~slearn.spec.pointer_spec` for pointer logs.

    Raises:
        SpecError: the first log is not a pointer log; the message says how to get a spec.
    """
    paths = list(paths)
    wanted = {POINTER_COMMAND, POINTER_POSITION}
    if paths and wanted <= _log_topics(paths[0], wanted):
        return pointer_spec()
    raise SpecError(f"{os.fspath(paths[0]) if paths else 'no logs'}: not a pointer log, so there is "
                    f"no default spec: give --spec FILE (start from `slearn info LOG "
                    f"--suggest-spec spec.toml`) or --channel TOPIC:FIELD:ROLE")


# --- fitting ----------------------------------------------------------------------------

class _Sample:
    """A bounded, deterministic sample: every value until full, then every 2nd, 4th, ..."""

    def __init__(self) -> None:
        self.values: list[float] = []
        self.stride, self.seen = 1, 0

    def add(self, value: float) -> None:
        if self.seen % self.stride == 0:
            self.values.append(value)
            if len(self.values) >= _QUANTILE_SAMPLE:
                self.values = self.values[::2]
                self.stride *= 2
        self.seen += 1


def _fitted_edges(values: list[float], n: int) -> tuple[float, ...]:
    qs = np.quantile(np.asarray(values, dtype=np.float64), np.arange(1, n) / n)
    return tuple(float(q) for q in np.unique(qs))


def fit_spec(spec: Spec, paths: Iterable[str | os.PathLike], progress: bool = False) -> Spec:
    """Fit the edges of quantile bins on training logs; return the fitted spec.

    Entries that need no fitting are kept as they are; a spec without quantile bins is
    returned unchanged. The edges are the ``k / n`` quantiles of the entry's finite values
    over all logs (duplicates merged), from a deterministic sample of at most about a
    million values per entry.

    Raises:
        SpecError: an entry to fit got no numeric value from the logs.
    """
    todo = {i for i, c in enumerate(spec.channels) if not c.symbolizer.fitted}
    if not todo:
        return spec
    samples = {i: _Sample() for i in todo}
    damaged = []
    for path in paths:
        report = ReadReport(os.fspath(path))
        for _, index, value in iter_field_values(path, spec, report, progress):
            if index in samples:
                try:
                    x = float(value)
                except (TypeError, ValueError):
                    continue
                if np.isfinite(x):
                    samples[index].add(x)
        if report.truncated:
            damaged.append(report)
    channels = list(spec.channels)
    for i in sorted(todo):
        if not samples[i].values:
            why = f" (the log is damaged: {damaged[0].describe()})" if damaged else ""
            raise SpecError(f"{spec.source}: entry {i + 1} ({channels[i].name!r}): no numeric value "
                            f"in the training logs to fit quantile bins on{why}")
        bins: Bins = channels[i].symbolizer
        channels[i] = replace(channels[i], symbolizer=Bins(
            quantiles=bins.quantiles, edges=_fitted_edges(samples[i].values, bins.quantiles)))
    return spec.with_channels(channels)


# --- progress ---------------------------------------------------------------------------

class _Progress:
    """A one-line byte progress indicator on stderr, redrawn at most 5 times a second."""

    def __init__(self, path: str, enabled: bool) -> None:
        self.path, self.enabled = os.path.basename(path), enabled
        self.last = 0.0

    def __enter__(self) -> "_Progress":
        return self

    def update(self, done: int, total: int) -> None:
        now = time.monotonic()
        if self.enabled and (now - self.last > 0.2 or done >= total):
            self.last = now
            sys.stderr.write(f"\r{self.path}: {100 * done // max(total, 1):3d}%")
            sys.stderr.flush()

    def __exit__(self, *exc) -> None:
        if self.enabled:
            sys.stderr.write("\n")
            sys.stderr.flush()
