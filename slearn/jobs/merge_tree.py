"""Learning many logs on Ray (``slearn learn --workers N`` / ``--ray ADDRESS``).

The logs are taken in the order a one-process run takes them. Each log is one task: it
learns the log's episodes into a partial library, grown from empty (the share of a task
is one log, so the result does not depend on how many workers or nodes ran it). The
partials merge in a balanced tree of tasks with :func:`slearn.jobs.merge.merge_libraries`,
each merge shifting the later library's recency by the earlier one's clock. The merge is
associative, so the tree gives the bytes of merging the per-log libraries in order one
after the other, as ``slearn merge`` does.

What equals one process, exactly: the vocabulary and token tables, every pattern with
its count and recency, their order, the clock, the spec, parameters and provenance (each
task hashes its own log). What cannot: the scoring state (expert weights, change
detectors, epochs and fresh counts) is trained by predicting each step with the library
as it stood, which a task that starts from empty does not have; it follows the rule of
:func:`~slearn.jobs.merge.merge_libraries` (the latest log's weights, the detectors'
calibration counts added; an alarm in a later log starts the epoch).
``bench/bench_ray.py`` measures the accuracy this costs on held-out logs. A single
log gives exactly the bytes of one process.

Refused, because they would change the library silently: ``--max-patterns`` (one
process forgets along the way, a merge only at the end) and ``--scoring literal`` (its
parse depends on the whole run). ``--resume`` works: the resumed library is the first
leaf. Errors keep one process's meaning: a bad log stops the job naming the file (exit
1), a truncated log is learned as far as it reads (exit 3), and the output is written
once, atomically, after every task succeeded. Range warnings are counted per log.
"""

from __future__ import annotations

import dataclasses
import os
import time
import warnings
from pathlib import Path
from typing import Any, Callable, Sequence

from slearn import __version__
from slearn.core.library import PatternLibrary
from slearn.core.vocabulary import Vocabulary
from slearn.errors import DataWarning, InputError
from slearn.io.bags import log_record
from slearn.io.library_file import save_library
from slearn.io.mcap_read import ReadReport
from slearn.io.serialize import prepare_vocabulary, read_episodes
from slearn.io.slicing import TimeSlice, slice_from_dict
from slearn.io.spec import Spec
from slearn.jobs.cluster import (
    MAX_RETRIES,
    Rate,
    check_visible,
    gather,
    library_bytes,
    library_from_bytes,
    loaded_bytes,
    ray_session,
)
from slearn.jobs.learn import (
    LearnResult,
    _new_job,
    _resumed_job,
    build_provenance,
    checked_inputs,
    repeated_inputs,
    source_date_epoch,
)
from slearn.jobs.merge import merge_libraries
from slearn.jobs.pages import small_pages

# A partial library's provenance: the job writes the real one (every input, in order).
_PARTIAL = {"slearn_version": __version__, "inputs": [], "time_unix": 0,
            "time": "1970-01-01T00:00:00Z", "time_source": "a partial library of a Ray job"}


def learn_on_ray(paths: Sequence[str | os.PathLike], output: str | os.PathLike, *,
                 workers: int | None = None, address: str | None = None,
                 spec: Spec | None = None, resume: str | os.PathLike | None = None,
                 max_length: int | None = None, max_patterns: int | None = None,
                 scoring: str | None = None, overwrite: bool = False, progress: bool = False,
                 echo: Callable[[str], None] | None = None,
                 window: TimeSlice | None = None) -> LearnResult:
    """:func:`slearn.jobs.learn.learn_files` on Ray: ``workers`` CPUs here, or the cluster at
    ``address`` (see the module docstring for what equals one process).

    ``echo`` receives a progress line per log learned (logs done / total, events/s).

    Raises:
        InputError: as :func:`~slearn.jobs.learn.learn_files`; ``max_patterns`` or the literal
            scoring (refused); Ray missing; a log a worker cannot see.
        ClusterError: the cluster cannot be reached, or a worker died too often.
    """
    start = time.perf_counter()
    paths = checked_inputs(paths, output, overwrite, resume, scoring)
    _refuse_order_dependent(scoring, max_patterns)
    source_date_epoch()
    job = (_resumed_job(os.fspath(resume), spec, max_length, None, scoring) if resume
           else _new_job(paths, spec, max_length, None, scoring, progress, window))
    _refuse_order_dependent(job.params.get("scoring"), job.library.max_patterns)
    for message in job.spec.warnings():
        warnings.warn(DataWarning(message), stacklevel=2)
    result = LearnResult(os.fspath(output), 0, 0, resumed_from=os.fspath(resume) if resume else None)
    first = Path(resume).read_bytes() if resume else None
    with ray_session(workers, address) as ray:
        stats, merged = _learn_tasks(ray, paths, job.spec, job.library.max_length, window, first,
                                     Rate("learned", len(paths), echo))
    _add_stats(result, stats)
    if not result.n_steps and result.truncated:
        raise InputError(f"nothing could be salvaged, so nothing was written: "
                         f"{result.truncated[0].describe()}")
    library, vocabulary = _final(merged, job)
    provenance = build_provenance(paths, job.provenance, window, [s["record"] for s in stats])
    for message in repeated_inputs(provenance["inputs"]):
        warnings.warn(DataWarning(message), stacklevel=2)
    saved = save_library(output, library, vocabulary, spec=job.spec, params=job.params,
                         provenance=provenance, overwrite=overwrite)
    result.n_patterns, result.size_bytes = saved.n_patterns, saved.size_bytes
    result.clock, result.forgotten = library.clock, library.forgotten
    result.n_symbols, result.seconds = len(vocabulary), time.perf_counter() - start
    return result


def _refuse_order_dependent(scoring: str | None, max_patterns: int | None) -> None:
    if scoring == "literal":
        raise InputError("--scoring literal cannot be learned with --merge-tree: its parse depends on "
                         "the whole run; learn it with --workers alone, or in one process")
    if max_patterns is not None:
        raise InputError("--max-patterns cannot be learned with --merge-tree: one process forgets along "
                         "the way, a merge only at the end, so the library would differ; leave it out, or "
                         "learn with --workers alone (the logs are read in parallel, learned in order)")


def _learn_tasks(ray, paths: Sequence[str | os.PathLike], spec: Spec, max_length: int, window: TimeSlice | None,
                 first: bytes | None, rate: Rate) -> tuple[list[dict], bytes | None]:
    """Per log its stats, and the bytes of the merged library (``None``: nothing learned)."""
    learn = ray.remote(num_returns=2, max_retries=MAX_RETRIES)(learn_log)
    merge = ray.remote(max_retries=MAX_RETRIES)(merge_pair)
    spec_data, window_data = spec.to_dict(), window.to_dict() if window else None
    tasks = [learn.remote(path, spec_data, spec.source, max_length, window_data) for path in paths]
    leaves = ([ray.put(first)] if first is not None else []) + [partial for _, partial in tasks]
    root = merge_tree(merge, leaves)
    stats = gather(ray, [s for s, _ in tasks], [os.fspath(p) for p in paths], lambda i, s: rate.add(s["events"]))
    return stats, gather(ray, [root], ["merging the partial libraries"])[0]


def merge_tree(merge, leaves: list):
    """The root of a balanced tree of ``merge.remote(a, b)`` over ``leaves``, in order."""
    while len(leaves) > 1:
        pairs = [merge.remote(leaves[i], leaves[i + 1]) for i in range(0, len(leaves) - 1, 2)]
        leaves = pairs + (leaves[-1:] if len(leaves) % 2 else [])
    return leaves[0]


def learn_log(path: str, spec: dict, source: str, max_length: int,
              window: dict | None) -> tuple[dict, bytes | None]:
    """The task: one log learned from empty. Returns its stats (``record`` for the
    provenance, ``truncated`` read report, ``warnings``) and its library file's bytes
    (``None`` when it has no step)."""
    small_pages()
    check_visible(path)
    spec_object = Spec.from_dict(spec, source)
    vocabulary = Vocabulary()
    library = PatternLibrary(max_length, None, vocabulary=vocabulary,
                             action_scopes=spec_object.action_scopes())
    stats: dict[str, Any] = {"path": path, "episodes": 0, "steps": 0, "events": 0, "truncated": None}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for _, episode, report in read_episodes([path], spec_object, vocabulary, False,
                                                slice_from_dict(window)):
            library.learn(episode)
            stats["episodes"] += 1
            stats["steps"] += len(episode)
            stats["events"] += episode.n_events
            if report.truncated:
                stats["truncated"] = dataclasses.asdict(report)
    stats["warnings"] = [str(w.message) for w in caught if issubclass(w.category, DataWarning)]
    stats["record"] = log_record(path)
    if not stats["steps"]:
        return stats, None
    return stats, library_bytes(lambda out: save_library(
        out, library, vocabulary, spec=spec_object, params={"scoring": "adaptive"},
        provenance=_PARTIAL))


def merge_pair(a: bytes | None, b: bytes | None) -> bytes | None:
    """The task: the library of ``a``'s episodes, then ``b``'s (file bytes; ``None`` is empty)."""
    small_pages()
    if a is None or b is None:
        return a if b is None else b
    return loaded_bytes(merge_libraries(library_from_bytes(a), library_from_bytes(b), consume=True))


def _add_stats(result: LearnResult, stats: list[dict]) -> None:
    seen = set()
    for s in stats:
        result.n_episodes += s["episodes"]
        result.n_steps += s["steps"]
        result.n_events += s["events"]
        if s["truncated"] is not None:
            result.truncated.append(ReadReport(**s["truncated"]))
        for message in s["warnings"]:
            if message not in seen:
                seen.add(message)
                warnings.warn(DataWarning(message), stacklevel=3)


def _final(merged: bytes | None, job) -> tuple:
    """The library and vocabulary to save: the merged one, or the job's empty one."""
    if merged is None:
        prepare_vocabulary(job.spec, job.vocabulary)
        return job.library, job.vocabulary
    loaded = library_from_bytes(merged)
    return loaded.library, loaded.vocabulary
