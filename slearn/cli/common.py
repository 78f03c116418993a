"""Options and output shared by several commands: time slices, topics, the --channel help,
and warnings printed once each on stderr."""

from __future__ import annotations

import contextlib
import os
import warnings
from typing import Callable, Iterator

import click

from slearn.errors import DataWarning, InputError
from slearn.io.slicing import TRAIN, TimeSlice, time_slice

CHANNEL_HELP = (
    "A spec entry (repeatable): TOPIC:FIELD:ROLE[:OPTIONS], OPTIONS as key=value separated by "
    "commas, lists in brackets. Keys: values=[a,b] (categorical), range=[lo,hi] with count=N "
    "(bins; wrap=true for angles, clip=true to accept values outside), width=W and origin=O, "
    "edges=[...], quantiles=N, unit=rad|deg|..., mode=message|change, name=NAME. "
    "E.g. /joint_states:position[name=j1]:observation:range=[0,6.2832],count=36,wrap=true,unit=rad")


def slice_options(split: bool) -> Callable:
    """Add --start, --end, --topics (and --split) to a command."""
    options = [
        click.option("--start", metavar="TIME",
                     help="Read each log from this time on: seconds from its start (12.5) or an "
                          "ISO 8601 time (2024-05-01T12:00:03Z)."),
        click.option("--end", metavar="TIME",
                     help="Read each log up to this time (excluded); as --start."),
        click.option("--topics", metavar="T1,T2", help="Only these topics (comma-separated)."),
    ]
    if split:
        options.append(click.option(
            "--split", type=click.FloatRange(0, 1, min_open=True, max_open=True), metavar="SHARE",
            help="Split each log's time: learn reads the first SHARE (0.7: 70 %), replay the "
                 "rest, so the same logs give a training and a held-out part."))

    def decorate(func: Callable) -> Callable:
        for option in reversed(options):
            func = option(func)
        return func
    return decorate


def make_slice(start: str | None, end: str | None, split: float | None,
               part: str = TRAIN) -> TimeSlice | None:
    """The :class:`~slearn.io.slicing.TimeSlice` of the options (``None``: whole logs)."""
    return time_slice(start, end, split, part)


def topic_list(topics: str | None) -> list[str] | None:
    """``--topics a,b`` as a list (``None`` when not given)."""
    if topics is None:
        return None
    return [t.strip() for t in topics.split(",") if t.strip()]


@contextlib.contextmanager
def warnings_on_stderr() -> Iterator[None]:
    """Print every :class:`~slearn.errors.DataWarning` raised inside once, as
    ``slearn: warning: ...`` on stderr (after the block, so results come first)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DataWarning)
        try:
            yield
        finally:
            shown = []
            for item in caught:
                text = str(item.message)
                if issubclass(item.category, DataWarning) and text not in shown:
                    shown.append(text)
                elif not issubclass(item.category, DataWarning):
                    warnings.warn_explicit(item.message, item.category, item.filename, item.lineno)
            for text in shown:
                click.echo(f"slearn: warning: {text}", err=True)



def ray_options(func: Callable) -> Callable:
    """Add --workers and --ray (run the job's tasks on Ray: :mod:`slearn.jobs.cluster`)."""
    func = click.option("--ray", "ray_address", metavar="ADDRESS",
                        help="Run on the Ray cluster at ADDRESS (host:6379, or auto: the one "
                             "`ray start` began here). Every node must see the logs at the same "
                             "path. Needs pip install 'slearn[ray]'.")(func)
    return click.option("--workers", type=click.IntRange(1, 4096), metavar="N",
                        help="Run on a Ray instance of N CPUs started on this machine for the job "
                             "(needs pip install 'slearn[ray]').")(func)


def echo_progress(line: str) -> None:
    """A progress line on stderr."""
    click.echo(line, err=True)


@contextlib.contextmanager
def reader_for(workers: int | None, address: str | None, what: str | None) -> Iterator[Callable]:
    """The log reader of a job: on Ray with --workers/--ray (progress lines ``what`` k/n
    logs when ``what`` is given), else the one-process reader."""
    from slearn.io.serialize import read_episodes

    if workers is None and address is None:
        yield read_episodes
        return
    from slearn.jobs.cluster import ray_session
    from slearn.jobs.distributed import RayReader

    with ray_session(workers, address) as ray:
        yield RayReader(ray, echo_progress if what else None, what or "read")


def check_distinct_outputs(outputs: list[tuple[str, str | None]]) -> None:
    """Refuse two outputs, ``(option, path)``, on one file (one would overwrite the other),
    before any work."""
    seen: dict[str, str] = {}
    for option, path in outputs:
        if path:
            key = os.path.realpath(path)
            if key in seen:
                raise InputError(f"{seen[key]} and {option} both write {path}: give each output its own path")
            seen[key] = option
