"""The one place the benchmarks call slearn's predictor: repoint these two functions when the
predictor's API changes, and every table follows.

Today: a :class:`slearn.library.PatternLibrary` read by a :class:`slearn.predictor.Predictor`,
learned prequentially with :func:`slearn.online.run_online` (as ``slearn demo`` does).
Options: ``scoring`` (``"adaptive"``, the default, or ``"literal"``) and ``max_length``
(the library's longest pattern, in steps).
"""

from __future__ import annotations

import numpy as np

from slearn.library import PatternLibrary
from slearn.online import run_online
from slearn.predictor import Predictor
from slearn.stream import Episode


def _predictor(options: dict) -> Predictor:
    library = PatternLibrary(**({"max_length": options["max_length"]}
                                if "max_length" in options else {}))
    return Predictor(library, options.get("scoring", "adaptive"))


def slearn_correct(episode: Episode, **options) -> np.ndarray:
    """Per step after the first, whether slearn predicted it right, online from an empty
    library (predict each step, then learn it; abstentions count as wrong)."""
    return run_online(_predictor(options), episode).correct


def slearn_sequence_predictions(train: list[list[int]], queries: list[list[int]],
                                **options) -> np.ndarray:
    """Learn ``train`` (one sequence = one episode, no actions) in order, then predict the
    item after each query with the library frozen; -1 where slearn abstains."""
    predictor = _predictor(options)
    for sequence in train:
        run_online(predictor, _episode(sequence))
    out = np.full(len(queries), -1, np.int64)
    for i, query in enumerate(queries):
        guess = predictor.predict([((), (int(item),)) for item in query], ())
        if not guess.abstained:
            out[i] = guess.observations[0]
    return out


def _episode(sequence: list[int]) -> Episode:
    return Episode.from_steps([((), (int(item),)) for item in sequence])
