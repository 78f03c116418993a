"""Serialization: the messages of logs become episodes of steps of symbols.

A log (an MCAP file, a rosbag2 folder, a ROS 2 ``.db3`` or a ROS 1 ``.bag``: see
:func:`slearn.io.bags.open_log`) is one episode, or several when it marks episode
boundaries (:mod:`slearn.io.episodes`); episodes are never glued together. All episodes
share one :class:`~slearn.core.vocabulary.Vocabulary`. A :class:`~slearn.io.slicing.TimeSlice`
keeps only the messages of a window of each log's time.

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

Modes, per entry (the spec's ``mode``, or the entry's own): ``message``: every message
of the entry is an event; ``change``: an event only when the entry's symbol differs from
its previous one. ``tick`` (whole spec): ticks ``t_k = t_0 + k * tick_ns`` from the first
event; each entry's latest symbol is sampled and held. Step 0 holds the observations at
``t_0``; step ``k`` the actions held at ``t_{k-1}``, then the observations held at
``t_{k-1} + phase_ns`` (default one tick: the next tick). A warning counts the commands
paired with a reading logged before them, or after a newer command: the sampling phase
is then wrong for the log.

Values outside an entry's ``range`` are binned into its end bins and counted; a warning
per entry says how many (unless the entry has ``clip = true``).

Vocabulary: :func:`prepare_vocabulary` registers the channels in spec order, each followed
by its declared values (``values``, or every bin of bounded bins) in declared order;
other values get symbols in first-seen order.
"""

from __future__ import annotations

import os
import sys
import time
import warnings
from array import array
from collections import Counter
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, Iterable, Iterator, cast

import numpy as np

from slearn.core.stream import Episode
from slearn.core.vocabulary import ACTION, Vocabulary
from slearn.errors import DataWarning, DecodeError, FieldPathError, InputError, SpecError, TruncatedLogWarning
from slearn.io.bags import open_log
from slearn.io.decode import MISSING, DecoderCache, FieldPath, decode_payload
from slearn.io.episodes import EPISODE_TOPIC, episode_name
from slearn.io.mcap_read import ReadReport
from slearn.io.slicing import TimeSlice
from slearn.io.spec import Bins, ChannelSpec, Spec, value_labels

if TYPE_CHECKING:
    from slearn.io.ingest import Piece

MAX_TICKS = 10_000_000
_QUANTILE_SAMPLE = 1 << 20  # values kept per entry when fitting quantiles


def prepare_vocabulary(spec: Spec, vocabulary: Vocabulary) -> Vocabulary:
    """Register the spec's channels (spec order) and declared values; return ``vocabulary``."""
    for entry in spec.channels:
        vocabulary.add_channel(entry.name, entry.role)
        for value in entry.symbolizer.declared_values() or ():
            vocabulary.symbol(entry.name, value)
    vocabulary.value_labels.update(value_labels(spec))
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
                      progress: bool = False, window: TimeSlice | None = None
                      ) -> Iterator[tuple[int, int, Any]]:
    """Yield ``(log_time_ns, entry index, field value)`` for every spec entry of every message.

    Messages come in log-time order (ties in file order); entries of one message in spec
    order. Only the spec's topics are decoded; ``window`` keeps a slice of the log's time. A
    message whose payload does not decode is skipped and counted in the report (per topic),
    like a damaged chunk.

    Raises:
        SpecError: a selected channel cannot be decoded, a field does not exist, a topic is
            missing from the file, or a field never matched; the message names file and entry.
    """
    for _, *value in _iter_marked_values(path, spec, report, progress, window):
        yield tuple(value)


def _iter_marked_values(path: str | os.PathLike, spec: Spec, report: ReadReport | None,
                        progress: bool, window: TimeSlice | None) -> Iterator[tuple]:
    """``(episode markers seen, log_time_ns, entry index, value)``; see :mod:`slearn.io.episodes`."""
    path = os.fspath(path)
    by_topic = _entries_by_topic(spec)
    cache = DecoderCache()
    seen: dict[str, int] = {}
    markers = 0
    with open_log(path) as log, _Progress(path, progress) as bar:
        low, high = _window(log, window)
        for message in log.iter_messages([*by_topic, EPISODE_TOPIC], on_progress=bar.update):
            if message.topic == EPISODE_TOPIC and message.topic not in by_topic:
                markers += 1
                continue
            if not low <= message.log_time_ns < high:
                continue
            seen[message.topic] = seen.get(message.topic, 0) + 1
            obj = _decoded(message, cache, path, log.report)
            if obj is MISSING:
                continue
            for entry in by_topic[message.topic]:
                value = _field_value(obj, entry, path)
                if value is not MISSING:
                    entry.n_values += 1
                    yield markers, message.log_time_ns, entry.index, value
        if report is not None:
            vars(report).update(vars(log.report))
        _check_coverage(path, by_topic, seen, log)


def _window(log, window: TimeSlice | None) -> tuple[int, int]:
    """The log times to keep, ``[low, high)``."""
    if window is None:
        return 0, 1 << 64
    span = log.time_range()
    if span is None:
        return 0, 0
    low, high = window.window(*span)
    if high <= low:
        raise InputError(f"{log.path}: {window.describe()} leaves no time of this log (its "
                         f"messages span {(span[1] - span[0]) / 1e9:.3f} s)")
    return low, high


def _check_coverage(path: str, by_topic: dict[str, list[_Entry]], seen: dict[str, int],
                    log) -> None:
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

@dataclass
class RangeCounts:
    """Per spec entry, values seen and values outside its ``range`` (and in how many logs)."""

    values: dict[int, int] = field(default_factory=dict)
    outside: dict[int, int] = field(default_factory=dict)
    logs: dict[int, set] = field(default_factory=dict)

    def add(self, index: int, is_outside: bool, path: str) -> None:
        self.values[index] = self.values.get(index, 0) + 1
        if is_outside:
            self.outside[index] = self.outside.get(index, 0) + 1
            self.logs.setdefault(index, set()).add(path)

    def messages(self, spec: Spec) -> list[str]:
        """One warning per entry that had values outside its range."""
        out = []
        for index, n in sorted(self.outside.items()):
            entry, total = spec.channels[index], self.values[index]
            lo, hi = cast(tuple, cast(Bins, entry.symbolizer).range)  # counted only for range bins
            out.append(f"channel {entry.name!r}: {n:,} of {total:,} values ({100 * n / total:.1f} %) "
                       f"in {len(self.logs[index])} log(s) fell outside range [{lo:g}, {hi:g}] and "
                       f"were counted in the end bins, which can make predictions look better "
                       f"than they are: widen `range`, or set `clip = true` to accept this")
        return out


def _symbolize(values: Iterable[tuple[int, int, Any]], spec: Spec, vocabulary: Vocabulary,
               path: str, ranges: RangeCounts | None = None) -> Iterator[tuple[int, int, int, bool]]:
    """``(log_time_ns, entry index, symbol, is_action)`` in the documented event order."""
    entries = spec.channels
    is_action = [c.role == ACTION for c in entries]
    bounded = [isinstance(c.symbolizer, Bins) and c.symbolizer.range is not None for c in entries]
    group: list[tuple] = []
    group_time = None
    known, per_channel = len(vocabulary), Counter(channel for _, channel, _ in vocabulary.items())
    for position, (log_time, index, value) in enumerate(values):
        if bounded[index] and ranges is not None:
            ranges.add(index, cast(Bins, entries[index].symbolizer).outside(value), path)
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


def _only_changes(events: Iterable[tuple[int, int, int, bool]],
                  change: set[int]) -> Iterator[tuple[int, int, int, bool]]:
    """Drop events of the entries in ``change`` whose symbol repeats the entry's previous one."""
    last: dict[int, int] = {}
    for event in events:
        if event[1] not in change:
            yield event
        elif last.get(event[1]) != event[2]:
            last[event[1]] = event[2]
            yield event


# --- steps ------------------------------------------------------------------------------

class _StepBuilder:
    """Accumulates steps into the flat arrays of an :class:`Episode`, and each step's time
    (the log time of its observations, or of its actions when it has none)."""

    def __init__(self) -> None:
        self.symbols = array("i")
        self.offsets = array("q", [0])
        self.n_actions = array("i")
        self.times = array("q")
        self.actions = self.observations = 0
        self.open = False
        self.obs_time: int | None = None
        self.action_time: int | None = None

    def close(self) -> None:
        if self.open:
            self.offsets.append(len(self.symbols))
            self.n_actions.append(self.actions)
            self.times.append(self.obs_time if self.obs_time is not None else cast(int, self.action_time))
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

    def add_step(self, actions: list[int], observations: list[int], at_ns: int) -> None:
        self.symbols.extend(actions)
        self.symbols.extend(observations)
        self.offsets.append(len(self.symbols))
        self.n_actions.append(len(actions))
        self.times.append(at_ns)

    def build(self) -> Episode:
        if self.open:
            self.close()
            self.open = False
        return Episode(np.frombuffer(self.symbols, dtype=np.int32).copy(),
                       np.frombuffer(self.offsets, dtype=np.int64).copy(),
                       np.frombuffer(self.n_actions, dtype=np.int32).copy())

    def take(self) -> Episode:
        """The complete steps added so far, which leave the builder (tick mode, whose
        steps are complete when added)."""
        episode = self.build()
        self.symbols, self.offsets, self.n_actions = array("i"), array("q", [0]), array("i")
        self.times = array("q")
        return episode

    def step_times(self) -> np.ndarray:
        """Log time (ns) of each step built so far."""
        return np.frombuffer(self.times, dtype=np.int64).copy()


def _event_steps(events: Iterable[tuple[int, int, int, bool]], builder: _StepBuilder) -> Episode:
    for log_time, _, symbol, action in events:
        builder.add(log_time, symbol, action)
    return builder.build()


class _TickSampler:
    """Tick mode: sample and hold at alternating instants (see the module docstring).

    Instants: ``o_0 = t_0`` (step 0's observations), then ``c_{k-1} = t_{k-1}`` (capture
    the actions of step ``k``) and ``o_k = t_{k-1} + phase`` (its observations), ...
    """

    def __init__(self, spec: Spec, builder: _StepBuilder, path: str) -> None:
        self.tick: int = cast(int, spec.tick_ns)  # tick mode always has its period
        self.phase: int = spec.phase_ns or self.tick
        self.is_action = [c.role == ACTION for c in spec.channels]
        self.builder, self.path = builder, path
        self.held: dict[int, tuple[int, int]] = {}  # entry -> (symbol, log time)
        self.t0: int | None = None
        self.k, self.observe_next = 0, True
        self.actions: list[int] = []
        self.action_time = self.latest_action = -1
        self.fresh = self.mismatched = 0

    def instant(self) -> int:
        t0 = cast(int, self.t0)  # set by the first add
        if self.k == 0:
            return t0
        return t0 + (self.k - 1) * self.tick + (self.phase if self.observe_next else 0)

    def add(self, log_time: int, index: int, symbol: int) -> None:
        if self.t0 is None:
            self.t0 = log_time
        if (log_time - self.t0) // self.tick > MAX_TICKS:
            raise InputError(f"{self.path}: more than {MAX_TICKS:,} ticks of {self.tick:,} ns by "
                             f"{(log_time - self.t0) / 1e9:.6g} s into the log: use a longer tick_ms "
                             f"(or check for messages at log time 0)")
        while self.instant() < log_time:
            self.fire()
        self.held[index] = (symbol, log_time)
        if self.is_action[index]:
            self.latest_action = log_time

    def fire(self) -> None:
        if self.observe_next:
            observations = [s for i, (s, _) in sorted(self.held.items()) if not self.is_action[i]]
            self._check_pairing()
            self.builder.add_step(self.actions, observations, self.instant())
            self.k += 1
            self.observe_next = False
        else:
            self._capture()
            self.observe_next = True

    def _capture(self) -> None:
        held = [(i, s, t) for i, (s, t) in sorted(self.held.items()) if self.is_action[i]]
        self.actions = [s for _, s, _ in held]
        previous = self.instant() - self.tick
        newest = max((t for _, _, t in held), default=-1)
        self.action_time = newest if newest > previous or self.k == 1 else -1

    def _check_pairing(self) -> None:
        """Count fresh commands paired with a reading logged before them or after a newer one."""
        if self.k == 0 or self.action_time < 0:
            return
        read = max((t for i, (_, t) in self.held.items() if not self.is_action[i]), default=-1)
        self.fresh += 1
        newer = self.latest_action > self.action_time
        if read <= self.action_time or (newer and read >= self.latest_action):
            self.mismatched += 1

    def finish(self) -> Episode:
        if self.t0 is not None:
            while not self.observe_next:
                self.fire()
            self.fire()
        if self.mismatched:
            warnings.warn(DataWarning(
                f"{self.path}: tick mode: {self.mismatched:,} of {self.fresh:,} commands are paired "
                f"with a reading logged before them or after the next command (same tick): set "
                f"phase_ms to sample the observations after each tick's commands took effect"),
                stacklevel=2)
        return self.builder.build()


def _tick_steps(events: Iterable[tuple[int, int, int, bool]], spec: Spec, path: str,
                builder: _StepBuilder) -> Episode:
    """Sample and hold every ``spec.tick_ns``; see the module docstring for the step layout."""
    sampler = _TickSampler(spec, builder, path)
    for log_time, index, symbol, _ in events:
        sampler.add(log_time, index, symbol)
    return sampler.finish()


def episode_from_values(values: Iterable[tuple[int, int, Any]], spec: Spec, vocabulary: Vocabulary,
                        path: str = "<values>", ranges: RangeCounts | None = None,
                        builder: _StepBuilder | None = None) -> Episode:
    """Serialize ``(log_time_ns, entry index, value)`` triples (see :func:`iter_field_values`)."""
    builder = builder if builder is not None else _StepBuilder()
    events = _symbolize(values, spec, vocabulary, path, ranges)
    if spec.mode == "tick":
        return _tick_steps(events, spec, path, builder)
    change = {i for i in range(len(spec.channels)) if spec.channel_mode(i) == "change"}
    if change:
        events = _only_changes(events, change)
    return _event_steps(events, builder)


def _log_episodes(path: str, spec: Spec, vocabulary: Vocabulary, report: ReadReport,
                  progress: bool, window: TimeSlice | None, ranges: RangeCounts | None
                  ) -> Iterator[tuple[str, Episode, np.ndarray, bool]]:
    """``(name, episode, step times, is last)`` for each episode of one log (one, empty,
    when nothing of the log could be read)."""
    stream = _iter_marked_values(path, spec, report, progress, window)
    pending = next(stream, None)
    if pending is None:
        builder = _StepBuilder()
        episode = episode_from_values((), spec, vocabulary, path, ranges, builder)
        yield path, episode, builder.step_times(), True
    while pending is not None:
        key, first = pending[0], pending[1:]
        pending = None

        def values(first=first, key=key) -> Iterator[tuple]:  # this episode's, bound now
            nonlocal pending
            yield first
            for item in stream:
                if item[0] != key:
                    pending = item
                    return
                yield item[1:]

        builder = _StepBuilder()
        episode = episode_from_values(values(), spec, vocabulary, path, ranges, builder)
        yield episode_name(path, key - 1 if key else None), episode, builder.step_times(), pending is None


def read_episodes(paths: Iterable[str | os.PathLike], spec: Spec, vocabulary: Vocabulary,
                  progress: bool = False, window: TimeSlice | dict[str, TimeSlice] | None = None
                  ) -> Iterator[tuple[str, Episode, ReadReport]]:
    """Read each log into its episodes, in the order given.

    Args:
        paths: logs (MCAP, rosbag2 folder, ``.db3``, ``.bag``); each is one episode, or
            several when it marks episode boundaries (:mod:`slearn.io.episodes`).
        spec: the channel spec (quantile bins must be fitted: :func:`fit_spec`).
        vocabulary: shared by all episodes and grown as values are first seen;
            :func:`prepare_vocabulary` is applied to it first.
        progress: show progress on stderr.
        window: the slice of each log's time to read (one for all, or per path).

    Yields:
        ``(name, episode, report)``: the name is the log's path (``LOG#k`` for episode
        ``k`` of a log with boundaries); the report of a log's last episode says how many
        messages were read and, for a truncated file, where it broke (a
        ``TruncatedLogWarning`` is also issued).

    Values outside an entry's ``range`` give one :class:`~slearn.errors.DataWarning` per
    entry at the end (see the module docstring). Each episode is held whole:
    :func:`read_pieces` streams them in bounded memory.

    Raises:
        SpecError: the spec does not fit a log (names the file, entry and field).
        InputError: a file cannot be read as a log.
    """
    parts: list[Episode] = []
    for name, piece, report, _, last in read_pieces(paths, spec, vocabulary, progress, window):
        parts.append(piece)
        if last:
            yield name, joined(parts), report
            parts = []


def joined(parts: list[Episode]) -> Episode:
    """The consecutive pieces of one episode as the episode."""
    if len(parts) == 1:
        return parts[0]
    sizes = np.concatenate([np.diff(p.step_offsets) for p in parts])
    return Episode(np.concatenate([p.symbols for p in parts]),
                   np.concatenate(([0], np.cumsum(sizes))).astype(np.int64),
                   np.concatenate([p.n_actions for p in parts]))


def read_pieces(paths: Iterable[str | os.PathLike], spec: Spec, vocabulary: Vocabulary,
                progress: bool = False, window: TimeSlice | dict[str, TimeSlice] | None = None,
                piece_events: int | None = None) -> Iterator[tuple[str, Episode, ReadReport, bool, bool]]:
    """:func:`read_episodes` in bounded memory: ``(name, piece, report, first, last)``, each
    episode as consecutive pieces of complete steps (``first`` and ``last`` mark its ends;
    the report is the log's on the last piece of its last episode). Learning the pieces
    in order, each after the previous one of its episode, is learning the episode. A piece
    leaves when it holds ``piece_events`` events (default :data:`slearn.io.ingest.PIECE_EVENTS`)
    or its episode ends."""
    if not spec.fitted:
        raise SpecError(f"{spec.source}: quantile bins are not fitted: fit them on the training "
                        f"logs first (fit_spec)")
    from slearn.io.ingest import iter_pieces

    prepare_vocabulary(spec, vocabulary)
    ranges = RangeCounts()
    for path in paths:
        path = os.fspath(path)
        report = ReadReport(path)
        log_window = window.get(path) if isinstance(window, dict) else window
        pending = None
        for piece in iter_pieces(path, spec, vocabulary, report, progress, log_window, ranges,
                                 piece_events=piece_events):
            if pending is not None:
                yield pending.name, pending.episode, ReadReport(path), pending.first, pending.last
            pending = piece
        _warn_if_truncated(report)
        last = cast("Piece", pending)  # every log yields a piece, an empty one at least
        yield last.name, last.episode, report, last.first, last.last
    for message in ranges.messages(spec):
        warnings.warn(DataWarning(message), stacklevel=2)


def iter_step_times(path: str | os.PathLike, spec: Spec, vocabulary: Vocabulary,
                    window: TimeSlice | None = None) -> Iterator[tuple[str, np.ndarray]]:
    """``(episode name, log time of each step)`` for the episodes :func:`read_episodes`
    makes of ``path`` (``vocabulary`` is not changed)."""
    import copy

    vocabulary = copy.deepcopy(vocabulary)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # already reported when the log was read
        for name, _, times, _ in _log_episodes(os.fspath(path), spec, vocabulary, ReadReport(os.fspath(path)),
                                               False, window, None):
            yield name, times


def _warn_if_truncated(report: ReadReport) -> None:
    if report.truncated:
        warnings.warn(TruncatedLogWarning(report.describe()), stacklevel=3)


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


def fit_spec(spec: Spec, paths: Iterable[str | os.PathLike], progress: bool = False,
             window: TimeSlice | None = None) -> Spec:
    """Fit the edges of quantile bins on training logs; return the fitted spec.

    Entries that need no fitting are kept as they are; a spec without quantile bins is
    returned unchanged. The edges are the ``k / n`` quantiles of the entry's finite values
    over all logs (duplicates merged; only ``window`` of each log's time when given), from
    a deterministic sample of at most about a million values per entry.

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
        for _, index, value in iter_field_values(path, spec, report, progress, window):
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
        bins = cast(Bins, channels[i].symbolizer)  # an entry to fit has quantile bins
        channels[i] = replace(channels[i], symbolizer=Bins(
            quantiles=bins.quantiles, edges=_fitted_edges(samples[i].values, bins.quantiles or 0)))
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
