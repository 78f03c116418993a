"""The one place the benchmarks call slearn's predictor: repoint these two functions when the
predictor's API changes, and every table follows.

Online runs learn prequentially from an empty library (predict each step, then learn it), as
``slearn demo`` does. Options: ``scoring`` (``"adaptive"``, the default: every occurrence
counted, contexts weighed by their record; or ``"literal"``: the paper's rule),
``max_length`` (steps of history in a context) and ``vocabulary`` (names the channels, so
each observation channel is predicted on its own; without it a step's observations are
predicted together).
"""

from __future__ import annotations

import numpy as np

from slearn.core.library import PatternLibrary
from slearn.core.literal import DEFAULT_MAX_LENGTH as LITERAL_MAX_LENGTH
from slearn.core.literal import LiteralLibrary
from slearn.core.predictor import Predictor
from slearn.core.stream import Episode


def new_library(options: dict) -> PatternLibrary | LiteralLibrary:
    """An empty library for ``options``."""
    if options.get("scoring", "adaptive") == "literal":
        return LiteralLibrary(options.get("max_length", LITERAL_MAX_LENGTH))
    kwargs = {"max_length": options["max_length"]} if "max_length" in options else {}
    return PatternLibrary(vocabulary=options.get("vocabulary"), **kwargs)


def step_correct(library, episode: Episode) -> np.ndarray:
    """Predict then learn every step of ``episode``; per step after the first, whether every
    observation of the step was predicted right (abstentions count as wrong)."""
    codes = library.encode(episode)
    reports = library.run(codes, learn=True, record=True, top_k=1)
    wrong = reports.context & (reports.predicted != codes.token)
    step_of = np.repeat(np.arange(len(codes)), np.diff(codes.offsets))
    bad = np.zeros(len(codes), bool)
    np.logical_or.at(bad, step_of, wrong)
    return ~bad[1:]


def slearn_correct(episode: Episode, **options) -> np.ndarray:
    """Per step after the first, whether slearn predicted it right, online from empty."""
    return step_correct(new_library(options), episode)


def slearn_sequence_predictions(train: list[list[int]], queries: list[list[int]],
                                **options) -> np.ndarray:
    """Learn ``train`` (one sequence = one episode, no actions) in order, then predict the
    item after each query with the library frozen; -1 where slearn abstains."""
    library = new_library(options)
    for sequence in train:
        library.learn(_episode(sequence))
    predictor = Predictor(library)
    out = np.full(len(queries), -1, np.int64)
    for i, query in enumerate(queries):
        guess = predictor.predict([((), (int(item),)) for item in query], ())
        if not guess.abstained:
            out[i] = guess.observations[0]
    return out


def _episode(sequence: list[int]) -> Episode:
    return Episode.from_steps([((), (int(item),)) for item in sequence])
