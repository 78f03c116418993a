"""The learning job: MCAP logs in, a saved pattern library out.

Each log is one episode, or several when it marks episode boundaries
(:mod:`slearn.io.episodes`); episodes are never glued together. The spec is the one given,
or the pointer's for pointer logs; quantile bins are fitted on the training logs before
learning. ``resume`` goes on learning from a saved library with its own spec, vocabulary
and parameters, so learning ``A`` then resuming on ``B`` writes the same bytes as learning
``A B`` in one run.

Provenance: slearn version, every input log (path as given, size, sha256; a resumed
library's inputs come first) and a time. The time is never the wall clock, so that the
same inputs give the same file: it is ``SOURCE_DATE_EPOCH`` when set, else the newest
modification time (whole seconds) among all inputs. A learned time slice
(``--start``/``--end``/``--split``) is recorded with each input, so replay can count its
baselines on exactly what the library learned.
"""

from __future__ import annotations

import glob
import os
import time
import warnings
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import Callable, Iterator, Protocol, Sequence, cast

from slearn import __version__
from slearn.core import literal
from slearn.core.library import DEFAULT_MAX_LENGTH, PatternLibrary
from slearn.core.literal import LiteralLibrary
from slearn.core.vocabulary import Vocabulary
from slearn.errors import DataWarning, InputError, SpecError
from slearn.io.bags import check_log_path, log_record, open_log
from slearn.io.files import check_output
from slearn.io.library_file import load_library, save_library
from slearn.io.library_header import MAX_TIME_UNIX
from slearn.io.mcap_read import ReadReport
from slearn.io.onepass import can_fit_in_one_pass, fit_and_read
from slearn.io.serialize import fit_spec, read_episodes, read_pieces
from slearn.io.slicing import TimeSlice, shares_time, slice_from_dict
from slearn.io.spec import POINTER_COMMAND, POINTER_POSITION, Spec, pointer_spec
from slearn.jobs.suggest import ScopeHint

SCORING_RULES = ("adaptive", "literal")
DEFAULT_SCORING = "adaptive"
_SNIFF_MESSAGES = 1000  # messages read to find the topics of a log without a summary


class PieceReader(Protocol):
    """A reader of logs elsewhere (:class:`slearn.jobs.distributed.RayReader`): its
    ``pieces`` yields what :func:`~slearn.io.serialize.read_pieces` yields."""

    def pieces(self, paths: Sequence[str | os.PathLike], spec: Spec, vocabulary: Vocabulary,
               progress: bool, window: TimeSlice | None) -> Iterator[tuple]: ...


@dataclass
class LearnResult:
    """What one learning job did and wrote."""

    output: str
    n_patterns: int
    size_bytes: int
    n_events: int = 0
    n_steps: int = 0
    n_episodes: int = 0
    seconds: float = 0.0
    clock: int = 0
    forgotten: int = 0
    n_symbols: int = 0
    resumed_from: str | None = None
    truncated: list[ReadReport] = field(default_factory=list)

    @property
    def bytes_per_pattern(self) -> float:
        """File bytes per pattern (0 for an empty library)."""
        return self.size_bytes / self.n_patterns if self.n_patterns else 0.0

    def to_dict(self) -> dict:
        """Plain JSON-able data."""
        return {"output": self.output, "patterns": self.n_patterns, "bytes": self.size_bytes,
                "bytes_per_pattern": self.bytes_per_pattern, "events": self.n_events,
                "steps": self.n_steps, "episodes": self.n_episodes, "seconds": self.seconds,
                "clock": self.clock, "forgotten": self.forgotten, "symbols": self.n_symbols,
                "resumed_from": self.resumed_from,
                "truncated": [r.describe() for r in self.truncated]}


@dataclass
class _Job:
    library: PatternLibrary | LiteralLibrary
    vocabulary: Vocabulary
    spec: Spec
    params: dict
    provenance: dict | None = None
    pieces: Iterator | None = None  # already read (quantiles fitted in the same read)


def expand_paths(patterns: list[str]) -> list[str]:
    """Logs as given; an argument that is not a file but a glob pattern is expanded (sorted).

    Raises:
        InputError: a file does not exist and no file matches it as a pattern.
    """
    paths: list[str] = []
    for pattern in patterns:
        if os.path.exists(pattern) or not glob.has_magic(pattern):
            paths.append(pattern)
            continue
        matches = sorted(glob.glob(pattern))
        if not matches:
            raise InputError(f"{pattern}: no file matches")
        paths += matches
    for path in paths:
        check_log_path(path)
    return paths


def log_topics(path: str) -> tuple[set[str], ReadReport]:
    """Topics of a log: from its channel records, else from its first messages; and the
    report of that read (where the log broke, if it did)."""
    with open_log(path) as log:
        topics = {c.topic for c in log.channels.values()}
        if not topics:
            for i, message in enumerate(log.iter_messages()):
                topics.add(message.topic)
                if i >= _SNIFF_MESSAGES:
                    break
        return topics, log.report


def default_spec(path: str) -> Spec:
    """The pointer spec for pointer logs.

    Raises:
        SpecError: the log is not a pointer log, so a spec is needed.
        InputError: no channel could be read from a damaged log.
    """
    topics, report = log_topics(path)
    if {POINTER_COMMAND, POINTER_POSITION} <= topics:
        return pointer_spec()
    if not topics and report.truncated:
        raise InputError(f"nothing could be read: {report.describe()}")
    shown = ", ".join(sorted(topics)[:8]) or "none"
    raise SpecError(f"{path}: not a pointer log (topics: {shown}): pass --spec auto (learn what "
                    f"`slearn info {path} --suggest-spec spec.toml` would write), --spec FILE or "
                    "--channel")


def _new_job(paths: Sequence[str | os.PathLike], spec: Spec | None, max_length: int | None,
             max_patterns: int | None, scoring: str | None, progress: bool,
             window: TimeSlice | None = None, one_read: bool = False) -> _Job:
    """A new job; ``one_read`` fits quantile bins in the read that learning then uses
    (:mod:`slearn.io.onepass`; only when this process reads the logs)."""
    spec = (spec if spec is not None else default_spec(os.fspath(paths[0]))).predicting()
    vocabulary = Vocabulary()
    pieces = None
    if one_read and can_fit_in_one_pass(spec):
        spec, pieces = fit_and_read(paths, spec, vocabulary, progress, window)
    else:
        spec = fit_spec(spec, paths, progress, window)
    scoring = scoring or DEFAULT_SCORING
    library: PatternLibrary | LiteralLibrary
    if scoring == "literal":
        if spec.action_scopes():
            raise SpecError(f"{spec.source}: `actions` scopes need the adaptive scoring (the literal "
                            f"rule predicts a step's observations together): drop them or the "
                            f"--scoring literal")
        library = LiteralLibrary(max_length or literal.DEFAULT_MAX_LENGTH, max_patterns)
    else:
        library = PatternLibrary(max_length or DEFAULT_MAX_LENGTH, max_patterns, vocabulary=vocabulary,
                                 action_scopes=spec.action_scopes())
    return _Job(library, vocabulary, spec, {"scoring": scoring}, pieces=pieces)


def _resumed_job(resume: str, spec: Spec | None, max_length: int | None,
                 max_patterns: int | None, scoring: str | None) -> _Job:
    loaded = load_library(resume)
    if spec is not None and loaded.spec is not None:
        raise SpecError(f"{resume}: --resume learns with the library's own spec (bins fitted "
                        f"on its logs): leave out --spec and --channel")
    if loaded.spec is None and spec is None:
        raise SpecError(f"{resume}: this library has no spec: pass --spec to go on learning")
    library = loaded.library
    if max_length is not None and max_length != library.max_length:
        raise InputError(f"{resume}: learned with max length {library.max_length}; "
                         f"--resume keeps it (leave out --max-length)")
    if scoring is not None and scoring != loaded.params.get("scoring"):
        raise InputError(f"{resume}: learned with scoring {loaded.params.get('scoring')}; "
                         f"--resume keeps it (leave out --scoring)")
    if max_patterns is not None:
        library.max_patterns = max_patterns
    spec = loaded.spec or cast(Spec, spec).predicting()  # one is set
    return _Job(library, loaded.vocabulary, spec, dict(loaded.params), loaded.provenance)


def checked_inputs(paths: Sequence[str | os.PathLike], output: str | os.PathLike, overwrite: bool,
                   resume: str | os.PathLike | None, scoring: str | None) -> list[str]:
    """The logs as strings, after the cheap checks every learn job makes before reading:
    some logs, an output that may be written and is none of the inputs, a known scoring."""
    logs = [os.fspath(p) for p in paths]
    if not logs:
        raise InputError("no logs to learn from")
    check_output(output, overwrite, inputs=logs + ([os.fspath(resume)] if resume else []))
    _check_scoring(scoring)
    return logs


def _check_scoring(scoring: str | None) -> None:
    if scoring is not None and scoring not in SCORING_RULES:
        raise InputError(f"scoring must be one of {', '.join(SCORING_RULES)}, not {scoring!r}")


def learn_files(paths: Sequence[str | os.PathLike], output: str | os.PathLike, *,
                spec: Spec | None = None, resume: str | os.PathLike | None = None,
                max_length: int | None = None, max_patterns: int | None = None,
                scoring: str | None = None, overwrite: bool = False, progress: bool = False,
                on_episode: Callable[[LearnResult, str], None] | None = None,
                window: TimeSlice | None = None, reader: Callable | PieceReader = read_episodes) -> LearnResult:
    """Learn the episodes of each log and save the library to ``output`` (atomically).

    Args:
        paths: logs (MCAP, rosbag2 folders, ``.db3``, ``.bag``), learned in this order.
        output: the library file (Parquet) to write.
        spec: the channel spec; ``None`` uses the pointer's for pointer logs.
        resume: a saved library to go on learning from (its spec, vocabulary, parameters).
        max_length: steps of history a context spans (default 6; 5 for ``literal``);
            fixed when resuming.
        max_patterns: forgetting bound (default none).
        scoring: ``adaptive`` (every occurrence counted, the default) or ``literal`` (the
            paper's rule); fixed when resuming.
        overwrite: replace an existing ``output``.
        progress: show reading progress on stderr.
        on_episode: called after each episode is learned with the running result
            (episodes, steps, events so far) and the episode's name.
        window: learn only this slice of each log's time (recorded in the provenance).
        reader: :func:`~slearn.io.serialize.read_episodes` (read here), or a reader with a
            ``pieces`` method as :func:`~slearn.io.serialize.read_pieces` (the logs' episodes
            in pieces: :class:`slearn.jobs.distributed.RayReader` reads them on Ray).

    Warnings (:class:`~slearn.errors.DataWarning`): a spec without an action channel,
    values outside an entry's ``range``.

    A truncated log is learned as far as it could be read; it is listed in the result's
    ``truncated`` (and warned about), and the library is still saved, unless nothing at
    all could be salvaged: then nothing is written. Cheap checks (the output, the resumed
    library with its provenance, ``SOURCE_DATE_EPOCH``) come before any learning.

    Raises:
        InputError: missing logs, an existing output without ``overwrite``, an output that
            is one of the inputs, bad parameters, nothing salvaged from damaged logs, no event
            at all in the logs (a new library).
        SpecError: the spec does not fit a log, or no spec for a log that is not a pointer log.
        LibraryFormatError: ``resume`` is not a readable library.
    """
    start = time.perf_counter()
    paths = checked_inputs(paths, output, overwrite, resume, scoring)
    source_date_epoch()
    job = (_resumed_job(os.fspath(resume), spec, max_length, max_patterns, scoring) if resume
           else _new_job(paths, spec, max_length, max_patterns, scoring, progress, window,
                         one_read=reader is read_episodes))
    for message in job.spec.warnings():
        warnings.warn(DataWarning(message), stacklevel=2)
    result = LearnResult(os.fspath(output), 0, 0, resumed_from=os.fspath(resume) if resume else None)
    _learn_episodes(job, paths, result, progress, on_episode, window, reader)
    if not result.n_steps and result.truncated:
        raise InputError(f"nothing could be salvaged, so nothing was written: "
                         f"{result.truncated[0].describe()}")
    if not result.n_events and not resume:
        names = ", ".join(f"{c.topic}:{c.field}" for c in job.spec.channels[:6])
        names += ", ..." if len(job.spec.channels) > 6 else ""
        raise InputError(f"{os.fspath(paths[0])}{' and the other logs' if len(paths) > 1 else ''}: no event to "
                         f"learn, so nothing was written: the spec's channels ({names}) gave no value they can "
                         f"take (text or a whole array under bins, or bins too fine to number?): check the "
                         f"fields with slearn info LOG")
    records = getattr(reader, "records", {})  # computed where the logs were read
    provenance = build_provenance(paths, job.provenance, window,
                                  [records[p] for p in paths] if all(p in records for p in paths) else None)
    for message in repeated_inputs(provenance["inputs"]):
        warnings.warn(DataWarning(message), stacklevel=2)
    saved = save_library(output, job.library, job.vocabulary, spec=job.spec, params=job.params,
                         provenance=provenance, overwrite=overwrite)
    result.n_patterns, result.size_bytes = saved.n_patterns, saved.size_bytes
    result.clock, result.forgotten = job.library.clock, job.library.forgotten
    result.n_symbols, result.seconds = len(job.vocabulary), time.perf_counter() - start
    return result


def _learn_episodes(job: _Job, paths: Sequence[str | os.PathLike], result: LearnResult, progress: bool,
                    on_episode: Callable[[LearnResult, str], None] | None,
                    window: TimeSlice | None, reader: Callable | PieceReader = read_episodes) -> None:
    if job.pieces is not None:  # read already (quantile bins fitted in the same read)
        pieces = job.pieces
    elif reader is read_episodes:  # read here, in pieces
        pieces = read_pieces(paths, job.spec, job.vocabulary, progress, window)
    else:  # read elsewhere, in pieces (Ray)
        pieces = cast(PieceReader, reader).pieces(paths, job.spec, job.vocabulary, progress, window)
    if isinstance(job.library, LiteralLibrary):  # its parse takes whole episodes
        pieces = ((name, episode, report, True, True)
                  for name, episode, report in _whole(pieces))
    hint = ScopeHint(job.spec, job.vocabulary, job.library)
    for path, piece, report, first, last in pieces:
        if isinstance(job.library, LiteralLibrary):
            job.library.learn(piece)
        else:
            job.library.learn(piece, new_episode=first)
            hint.see(piece)
        result.n_steps += len(piece)
        result.n_events += piece.n_events
        if not last:
            continue
        result.n_episodes += 1
        result.n_patterns = len(job.library)
        if report.truncated:
            result.truncated.append(report)
        if on_episode is not None:
            on_episode(result, path)
    hint.warn()


def _whole(pieces):
    """Pieces joined back into whole episodes."""
    from slearn.io.serialize import joined

    parts = []
    for name, piece, report, _, last in pieces:
        parts.append(piece)
        if last:
            yield name, joined(parts), report
            parts = []


def build_provenance(paths: Sequence[str | os.PathLike], previous: dict | None = None,
                     window: TimeSlice | None = None, records: list[dict] | None = None) -> dict:
    """Provenance of a library learned from ``paths`` (after ``previous``'s inputs, if any).

    Each input is ``{path, size_bytes, sha256}``, plus ``slice`` when only a slice of its
    time was learned. ``records`` are those of ``paths`` when already computed (by the
    workers that read the logs: :mod:`slearn.jobs.distributed`).

    Raises:
        InputError: a log cannot be read, or ``SOURCE_DATE_EPOCH`` is not an integer.
    """
    inputs = list(previous.get("inputs", [])) if previous else []
    records = records if records is not None else [log_record(p) for p in paths]
    inputs += [{**r, **({"slice": window.to_dict()} if window else {})} for r in records]
    stamp, source = source_date_epoch(), "SOURCE_DATE_EPOCH"
    if stamp is None:
        times = [int(os.stat(p).st_mtime) for p in paths]
        stamp = max(times + ([int(previous.get("time_unix", 0))] if previous else []))
        stamp, source = min(max(stamp, 0), MAX_TIME_UNIX), "newest input mtime"
    return {"slearn_version": __version__, "inputs": inputs, "time_unix": stamp,
            "time": datetime.fromtimestamp(stamp, timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
            "time_source": source}


def repeated_inputs(inputs: list[dict]) -> list[str]:
    """A warning for each input with the bytes of an earlier one (the same sha256; with
    ``--resume``, the library's own inputs come first) whose learned time overlaps it, or
    may: that time was learned twice, and its patterns count double."""
    out: list[str] = []
    earlier: dict[str | None, tuple[str | None, list[TimeSlice | None]]] = {}
    for entry in inputs:
        path, here = entry.get("path"), slice_from_dict(entry.get("slice"))
        first, learned = earlier.setdefault(entry.get("sha256"), (path, []))
        if shares_time(learned, here) is not False:
            what = "was learned before" if first == path else f"has the bytes of {first}, learned before"
            out.append(f"{path}: {what} into this library: that time was learned twice and "
                       f"counts double (give each log once, or disjoint --start/--end)")
        learned.append(here)
    return out


def source_date_epoch() -> int | None:
    """``SOURCE_DATE_EPOCH`` as whole seconds, ``None`` when unset.

    Raises:
        InputError: not an integer from 0 to 253402300799 (9999-12-31).
    """
    epoch = os.environ.get("SOURCE_DATE_EPOCH")
    if epoch is None:
        return None
    try:
        stamp = int(epoch)
    except ValueError:
        stamp = -1
    if not 0 <= stamp <= MAX_TIME_UNIX:
        raise InputError(f"SOURCE_DATE_EPOCH must be an integer from 0 to {MAX_TIME_UNIX} "
                         f"(9999-12-31), not {epoch[:40]!r}")
    return stamp
