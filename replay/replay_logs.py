"""``slearn replay`` without the command line: load a library, read held-out logs exactly as
at learning time, fit the baselines on the training logs, and run
:func:`slearn.replay.evaluation.evaluate` with a progress line per episode on stderr."""

from __future__ import annotations

import math
import os
import sys
import time
import warnings
from dataclasses import dataclass, field
from typing import Any, Iterable, Iterator

from slearn.core.library import DEFAULT_MAX_LENGTH, PatternLibrary
from slearn.core.literal import LiteralLibrary
from slearn.core.stream import Episode
from slearn.core.vocabulary import Vocabulary
from slearn.errors import DataWarning, InputError, TruncatedLogWarning
from slearn.io.bags import check_log_path, is_log_path
from slearn.io.library_file import input_places
from slearn.io.mcap_read import ReadReport
from slearn.io.slicing import TimeSlice, shares_time, slice_from_dict
from slearn.io.spec import Spec
from slearn.replay.baselines import Baselines
from slearn.replay.evaluation import FIT_PREQUENTIAL, FIT_TRAINING, Checkpoint, Evaluation, evaluate


def _progress_line(point: Checkpoint) -> None:
    e = point.episode
    sys.stderr.write(f"replay: {os.path.basename(e.name)}: {e.tally.events} events, accuracy "
                     f"{_pct(e.tally.accuracy)} (frequency {_pct(e.tally.rate('frequency'))}, "
                     f"markov {_pct(e.tally.rate('markov'))}); {point.predictions} predictions, "
                     f"{point.predictions / max(point.elapsed_s, 1e-9):,.0f}/s\n")
    sys.stderr.flush()


def _pct(x: float) -> str:
    return "-" if math.isnan(x) else f"{100 * x:.2f} %"


# --- logs on disk ---------------------------------------------------------------------

@dataclass
class _Setup:
    library: PatternLibrary | LiteralLibrary
    vocabulary: Vocabulary
    spec: Spec
    facts: dict[str, Any]
    training_logs: list[str]
    notes: list[str]
    training_slices: dict[str, TimeSlice] = field(default_factory=dict)


def replay_logs(logs: Iterable[str | os.PathLike], *, library: str | os.PathLike | None = None,
                spec: str | os.PathLike | None = None, online: bool = False, top_k: int = 3,
                window: int | None = None, max_length: int = DEFAULT_MAX_LENGTH,
                baseline_logs: Iterable[str | os.PathLike] | None = None,
                keep_outcomes: bool = False, progress: bool = False,
                time_slice: TimeSlice | None = None, reader: Any = None) -> Evaluation:
    """Evaluate a saved library (or, with ``spec`` only, an empty one) on MCAP logs.

    The logs are read and binned as at learning time (the library's spec, fitted edges
    included, and its vocabulary, so symbols match; values never seen while learning get
    new symbols the library simply cannot predict).

    Args:
        logs: held-out MCAP files, one episode each, in this order.
        library: a library file written by :func:`slearn.io.library_file.save_library`.
        spec: a TOML spec (or a :class:`~slearn.io.spec.Spec`), to start from an empty
            library (``online`` is then implied) or for a library saved without its spec.
        online: learn while replaying (prequential); else the library stays frozen.
        top_k, window: see :func:`iter_evaluation`.
        max_length: context length of an empty library.
        baseline_logs: the logs to count the baselines on (default: the library's
            training logs when its provenance names them and they are unchanged on disk).
        keep_outcomes: keep per-step predictions (for :mod:`slearn.replay.annotate`).
        progress: progress on stderr.
        time_slice: replay only this slice of each log's time (``--split``: the held-out
            part); the baselines count each training log's slice the library learned.
        reader: reads logs into episodes, as :func:`slearn.io.serialize.read_episodes` (the
            default; :class:`slearn.jobs.distributed.RayReader` reads them on Ray).

    Data warnings (values outside a range, a spec without actions, too few events per
    channel) end up in the result's ``warnings``.

    Raises:
        InputError: no library and no spec, a spec given for a library that has its own,
            a library without spec, or a log that cannot be read (names the file).
        LibraryFormatError: the library file cannot be read.
    """
    started = time.perf_counter()
    logs = [os.fspath(p) for p in logs]
    if not logs:
        raise InputError("no logs to replay: give at least one MCAP file")
    for path in logs:
        check_log_path(path)
    setup = _open_library(library, spec, logs) if library is not None else \
        _empty_library(spec, max_length, logs, progress)
    online = online or library is None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("ignore", TruncatedLogWarning)  # reported in the result instead
        warnings.simplefilter("always", DataWarning)
        baselines, fit, salvaged = _fit_baselines(setup, baseline_logs, progress, reader)
        source = "the --baseline-train logs" if baseline_logs else "the library's training logs"
        episodes = _read(logs, setup.spec, setup.vocabulary, progress, time_slice, reader)
        result = evaluate(setup.library, episodes, setup.vocabulary, online=online, top_k=top_k,
                          window=window, baselines=baselines, baseline_fit=fit,
                          baseline_source=source,
                          keep_outcomes=keep_outcomes, on_episode=_progress_line if progress else None)
    result.warnings[:0] = setup.spec.warnings() + _learned_here(logs, setup.facts["provenance"], time_slice) \
        + ([] if online else _fresh_leaders(setup)) \
        + list(dict.fromkeys(str(w.message) for w in caught if issubclass(w.category, DataWarning)))
    result.baseline_truncated = [report.path for report in salvaged]
    result.warnings += [f"baselines: {report.describe()}; the baselines were counted on what was salvaged"
                        for report in salvaged]
    result.setup = {**setup.facts, "logs": logs, "spec": setup.spec.to_dict()}
    if time_slice is not None:
        result.setup["slice"] = time_slice.to_dict()
    result.notes[:0] = setup.notes
    result.spec = setup.spec
    result.total_s = time.perf_counter() - started
    return result


def _read(paths: list[str], spec: Spec, vocabulary: Vocabulary, progress: bool,
          window: TimeSlice | dict[str, TimeSlice] | None = None, reader: Any = None
          ) -> Iterator[tuple[str, Episode, ReadReport]]:
    from slearn.io.serialize import read_episodes

    yield from (reader or read_episodes)(paths, spec, vocabulary, progress, window)


def _open_library(path: str | os.PathLike, spec_path: str | os.PathLike | None,
                  logs: list[str]) -> _Setup:
    from slearn.io.library_file import load_library
    from slearn.io.spec import load_spec

    loaded = load_library(path)
    if loaded.spec is not None and spec_path is not None:
        raise InputError(f"{path}: the library carries the spec it was learned with; drop --spec "
                         "(logs must be binned as at learning time)")
    if loaded.spec is None and spec_path is None:
        raise InputError(f"{path}: the library was saved without a spec: give the one it was "
                         "learned with (--spec FILE)")
    spec = loaded.spec if loaded.spec is not None else \
        spec_path if isinstance(spec_path, Spec) else load_spec(spec_path)
    if not spec.fitted:
        raise InputError(f"{path}: the library's spec has unfitted quantile bins: re-learn it")
    lib = loaded.library
    facts = {"library": {"path": os.fspath(path), "format_version": loaded.format_version,
                         "patterns": len(lib), "max_length": lib.max_length,
                         "max_patterns": lib.max_patterns, "clock": lib.clock},
             "params": _jsonable(loaded.params), "provenance": _jsonable(loaded.provenance)}
    training = _training_logs(loaded.provenance, os.path.dirname(os.fspath(path)))
    return _Setup(lib, loaded.vocabulary, spec, facts, training, [],
                  _training_slices(loaded.provenance, training))


def _empty_library(spec_path: str | os.PathLike | None, max_length: int, logs: list[str],
                   progress: bool) -> _Setup:
    from slearn.io.serialize import fit_spec, prepare_vocabulary
    from slearn.io.spec import load_spec

    if spec_path is None:
        raise InputError("no library: give a library file, or --spec FILE to start from an empty one")
    spec = (spec_path if isinstance(spec_path, Spec) else load_spec(spec_path)).predicting()
    notes = ["no library: started from an empty one and learned online"]
    if not spec.fitted:
        spec = fit_spec(spec, logs, progress)
        notes.append("quantile bins were fitted on the replayed logs themselves")
    vocabulary = prepare_vocabulary(spec, Vocabulary())
    library = PatternLibrary(max_length, vocabulary=vocabulary, action_scopes=spec.action_scopes())
    facts = {"library": None, "params": {"max_length": max_length, "max_patterns": None,
                                         "scoring": "adaptive"}, "provenance": None}
    return _Setup(library, vocabulary, spec, facts, [], notes)


def _training_logs(provenance: dict, library_dir: str) -> list[str]:
    """The library's input logs when all are still on disk, unchanged (size and sha256).

    Relative paths are tried from the working folder, then from the library's folder.
    """
    inputs = provenance.get("inputs") if isinstance(provenance, dict) else None
    if not inputs or not isinstance(inputs, list):
        return []
    paths = [_unchanged(entry, library_dir) for entry in inputs]
    return paths if all(paths) else []


def _unchanged(entry: Any, library_dir: str) -> str | None:
    from slearn.io.bags import log_record

    for path in input_places(entry, library_dir):
        if os.path.isfile(path) or is_log_path(path):
            record = log_record(path)  # reads the whole log: once
            if (record["size_bytes"], record["sha256"]) == (entry.get("size_bytes"), entry.get("sha256")):
                return path
    return None


def _learned_here(logs: list[str], provenance: Any, replayed: TimeSlice | None) -> list[str]:
    """A warning for each held-out log the library learned (the same bytes, by its
    provenance's sha256) where the time replayed overlaps the time learned, or may: its
    accuracy is not held-out."""
    from slearn.io.bags import log_files, log_record

    inputs = provenance.get("inputs") if isinstance(provenance, dict) else None
    learned: dict[str, list[TimeSlice | None]] = {}
    sizes = set()
    for entry in inputs if isinstance(inputs, list) else []:
        if isinstance(entry, dict) and isinstance(entry.get("sha256"), str):
            learned.setdefault(entry["sha256"], []).append(slice_from_dict(entry.get("slice")))
            sizes.add(entry.get("size_bytes"))
    out = []
    for path in logs if learned else []:
        if sum(f.stat().st_size for f in log_files(path)) not in sizes:
            continue  # other bytes for sure: no need to read the log to hash it
        shared = shares_time(learned.get(log_record(path)["sha256"], []), replayed)
        if shared is not False:
            how = "overlaps the time it learned: its accuracy is" if shared else \
                "may overlap the time it learned: its accuracy may be"
            out.append(f"{path}: the library learned this log (same bytes), and the time replayed "
                       f"{how} no held-out figure; replay other logs, or learn with --split and "
                       f"replay with the same --split")
    return out


def _fresh_leaders(setup: _Setup) -> list[str]:
    """A warning when a frozen library's views predict with fresh counts: at the end of
    learning their leading expert reads the counts since the last change of dynamics the
    view detected, so a held-out log that starts in other dynamics (each training log of a
    switch condition starts before its switch) is predicted with those of after the change
    until it ends, and nothing frozen can notice."""
    from slearn.core.library import JOINT
    from slearn.core.mixer import FRESH

    library = setup.library
    mixer = getattr(library, "mixer", None)
    if mixer is None or setup.facts.get("library") is None:
        return []
    leading_kind = mixer.weight.max(axis=1).argmax(axis=1)  # per view: the kind of its best expert
    fresh = [(name, int(mixer.epoch[v])) for v, name in enumerate(library.view_names)
             if mixer.epoch[v] > 0 and leading_kind[v] == FRESH]
    if not fresh:
        return []
    if [name for name, _ in fresh] == [JOINT]:
        which = f"it predicts (after {fresh[0][1]} alarms)"
    else:
        views = ", ".join(f"{name} ({alarms} alarms)" for name, alarms in fresh)
        which = f"view {views} predicts" if len(fresh) == 1 else f"views {views} predict"
    return [f"{setup.facts['library']['path']}: frozen, {which} with the counts since the last "
            "change of dynamics detected while learning; a held-out log that starts in other "
            "dynamics (as a training log with a switch did) is predicted with those throughout: "
            "replay it --online to follow changes as learning does"]


def _training_slices(provenance: dict, training: list[str]) -> dict[str, TimeSlice]:
    """The slice of each training log the library learned (``slice`` in its provenance)."""
    inputs = provenance.get("inputs") if isinstance(provenance, dict) else None
    if not training or not isinstance(inputs, list):
        return {}
    return {path: slice_from_dict(entry.get("slice")) for path, entry in zip(training, inputs)
            if isinstance(entry, dict) and entry.get("slice")}


def _fit_baselines(setup: _Setup, baseline_logs: Iterable[str | os.PathLike] | None,
                   progress: bool, reader: Any = None) -> tuple[Baselines | None, str, list[ReadReport]]:
    """The baselines counted on their training logs (``--baseline-train``, else the
    library's own), how they were fitted, and the read reports of training logs that were
    truncated (the baselines count what was salvaged; replay warns and exits 3)."""
    paths = [os.fspath(p) for p in baseline_logs] if baseline_logs else setup.training_logs
    if not paths:
        return None, FIT_PREQUENTIAL, []
    baselines = Baselines(setup.library)
    if progress:
        sys.stderr.write(f"replay: counting the baselines on {len(paths)} training log(s)\n")
    salvaged = []
    for _, episode, report in _read(paths, setup.spec, setup.vocabulary, False,
                                    setup.training_slices if not baseline_logs else None, reader):
        baselines.learn(setup.library.encode(episode))
        if report is not None and report.truncated:
            salvaged.append(report)
    setup.facts["baseline_logs"] = paths
    return baselines, FIT_TRAINING, salvaged


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (str, int, float, bool)) or value is None:
        return value
    return str(value)
