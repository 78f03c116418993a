"""Reading logs on Ray, so that learning and replaying many logs give one process's bytes.

Reading is most of the cost of learning (decoding and binning every message: on the
pointer logs about 60 % of ``slearn learn``'s time, 95 % of a frozen replay's), and it
depends on nothing but the log. So ``--workers N`` / ``--ray ADDRESS`` read the logs in
Ray tasks, many at once, and the driver learns (or scores) their episodes in the order a
one-process run takes them. The library, its scoring state included, and the replay
report are then those of one process by construction (``tests/test_ray.py`` compares
the bytes).

A task reads one log with its own vocabulary and streams its episodes back as they are
read, in the pieces of complete steps one process learns (:func:`read_log` is a Ray
generator): each piece carries the ``(channel, value)`` names its log's vocabulary gained
since the previous one, and the driver renumbers them into the run's vocabulary,
registering the values it has not seen in the order the log first shows them, as one
process would. So the driver starts learning a log as soon as its first piece is read
and finishes soon after the last one, and neither it nor a task holds a whole log:
memory stays bounded however long a log is. At most ``2 x CPUs`` logs are in flight, and
a task runs at most :data:`PIECES_AHEAD` pieces ahead of the driver. Past what one core
learns per second (the driver's share), :mod:`slearn.jobs.merge_tree` learns in the
tasks too, at the price of the scoring state following the merge rule.

Differences from one process: values outside a range are warned about per log (not
counted over all logs), and quantile bins (``quantiles=N``) are still fitted by the
driver, which reads those logs once more.
"""

from __future__ import annotations

import dataclasses
import functools
import os
import warnings
from collections import Counter, deque
from typing import Callable, Iterable, Iterator

import numpy as np

from slearn.core.stream import Episode
from slearn.core.vocabulary import Vocabulary
from slearn.errors import DataWarning, SpecError, TruncatedLogWarning
from slearn.io.bags import log_record
from slearn.io.mcap_read import ReadReport
from slearn.io.serialize import RangeCounts, joined, prepare_vocabulary
from slearn.io.slicing import TimeSlice, slice_from_dict
from slearn.io.spec import Spec
from slearn.jobs.cluster import MAX_RETRIES, Rate, check_visible, streamed
from slearn.jobs.pages import small_pages

IN_FLIGHT_PER_CPU = 2
STREAMED_EVENTS = 1 << 16
"""Events of a piece a read task streams (one process learns larger ones: the size of a
piece changes nothing learned, and small ones let the driver start and end a log sooner)."""
PIECES_AHEAD = 64
"""Pieces a read task may stream ahead of the driver (at most 4 M events, about 50 MB)."""


class RayReader:
    """:func:`slearn.io.serialize.read_pieces` (and :func:`~slearn.io.serialize.read_episodes`,
    by calling it) with each log read by a Ray task.

    Same arguments, same yields, same vocabulary afterwards; ``echo`` receives a
    progress line per log (logs done / total, events/s).
    """

    def __init__(self, ray, echo: Callable[[str], None] | None = None, what: str = "read",
                 piece_events: int = STREAMED_EVENTS) -> None:
        self.ray, self.echo, self.what, self.piece_events = ray, echo, what, piece_events
        self.records: dict[str, dict] = {}
        """Each log read: its provenance record (size and sha256, computed by its task)."""
        cpus = int(ray.cluster_resources().get("CPU", 1))
        self.in_flight = max(IN_FLIGHT_PER_CPU * cpus, 2)

    def __call__(self, paths: Iterable[str | os.PathLike], spec: Spec, vocabulary: Vocabulary,
                 progress: bool = False, window: TimeSlice | dict[str, TimeSlice] | None = None
                 ) -> Iterator[tuple[str, Episode, ReadReport]]:
        parts: list[Episode] = []
        for name, piece, report, _, last in self.pieces(paths, spec, vocabulary, progress, window):
            parts.append(piece)
            if last:
                yield name, joined(parts), report
                parts = []

    def pieces(self, paths: Iterable[str | os.PathLike], spec: Spec, vocabulary: Vocabulary,
               progress: bool = False, window: TimeSlice | dict[str, TimeSlice] | None = None
               ) -> Iterator[tuple[str, Episode, ReadReport, bool, bool]]:
        """``(name, piece, report, first, last)`` as :func:`~slearn.io.serialize.read_pieces`
        yields them: each log's episodes in pieces, the log's report on its last piece."""
        paths = [os.fspath(p) for p in paths]
        task = self.ray.remote(max_retries=MAX_RETRIES, _generator_backpressure_num_objects=PIECES_AHEAD)(read_log)
        prepare_vocabulary(spec, vocabulary)
        data, rate = spec.to_dict(), Rate(self.what, len(paths), self.echo)
        shown: set[str] = set()
        pending: deque = deque()
        todo = iter(paths)
        submit = functools.partial(_submit, task, todo, pending, data, spec.source, window, self.piece_events)
        for _ in range(self.in_flight):
            submit()
        while pending:
            path, stream = pending.popleft()
            names, held = Renumbering(vocabulary, spec, path), None
            for item in streamed(self.ray, stream, path):
                if "report" in item:  # the log's end: its last piece carries the report
                    assert held is not None  # every log yields a piece, an empty one at least
                    report = ReadReport(**item["report"])
                    if report.truncated:
                        warnings.warn(TruncatedLogWarning(report.describe()), stacklevel=2)
                    yield (*held[:2], report, *held[3:])
                    rate.add(item["events"])
                    self.records[path] = item["record"]
                    _warn_once(item["warnings"], shown)
                    break
                if held is not None:
                    yield held
                piece = Episode(names.extend(item["names"])[item["symbols"]], item["offsets"], item["n_actions"])
                held = (item["name"], piece, ReadReport(path), item["first"], item["last"])
            submit()


def _submit(task, todo: Iterator[str | os.PathLike], pending: deque, spec: dict, source: str,
            window: TimeSlice | dict[str, TimeSlice] | None, piece_events: int) -> None:
    path = next(todo, None)
    if path is not None:
        log_window = window.get(os.fspath(path)) if isinstance(window, dict) else window
        pending.append((path, task.remote(path, spec, source, log_window.to_dict() if log_window else None,
                                          piece_events)))


class Renumbering:
    """A task's symbols in the run's vocabulary, extended as the task names new ones
    (registering the values the run has not seen, in the task's order).

    Raises (from :meth:`extend`):
        SpecError: a channel gets more distinct values than its entry allows.
    """

    def __init__(self, vocabulary: Vocabulary, spec: Spec, path: str) -> None:
        self.vocabulary, self.path = vocabulary, path
        self.per_channel = Counter(channel for channel, _ in vocabulary.names())
        self.limits = {c.name: c.symbol_limit for c in spec.channels}
        self.mapping = np.empty(0, np.int32)

    def extend(self, names: list[tuple[str, object]]) -> np.ndarray:
        """The mapping, for the task's symbols so far and ``names`` (its next ones)."""
        if not names:
            return self.mapping
        vocabulary, known = self.vocabulary, len(self.vocabulary)
        more = np.empty(len(names), np.int32)
        for i, (channel, value) in enumerate(names):
            more[i] = vocabulary.symbol(channel, value)
            if more[i] >= known:
                known += 1
                self.per_channel[channel] += 1
                if self.per_channel[channel] > self.limits.get(channel, self.per_channel[channel]):
                    raise SpecError(f"{self.path}: channel {channel!r} has more than {self.limits[channel]:,} "
                                    f"distinct values: use coarser bins, or raise the entry's max_symbols")
        self.mapping = np.concatenate((self.mapping, more))
        return self.mapping


def _warn_once(messages: list[str], shown: set) -> None:
    for message in messages:
        if message not in shown:
            shown.add(message)
            warnings.warn(DataWarning(message), stacklevel=4)


def read_log(path: str, spec: dict, source: str, window: dict | None,
             piece_events: int = STREAMED_EVENTS) -> Iterator[dict]:
    """The task, a generator: one log read with a vocabulary of its own, as plain data. A
    dict per piece as it is read (:func:`slearn.io.ingest.iter_pieces`): ``name``,
    ``symbols``, ``offsets`` (of the steps), ``n_actions`` (per step), ``first``, ``last``
    (the piece begins or ends its episode) and ``names`` (the ``(channel, value)`` of the
    symbols the vocabulary gained since the previous piece); then one dict that ends the
    log: ``report`` (the read report's fields), ``warnings``, ``events`` and ``record`` (the
    log's provenance record, :func:`slearn.io.bags.log_record`: hashing every input is
    work the driver would otherwise do alone)."""
    from slearn.io.ingest import iter_pieces

    small_pages()
    check_visible(path)
    log_spec = Spec.from_dict(spec, source)
    vocabulary = prepare_vocabulary(log_spec, Vocabulary())
    report, ranges, named, events = ReadReport(path), RangeCounts(), 0, 0
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for piece in iter_pieces(path, log_spec, vocabulary, report, False, slice_from_dict(window), ranges,
                                 piece_events=piece_events):
            episode = piece.episode
            yield {"name": piece.name, "symbols": episode.symbols, "offsets": episode.step_offsets,
                   "n_actions": episode.n_actions, "first": piece.first, "last": piece.last,
                   "names": vocabulary.names(named)}
            named, events = len(vocabulary), events + len(episode.symbols)
        messages = [str(w.message) for w in caught if issubclass(w.category, DataWarning)]
    yield {"report": dataclasses.asdict(report), "events": events, "warnings": messages + ranges.messages(log_spec),
           "record": log_record(path)}
