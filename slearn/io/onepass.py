"""Quantile bins fitted and logs learned in one read of each log.

Quantile edges are only known once every log has been read, and symbols need them. So the
first (and only) read decodes each log once, as :mod:`slearn.io.ingest` does, and spills its
values to a temporary folder: the values of quantile entries as floats (they feed the
same deterministic sample :func:`slearn.io.serialize.fit_spec` keeps), every other value as
its symbol in a scratch vocabulary. Once the edges are fitted, the spilled values are
read back in bounded batches, mapped to the final vocabulary (which registers the
scratch's values in their first-seen order, as the two-pass path does) and cut into
steps. Edges, vocabulary, episodes and library are those of :func:`fit_spec` followed by
:func:`read_pieces` (tests compare); the spill takes 28 bytes per value on disk.
"""

from __future__ import annotations

import os
import tempfile
import warnings
from dataclasses import dataclass, field, replace
from typing import Iterable, Iterator, cast

import numpy as np

from slearn.core.vocabulary import Vocabulary
from slearn.errors import DataWarning, SpecError
from slearn.io import ingest
from slearn.io.mcap_read import ReadReport
from slearn.io.spec import Bins, Spec

_COLUMNS = (("time", np.uint64), ("entry", np.int32), ("code", np.int64), ("value", np.float64))


def can_fit_in_one_pass(spec: Spec) -> bool:
    """Whether :func:`fit_and_read` handles this spec (quantile entries without ``range`` or
    ``wrap``, whose values are then simply numbers)."""
    todo = [cast(Bins, c.symbolizer) for c in spec.channels if not c.symbolizer.fitted]  # only Bins fit
    return bool(todo) and all(b.range is None and not b.wrap for b in todo)


class _Sample:
    """:class:`slearn.io.serialize._Sample` fed a batch at a time (the same values kept)."""

    def __init__(self, cap: int) -> None:
        self.parts: list[np.ndarray] = []
        self.n, self.cap, self.stride, self.seen = 0, cap, 1, 0

    def add_many(self, xs: np.ndarray) -> None:
        pos = 0
        while pos < len(xs):
            first = pos + (-self.seen) % self.stride
            take = xs[first::self.stride][:self.cap - self.n]
            self.parts.append(take)
            self.n += len(take)
            if self.n < self.cap:
                self.seen += len(xs) - pos
                return
            last = first + (len(take) - 1) * self.stride
            kept = np.concatenate(self.parts)[::2]
            self.parts, self.n, self.stride = [kept], len(kept), self.stride * 2
            self.seen += last + 1 - pos
            pos = last + 1

    def values(self) -> np.ndarray:
        return np.concatenate(self.parts) if self.parts else np.zeros(0)


@dataclass
class _Log:
    path: str
    report: ReadReport
    episodes: list[tuple[str, int, int]] = field(default_factory=list)  # name, start, stop


class _Spill:
    """The values of every log, appended to four files in a temporary folder."""

    def __init__(self, folder: str) -> None:
        self.files = {name: open(os.path.join(folder, name), "w+b") for name, _ in _COLUMNS}
        self.n = 0

    def write(self, **columns: np.ndarray) -> None:
        for name, dtype in _COLUMNS:
            self.files[name].write(np.ascontiguousarray(columns[name], dtype).tobytes())
        self.n += len(columns["time"])

    def read(self, start: int, stop: int) -> dict[str, np.ndarray]:
        out = {}
        for name, dtype in _COLUMNS:
            f = self.files[name]
            f.seek(start * np.dtype(dtype).itemsize)
            out[name] = np.frombuffer(f.read((stop - start) * np.dtype(dtype).itemsize), dtype)
        return out

    def flush(self) -> None:
        for f in self.files.values():
            f.flush()

    def close(self) -> None:
        for f in self.files.values():
            f.close()


class _SpillStream:
    """One episode's values to the spill (the interface of ``ingest._EpisodeStream``)."""

    def __init__(self, name: str, fit: "_FirstRead", log: _Log) -> None:
        self.name, self.fit, self.log = name, fit, log
        self.start = fit.spill.n

    def add(self, times: np.ndarray, entries: np.ndarray, values: list) -> None:
        fit = self.fit
        quantile = np.isin(entries, fit.todo)
        code = np.full(len(values), ingest._NO_SYMBOL, np.int64)
        value = np.full(len(values), np.nan)
        other = np.flatnonzero(~quantile)
        if len(other):
            symbols = cast(ingest._Symbols, fit.symbols)  # set while a log is read
            code[other] = symbols.symbols(entries[other], [values[i] for i in other.tolist()])
        for index in fit.todo:
            where = np.flatnonzero(entries == index)
            if len(where):
                xs = _floats([values[i] for i in where.tolist()])
                value[where] = xs
                fit.samples[index].add_many(xs[np.isfinite(xs)])
        fit.spill.write(time=times, entry=entries, code=code, value=value)

    def finish(self) -> None:
        self.log.episodes.append((self.name, self.start, self.fit.spill.n))


def _floats(vals: list) -> np.ndarray:
    """``float(v)`` of each value, NaN where it has none (as :meth:`Bins.symbol_value` reads)."""
    if {type(v) for v in vals} <= {int, float}:
        try:
            return np.array(vals, dtype=np.float64)
        except OverflowError:
            pass
    out = np.empty(len(vals))
    for i, v in enumerate(vals):
        try:
            out[i] = float(v)
        except (TypeError, ValueError, OverflowError):
            out[i] = np.nan
    return out


class _FirstRead:
    """The one read of every log: spilled values, quantile samples, reports."""

    def __init__(self, spec: Spec, folder: str) -> None:
        from slearn.io.serialize import _QUANTILE_SAMPLE, RangeCounts, prepare_vocabulary

        self.spec = spec
        self.todo = [i for i, c in enumerate(spec.channels) if not c.symbolizer.fitted]
        self.samples = {i: _Sample(_QUANTILE_SAMPLE) for i in self.todo}
        self.scratch = prepare_vocabulary(spec, Vocabulary())
        self.ranges = RangeCounts()
        self.spill = _Spill(folder)
        self.logs: list[_Log] = []
        self.symbols: ingest._Symbols | None = None  # the log being read's

    def read(self, path: str, progress: bool, window) -> None:
        log = _Log(path, ReadReport(path))
        self.logs.append(log)
        self.symbols = ingest._Symbols(self.spec, self.scratch, path, self.ranges)
        for _ in ingest.iter_pieces(path, self.spec, self.scratch, log.report, progress, window,
                                    self.ranges, lambda name: _SpillStream(name, self, log)):
            pass
        self.spill.flush()

    def fitted_spec(self) -> Spec:
        from slearn.io.serialize import _fitted_edges

        damaged = [log.report for log in self.logs if log.report.truncated]
        channels = list(self.spec.channels)
        for i in self.todo:
            values = self.samples[i].values()
            if not len(values):
                why = f" (the log is damaged: {damaged[0].describe()})" if damaged else ""
                raise SpecError(f"{self.spec.source}: entry {i + 1} ({channels[i].name!r}): no numeric "
                                f"value in the training logs to fit quantile bins on{why}")
            bins = cast(Bins, channels[i].symbolizer)  # an entry to fit has quantile bins
            channels[i] = replace(channels[i], symbolizer=Bins(
                quantiles=bins.quantiles, edges=_fitted_edges(list(values), bins.quantiles or 0)))
        return self.spec.with_channels(channels)


def _symbol_tables(first: _FirstRead, spec: Spec, vocabulary: Vocabulary):
    """Scratch symbol -> final symbol, and per quantile entry its cuts and bin -> symbol."""
    from slearn.io.serialize import prepare_vocabulary

    prepare_vocabulary(spec, vocabulary)
    scratch = np.array([vocabulary.symbol(channel, value) for _, channel, value in first.scratch.items()]
                       + [ingest._NO_SYMBOL], np.int64)  # index -1: no symbol
    quantile = {}
    for i in first.todo:
        entry = spec.channels[i]
        cuts = np.asarray(cast(Bins, entry.symbolizer).cuts(), np.float64)
        quantile[i] = cuts, np.array([vocabulary.get_symbol(entry.name, k)
                                      for k in range(len(cuts) + 1)], np.int64)
    return scratch, quantile


def _final_symbols(batch: dict, scratch: np.ndarray, quantile: dict) -> np.ndarray:
    symbols = scratch[batch["code"]]
    for i, (cuts, table) in quantile.items():
        where = np.flatnonzero(batch["entry"] == i)
        x = batch["value"][where]
        finite = np.isfinite(x)
        k = np.searchsorted(cuts, x[finite], side="right")
        symbols[where] = ingest._NO_SYMBOL
        symbols[where[finite]] = table[k]
    return symbols


def _replay(first: _FirstRead, spec: Spec, vocabulary: Vocabulary
            ) -> Iterator[tuple[str, object, ReadReport, bool, bool]]:
    """The pieces of every log's episodes, from the spill (as ``read_pieces`` yields them)."""
    from slearn.io.serialize import _warn_if_truncated

    scratch, quantile = _symbol_tables(first, spec, vocabulary)
    for log in first.logs:
        pieces: list[ingest.Piece] = []
        out: list[ingest.Piece] = []
        for name, start, stop in log.episodes:
            # no symbolizer: the spill's symbols are mapped by add_symbols
            stream = ingest._EpisodeStream(name, spec, cast(ingest._Symbols, None), pieces.append)
            for at in range(start, stop, ingest.BATCH_MESSAGES):
                batch = first.spill.read(at, min(stop, at + ingest.BATCH_MESSAGES))
                stream.add_symbols(batch["time"], batch["entry"].astype(np.int64),
                                   _final_symbols(batch, scratch, quantile))
                out += pieces
                pieces.clear()
                yield from _pending(out, log, keep=1)
            stream.finish()
            out += pieces
            pieces.clear()
            yield from _pending(out, log, keep=1)
        _warn_if_truncated(log.report)
        yield from _pending(out, log, keep=0)
    for message in first.ranges.messages(spec):
        warnings.warn(DataWarning(message), stacklevel=2)


def _pending(out: list, log: _Log, keep: int) -> Iterator[tuple]:
    """Pass on all but the last ``keep`` pieces (the log's report goes with its last one)."""
    while len(out) > keep:
        piece = out.pop(0)
        report = log.report if not out and not keep else ReadReport(log.path)
        yield piece.name, piece.episode, report, piece.first, piece.last


def fit_and_read(paths: Iterable[str | os.PathLike], spec: Spec, vocabulary: Vocabulary,
                 progress: bool = False, window=None) -> tuple[Spec, Iterator[tuple]]:
    """Fit ``spec``'s quantile bins on ``paths`` and read them into episode pieces, reading
    each log once (see the module docstring; :func:`can_fit_in_one_pass` says when).

    Returns:
        The fitted spec, and the pieces as :func:`slearn.io.serialize.read_pieces` yields
        them (consume them before anything else uses ``vocabulary``).

    Raises:
        SpecError, InputError: as :func:`~slearn.io.serialize.fit_spec` and ``read_pieces``.
    """
    folder = tempfile.TemporaryDirectory(prefix="slearn-fit-")
    try:
        first = _FirstRead(spec, folder.name)
        for path in paths:
            first.read(os.fspath(path), progress, window)
        fitted = first.fitted_spec()
    except BaseException:
        _close(locals().get("first"), folder)
        raise

    def pieces() -> Iterator[tuple]:
        try:
            yield from _replay(first, fitted, vocabulary)
        finally:
            _close(first, folder)
    return fitted, pieces()


def _close(first: _FirstRead | None, folder: tempfile.TemporaryDirectory) -> None:
    """Close the spill and remove its folder."""
    if first is not None:
        first.spill.close()
    folder.cleanup()
