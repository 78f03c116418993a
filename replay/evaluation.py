"""Replay's evaluation, pure: how well a pattern library predicts episodes, next to baselines.

:func:`iter_evaluation` is the core, a generator in the manner of river's
``iter_progressive_val_score``: it runs the library's predictor over each episode
(:func:`slearn.core.online.run_online`; ``online=False`` keeps the library frozen, ``True``
learns each step after predicting it, prequentially) and yields a :class:`Checkpoint`
per episode. :func:`evaluate` collects the checkpoints into an :class:`Evaluation`,
reporting progress through a callback; it reads and writes no file
(:func:`slearn.replay.replay_logs.replay_logs` does the I/O around it).

Baselines (:mod:`slearn.replay.baselines`) see the same token stream. How they are
trained is reported as ``baselines.fit``:

* ``"training"``: counted on training logs (given, e.g. ``--baseline-train``, or the
  library's own, named in its provenance and still on disk), then scored like the library: frozen in a
  frozen replay, learning as they go in an online one. The fair comparison.
* ``"prequential"``: no training logs at hand, so they learn on the held-out stream as
  they go (predict each step, then count it). In a frozen replay that favours the
  baselines, which adapt to the held-out logs while the library does not: the lift is a
  lower bound. In an online replay of a library learned elsewhere it favours the library.
"""

from __future__ import annotations

import copy
import math
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Iterator

import numpy as np

from slearn.core.library import PatternLibrary
from slearn.core.literal import LiteralLibrary
from slearn.core.online import HOLD, Reports
from slearn.core.stream import Episode
from slearn.core.tokens import TokenTable, join_steps
from slearn.core.views import StepCodes
from slearn.core.vocabulary import Vocabulary
from slearn.io.mcap_read import ReadReport
from slearn.io.spec import Spec
from slearn.replay.baselines import Baselines
from slearn.replay.honest import HonestScores
from slearn.replay.metrics import (
    ChannelCounts,
    ChannelDecoder,
    Curve,
    Tally,
    channel_counts,
    channel_hits,
    confusions,
    learning_curve,
    score_steps,
)
from slearn.replay.windows import data_window

SCHEMA = "slearn.replay/3"
"""Name and version of the JSON document (:meth:`Evaluation.to_dict`)."""

FROZEN, ONLINE = "frozen", "online"
FIT_TRAINING, FIT_PREQUENTIAL = "training", "prequential"
SURPRISE_FLOOR = 2.0 ** -16
"""Smallest probability a surprise is computed from (so at most 16 bits)."""

N_CONFUSIONS = 10


@dataclass(frozen=True)
class EpisodeOutcome:
    """Per step of one episode: predictions and truth, each step's observations as one tuple.

    A step's tuple joins the observations of every view that reported with some history
    (the first observation of an episode has none); the predicted tuple joins every
    view's prediction, so a step is right when every view is. Tuples are tokens of the
    evaluation's own step table (:attr:`Evaluation.tokens`).

    Attributes:
        name: the episode's name (its log's path).
        actual: the observed step tuple.
        predicted: the library's predicted tuple, -1 where every view abstained.
        top_k: whether every view's observation was among its ``k`` best guesses.
        score: the product of the views' shares behind their predictions.
        matched_length: the longest context, in tokens, among the views' chosen ones (-1).
        frequency, markov, persistence: the baselines' predicted tuples (-1 abstained).
        evaluated: steps that count (some view reported with some history).
        first_step: the episode step of index 0: 1 when the episode begins with a reading
            (nothing can predict it), else 0.
        truth_probability: the product of the views' shares behind what happened (frozen
            replays; NaN online, where the library has moved on since); a view that held its
            reading has no share, and counts 1 when it was right, 0 when wrong.
        confused: ``(predicted, actual) -> count`` of each view's wrong predictions, in the
            library's tokens (one channel's values in a factored library; abstentions left
            out, so a step where one channel abstained and the others were right is none).
    """

    name: str
    actual: np.ndarray
    predicted: np.ndarray
    top_k: np.ndarray
    score: np.ndarray
    matched_length: np.ndarray
    frequency: np.ndarray
    markov: np.ndarray
    persistence: np.ndarray
    evaluated: np.ndarray
    first_step: int
    truth_probability: np.ndarray
    confused: Counter = field(default_factory=Counter)

    def __len__(self) -> int:
        return len(self.actual)

    def surprise_bits(self) -> np.ndarray:
        """``-log2`` of the probability the library gave what happened (floored).

        Where that is not known (online), a wrong prediction gets the share left to all
        other outcomes, ``1 - score``: an upper bound, so the surprise is a lower bound.
        """
        bound = np.where(self.predicted == self.actual, self.score, 1.0 - self.score)
        p = np.where(np.isnan(self.truth_probability), bound, self.truth_probability)
        p = np.where(self.predicted < 0, 0.0, p)
        return -np.log2(np.maximum(p, SURPRISE_FLOOR)) + 0.0  # (+ 0.0: no -0.0 bits when certain)


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
    baseline_truncated: list[str] = field(default_factory=list)  # training logs the baselines salvaged
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
        """Whether some log was truncated (only what was salvaged was scored or, for the
        baselines' training logs, counted)."""
        return any(e.truncated for e in self.episodes) or bool(self.baseline_truncated)

    @property
    def predictions_per_s(self) -> float:
        """Predictions per second of the evaluation core (reading excluded)."""
        return self.predictions / self.elapsed_s if self.elapsed_s > 0 else math.nan

    def to_dict(self) -> dict:
        """The ``slearn.replay/3`` JSON document.

        Rates are in [0, 1] and ``null`` when undefined (no events); lifts are in
        percentage points (library accuracy minus baseline accuracy). Keys::

            schema        "slearn.replay/3" (/2 counted confusions of whole steps)
            mode          "frozen" | "online"
            top_k, window ranked guesses counted; steps per learning-curve window
            scoring       {rule: "adaptive" | "literal", factored}
            library       {path, format_version, patterns, max_length, max_patterns, clock}
                          or null (empty start)
            params, provenance, spec, logs, baseline_logs (when the baselines were trained)
            totals        TALLY over all logs
            baselines     {fit: "training" | "prequential", max_length}
            channels      [{channel, events, correct, abstained, accuracy,
                            frequency_accuracy, markov_accuracy, persistence_accuracy}]
            episodes      [{name, steps, TALLY..., channels, truncated, read,
                            curve: [{start_step, end_step, events, accuracy,
                                     frequency_accuracy, markov_accuracy,
                                     persistence_accuracy, channel_accuracy: [per channel, in "channels" order]}]}]
            confusions    [{predicted, actual, count}] most frequent first, each
                          within one view ("channel=value" labels: one channel in
                          a factored library, a step's channels otherwise);
                          abstentions are not confusions
            speed         {predictions, evaluation_s, predictions_per_s, total_s}
            notes, warnings  [str]
            honest        intervals, the persistence baseline, paired lift intervals,
                          small-sample channels (:meth:`HonestScores.to_dict`)

        ``TALLY`` is ``events, correct, abstained, accuracy, abstention_rate,
        accuracy_when_predicting, top_k_correct, top_k_accuracy, baselines: {frequency,
        markov, persistence: {correct, abstained, accuracy, lift_points}}``. Accuracy is
        whole-step accuracy (every view right); ``channels`` gives each channel's own.
        ``slearn replay --json``
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
            "baselines": {"fit": self.baseline_fit, "max_length": self.baseline_order},
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

def iter_evaluation(library: PatternLibrary | LiteralLibrary,
                    episodes: Iterable[tuple[str, Episode, ReadReport | None]],
                    vocabulary: Vocabulary, *, online: bool = False, top_k: int = 3,
                    window: int | None = None, baselines: Baselines | None = None,
                    baselines_learn: bool = True, steps: TokenTable | None = None
                    ) -> Iterator[Checkpoint]:
    """Predict every observation of every episode; yield a :class:`Checkpoint` per episode.

    Args:
        library: the pattern library; it learns only when ``online``.
        episodes: ``(name, episode, read report or None)``, symbols of ``vocabulary``.
        vocabulary: names the symbols (for the per-channel scores).
        online: learn each step after predicting it (prequential); else frozen: nothing
            in the library changes, not even its scoring weights.
        top_k: how many ranked guesses count for the top-k accuracy.
        window: steps per learning-curve window (default: about 50 over the first episode).
        baselines: the baselines to run beside the library (default: fresh, of the
            library's shape).
        baselines_learn: whether the baselines count each step after predicting it.
        steps: the table the step tuples are interned in (default: a new one).
    """
    baselines = baselines if baselines is not None else Baselines(library)
    steps = steps if steps is not None else TokenTable()
    decoder = ChannelDecoder(steps, vocabulary)
    totals, predictions, elapsed = Tally(), 0, 0.0
    for name, episode, report in episodes:
        started = time.perf_counter()
        outcome = _predict_episode(name, episode, library, baselines, online, baselines_learn,
                                   top_k, steps)
        if window is None and len(outcome):
            window = data_window(len(outcome), int(outcome.evaluated.sum()))
        summary = _summarize(outcome, decoder, window or 1, report)
        elapsed += time.perf_counter() - started
        totals += summary.tally
        predictions += int(np.count_nonzero(outcome.evaluated))
        yield Checkpoint(summary, outcome, copy.copy(totals), predictions, elapsed)


def _predict_episode(name: str, episode: Episode, library, baselines: Baselines, online: bool,
                     baselines_learn: bool, top_k: int, steps: TokenTable) -> EpisodeOutcome:
    codes = library.encode(episode)
    reports = library.run(codes, learn=online, record=True, top_k=top_k)
    guesses = baselines.run(codes, learn=baselines_learn)
    first = 1 if len(episode) and episode.n_actions[0] == 0 else 0  # a first reading is not predicted
    return _joined(name, codes, reports, guesses, library.tokens, steps, online, first)


def _joined(name: str, codes: StepCodes, reports: Reports, guesses: Reports, tokens: TokenTable,
            steps: TokenTable, online: bool, first: int) -> EpisodeOutcome:
    """Per step from ``first`` on, the tuples of what every view saw, was predicted and the
    baselines said."""
    use = reports.context
    columns = (codes.token, reports.predicted, guesses.frequency, guesses.markov, guesses.persistence)
    sizes = np.diff(tokens.arrays.offsets[: len(tokens) + 1])
    symbols = sum(int(sizes[c[use & (c >= 0)]].sum()) for c in columns)
    per_step = int(np.max(np.add.reduceat(np.where(use, sizes.max(initial=1), 0),
                                          codes.offsets[:-1].clip(max=max(len(use) - 1, 0)))))\
        if len(use) else 1
    steps.reserve(len(columns) * len(codes) + 1, symbols + 1)
    offsets = codes.offsets
    table, lib = steps.arrays, tokens.arrays
    buf = np.empty(max(per_step, 1), np.int32)

    def join(column: np.ndarray) -> np.ndarray:
        return join_steps(table, lib, offsets, column, use, buf)

    actual = join(codes.token)
    evaluated = actual >= 0
    hit_top = (reports.top == codes.token[:, None]).any(axis=1) | ~use
    top_k = np.logical_and.reduceat(hit_top, offsets[:-1].clip(max=max(len(hit_top) - 1, 0))) \
        if len(hit_top) else np.zeros(len(codes), bool)
    top_k = top_k & evaluated
    score = _step_product(offsets, reports.score, use)
    held = reports.kind == HOLD  # (no share: a held reading counts 1 when right, 0 when wrong)
    truth_p = np.where(held, (reports.predicted == codes.token).astype(np.float64), reports.truth_p)
    truth = np.full(len(codes), np.nan) if online else _step_product(offsets, truth_p, use)
    length = _step_max(offsets, reports.length, use)
    columns = (actual, join(reports.predicted), top_k, score, length, join(guesses.frequency),
               join(guesses.markov), join(guesses.persistence), evaluated)
    scored = reports.context.copy()
    scored[:codes.offsets[first]] = False  # (a first reading is not predicted)
    return EpisodeOutcome(name, *(c[first:] for c in columns), first, truth[first:],
                          confusions(reports.predicted, codes.token, scored))


def _step_product(offsets: np.ndarray, values: np.ndarray, use: np.ndarray) -> np.ndarray:
    logs = np.where(use, np.log(np.maximum(values, 1e-300)), 0.0)
    summed = np.add.reduceat(logs, offsets[:-1].clip(max=max(len(logs) - 1, 0))) if len(logs) \
        else np.zeros(len(offsets) - 1)
    summed[np.diff(offsets) == 0] = 0.0
    return np.exp(summed)


def _step_max(offsets: np.ndarray, values: np.ndarray, use: np.ndarray) -> np.ndarray:
    if not len(values):
        return np.full(len(offsets) - 1, -1, np.int32)
    out = np.maximum.reduceat(np.where(use, values, -1), offsets[:-1].clip(max=len(values) - 1))
    out[np.diff(offsets) == 0] = -1
    return out.astype(np.int32)


def _summarize(outcome: EpisodeOutcome, decoder: ChannelDecoder, window: int,
               report: ReadReport | None) -> EpisodeSummary:
    o = outcome
    scores = score_steps(o.predicted, o.actual, o.top_k, o.frequency, o.markov, o.persistence,
                         o.evaluated)
    hits = channel_hits(decoder, o.predicted, o.actual, o.frequency, o.markov, o.persistence)
    hits = {k: v & o.evaluated[:, None] for k, v in hits.items()}
    truncated = bool(report is not None and report.truncated)
    return EpisodeSummary(o.name, len(o), scores.tally(), channel_counts(decoder.channels, hits),
                          learning_curve(scores, hits, window), truncated,
                          report.describe() if report is not None else None)


def evaluate(library: PatternLibrary | LiteralLibrary,
             episodes: Iterable[tuple[str, Episode, ReadReport | None]],
             vocabulary: Vocabulary, *, online: bool = False, top_k: int = 3,
             window: int | None = None, baselines: Baselines | None = None,
             baseline_fit: str | None = None, baseline_source: str = "the library's training logs",
             keep_outcomes: bool = False, on_episode: Callable[[Checkpoint], None] | None = None) -> Evaluation:
    """Run :func:`iter_evaluation` to the end and collect an :class:`Evaluation`.

    Args:
        baselines: baselines already counted on the training data (``baseline_fit``
            ``"training"``); ``None`` starts them empty and lets them learn as they go.
        baseline_fit: how ``baselines`` were fitted (default from whether they were given).
        baseline_source: which logs they were counted on, for the note (``"training"`` fit).
        keep_outcomes: keep every episode's per-step predictions (for annotated logs).
        on_episode: called with each episode's :class:`Checkpoint` as it is done
            (progress display; the evaluation itself writes nothing).

    The other arguments are those of :func:`iter_evaluation`.
    """
    fit = baseline_fit or (FIT_TRAINING if baselines is not None else FIT_PREQUENTIAL)
    learn = online or fit == FIT_PREQUENTIAL
    steps = TokenTable()
    decoder = ChannelDecoder(steps, vocabulary)
    baselines = baselines if baselines is not None else Baselines(library)
    result = Evaluation(ONLINE if online else FROZEN, top_k, window or 0, fit,
                        baselines.max_length, Tally(), ChannelCounts.zeros(decoder.channels), [],
                        [], 0, 0.0)
    wrong: Counter = Counter()
    checkpoints = iter_evaluation(library, episodes, vocabulary, online=online, top_k=top_k,
                                  window=window, baselines=baselines, baselines_learn=learn,
                                  steps=steps)
    result.honest = HonestScores()
    for point in checkpoints:
        _collect(result, point, wrong, keep_outcomes)
        result.honest.add(point.outcome, decoder)
        if on_episode is not None:
            on_episode(point)
    result.warnings += result.honest.warnings()
    labels = ChannelDecoder(library.tokens, vocabulary)  # each view's own values
    result.confusions = [(labels.label(p), labels.label(a), n) for (p, a), n in wrong.most_common(N_CONFUSIONS)]
    result.notes.append(_fit_note(fit, online, baseline_source))
    result.scoring = {"rule": "literal" if isinstance(library, LiteralLibrary) else "adaptive",
                      "factored": bool(getattr(library, "factored", False))}
    result.vocabulary, result.tokens = vocabulary, steps
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
    wrong.update(o.confused)
    if point.episode.truncated:
        result.warnings.append(point.episode.read)
    if keep_outcomes:
        result.outcomes.append(o)


def _fit_note(fit: str, online: bool, source: str) -> str:
    if fit == FIT_TRAINING:
        how = "then learned as they went" if online else "then frozen, like the library"
        return f"baselines were counted on {source}, {how}"
    if online:
        return ("baselines had no training logs: they started empty and learned as they went; "
                "a library learned beforehand starts ahead of them")
    return ("baselines had no training logs: they learned on the held-out logs as they went "
            "(prequential) while the library stayed frozen, which favours them: the lift is "
            "a lower bound")
