"""Scoring predictions of observation tuples: counts, per channel, per window, confusions.

The unit is a *predicted observation event*: a step where some view reported with some
history (a step of actions only has nothing to predict and is skipped). A prediction is
right when the predicted tuple (every view's prediction joined) equals the observed one:
the whole-step accuracy; an abstention counts as wrong and is also counted on its own.
Per channel, the channels of one step are compared one by one: an event of channel ``c``
is right when the prediction holds the same value(s) of ``c``.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, fields

import numpy as np

from slearn.core.tokens import TokenTable
from slearn.core.vocabulary import OBSERVATION, Vocabulary

MODEL = "model"
BASELINES = ("frequency", "markov", "persistence")


@dataclass
class Tally:
    """Counts over some predicted observation events.

    Attributes:
        events: predicted observation events (steps with observations).
        correct: right predictions of the library (abstentions are wrong).
        abstained: events the library made no prediction for.
        top_k: events whose observation was among the library's ``k`` best guesses.
        frequency, markov, persistence: right predictions of each baseline.
        frequency_abstained, markov_abstained, persistence_abstained: events each
            baseline could not predict.
    """

    events: int = 0
    correct: int = 0
    abstained: int = 0
    top_k: int = 0
    frequency: int = 0
    markov: int = 0
    persistence: int = 0
    frequency_abstained: int = 0
    markov_abstained: int = 0
    persistence_abstained: int = 0

    def __iadd__(self, other: "Tally") -> "Tally":
        for f in fields(self):
            setattr(self, f.name, getattr(self, f.name) + getattr(other, f.name))
        return self

    def rate(self, name: str = "correct") -> float:
        """``name`` (a count) over events; NaN without events."""
        return getattr(self, name) / self.events if self.events else math.nan

    @property
    def accuracy(self) -> float:
        """Share of events predicted right (abstentions wrong); NaN without events."""
        return self.rate("correct")

    def to_dict(self) -> dict:
        """Counts, rates and lifts (rates in [0, 1], ``None`` when undefined)."""
        predicted = self.events - self.abstained
        out = {"events": self.events, "correct": self.correct, "abstained": self.abstained}
        out.update(accuracy=_num(self.accuracy), abstention_rate=_num(self.rate("abstained")),
                   accuracy_when_predicting=_num(self.correct / predicted if predicted else math.nan),
                   top_k_correct=self.top_k, top_k_accuracy=_num(self.rate("top_k")))
        out["baselines"] = {name: {"correct": getattr(self, name),
                                   "abstained": getattr(self, f"{name}_abstained"),
                                   "accuracy": _num(self.rate(name)),
                                   "lift_points": _num(100 * (self.accuracy - self.rate(name)))}
                            for name in BASELINES}
        return out


def _num(x: float) -> float | None:
    return None if math.isnan(x) else round(float(x), 6)


def _ratio(count: int, n: int) -> float | None:
    return _num(count / n) if n else None


@dataclass(frozen=True)
class StepScores:
    """Per step of one episode, what each predictor got right (``bool`` arrays).

    ``evaluated`` marks the steps that count (observations not empty).
    """

    evaluated: np.ndarray
    correct: np.ndarray
    abstained: np.ndarray
    top_k: np.ndarray
    frequency: np.ndarray
    markov: np.ndarray
    persistence: np.ndarray
    frequency_abstained: np.ndarray
    markov_abstained: np.ndarray
    persistence_abstained: np.ndarray

    def tally(self, mask: slice | np.ndarray = slice(None)) -> Tally:
        """Counts over the evaluated steps (of ``mask``)."""
        ev = self.evaluated[mask]
        counts = {name: int(np.count_nonzero(getattr(self, name)[mask] & ev))
                  for name in _HIT_NAMES}
        return Tally(events=int(np.count_nonzero(ev)), **counts)


_HIT_NAMES = ("correct", "abstained", "top_k", *BASELINES,
              *(f"{name}_abstained" for name in BASELINES))


def score_steps(predicted: np.ndarray, actual: np.ndarray, top_k: np.ndarray, frequency: np.ndarray,
                markov: np.ndarray, persistence: np.ndarray, evaluated: np.ndarray) -> StepScores:
    """Right, wrong and abstained per step for the library and the baselines."""
    return StepScores(evaluated, predicted == actual, predicted < 0, top_k,
                      frequency == actual, markov == actual, persistence == actual,
                      frequency < 0, markov < 0, persistence < 0)


class ChannelDecoder:
    """Splits observation tokens into their channels' values (cached per token).

    Args:
        tokens: the library's token table (it may grow while replaying unseen values).
        vocabulary: names of the symbols.
    """

    def __init__(self, tokens: TokenTable, vocabulary: Vocabulary) -> None:
        self.tokens = tokens
        self.vocabulary = vocabulary
        self.channels: list[str] = []
        self._reset()

    def _reset(self) -> None:
        self.channels = [c for c, role in self.vocabulary.roles.items() if role == OBSERVATION]
        self._column = {c: i for i, c in enumerate(self.channels)}
        self._values: dict[tuple, int] = {}
        self._rows: list[list[int]] = []
        self._table = np.full((1, len(self.channels)), -1, np.int64)

    def table(self) -> np.ndarray:
        """``(n_tokens + 1, n_channels)`` value ids, -1 = channel absent; the last row is 'no token'.

        Channels declared since the last call (a vocabulary prepared late) are picked up.
        """
        if sum(role == OBSERVATION for role in self.vocabulary.roles.values()) != len(self.channels):
            self._reset()
        n = len(self.tokens)
        if len(self._table) != n + 1:
            while len(self._rows) < n:
                self._rows.append(self._row(len(self._rows)))
            blank = [-1] * len(self.channels)
            self._table = np.array(self._rows + [blank], np.int64).reshape(n + 1, len(self.channels))
        return self._table

    def _row(self, token: int) -> list[int]:
        by_channel: dict[str, list[int]] = {}
        for symbol in self.tokens.symbols(token):
            by_channel.setdefault(self.vocabulary.name(symbol)[0], []).append(symbol)
        row = [-1] * len(self.channels)
        for channel, symbols in by_channel.items():
            if channel in self._column:
                key = (channel, tuple(symbols))
                row[self._column[channel]] = self._values.setdefault(key, len(self._values))
        return row

    def split(self, tokens: np.ndarray) -> np.ndarray:
        """``(n, n_channels)`` value ids of ``tokens`` (-1 tokens give all -1)."""
        table = self.table()
        return table[np.where(tokens < 0, len(table) - 1, tokens)]

    def label(self, token: int) -> str:
        """``channel=value`` labels of a token's symbols, ``"(none)"`` when empty."""
        if token < 0:
            return "(abstained)"
        symbols = self.tokens.symbols(token)
        return ", ".join(self.vocabulary.label(s) for s in symbols) if symbols else "(none)"


_CHANNEL_COUNTS = ("events", "correct", "abstained", *BASELINES)


@dataclass
class ChannelCounts:
    """Per observation channel: events, right predictions of the library and baselines."""

    channels: list[str]
    events: np.ndarray
    correct: np.ndarray
    abstained: np.ndarray
    frequency: np.ndarray
    markov: np.ndarray
    persistence: np.ndarray

    @classmethod
    def zeros(cls, channels: list[str]) -> "ChannelCounts":
        """All counts zero."""
        return cls(channels, *(np.zeros(len(channels), np.int64) for _ in _CHANNEL_COUNTS))

    def __iadd__(self, other: "ChannelCounts") -> "ChannelCounts":
        for name in _CHANNEL_COUNTS:
            setattr(self, name, getattr(self, name) + getattr(other, name))
        return self

    def to_list(self) -> list[dict]:
        """One dict per channel, rates in [0, 1]."""
        out = []
        for i, channel in enumerate(self.channels):
            n = int(self.events[i])
            out.append({"channel": channel, "events": n, "correct": int(self.correct[i]),
                        "abstained": int(self.abstained[i]),
                        "accuracy": _ratio(self.correct[i], n),
                        **{f"{b}_accuracy": _ratio(getattr(self, b)[i], n) for b in BASELINES}})
        return out


def channel_hits(decoder: ChannelDecoder, predicted: np.ndarray, actual: np.ndarray,
                 frequency: np.ndarray, markov: np.ndarray,
                 persistence: np.ndarray) -> dict[str, np.ndarray]:
    """``(n, n_channels)`` booleans: ``events`` (channel observed) and each predictor's hits.

    Columns follow ``decoder.channels`` as of this call.
    """
    truth = decoder.split(actual)
    events = truth >= 0
    # a channel the prediction has no value for was abstained on: every view abstained, or
    # (a factored library) this channel's view did while others spoke
    hits = {"events": events, "abstained": events & (decoder.split(predicted) < 0)}
    for name, tokens in ((MODEL, predicted), ("frequency", frequency), ("markov", markov),
                         ("persistence", persistence)):
        hits[name] = events & (decoder.split(tokens) == truth)
    return hits


def channel_counts(channels: list[str], hits: dict[str, np.ndarray]) -> ChannelCounts:
    """Sum :func:`channel_hits` over steps."""
    return ChannelCounts(channels, hits["events"].sum(axis=0), hits[MODEL].sum(axis=0),
                         hits["abstained"].sum(axis=0),
                         *(hits[name].sum(axis=0) for name in BASELINES))


@dataclass(frozen=True)
class Curve:
    """Accuracy per window of ``window`` steps of one episode (the learning curve).

    ``start`` is each window's first step (0-based, steps after the first observation);
    the other arrays count events per window; ``channel_*`` are ``(windows, channels)``.
    """

    window: int
    start: np.ndarray
    events: np.ndarray
    correct: np.ndarray
    frequency: np.ndarray
    markov: np.ndarray
    persistence: np.ndarray
    channel_events: np.ndarray
    channel_correct: np.ndarray

    def accuracy(self, name: str = "correct") -> np.ndarray:
        """Per window, ``name`` hits over events (NaN for windows without events)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return getattr(self, name) / np.where(self.events > 0, self.events, np.nan)

    def channel_accuracy(self) -> np.ndarray:
        """``(windows, channels)`` accuracy per channel (NaN without events)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return self.channel_correct / np.where(self.channel_events > 0, self.channel_events, np.nan)

    def to_list(self) -> list[dict]:
        """One dict per window, rates in [0, 1] or ``None``; ``channel_accuracy`` per channel."""
        acc = self.accuracy()
        base = {name: self.accuracy(name) for name in BASELINES}
        by_channel = self.channel_accuracy()
        return [{"start_step": int(s), "end_step": int(s) + self.window, "events": int(e),
                 "accuracy": _num(acc[i]),
                 **{f"{name}_accuracy": _num(base[name][i]) for name in BASELINES},
                 "channel_accuracy": [_num(x) for x in by_channel[i]]}
                for i, (s, e) in enumerate(zip(self.start, self.events))]


def learning_curve(scores: StepScores, hits: dict[str, np.ndarray], window: int) -> Curve:
    """Window the per-step scores of one episode."""
    n = len(scores.evaluated)
    starts = np.arange(0, max(n, 1), window) if n else np.zeros(0, np.int64)
    ev = scores.evaluated

    def per_window(x: np.ndarray) -> np.ndarray:
        return np.add.reduceat(x & (ev if x.ndim == 1 else ev[:, None]), starts, axis=0) if n else \
            np.zeros((0,) + x.shape[1:], np.int64)

    return Curve(window, starts, per_window(ev), per_window(scores.correct),
                 per_window(scores.frequency), per_window(scores.markov),
                 per_window(scores.persistence), per_window(hits["events"]), per_window(hits[MODEL]))


def confusions(predicted: np.ndarray, actual: np.ndarray, evaluated: np.ndarray) -> Counter:
    """``(predicted token, actual token) -> count`` of the wrong, non-abstained predictions."""
    wrong = evaluated & (predicted >= 0) & (predicted != actual)
    keys = (predicted[wrong].astype(np.int64) << 32) | actual[wrong].astype(np.int64)
    values, counts = np.unique(keys, return_counts=True)
    return Counter({(int(v >> 32), int(v & 0xFFFFFFFF)): int(c) for v, c in zip(values, counts)})


def nice_window(n_steps: int, points: int = 50) -> int:
    """A round window (1, 2 or 5 times a power of ten) giving about ``points`` windows."""
    target = max(n_steps / points, 1.0)
    exponent = 10 ** math.floor(math.log10(target))
    for m in (1, 2, 5, 10):
        if m * exponent >= target:
            return int(m * exponent)
    return int(10 * exponent)
