"""Replay: how well a pattern library predicts held-out episodes, next to two baselines.

:func:`iter_evaluation` is the core, a generator in the manner of river's
``iter_progressive_val_score``: it runs the library's predictor over each episode
(:func:`slearn.online.run_online`; ``online=False`` keeps the library frozen, ``True``
learns each step after predicting it, prequentially) and yields a :class:`Checkpoint`
per episode. :func:`evaluate` collects the checkpoints into an :class:`Evaluation`;
:func:`replay_logs` does the I/O around it (load the library, read the logs exactly as
at learning time, fit the baselines) for ``slearn replay``.

Baselines (:mod:`slearn.replay.baselines`) see the same token stream. How they are
trained is reported as ``baselines.fit``:

* ``"training"``: counted on the library's training logs (given, or named in the
  library's provenance and still on disk), then scored like the library: frozen in a
  frozen replay, learning as they go in an online one. The fair comparison.
* ``"prequential"``: no training logs at hand, so they learn on the held-out stream as
  they go (predict each step, then count it). In a frozen replay that favours the
  baselines, which adapt to the held-out logs while the library does not: the lift is a
  lower bound. In an online replay of a library learned elsewhere it favours the library.
"""

from __future__ import annotations

import copy
import math
import os
import sys
import time
import warnings
from collections import Counter
from dataclasses import asdict, dataclass, field
from typing import Any, Iterable, Iterator

import numba
import numpy as np

from slearn.bags import is_log_path
from slearn.context_index import find_entry
from slearn.errors import DataWarning, InputError, TruncatedLogWarning
from slearn.library import DEFAULT_MAX_LENGTH, PatternLibrary
from slearn.mcap_read import ReadReport
from slearn.online import run_online_tokens
from slearn.predictor import Predictor, Scoring, collect
from slearn.replay.baselines import Baselines
from slearn.replay.honest import HonestScores
from slearn.replay.metrics import (ChannelCounts, ChannelDecoder, Curve, Tally, channel_counts,
                                   channel_hits, confusions, learning_curve, score_steps)
from slearn.replay.windows import data_window
from slearn.slicing import TimeSlice, slice_from_dict
from slearn.spec import Spec
from slearn.stream import Episode
from slearn.tokens import TokenTable
from slearn.vocabulary import Vocabulary

SCHEMA = "slearn.replay/1"
"""Name and version of the JSON document (:meth:`Evaluation.to_dict`)."""

FROZEN, ONLINE = "frozen", "online"
FIT_TRAINING, FIT_PREQUENTIAL = "training", "prequential"
SURPRISE_FLOOR = 2.0 ** -16
"""Smallest probability a surprise is computed from (so at most 16 bits)."""

N_CONFUSIONS = 10


@dataclass(frozen=True)
class EpisodeOutcome:
    """Per step of one episode (after its first observation): predictions and truth.

    Attributes:
        name: the episode's name (its log's path).
        actual: the observed token.
        predicted: the library's prediction, -1 where it abstained.
        top: ``(steps, top_k)`` the library's ranked guesses, -1 padded.
        score: the share of the chosen context's weight behind the prediction.
        matched_length: history tokens the chosen context spans (-1 abstained).
        frequency: the frequency baseline's prediction (-1 abstained).
        markov: the Markov baseline's prediction (-1 abstained).
        evaluated: steps that count (their observations are not empty).
        first_step: the episode step predicted by step 0 (1, or 0 when the episode's
            first step carries actions).
        truth_probability: the share of the chosen context's weight behind what happened
            (frozen replays asked for it; else NaN: online, the library has moved on since).
    """

    name: str
    actual: np.ndarray
    predicted: np.ndarray
    top: np.ndarray
    score: np.ndarray
    matched_length: np.ndarray
    frequency: np.ndarray
    markov: np.ndarray
    evaluated: np.ndarray
    first_step: int
    truth_probability: np.ndarray

    def __len__(self) -> int:
        return len(self.actual)

    def surprise_bits(self) -> np.ndarray:
        """``-log2`` of the probability the library gave what happened (floored).

        The probability is the share of the chosen context's weight behind what happened
        (0 when abstaining). Where that is not known (online, or not asked for), a wrong
        prediction gets the share left to all other outcomes, ``1 - score``: an upper
        bound, so the surprise is a lower bound.
        """
        bound = np.where(self.predicted == self.actual, self.score, 1.0 - self.score)
        p = np.where(np.isnan(self.truth_probability), bound, self.truth_probability)
        p = np.where(self.predicted < 0, 0.0, p)
        return -np.log2(np.maximum(p, SURPRISE_FLOOR))


@dataclass
class EpisodeSummary:
    """The scores of one episode."""

    name: str
    steps: int
    tally: Tally
    channels: ChannelCounts
    curve: Curve
    truncated: bool = False
    read: str | None = None

    def to_dict(self) -> dict:
        """JSON-ready (see :meth:`Evaluation.to_dict`)."""
        return {"name": self.name, "steps": self.steps, **self.tally.to_dict(),
                "channels": self.channels.to_list(), "truncated": self.truncated,
                "read": self.read, "curve": self.curve.to_list()}


@dataclass(frozen=True)
class Checkpoint:
    """What :func:`iter_evaluation` yields after each episode.

    Attributes:
        episode: the episode's scores.
        outcome: its per-step predictions.
        totals: scores over all episodes so far.
        predictions: predictions made so far.
        elapsed_s: seconds spent predicting and scoring so far (reading excluded).
    """

    episode: EpisodeSummary
    outcome: EpisodeOutcome
    totals: Tally
    predictions: int
    elapsed_s: float


@dataclass
class Evaluation:
    """A whole replay: scores, per channel and episode, confusions, and its setup."""

    mode: str
    top_k: int
    window: int
    baseline_fit: str
    baseline_order: int
    totals: Tally
    channels: ChannelCounts
    episodes: list[EpisodeSummary]
    confusions: list[tuple[str, str, int]]
    predictions: int
    elapsed_s: float
    setup: dict[str, Any] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    outcomes: list[EpisodeOutcome] = field(default_factory=list)
    total_s: float | None = None
    spec: Spec | None = None
    vocabulary: Vocabulary | None = None
    tokens: TokenTable | None = None
    scoring: dict[str, Any] = field(default_factory=dict)
    honest: HonestScores | None = None

    @property
    def accuracy(self) -> float:
        """Overall accuracy in [0, 1] (NaN without events)."""
        return self.totals.accuracy

    @property
    def truncated(self) -> bool:
        """Whether some log was truncated (only what was salvaged was scored)."""
        return any(e.truncated for e in self.episodes)

    @property
    def predictions_per_s(self) -> float:
        """Predictions per second of the evaluation core (reading excluded)."""
        return self.predictions / self.elapsed_s if self.elapsed_s > 0 else math.nan

    def to_dict(self) -> dict:
        """The ``slearn.replay/1`` JSON document.

        Rates are in [0, 1] and ``null`` when undefined (no events); lifts are in
        percentage points (library accuracy minus baseline accuracy). Keys::

            schema        "slearn.replay/1"
            mode          "frozen" | "online"
            top_k, window ranked guesses counted; steps per learning-curve window
            scoring       the predictor's {rule, alpha, buckets, prior}
            library       {path, format_version, patterns, max_length, max_patterns, clock}
                          or null (empty start)
            params, provenance, spec, logs, baseline_logs (when the baselines were trained)
            totals        TALLY over all logs
            baselines     {fit: "training" | "prequential", markov_max_order}
            channels      [{channel, events, correct, abstained, accuracy,
                            frequency_accuracy, markov_accuracy}]
            episodes      [{name, steps, TALLY..., channels, truncated, read,
                            curve: [{start_step, end_step, events, accuracy,
                                     frequency_accuracy, markov_accuracy,
                                     channel_accuracy: [per channel, in "channels" order]}]}]
            confusions    [{predicted, actual, count}] most frequent first,
                          "channel=value, ..." labels
            speed         {predictions, evaluation_s, predictions_per_s, total_s}
            notes, warnings  [str]
            honest        intervals, the persistence baseline, paired lift intervals,
                          small-sample channels (:meth:`HonestScores.to_dict`)

        ``TALLY`` is ``events, correct, abstained, accuracy, abstention_rate,
        accuracy_when_predicting, top_k_correct, top_k_accuracy, baselines: {frequency,
        markov: {correct, abstained, accuracy, lift_points}}``. ``slearn replay --json``
        adds ``outputs`` (``plot``, ``report``, ``annotated``: the files written).
        New keys may appear within a version; renamed or removed keys bump it.
        """
        return {
            "schema": SCHEMA,
            "mode": self.mode,
            "top_k": self.top_k,
            "window": self.window,
            "scoring": self.scoring,
            **self.setup,
            "totals": self.totals.to_dict(),
            "baselines": {"fit": self.baseline_fit, "markov_max_order": self.baseline_order},
            "channels": self.channels.to_list(),
            "episodes": [e.to_dict() for e in self.episodes],
            "confusions": [{"predicted": p, "actual": a, "count": c} for p, a, c in self.confusions],
            "speed": {"predictions": self.predictions, "evaluation_s": round(self.elapsed_s, 6),
                      "predictions_per_s": _finite(self.predictions_per_s),
                      "total_s": None if self.total_s is None else round(self.total_s, 6)},
            "notes": self.notes,
            "warnings": self.warnings,
            "honest": self.honest.to_dict() if self.honest is not None else None,
        }


def _finite(x: float) -> float | None:
    return None if math.isnan(x) else round(x, 1)


# --- the core -------------------------------------------------------------------------

def iter_evaluation(library: PatternLibrary, episodes: Iterable[tuple[str, Episode, ReadReport | None]],
                    vocabulary: Vocabulary, *, online: bool = False, top_k: int = 3,
                    scoring: Scoring | str = "adaptive", window: int | None = None,
                    baselines: Baselines | None = None, baselines_learn: bool = True,
                    truth_probability: bool = False) -> Iterator[Checkpoint]:
    """Predict every observation of every episode; yield a :class:`Checkpoint` per episode.

    Args:
        library: the pattern library; it learns only when ``online``.
        episodes: ``(name, episode, read report or None)``, symbols of ``vocabulary``.
        vocabulary: names the symbols (for the per-channel scores).
        online: learn each step after predicting it (prequential); else frozen.
        top_k: how many ranked guesses count for the top-k accuracy.
        scoring: the predictor's scoring rule.
        window: steps per learning-curve window (default: about 50 over the first episode).
        baselines: the baselines to run beside the library (default: fresh, of the
            library's order).
        baselines_learn: whether the baselines count each step after predicting it.
        truth_probability: in a frozen replay, also compute the probability the library
            gave what happened (for surprise; about 10 % more time), else NaN.
    """
    predictor = Predictor(library, scoring, top_k)
    baselines = baselines if baselines is not None else Baselines(library.max_length - 1)
    decoder = ChannelDecoder(library.tokens, vocabulary)
    totals, predictions, elapsed = Tally(), 0, 0.0
    for name, episode, report in episodes:
        started = time.perf_counter()
        outcome = _predict_episode(name, episode, predictor, baselines, online, baselines_learn,
                                   truth_probability)
        if window is None and len(outcome):
            window = data_window(len(outcome), int(outcome.evaluated.sum()))
        summary = _summarize(outcome, decoder, window or 1, report)
        elapsed += time.perf_counter() - started
        totals += summary.tally
        predictions += len(outcome)
        yield Checkpoint(summary, outcome, copy.copy(totals), predictions, elapsed)


def _predict_episode(name: str, episode: Episode, predictor: Predictor, baselines: Baselines,
                     online: bool, baselines_learn: bool, truth_probability: bool) -> EpisodeOutcome:
    tokens = predictor.library.tokens.tokenize(episode)
    result = run_online_tokens(predictor, tokens, learn=online)
    guesses = baselines.run_tokens(tokens, learn=baselines_learn)
    offsets = predictor.library.tokens.arrays.offsets
    evaluated = offsets[result.actual + 1] > offsets[result.actual]
    first_step = 0 if len(episode) and episode.n_actions[0] > 0 else 1
    if online or not truth_probability:
        truth = np.full(len(result.actual), np.nan)
    else:
        library = predictor.library
        truth = _truth_probability(library.context_index(), tokens, result.matched_length,
                                   library.max_length)
    return EpisodeOutcome(name, result.actual, result.predicted, result.top, result.score,
                          result.matched_length, guesses.frequency, guesses.markov, evaluated,
                          first_step, truth)


@numba.njit(cache=True)
def _truth_probability(index, tokens, matched, max_length):
    """Per step, the share of the chosen context's weight behind the observed token."""
    out = np.zeros(len(matched))
    cand = np.zeros(2 * max_length, np.int32)
    for step in range(1, len(matched) + 1):
        if matched[step - 1] < 0:
            continue
        obs_pos = 2 * step - 2
        collect(index, tokens, obs_pos, tokens[obs_pos + 1], max_length, cand)
        node = cand[matched[step - 1] - 1]
        e = find_entry(index, node, tokens[obs_pos + 2])
        if e >= 0:
            out[step - 1] = index.weight[e] / index.total[node]
    return out


def _summarize(outcome: EpisodeOutcome, decoder: ChannelDecoder, window: int,
               report: ReadReport | None) -> EpisodeSummary:
    o = outcome
    scores = score_steps(o.predicted, o.actual, o.top, o.frequency, o.markov, o.evaluated)
    hits = channel_hits(decoder, o.predicted, o.actual, o.frequency, o.markov)
    hits = {k: v & o.evaluated[:, None] for k, v in hits.items()}
    truncated = bool(report is not None and report.truncated)
    return EpisodeSummary(o.name, len(o), scores.tally(), channel_counts(decoder.channels, hits),
                          learning_curve(scores, hits, window), truncated,
                          report.describe() if report is not None else None)


def evaluate(library: PatternLibrary, episodes: Iterable[tuple[str, Episode, ReadReport | None]],
             vocabulary: Vocabulary, *, online: bool = False, top_k: int = 3,
             scoring: Scoring | str = "adaptive", window: int | None = None,
             baselines: Baselines | None = None, baseline_fit: str | None = None,
             keep_outcomes: bool = False, progress: bool = False) -> Evaluation:
    """Run :func:`iter_evaluation` to the end and collect an :class:`Evaluation`.

    Args:
        baselines: baselines already counted on the training data (``baseline_fit``
            ``"training"``); ``None`` starts them empty and lets them learn as they go.
        baseline_fit: how ``baselines`` were fitted (default from whether they were given).
        keep_outcomes: keep every episode's per-step predictions, with the probability of
            what happened in a frozen replay (for annotated logs).
        progress: one line per episode on stderr.

    The other arguments are those of :func:`iter_evaluation`.
    """
    fit = baseline_fit or (FIT_TRAINING if baselines is not None else FIT_PREQUENTIAL)
    learn = online or fit == FIT_PREQUENTIAL
    decoder = ChannelDecoder(library.tokens, vocabulary)
    result = Evaluation(ONLINE if online else FROZEN, top_k, window or 0, fit,
                        library.max_length - 1, Tally(), ChannelCounts.zeros(decoder.channels), [],
                        [], 0, 0.0)
    wrong: Counter = Counter()
    checkpoints = iter_evaluation(library, episodes, vocabulary, online=online, top_k=top_k,
                                  scoring=scoring, window=window, baselines=baselines,
                                  baselines_learn=learn, truth_probability=keep_outcomes)
    result.honest = HonestScores()
    for point in checkpoints:
        _collect(result, point, wrong, keep_outcomes)
        result.honest.add(point.outcome, decoder)
        if progress:
            _progress_line(point)
    result.warnings += result.honest.warnings()
    result.confusions = [(decoder.label(p), decoder.label(a), n)
                         for (p, a), n in wrong.most_common(N_CONFUSIONS)]
    result.notes.append(_fit_note(fit, online))
    scoring = Scoring(scoring) if isinstance(scoring, str) else scoring
    result.scoring = asdict(scoring)
    if not online and scoring.rule == "adaptive":
        result.notes.append("frozen: no pattern was learned, but the adaptive scoring still "
                            "re-weighed its context orders from each outcome (slearn.online)")
    result.vocabulary, result.tokens = vocabulary, library.tokens
    return result


def _collect(result: Evaluation, point: Checkpoint, wrong: Counter, keep_outcomes: bool) -> None:
    o = point.outcome
    result.window = point.episode.curve.window
    result.totals = point.totals
    if result.channels.channels != point.episode.channels.channels:  # declared while reading
        result.channels = ChannelCounts.zeros(point.episode.channels.channels)
    result.channels += point.episode.channels
    result.episodes.append(point.episode)
    result.predictions, result.elapsed_s = point.predictions, point.elapsed_s
    wrong.update(confusions(o.predicted, o.actual, o.evaluated))
    if point.episode.truncated:
        result.warnings.append(point.episode.read)
    if keep_outcomes:
        result.outcomes.append(o)


def _progress_line(point: Checkpoint) -> None:
    e = point.episode
    sys.stderr.write(f"replay: {os.path.basename(e.name)}: {e.tally.events} events, accuracy "
                     f"{_pct(e.tally.accuracy)} (frequency {_pct(e.tally.rate('frequency'))}, "
                     f"markov {_pct(e.tally.rate('markov'))}); {point.predictions} predictions, "
                     f"{point.predictions / max(point.elapsed_s, 1e-9):,.0f}/s\n")
    sys.stderr.flush()


def _pct(x: float) -> str:
    return "-" if math.isnan(x) else f"{100 * x:.2f} %"


def _fit_note(fit: str, online: bool) -> str:
    if fit == FIT_TRAINING:
        how = "then learned as they went" if online else "then frozen, like the library"
        return f"baselines were counted on the library's training logs, {how}"
    if online:
        return ("baselines had no training logs: they started empty and learned as they went; "
                "a library learned beforehand starts ahead of them")
    return ("baselines had no training logs: they learned on the held-out logs as they went "
            "(prequential) while the library stayed frozen, which favours them: the lift is "
            "a lower bound")


# --- logs on disk ---------------------------------------------------------------------

@dataclass
class _Setup:
    library: PatternLibrary
    vocabulary: Vocabulary
    spec: Spec
    scoring: Scoring
    facts: dict[str, Any]
    training_logs: list[str]
    notes: list[str]
    training_slices: dict[str, TimeSlice] = field(default_factory=dict)


def replay_logs(logs: Iterable[str | os.PathLike], *, library: str | os.PathLike | None = None,
                spec: str | os.PathLike | None = None, online: bool = False, top_k: int = 3,
                window: int | None = None, max_length: int = DEFAULT_MAX_LENGTH,
                scoring: str | None = None, baseline_logs: Iterable[str | os.PathLike] | None = None,
                keep_outcomes: bool = False, progress: bool = False,
                time_slice: TimeSlice | None = None) -> Evaluation:
    """Evaluate a saved library (or, with ``spec`` only, an empty one) on MCAP logs.

    The logs are read and binned as at learning time (the library's spec, fitted edges
    included, and its vocabulary, so symbols match; values never seen while learning get
    new symbols the library simply cannot predict).

    Args:
        logs: held-out MCAP files, one episode each, in this order.
        library: a library file written by :func:`slearn.storage.save_library`.
        spec: a TOML spec (or a :class:`~slearn.spec.Spec`), to start from an empty
            library (``online`` is then implied) or for a library saved without its spec.
        online: learn while replaying (prequential); else the library stays frozen.
        top_k, window, scoring: see :func:`iter_evaluation` (``scoring`` defaults to the
            library's own).
        max_length: pattern length of an empty library.
        baseline_logs: the logs to count the baselines on (default: the library's
            training logs when its provenance names them and they are unchanged on disk).
        keep_outcomes: keep per-step predictions (for :mod:`slearn.replay.annotate`).
        progress: progress on stderr.
        time_slice: replay only this slice of each log's time (``--split``: the held-out
            part); the baselines count each training log's slice the library learned.

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
        if not os.path.isfile(path) and not is_log_path(path):
            raise InputError(f"{path}: no such log file")
    setup = _open_library(library, spec, max_length, logs) if library is not None else \
        _empty_library(spec, max_length, logs, progress)
    online = online or library is None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("ignore", TruncatedLogWarning)  # reported in the result instead
        warnings.simplefilter("always", DataWarning)
        baselines, fit = _fit_baselines(setup, baseline_logs, progress)
        episodes = _read(logs, setup.spec, setup.vocabulary, progress, time_slice)
        result = evaluate(setup.library, episodes, setup.vocabulary, online=online, top_k=top_k,
                          scoring=scoring or setup.scoring, window=window, baselines=baselines,
                          baseline_fit=fit, keep_outcomes=keep_outcomes, progress=progress)
    result.warnings[:0] = setup.spec.warnings() + list(dict.fromkeys(
        str(w.message) for w in caught if issubclass(w.category, DataWarning)))
    result.setup = {**setup.facts, "logs": logs, "spec": setup.spec.to_dict()}
    if time_slice is not None:
        result.setup["slice"] = time_slice.to_dict()
    result.notes[:0] = setup.notes
    result.spec = setup.spec
    result.total_s = time.perf_counter() - started
    return result


def _read(paths: list[str], spec: Spec, vocabulary: Vocabulary, progress: bool,
          window: TimeSlice | dict[str, TimeSlice] | None = None
          ) -> Iterator[tuple[str, Episode, ReadReport]]:
    from slearn.serialize import read_episodes

    yield from read_episodes(paths, spec, vocabulary, progress=progress, window=window)


def _scoring(params: dict) -> Scoring:
    value = params.get("scoring") or "adaptive"
    if isinstance(value, str):
        return Scoring(value)
    return Scoring(**{k: v for k, v in value.items() if k in ("rule", "alpha", "buckets", "prior")})


def _open_library(path: str | os.PathLike, spec_path: str | os.PathLike | None, max_length: int,
                  logs: list[str]) -> _Setup:
    from slearn.spec import load_spec
    from slearn.storage import load_library

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
    return _Setup(lib, loaded.vocabulary, spec, _scoring(loaded.params), facts, training, [],
                  _training_slices(loaded.provenance, training))


def _empty_library(spec_path: str | os.PathLike | None, max_length: int, logs: list[str],
                   progress: bool) -> _Setup:
    from slearn.serialize import fit_spec
    from slearn.spec import load_spec

    if spec_path is None:
        raise InputError("no library: give a library file, or --spec FILE to start from an empty one")
    spec = spec_path if isinstance(spec_path, Spec) else load_spec(spec_path)
    notes = ["no library: started from an empty one and learned online"]
    if not spec.fitted:
        spec = fit_spec(spec, logs, progress)
        notes.append("quantile bins were fitted on the replayed logs themselves")
    library = PatternLibrary(max_length)
    facts = {"library": None, "params": {"max_length": max_length, "max_patterns": None,
                                         "scoring": "adaptive"}, "provenance": None}
    return _Setup(library, Vocabulary(), spec, Scoring(), facts, [], notes)


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
    from slearn.bags import log_record

    if not isinstance(entry, dict) or not isinstance(entry.get("path"), str):
        return None
    for path in dict.fromkeys([entry["path"], os.path.join(library_dir, entry["path"])]):
        if (os.path.isfile(path) or is_log_path(path)) and \
                log_record(path)["size_bytes"] == entry.get("size_bytes") and \
                log_record(path)["sha256"] == entry.get("sha256"):
            return path
    return None


def _training_slices(provenance: dict, training: list[str]) -> dict[str, TimeSlice]:
    """The slice of each training log the library learned (``slice`` in its provenance)."""
    inputs = provenance.get("inputs") if isinstance(provenance, dict) else None
    if not training or not isinstance(inputs, list):
        return {}
    return {path: slice_from_dict(entry.get("slice")) for path, entry in zip(training, inputs)
            if isinstance(entry, dict) and entry.get("slice")}


def _fit_baselines(setup: _Setup, baseline_logs: Iterable[str | os.PathLike] | None,
                   progress: bool) -> tuple[Baselines | None, str]:
    paths = [os.fspath(p) for p in baseline_logs] if baseline_logs else setup.training_logs
    if not paths:
        return None, FIT_PREQUENTIAL
    baselines = Baselines(setup.library.max_length - 1)
    if progress:
        sys.stderr.write(f"replay: counting the baselines on {len(paths)} training log(s)\n")
    for _, episode, _ in _read(paths, setup.spec, setup.vocabulary, False,
                               setup.training_slices if not baseline_logs else None):
        baselines.learn_tokens(setup.library.tokens.tokenize(episode))
    setup.facts["baseline_logs"] = paths
    return baselines, FIT_TRAINING


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (str, int, float, bool)) or value is None:
        return value
    return str(value)
