"""One-pass streaming ingest: message batches in, pieces of episodes out.

Messages come from the reader a block at a time (:meth:`slearn.io.mcap_read.McapLog.iter_batches`);
each batch is decoded (JSON as one array per batch, ROS 2 CDR reading only the spec's
fields: :mod:`slearn.io.cdr`), its field values are symbolized per entry with numpy, ordered, and cut
into steps with numpy. Only the steps not yet complete (the last log time, the open step)
are carried to the next batch, so memory does not grow with the log: an episode leaves as
pieces of complete steps, and learning a piece after the previous one
(``PatternLibrary.learn(piece, new_episode=False)``) gives the library of learning the
whole episode at once.

The events, steps and vocabulary are exactly those of the per-message path in
:mod:`slearn.io.serialize` (documented there); tests compare the two.
"""

from __future__ import annotations

import json
import os
from collections import Counter
from dataclasses import dataclass
from itertools import chain, repeat
from operator import is_, itemgetter
from typing import TYPE_CHECKING, Any, Callable, Iterator, cast

import numpy as np

from slearn.core.stream import Episode
from slearn.core.vocabulary import ACTION, Vocabulary
from slearn.errors import SpecError
from slearn.io import cdr
from slearn.io.decode import MISSING, DecodeError, DecoderCache, decode_payload
from slearn.io.mcap_read import MessageBatch, ReadReport, iter_batches_of
from slearn.io.spec import Bins, Spec

if TYPE_CHECKING:
    from slearn.io.serialize import _TickSampler

PIECE_EVENTS = 1 << 18  # events of complete steps gathered before a piece leaves
BATCH_MESSAGES = 1 << 16  # messages decoded at once
_NO_SYMBOL = -1
_NO_BIN = np.iinfo(np.int64).min
_UNSEEN = object()
_GATHER_BYTES = 1 << 20  # payload bytes of a channel's batch joined with numpy (beyond: by slices)
_PLAIN_KEYS = frozenset((str, int))    # values that are their own keys
_PLAIN_NUMBERS = frozenset((int, float))  # values binned as one array


@dataclass
class Piece:
    """A run of complete steps of one episode of one log."""

    name: str
    episode: Episode
    first: bool
    last: bool


# --- decoding a batch ---------------------------------------------------------------------

_SCAN = json.decoder.JSONDecoder().scan_once  # type: ignore[attr-defined]  # the C scanner json uses
_SPACE = json.decoder.WHITESPACE.match  # type: ignore[attr-defined]


def _json(data: bytes) -> Any:
    """``json.loads(data)`` through the C scanner directly (the same value, or its error)."""
    if data and data[0] not in (0, 0xEF, 0xFE, 0xFF) and (len(data) < 2 or data[1]):
        try:
            text = data.decode("utf-8", "surrogatepass")
            obj, end = _SCAN(text, _SPACE(text, 0).end())
            if _SPACE(text, end).end() == len(text):
                return obj
        except (StopIteration, ValueError, RecursionError):
            pass
    return json.loads(data)  # what json.loads makes of it, error included


_VALUE_START = np.zeros(256, bool)
_VALUE_START[list(b'{["-0123456789tfnNI')] = True  # a JSON value starts with one of these
_VALUE_END = np.zeros(256, bool)
_VALUE_END[list(b'}]"0123456789elyN')] = True  # and ends with one of these


def _joined(batch: MessageBatch, on: np.ndarray) -> tuple[bytes, np.ndarray]:
    """The payloads of messages ``on`` of ``batch`` joined with commas, and their sizes:
    gathered with numpy (one bytes object, not one per message) unless they are large."""
    starts = batch.starts[on]
    sizes = batch.ends[on] - starts
    total = int(sizes.sum())
    if total > _GATHER_BYTES or not sizes.all() or not len(sizes):
        return b",".join(_payloads(batch, on)), sizes
    message = np.repeat(np.arange(len(sizes)), sizes)  # the message of each payload byte
    at = np.arange(total)
    joined = np.full(total + len(sizes) - 1, ord(","), np.uint8)
    joined[at + message] = np.frombuffer(batch.buf, np.uint8)[(starts - (np.cumsum(sizes) - sizes))[message] + at]
    return joined.tobytes(), sizes


def _json_joined(joined: bytes, sizes: np.ndarray) -> list | None:
    """Every payload of ``sizes`` bytes in ``joined`` (their bytes joined with commas) parsed
    as :func:`json.loads` parses it, by one parse of the JSON array of them all; ``None``
    when some payload needs a closer look (not ASCII, empty, or the array would not split
    where the payloads do).

    The array ``[p1,p2,...]`` parses to the payloads' own values exactly when it has one
    element per payload and every comma put between payloads lies at the array's top
    level, outside strings (then each payload is one whole value; a value parses alike
    alone or in an array). Both are checked, the second with numpy over the bytes, unless
    the payloads have no comma of their own: then the array's elements are one more than
    its top-level commas, all of them put between payloads, and one element per payload
    means every one of those is at the top level.
    """
    if not len(sizes):
        return []
    if not joined.isascii() or not sizes.all():
        return None
    commas = np.cumsum(sizes + 1)[:-1] - 1  # where the commas put between payloads are
    raw = np.frombuffer(joined, np.uint8)
    starts = np.concatenate(([0], commas + 1))
    if not (_VALUE_START[raw[starts]].all() and _VALUE_END[raw[starts + sizes - 1]].all()):
        return None
    if len(commas) and joined.count(b",") != len(commas) and not _top_level(raw, commas):
        return None
    try:
        values = json.loads(b"[" + joined + b"]")
    except (ValueError, RecursionError):
        return None
    return values if len(values) == len(sizes) else None


def _top_level(raw: np.ndarray, commas: np.ndarray) -> bool:
    """Whether the bytes before each of ``commas`` close every string and bracket they open."""
    index = np.arange(len(raw))
    quote = raw == ord('"')
    if quote.any():
        not_slash = np.maximum.accumulate(np.where(raw != ord("\\"), index, -1))
        at = np.flatnonzero(quote)
        run = np.where(at > 0, at - 1 - not_slash[np.maximum(at - 1, 0)], 0)
        quote[at[run % 2 == 1]] = False  # escaped quotes
    in_string = (np.cumsum(quote) % 2).astype(bool) | quote
    if in_string[commas].any():
        return False
    step = np.zeros(len(raw), np.int64)
    step[(raw == ord("[")) | (raw == ord("{"))] = 1
    step[(raw == ord("]")) | (raw == ord("}"))] = -1
    step[in_string] = 0
    return not np.cumsum(step)[commas].any()


class _ChannelReader:
    """Field values of one channel's payloads, one list per spec entry of its topic."""

    def __init__(self, channel, entries: list, cache: DecoderCache, path: str) -> None:
        self.channel, self.entries, self.path = channel, entries, path
        try:
            self.decoder = cache.require(channel)
        except DecodeError as err:
            raise SpecError(f"{path}: the spec selects topic {channel.topic!r}, but {err}") from err
        self.plan: cdr.FieldPlan | None = None
        if "_rosbags_cdr_decoder" in getattr(self.decoder, "__qualname__", ""):
            self.plan = cdr.field_plan(channel, [e.spec.field for e in entries])
        if self.decoder is json.loads:
            self.decoder = _json
        json_objects = self.plan is None and self.decoder is _json
        self.getters = [_getter(e.path) if json_objects else _never for e in entries]

    def values(self, batch: MessageBatch, on: np.ndarray, report: ReadReport) -> list[list]:
        """Per entry, the value of each of messages ``on`` of ``batch`` (:data:`MISSING` when
        it has none or does not decode; undecodable payloads are counted in ``report``)."""
        if self.plan is not None:
            return self._plan_values(batch, on, report)
        objs = _json_joined(*_joined(batch, on)) if self.decoder is _json else None
        if objs is None:
            objs = [self._decode(data, offset, report)
                    for data, offset in zip(_payloads(batch, on), _where(batch, on, report))]
        return [self._field(get, entry, objs) for get, entry in zip(self.getters, self.entries)]

    def _plan_values(self, batch: MessageBatch, on: np.ndarray, report: ReadReport) -> list[list]:
        """:meth:`values` through the CDR plan: the payloads laid out as the first one is as
        columns (``FieldPlan.many``), the others one by one."""
        plan = cast(cdr.FieldPlan, self.plan)
        columns, alike = plan.many(batch.buf, batch.starts[on], batch.ends[on])
        if alike.all():
            return columns
        rest = on[~alike]
        rows = [self._plan_row(data, offset, report)
                for data, offset in zip(_payloads(batch, rest), _where(batch, rest, report))]
        order = np.argsort(np.concatenate((np.flatnonzero(alike), np.flatnonzero(~alike))))  # back in message order
        return [_taken(column + [row[k] for row in rows], order) for k, column in enumerate(columns)]

    def _plan_row(self, data: bytes, offset: int, report: ReadReport) -> list:
        try:
            return cast(cdr.FieldPlan, self.plan)(data)  # rows are read only with a plan
        except cdr.CdrError:  # the full decoder gives its own verdict
            from slearn.io.serialize import _field_value

            obj = self._decode(data, offset, report)
            return [MISSING if obj is MISSING else _field_value(obj, entry, self.path)
                    for entry in self.entries]

    def _decode(self, data: bytes, offset: int, report: ReadReport) -> Any:
        try:
            return decode_payload(self.decoder, self.channel, data)
        except DecodeError as err:
            if offset >= 0:
                report.note_undecodable(self.channel.topic, offset, str(err))
            else:  # the -n-th message read (see _where)
                read, report.n_messages = report.n_messages, -offset
                report.note_undecodable(self.channel.topic, -1, str(err))
                report.n_messages = read
            return MISSING

    def _field(self, get: Callable, entry, objs: list) -> list:
        from slearn.io.serialize import _field_value

        try:
            return get(objs)  # MISSING (undecodable) has no items: falls back below
        except (KeyError, TypeError, IndexError):
            return [MISSING if obj is MISSING else _field_value(obj, entry, self.path) for obj in objs]


def _never(objs: list) -> list:
    raise TypeError  # no fast reader: FieldPath.get reads every message


def _getter(path) -> Callable[[list], list]:
    """A fast reader of a field path made of names only over JSON objects (plain dicts,
    lists, strings and numbers); any miss raises, and the caller falls back to
    :meth:`FieldPath.get`, which says what is wrong."""
    names = [args[0] for kind, *args in path.steps if kind == "attr"]
    if len(names) != len(path.steps) or not names:
        return _never
    get = itemgetter(names[0])
    if len(names) == 1:
        return lambda objs: list(map(get, objs))
    gets = [itemgetter(name) for name in names]

    def get_nested(objs: list) -> list:
        for get in gets:
            objs = list(map(get, objs))
        return objs
    return get_nested


# --- symbols ------------------------------------------------------------------------------

class _Symbols:
    """Symbolizes the values of a batch per entry; new symbols are registered in value order
    (as the per-message path does), so the vocabulary comes out the same."""

    def __init__(self, spec: Spec, vocabulary: Vocabulary, path: str, ranges) -> None:
        self.spec, self.vocabulary, self.path, self.ranges = spec, vocabulary, path, ranges
        self.known: list[dict] = [{} for _ in spec.channels]  # per entry: value -> symbol
        self.per_channel = Counter(channel for _, channel, _ in vocabulary.items())
        self.n_known = len(vocabulary)
        self.bounded = [isinstance(c.symbolizer, Bins) and c.symbolizer.range is not None
                        for c in spec.channels]

    def symbols(self, entries: np.ndarray, values: list) -> np.ndarray:
        """Symbol of each value (``-1`` when the value gives none)."""
        out = np.full(len(values), _NO_SYMBOL, np.int64)
        new: list[tuple[int, int, Any]] = []  # (position, entry, value) never seen
        keyed = {}
        indexes = np.unique(entries).tolist()
        for index in indexes:
            where = np.flatnonzero(entries == index)
            keyed[index] = where, self._keys(index, values if len(indexes) == 1 else _taken(values, where))
            self._map(index, *keyed[index], out, new)
        new.sort(key=lambda item: item[0])
        for _, index, key in new:
            self._register(index, key)
        for index in {index for _, index, _ in new}:  # every value of the entry is known now
            self._map(index, *keyed[index], out, [])
        return out

    def _map(self, index: int, where: np.ndarray, keys, out: np.ndarray, new: list) -> None:
        if isinstance(keys, np.ndarray):
            self._bin_symbols(index, where, keys, out, new)
        else:
            self._value_symbols(index, where, keys, out, new)

    def _value_symbols(self, index: int, where: np.ndarray, keys: list, out: np.ndarray,
                       new: list) -> None:
        get = self.known[index].get
        try:
            found = list(map(get, keys, repeat(_UNSEEN)))  # (no value, a None key, is never known)
        except TypeError:
            self._unhashable(index)
        if _UNSEEN not in found:  # every value seen before: the common case, without a loop
            out[where] = found
            return
        found = [None if key is None else get(key, _UNSEEN) for key in keys]
        unseen = {}
        for i, key, symbol in zip(where.tolist(), keys, found):
            if symbol is _UNSEEN and key not in unseen:
                unseen[key] = i
                new.append((i, index, key))
        symbols = np.fromiter((s if type(s) is int else _NO_SYMBOL for s in found),  # noqa: E721
                              np.int64, len(found))
        out[where] = symbols

    def _bin_symbols(self, index: int, where: np.ndarray, bins: np.ndarray, out: np.ndarray,
                     new: list) -> None:
        """Bin indexes (``-2**63`` where no bin) to symbols, by each distinct bin once."""
        ok = bins != _NO_BIN
        unique, first, inverse = np.unique(bins[ok], return_index=True, return_inverse=True)
        known = self.known[index]
        lut = np.empty(len(unique), np.int64)
        at = where[ok]
        for u, (b, f) in enumerate(zip(unique.tolist(), first.tolist())):
            symbol = known.get(b)
            if symbol is None:
                new.append((int(at[f]), index, b))
                symbol = _NO_SYMBOL  # set when registered
            lut[u] = symbol
        out[at] = lut[inverse.reshape(-1)]

    def _keys(self, index: int, vals: list):
        symbolizer = self.spec.channels[index].symbolizer
        if isinstance(symbolizer, Bins):
            return _bin_keys(symbolizer, vals, self, index)
        if set(map(type, vals)) <= _PLAIN_KEYS:
            return vals
        return [symbolizer.symbol_value(v) for v in vals]

    def count_range(self, index: int, n_values: int, n_outside: int) -> None:
        """Range counts of :class:`~slearn.io.serialize.RangeCounts` for a bounded entry."""
        if not self.bounded[index] or self.ranges is None:
            return
        ranges = self.ranges
        ranges.values[index] = ranges.values.get(index, 0) + n_values
        if n_outside:
            ranges.outside[index] = ranges.outside.get(index, 0) + n_outside
            ranges.logs.setdefault(index, set()).add(self.path)

    def _register(self, index: int, key: Any) -> int:
        from slearn.io.serialize import _check_symbols

        entry = self.spec.channels[index]
        known = self.known[index]
        if key in known:
            return known[key]
        symbol = self.vocabulary.symbol(entry.name, key)
        if symbol >= self.n_known:
            self.n_known += 1
            _check_symbols(self.per_channel, entry, self.path)
        known[key] = symbol
        return symbol

    def _unhashable(self, index: int):
        entry = self.spec.channels[index]
        raise SpecError(f"{self.path}: spec entry {index + 1} ({entry.name!r}): field "
                        f"{entry.field!r} is a message, not a value; pick a field inside it "
                        f"(see `slearn info`)")


def _bin_keys(bins: Bins, vals: list, symbols: _Symbols, index: int) -> np.ndarray | list:
    """Bin indexes as :meth:`Bins.symbol_value` gives them: an array (``_NO_BIN`` where no
    bin) for plain numbers, else a list (``None`` where no bin); range counts are added to
    ``symbols``."""
    if not vals:
        return []
    x = None
    if set(map(type, vals)) <= _PLAIN_NUMBERS:
        try:
            x = np.array(vals, dtype=np.float64)
        except OverflowError:  # an int too large for a float: value by value below
            x = None
    if x is None:
        symbols.count_range(index, len(vals), sum(bins.outside(v) for v in vals))
        return [bins.symbol_value(v) for v in vals]
    finite = np.isfinite(x)
    if symbols.bounded[index]:
        outside = 0
        if bins.quantiles is None and not bins.wrap and not bins.clip and bins.range is not None:
            lo, hi = bins.range
            outside = int(np.count_nonzero(finite & ((x < lo) | (x > hi))))
        symbols.count_range(index, len(vals), outside)
    if bins.wrap and bins.range is not None:
        lo, hi = bins.range
        x = lo + np.remainder(x - lo, hi - lo)
    if bins.width is not None:
        q = (x - bins.origin) / bins.width
        ok = finite & (np.abs(q) < float(1 << 53))
        k = np.floor(np.where(ok, q, 0.0)).astype(np.int64)
    else:
        ok = finite
        k = np.searchsorted(np.asarray(bins._cuts, np.float64), x, side="right").astype(np.int64)
    return np.where(ok, k, _NO_BIN)


# --- events and steps ---------------------------------------------------------------------

@dataclass
class _Events:
    """Events as arrays: log time, whether an action, entry index, position among the
    episode's values, symbol."""

    time: np.ndarray
    action: np.ndarray
    entry: np.ndarray
    position: np.ndarray
    symbol: np.ndarray

    def take(self, where) -> "_Events":
        return _Events(self.time[where], self.action[where], self.entry[where],
                       self.position[where], self.symbol[where])

    def __len__(self) -> int:
        return len(self.time)

    @staticmethod
    def join(a: "_Events", b: "_Events") -> "_Events":
        return _Events(*(np.concatenate((x, y)) for x, y in zip(
            (a.time, a.action, a.entry, a.position, a.symbol),
            (b.time, b.action, b.entry, b.position, b.symbol))))


def _no_events() -> _Events:
    return _Events(np.zeros(0, np.uint64), np.zeros(0, bool), np.zeros(0, np.int64),
                   np.zeros(0, np.int64), np.zeros(0, np.int64))


class _EpisodeStream:
    """One episode: values in, pieces of complete steps out (see the module docstring)."""

    def __init__(self, name: str, spec: Spec, symbols: _Symbols, emit: Callable[[Piece], None],
                 piece_events: int | None = None) -> None:
        self.name, self.spec, self.symbols, self.emit = name, spec, symbols, emit
        self.piece_events = piece_events or PIECE_EVENTS
        self.key = 0  # the episode marker it follows (0: none)
        self.is_action = np.array([c.role == ACTION for c in spec.channels], bool)
        self.change = [] if spec.mode == "tick" else [
            i for i in range(len(spec.channels)) if spec.channel_mode(i) == "change"]
        self.last_symbol = {i: _NO_SYMBOL for i in self.change}
        self.n_values = 0
        self.run = _no_events()       # the events of the last log time, not yet ordered
        self.open = _no_events()      # the events of the open step
        self.done: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # complete steps
        self.done_events = 0
        self.first = True
        self.sampler = None
        if spec.mode == "tick":
            from slearn.io.serialize import _StepBuilder, _TickSampler

            self.builder = _StepBuilder()
            self.sampler = _TickSampler(spec, self.builder, name)

    def add(self, times: np.ndarray, entries: np.ndarray, values: list) -> None:
        """Values in the order of :func:`slearn.io.serialize.iter_field_values`."""
        self.add_symbols(times, entries, self.symbols.symbols(entries, values))

    def add_symbols(self, times: np.ndarray, entries: np.ndarray, symbol: np.ndarray) -> None:
        """Symbols of values (``-1``: the value gives none) in the order of :meth:`add`."""
        position = self.n_values + np.arange(len(symbol), dtype=np.int64)
        self.n_values += len(symbol)
        keep = symbol != _NO_SYMBOL
        events = _Events(times[keep], self.is_action[entries[keep]], entries[keep], position[keep],
                         symbol[keep])
        events = _Events.join(self.run, events)
        if not len(events):
            return
        t = events.time
        run = np.concatenate(([0], np.cumsum(t[1:] != t[:-1])))
        order = np.lexsort((events.position, events.entry, events.action, run))  # observations first
        ready = int(np.searchsorted(run, run[-1], "left"))
        self.run = events.take(slice(ready, None))
        self._ordered(events.take(order[:ready]))

    def _ordered(self, events: _Events) -> None:
        for index in self.change:
            where = np.flatnonzero(events.entry == index)
            if not len(where):
                continue
            s = events.symbol[where]
            previous = np.concatenate(([self.last_symbol[index]], s[:-1]))
            self.last_symbol[index] = int(s[-1])
            drop = where[s == previous]
            if len(drop):
                events = events.take(np.setdiff1d(np.arange(len(events)), drop))
        if self.sampler is not None:
            self._sample(events)
        else:
            self._steps(events)

    def _sample(self, events: _Events) -> None:
        add = cast("_TickSampler", self.sampler).add  # tick mode
        for t, index, symbol in zip(events.time.tolist(), events.entry.tolist(), events.symbol.tolist()):
            add(t, index, symbol)
        self._take_builder(final=False)

    def _take_builder(self, final: bool) -> None:
        builder = self.builder
        if final or len(builder.symbols) >= self.piece_events:
            episode = cast("_TickSampler", self.sampler).finish() if final else builder.take()
            self.done.append((episode.symbols, np.diff(episode.step_offsets), episode.n_actions))
            self.done_events += episode.n_events
            self._flush(final)

    def _steps(self, events: _Events) -> None:
        events = _Events.join(self.open, events)
        if not len(events):
            return
        t, a = events.time, events.action
        new = np.ones(len(t), bool)
        same = t[1:] == t[:-1]
        new[1:] = np.where(a[1:], ~a[:-1] | ~same, ~a[:-1] & ~same)
        starts = np.flatnonzero(new)
        last = int(starts[-1])
        self.open = events.take(slice(last, None))
        if last:
            sizes = np.diff(starts)
            n_actions = np.add.reduceat(a[:last].astype(np.int32), starts[:-1])
            self.done.append((events.symbol[:last].astype(np.int32), sizes, n_actions))
            self.done_events += last
            self._flush(False)

    def _flush(self, final: bool) -> None:
        if not final and self.done_events < self.piece_events:
            return
        symbols = np.concatenate([d[0] for d in self.done] or [np.zeros(0, np.int32)])
        sizes = np.concatenate([d[1] for d in self.done] or [np.zeros(0, np.int64)])
        n_actions = np.concatenate([d[2] for d in self.done] or [np.zeros(0, np.int32)])
        offsets = np.concatenate(([0], np.cumsum(sizes))).astype(np.int64)
        self.done, self.done_events = [], 0
        self.emit(Piece(self.name, Episode(symbols.astype(np.int32), offsets,
                                           n_actions.astype(np.int32)), self.first, final))
        self.first = False

    def finish(self) -> None:
        """Order the last log time, close the open step, emit the last piece."""
        run = self.run
        self.run = _no_events()
        if len(run):
            order = np.lexsort((run.position, run.entry, run.action))
            self._ordered(run.take(order))
        if self.sampler is not None:
            self._take_builder(final=True)
            return
        if len(self.open):
            a = self.open.action
            self.done.append((self.open.symbol.astype(np.int32), np.array([len(a)], np.int64),
                              np.array([int(a.sum())], np.int32)))
            self.open = _no_events()
        self._flush(True)


# --- a log --------------------------------------------------------------------------------

def _batches(log, topics: list[str], on_progress) -> Iterator[MessageBatch]:
    """The log's messages in batches of at most :data:`BATCH_MESSAGES` (a chunk of
    millions of messages is decoded a part at a time)."""
    if not hasattr(log, "iter_batches"):
        yield from iter_batches_of(log.iter_messages(topics, on_progress=on_progress))
        return
    for batch in log.iter_batches(topics, on_progress=on_progress):
        if len(batch) <= BATCH_MESSAGES:
            yield batch
            continue
        for start in range(0, len(batch), BATCH_MESSAGES):
            part = slice(start, start + BATCH_MESSAGES)
            yield MessageBatch(batch.buf, batch.channel_ids[part], batch.log_times[part],
                               batch.starts[part], batch.ends[part], batch.offsets[part],
                               batch.channels)


class _LogReader:
    """The value batches of one log, cut into episodes at the episode markers."""

    def __init__(self, path: str, spec: Spec, vocabulary: Vocabulary, ranges,
                 emit: Callable[[Piece], None], new_stream=None, piece_events: int | None = None) -> None:
        from slearn.io.serialize import _entries_by_topic

        self.path, self.spec, self.emit = path, spec, emit
        self.symbols = _Symbols(spec, vocabulary, path, ranges)
        self.new_stream = new_stream or (lambda name: _EpisodeStream(name, spec, self.symbols, emit, piece_events))
        self.by_topic = _entries_by_topic(spec)
        self.cache = DecoderCache()
        self.readers: dict[int, _ChannelReader] = {}
        self.seen: dict[str, int] = {}
        self.markers = 0
        self.stream: _EpisodeStream | None = None

    def read(self, log, low: int, high: int, on_progress) -> Iterator[None]:
        """Read the log, pausing after each batch (so that pieces can leave)."""
        from slearn.io.episodes import EPISODE_TOPIC

        for batch in _batches(log, [*self.by_topic, EPISODE_TOPIC], on_progress):
            topics = {cid: batch.channels[cid].topic for cid in np.unique(batch.channel_ids).tolist()}
            marker = np.zeros(len(batch), bool)
            if EPISODE_TOPIC in topics.values() and EPISODE_TOPIC not in self.by_topic:
                marker = np.isin(batch.channel_ids, [c for c, t in topics.items() if t == EPISODE_TOPIC])
            times = batch.log_times
            inside = ~marker
            if (low, high) != (0, 1 << 64):
                inside &= (times >= np.uint64(low)) & (times < np.uint64(min(high, (1 << 64) - 1)))
            for start, stop, markers in _segments(marker):
                self._segment(batch, topics, inside, start, stop, self.markers + markers, log.report)
            self.markers += int(marker.sum())
            yield None

    def _segment(self, batch: MessageBatch, topics: dict, inside: np.ndarray, start: int, stop: int,
                 key: int, report: ReadReport) -> None:
        idx = np.arange(start, stop)[inside[start:stop]]
        if not len(idx):
            return
        cids = batch.channel_ids[idx]
        parts_pos, parts_entry, parts_values = [], [], []
        for cid in np.unique(cids).tolist():
            topic = topics[cid]
            on = idx[cids == cid]
            self.seen[topic] = self.seen.get(topic, 0) + len(on)
            reader = self._reader(batch.channels[cid])
            per_entry = reader.values(batch, on, report)
            for entry, values in zip(reader.entries, per_entry):
                if any(map(is_, values, repeat(MISSING))):
                    got = [i for i, v in enumerate(values) if v is not MISSING]
                    parts_pos.append(on[got])
                    values = [values[i] for i in got]
                else:  # a value in every message: the common case, without a loop
                    parts_pos.append(on)
                entry.n_values += len(values)
                parts_entry.append(np.full(len(values), entry.index, np.int64))
                parts_values.append(values)
        if not sum(len(p) for p in parts_pos):
            return
        stream = self._episode(key)
        pos, entries = np.concatenate(parts_pos), np.concatenate(parts_entry)
        if len(parts_values) == 1:  # one entry's values, in message order already
            stream.add(batch.log_times[pos], entries, parts_values[0])
            return
        order = np.lexsort((entries, pos))  # message order, then spec order
        stream.add(batch.log_times[pos[order]], entries[order], _taken(list(chain.from_iterable(parts_values)), order))

    def _reader(self, channel) -> _ChannelReader:
        reader = self.readers.get(channel.id)
        if reader is None or reader.channel is not channel:
            reader = self.readers[channel.id] = _ChannelReader(
                channel, self.by_topic[channel.topic], self.cache, self.path)
        return reader

    def _episode(self, key: int) -> _EpisodeStream:
        """The stream of the episode after marker ``key``, the previous one finished."""
        from slearn.io.episodes import episode_name

        if self.stream is not None and self.stream.key == key:
            return self.stream
        if self.stream is not None:
            self.stream.finish()
        stream = self.stream = self.new_stream(episode_name(self.path, key - 1 if key else None))
        stream.key = key
        return stream

    def finish(self) -> None:
        """The last episode's last piece (an empty episode when nothing was read)."""
        if self.stream is None:
            self.stream = self.new_stream(self.path)
            self.stream.key = 0
        self.stream.finish()


def _payloads(batch: MessageBatch, on: np.ndarray) -> list[bytes]:
    """The payloads of messages ``on`` of ``batch``, one bytes object each."""
    return [batch.buf[a:b] for a, b in zip(batch.starts[on].tolist(), batch.ends[on].tolist())]


def _taken(values: list, at: np.ndarray) -> list:
    """``[values[i] for i in at]``, without a Python loop."""
    if len(at) < 2:
        return [values[i] for i in at.tolist()]
    return list(itemgetter(*at.tolist())(values))


def _where(batch: MessageBatch, on: np.ndarray, report: ReadReport) -> list[int]:
    """Byte offsets of messages ``on``; where a log cannot tell them, ``-n`` for the
    ``n``-th message read (so an undecodable one is named as the per-message path names it)."""
    offsets = batch.offsets[on]
    if (offsets >= 0).all():
        return offsets.tolist()
    numbers = report.n_messages - len(batch) + on + 1
    return np.where(offsets >= 0, offsets, -numbers).tolist()


def _segments(marker: np.ndarray) -> Iterator[tuple[int, int, int]]:
    """``(start, stop, markers before start)`` of the runs between marker messages."""
    cuts = np.flatnonzero(marker).tolist()
    start = 0
    for k, cut in enumerate(cuts):
        if cut > start:
            yield start, cut, k
        start = cut + 1
    if start < len(marker):
        yield start, len(marker), len(cuts)


def iter_pieces(path: str | os.PathLike, spec: Spec, vocabulary: Vocabulary, report: ReadReport,
                progress: bool = False, window=None, ranges=None, new_stream=None,
                piece_events: int | None = None) -> Iterator[Piece]:
    """The pieces of the episodes of one log, in order (see the module docstring);
    ``report`` receives the read report. ``new_stream(name)`` makes what each episode's
    values go to (default: an episode stream that emits the pieces)."""
    from slearn.io.bags import open_log
    from slearn.io.serialize import _check_coverage, _Progress, _window

    path = os.fspath(path)
    pieces: list[Piece] = []
    reader = _LogReader(path, spec, vocabulary, ranges, pieces.append, new_stream, piece_events)
    with open_log(path) as log, _Progress(path, progress) as bar:
        low, high = _window(log, window)
        for _ in reader.read(log, low, high, bar.update):
            yield from pieces
            pieces.clear()
        reader.finish()
        vars(report).update(vars(log.report))
        _check_coverage(path, reader.by_topic, reader.seen, log)
    yield from pieces

