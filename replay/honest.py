"""What a replay needs to be read honestly: how sure each number is, and the bar to clear.

:class:`HonestScores` is fed each episode's per-step outcome as the replay goes
(:meth:`HonestScores.add`) and gives:

- the **persistence** baseline (each view's last observation again: the value stays the
  same) next to the frequency and Markov baselines, overall and per channel;
- a **Wilson 95 % interval** (:mod:`slearn.replay.intervals`) for every accuracy, overall
  and per channel;
- for each baseline, the library's **lift** with **Newcombe's paired 95 % interval**
  (both predictors scored on the same events);
- a **small-sample warning** for every observation channel with fewer than
  :data:`SMALL_SAMPLE` predicted events.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from slearn.replay.intervals import paired_difference, wilson

SMALL_SAMPLE = 1000
BASELINES = ("frequency", "markov", "persistence")


def _interval(lo_hi: tuple[float, float], scale: float = 1.0) -> list[float] | None:
    if math.isnan(lo_hi[0]):
        return None
    return [round(scale * lo_hi[0], 6), round(scale * lo_hi[1], 6)]


@dataclass
class HonestScores:
    """Paired hit counts of the library and the baselines, and persistence per channel."""

    events: int = 0
    correct: int = 0
    top_k: int = 0
    right: dict[str, int] = field(default_factory=lambda: dict.fromkeys(BASELINES, 0))
    only_library: dict[str, int] = field(default_factory=lambda: dict.fromkeys(BASELINES, 0))
    only_baseline: dict[str, int] = field(default_factory=lambda: dict.fromkeys(BASELINES, 0))
    channel_events: dict[str, int] = field(default_factory=dict)
    channel_correct: dict[str, int] = field(default_factory=dict)
    channel_persistence: dict[str, int] = field(default_factory=dict)

    def add(self, outcome, decoder) -> None:
        """Count one episode's outcome (:class:`~slearn.replay.evaluation.EpisodeOutcome`)
        with the replay's :class:`~slearn.replay.metrics.ChannelDecoder`."""
        ev, actual = outcome.evaluated, outcome.actual
        library = (outcome.predicted == actual) & ev
        persistence = outcome.persistence
        self.events += int(ev.sum())
        self.correct += int(library.sum())
        self.top_k += int((outcome.top_k & ev).sum())
        for name, predicted in (("frequency", outcome.frequency), ("markov", outcome.markov),
                                ("persistence", persistence)):
            base = (predicted == actual) & ev
            self.right[name] += int(base.sum())
            self.only_library[name] += int((library & ~base).sum())
            self.only_baseline[name] += int((base & ~library).sum())
        self._add_channels(decoder, outcome, persistence)

    def _add_channels(self, decoder, outcome, persistence: np.ndarray) -> None:
        truth = decoder.split(outcome.actual)
        observed = (truth >= 0) & outcome.evaluated[:, None]
        library = observed & (decoder.split(outcome.predicted) == truth)
        persisted = observed & (decoder.split(persistence) == truth)
        for i, channel in enumerate(decoder.channels):
            self.channel_events[channel] = self.channel_events.get(channel, 0) + int(observed[:, i].sum())
            self.channel_correct[channel] = self.channel_correct.get(channel, 0) + int(library[:, i].sum())
            self.channel_persistence[channel] = (self.channel_persistence.get(channel, 0)
                                                 + int(persisted[:, i].sum()))

    def lift(self, name: str) -> tuple[float, float, float]:
        """``(lift, low, high)`` of the library over baseline ``name``, in [-1, 1]."""
        return paired_difference(self.correct, self.right[name], self.only_library[name],
                                 self.only_baseline[name], self.events)

    def rate(self, count: int, n: int) -> float:
        """``count / n``, NaN when ``n == 0``."""
        return count / n if n else math.nan

    def small_channels(self) -> list[tuple[str, int]]:
        """Observation channels with fewer than :data:`SMALL_SAMPLE` predicted events."""
        return [(c, n) for c, n in self.channel_events.items() if n < SMALL_SAMPLE]

    def warnings(self) -> list[str]:
        """One warning per channel evaluated on too few events (none: one line for all)."""
        small = self.small_channels()
        if small and not self.events:
            return ["nothing was predicted: the logs (or the time replayed) hold no observation "
                    "after a first one, so there is no accuracy: replay more of them"]
        return [f"channel {c!r}: only {n:,} predicted events (fewer than {SMALL_SAMPLE:,}): its "
                f"accuracy is uncertain (see the 95 % interval), and differences of a few points "
                f"mean nothing; evaluate on more held-out data" if n else
                f"channel {c!r}: no predicted event, so no accuracy" for c, n in small]

    def to_dict(self) -> dict:
        """The JSON ``honest`` section (rates in [0, 1], lifts in points)::

            confidence   0.95
            accuracy_interval, top_k_interval     [low, high]
            baselines    {frequency, markov, persistence: {correct, accuracy,
                          accuracy_interval, lift_points, lift_interval_points}}
            channels     [{channel, events, accuracy_interval, persistence_accuracy,
                           persistence_interval}]
            small_sample [{channel, events}]  (fewer than 1,000 events)
        """
        out = {"confidence": 0.95, "events": self.events,
               "accuracy_interval": _interval(wilson(self.correct, self.events)),
               "top_k_interval": _interval(wilson(self.top_k, self.events)),
               "baselines": {name: self._baseline(name) for name in BASELINES},
               "channels": [self._channel(c) for c in self.channel_events],
               "small_sample": [{"channel": c, "events": n} for c, n in self.small_channels()]}
        return out

    def _baseline(self, name: str) -> dict:
        lift, lo, hi = self.lift(name)
        accuracy = self.rate(self.right[name], self.events)
        return {"correct": self.right[name],
                "accuracy": None if math.isnan(accuracy) else round(accuracy, 6),
                "accuracy_interval": _interval(wilson(self.right[name], self.events)),
                "lift_points": None if math.isnan(lift) else round(100 * lift, 4),
                "lift_interval_points": _interval((lo, hi), 100.0)}

    def _channel(self, channel: str) -> dict:
        n = self.channel_events[channel]
        persistence = self.rate(self.channel_persistence[channel], n)
        return {"channel": channel, "events": n,
                "accuracy_interval": _interval(wilson(self.channel_correct[channel], n)),
                "persistence_accuracy": None if math.isnan(persistence) else round(persistence, 6),
                "persistence_interval": _interval(wilson(self.channel_persistence[channel], n))}
