"""Reading logs on Ray, so that learning and replaying many logs give one process's bytes.

Reading is most of the cost of learning (decoding and binning every message: on the
pointer logs about 85 % of ``slearn learn``'s time, 95 % of a frozen replay's), and it
depends on nothing but the log. So ``--workers N`` / ``--ray ADDRESS`` read the logs in
Ray tasks, many at once, and the driver learns (or scores) their episodes in the order a
one-process run takes them. The library, its scoring state included, and the replay
report are then those of one process by construction (``tests/test_ray.py`` compares
the bytes).

A task reads one log with its own vocabulary and returns its episodes as arrays, with
its vocabulary's ``(channel, value)`` names; the driver renumbers them into the run's
vocabulary, registering the values it has not seen in the order the log first shows
them, as one process would. At most ``2 x CPUs`` logs are in flight, so the driver holds
a bounded number of read logs. Past what one core learns per second (the driver's
share), :mod:`slearn.jobs.merge_tree` learns in the tasks too, at the price of the scoring
state following the merge rule.

Differences from one process: values outside a range are warned about per log (not
counted over all logs), and quantile bins (``quantiles=N``) are still fitted by the
driver, which reads those logs once more.
"""

from __future__ import annotations

import dataclasses
import os
import warnings
from collections import Counter, deque
from typing import Callable, Iterable, Iterator

import numpy as np

from slearn.core.stream import Episode
from slearn.core.vocabulary import Vocabulary
from slearn.errors import DataWarning, SpecError, TruncatedLogWarning
from slearn.io.mcap_read import ReadReport
from slearn.io.serialize import prepare_vocabulary, read_episodes
from slearn.io.slicing import TimeSlice, slice_from_dict
from slearn.io.spec import Spec
from slearn.jobs.cluster import MAX_RETRIES, Rate, check_visible, gather
from slearn.jobs.pages import small_pages

IN_FLIGHT_PER_CPU = 2


class RayReader:
    """:func:`slearn.io.serialize.read_episodes` with each log read by a Ray task.

    Same arguments, same yields, same vocabulary afterwards; ``echo`` receives a
    progress line per log (logs done / total, events/s).
    """

    def __init__(self, ray, echo: Callable[[str], None] | None = None, what: str = "read") -> None:
        self.ray, self.echo, self.what = ray, echo, what
        cpus = int(ray.cluster_resources().get("CPU", 1))
        self.in_flight = max(IN_FLIGHT_PER_CPU * cpus, 2)

    def __call__(self, paths: Iterable[str | os.PathLike], spec: Spec, vocabulary: Vocabulary,
                 progress: bool = False, window: TimeSlice | dict[str, TimeSlice] | None = None
                 ) -> Iterator[tuple[str, Episode, ReadReport]]:
        paths = [os.fspath(p) for p in paths]
        task = self.ray.remote(max_retries=MAX_RETRIES)(read_log)
        prepare_vocabulary(spec, vocabulary)
        data, rate = spec.to_dict(), Rate(self.what, len(paths), self.echo)
        shown: set[str] = set()
        pending: deque = deque()
        todo = iter(paths)
        for _ in range(self.in_flight):
            _submit(task, todo, pending, data, spec.source, window)
        while pending:
            path, ref = pending.popleft()
            log = gather(self.ray, [ref], [path])[0]
            _submit(task, todo, pending, data, spec.source, window)
            yield from _episodes(log, path, spec, vocabulary)
            rate.add(log["events"])
            _warn_once(log["warnings"], shown)


def _submit(task, todo: Iterator[str | os.PathLike], pending: deque, spec: dict, source: str,
            window: TimeSlice | dict[str, TimeSlice] | None) -> None:
    path = next(todo, None)
    if path is not None:
        log_window = window.get(os.fspath(path)) if isinstance(window, dict) else window
        pending.append((path, task.remote(path, spec, source,
                                          log_window.to_dict() if log_window else None)))


def _episodes(log: dict, path: str, spec: Spec, vocabulary: Vocabulary
              ) -> Iterator[tuple[str, Episode, ReadReport]]:
    mapping = renumber(log["vocabulary"], vocabulary, spec, path)
    report = ReadReport(**log["report"])
    for i, (name, symbols, offsets, n_actions) in enumerate(log["episodes"]):
        last = i == len(log["episodes"]) - 1
        if last and report.truncated:
            warnings.warn(TruncatedLogWarning(report.describe()), stacklevel=3)
        yield name, Episode(mapping[symbols], offsets, n_actions), report if last else ReadReport(path)


def renumber(names: list[tuple[str, object]], vocabulary: Vocabulary, spec: Spec,
             path: str) -> np.ndarray:
    """The run's symbol of each of a task's symbols, registering the new values in order.

    Raises:
        SpecError: a channel gets more distinct values than its entry allows.
    """
    known = len(vocabulary)
    per_channel = Counter(channel for _, channel, _ in vocabulary.items())
    limits = {c.name: c.symbol_limit for c in spec.channels}
    mapping = np.empty(len(names), np.int32)
    for i, (channel, value) in enumerate(names):
        mapping[i] = vocabulary.symbol(channel, value)
        if mapping[i] >= known:
            known += 1
            per_channel[channel] += 1
            if per_channel[channel] > limits.get(channel, per_channel[channel]):
                raise SpecError(f"{path}: channel {channel!r} has more than {limits[channel]:,} "
                                f"distinct values: use coarser bins, or raise the entry's max_symbols")
    return mapping


def _warn_once(messages: list[str], shown: set) -> None:
    for message in messages:
        if message not in shown:
            shown.add(message)
            warnings.warn(DataWarning(message), stacklevel=4)


def read_log(path: str, spec: dict, source: str, window: dict | None) -> dict:
    """The task: one log read with a vocabulary of its own, as plain data: ``episodes``
    (name, symbols, step offsets, actions per step), ``vocabulary`` (``(channel, value)``
    per symbol), ``report`` (the read report's fields), ``warnings``, ``events``."""
    small_pages()
    check_visible(path)
    vocabulary = Vocabulary()
    episodes, report = [], ReadReport(path)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for name, episode, report in read_episodes([path], Spec.from_dict(spec, source),  # noqa: B007
                                                   vocabulary, False, slice_from_dict(window)):
            # every item carries the log's report so far: the last one is kept
            episodes.append((name, episode.symbols, episode.step_offsets, episode.n_actions))
    return {"episodes": episodes, "vocabulary": [(c, v) for _, c, v in vocabulary.items()],
            "report": dataclasses.asdict(report), "events": sum(len(e[1]) for e in episodes),
            "warnings": [str(w.message) for w in caught if issubclass(w.category, DataWarning)]}
