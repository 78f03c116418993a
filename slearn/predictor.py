"""Prediction from a history: what each view observes next, given the actions just issued.

:class:`Predictor` answers one query at a time from a frozen library (nothing changes,
not even the scoring weights: learning trained them). The history is replayed on scratch
view streams, exactly as the library's own streams would have seen it, and every view
gets a prediction for the step after it. Tokens the library never saw match no context.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from slearn.errors import ParameterError
from slearn.mixer import KINDS
from slearn.online import Reports
from slearn.stream import Episode, Step
from slearn.views import UNKNOWN, StepCodes, new_view_state


@dataclass(frozen=True)
class ViewPrediction:
    """One view's prediction.

    Attributes:
        view: the view's index; ``name`` its channel (``"*"``: all observation channels).
        observations: the predicted observation symbols, ``None`` when abstaining.
        score: the chosen context's share behind the prediction.
        length: the chosen context's length in tokens (-1 when abstaining).
        kind: which expert spoke (``frequent``, ``recent``, ``fresh``; ``""`` abstaining).
        ranked: ``(observations, share)`` best first.
    """

    view: int
    name: str
    observations: tuple[int, ...] | None
    score: float
    length: int
    kind: str
    ranked: list[tuple[tuple[int, ...], float]] = field(default_factory=list)

    @property
    def abstained(self) -> bool:
        return self.observations is None


@dataclass(frozen=True)
class Prediction:
    """Every view's prediction for one step."""

    views: list[ViewPrediction]

    @property
    def observations(self) -> tuple[int, ...] | None:
        """The predicted symbols of all views that did not abstain, or ``None``."""
        said = [v.observations for v in self.views if v.observations is not None]
        return tuple(s for symbols in said for s in symbols) if said else None

    @property
    def abstained(self) -> bool:
        return all(v.abstained for v in self.views)


class Predictor:
    """Frozen predictions from a library (:class:`~slearn.library.PatternLibrary` or
    :class:`~slearn.literal.LiteralLibrary`)."""

    def __init__(self, library, top_k: int = 3) -> None:
        if isinstance(top_k, bool) or not isinstance(top_k, int) or not 1 <= top_k <= 1000:
            raise ParameterError(f"top_k must be an integer in 1..1000, not {top_k!r}")
        self.library = library
        self.top_k = top_k

    def predict(self, history: list[Step], actions: tuple[int, ...] = ()) -> Prediction:
        """Predict the observations that follow ``actions`` after the steps in ``history``.

        ``history`` is a list of ``(actions, observations)`` steps of symbols, oldest first.
        """
        return self.predict_unknown(list(history) + [(tuple(actions), ())])

    def predict_unknown(self, steps: list[Step], unknown_views: np.ndarray | None = None) -> Prediction:
        """Predict the observations of the last step of ``steps`` (its observations are
        ignored). Symbols past the vocabulary are values never seen; ``unknown_views``
        gives the view of each (factored libraries)."""
        if self.library.clock == 0 or not self.library.view_names:
            return Prediction([ViewPrediction(v, name, None, 0.0, -1, "")
                               for v, name in enumerate(self.library.view_names)])
        codes = self._codes(steps, unknown_views)
        reports = self._run(codes)
        first = int(codes.offsets[-2])
        return Prediction([self._view(reports, first + v, v) for v in range(self._n_views())])

    def _n_views(self) -> int:
        return len(self.library.view_names)

    def _codes(self, steps: list[Step], unknown_views: np.ndarray | None) -> StepCodes:
        library = self.library
        steps = steps[:-1] + [(tuple(steps[-1][0]), ())]
        episode = Episode.from_steps(steps)
        if unknown_views is not None and len(unknown_views) and library.factored:
            codes = library.encode(episode, intern=False, unknown_views=unknown_views)
        else:
            codes = library.encode(episode, intern=False)
        n_views = self._n_views()
        offsets = codes.offsets.copy()
        offsets[-1] = offsets[-2] + n_views  # the last step reports every view, truth unknown
        return StepCodes(codes.action, offsets,
                         np.concatenate((codes.view[: offsets[-2]], np.arange(n_views, dtype=np.int32))),
                         np.concatenate((codes.token[: offsets[-2]], np.full(n_views, UNKNOWN, np.int32))))

    def _run(self, codes: StepCodes) -> Reports:
        library = self.library
        if getattr(library, "streams", None) is None:
            return library.run(codes, learn=False, record=True, top_k=self.top_k)
        scratch = new_view_state(len(library.streams.root), library.max_context, library.streams.root)
        return library.run(codes, learn=False, record=True, top_k=self.top_k, streams=scratch)

    def _view(self, reports: Reports, r: int, v: int) -> ViewPrediction:
        symbols = self.library.tokens.symbols
        name = self.library.view_names[v]
        token = int(reports.predicted[r])
        if token < 0:
            return ViewPrediction(v, name, None, 0.0, -1, "")
        ranked = [(symbols(int(t)), float(p)) for t, p in zip(reports.top[r], reports.top_p[r]) if t >= 0]
        return ViewPrediction(v, name, symbols(token), float(reports.score[r]), int(reports.length[r]),
                              KINDS[int(reports.kind[r])], ranked)
