"""The ceiling: an optimal predictor of the pointer that knows its dynamics.

Before trial ``k``'s outcome is read, the oracle has seen every earlier label and command
and the command just issued. It predicts the label of largest predictive probability
(the Bayes-optimal guess under 0/1 loss), so its hit rate is the best any predictor can
reach in expectation. Derivation per condition:

- ``simple``, ``hardstop``, ``reversal``, ``scramble``: the label determines the bin (the
  oracle knows the switch trial, the reversal and the scramble permutation) and the angle
  is always a bin centre, so the next label is a function of the current label and command:
  the ceiling is 100 %.
- ``error``: the hidden state is the continuous angle. Its posterior after each reading is
  confined to the read bin, so the filter keeps a density over the offset inside that bin
  on a grid of ``cells_per_bin`` cells (0.05 degrees by default), starting as a point at the
  bin centre. Predict: shift by the commanded 10 degrees and convolve with the move noise,
  U[-e, e], discretized exactly for a position uniform within a cell; sum the mass per bin
  for the predictive distribution of the label (only bins -2..+2 away can be reached).
  Update: keep the mass inside the bin read, renormalize. The ceiling is about 75 %.
- ``delay``: the angle stays at bin centres, so the bin is read exactly; the hidden state is
  whether a command is pending, and a pending command can only be the previous one. With
  ``b`` = P(pending), ``p`` = ``delay_prob``, previous turn ``u`` and current turn ``d``,
  the displacement is ``u + d`` w.p. ``b(1-p)``, ``u`` w.p. ``bp`` (``d`` now pending),
  ``d`` w.p. ``(1-b)(1-p)``, ``0`` w.p. ``(1-b)p`` (``d`` now pending). The reading gives
  the displacement, and ``b`` for the next trial is the pending share of its probability.
  With ``p = 0.5`` the best displacement always has probability 1/2: the ceiling is 50 %.
  Ties (frequent at ``p = 0.5``) go to the first of that list, deterministically.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slearn.errors import InputError
from slearn.recorders.pointer import (BIN_DEG, N_BINS, PointerRun, command_directions, sense)

DEFAULT_CELLS_PER_BIN = 200
_REACH = 2  # a move of at most 20 degrees reaches bins at most 2 away


@dataclass(frozen=True, eq=False)
class OraclePrediction:
    """The oracle's guess per trial.

    Attributes:
        labels: ``int16`` predicted sensed label of each trial's outcome.
        probabilities: ``float64`` predictive probability of that label.
    """

    labels: np.ndarray
    probabilities: np.ndarray

    @property
    def expected_accuracy(self) -> float:
        """Mean predictive probability of the guesses: the ceiling without sampling noise."""
        return float(self.probabilities.mean())


def oracle_correct(run: PointerRun) -> np.ndarray:
    """Per trial, whether the optimal predictor's guess equals the label actually read."""
    return oracle_predict(run).labels == run.positions[1:]


def oracle_predict(run: PointerRun, cells_per_bin: int = DEFAULT_CELLS_PER_BIN
                   ) -> OraclePrediction:
    """The optimal predictor's guesses on ``run`` (``cells_per_bin`` only matters for error).

    Raises:
        InputError: a reading is impossible under the run's dynamics.
    """
    condition = run.config.condition
    if condition == "error":
        return _error_filter(run, cells_per_bin)
    if condition == "delay":
        return _delay_filter(run)
    return _deterministic(run)


def _true_bins(run: PointerRun) -> np.ndarray:
    bins = run.positions.astype(np.int64) - 1
    if run.config.condition == "scramble":
        after = run.config.switch_trial + 1
        bins[after:] = np.argsort(run.sensor_labels)[bins[after:]]
    return bins


def _deterministic(run: PointerRun) -> OraclePrediction:
    bins = _true_bins(run)
    targets = bins[:-1] + command_directions(run.commands, run.config)
    if run.config.condition == "hardstop":
        targets = np.where((targets < 0) | (targets >= N_BINS), bins[:-1], targets)
    predicted = np.concatenate((bins[:1], targets % N_BINS))
    labels = sense(predicted, run.config, run.sensor_labels)[1:]
    return OraclePrediction(labels, np.ones(len(labels)))


def _delay_filter(run: PointerRun) -> OraclePrediction:
    p = run.config.delay_prob
    bins = run.positions.astype(np.int64) - 1
    turns = command_directions(run.commands, run.config).tolist()
    labels = np.empty(len(turns), dtype=np.int16)
    probabilities = np.empty(len(turns))
    pending, previous = 0.0, 0
    for k, turn in enumerate(turns):
        outcomes = ((previous + turn, pending * (1 - p), 0.0),
                    (previous, pending * p, pending * p),
                    (turn, (1 - pending) * (1 - p), 0.0),
                    (0, (1 - pending) * p, (1 - pending) * p))
        mass: dict[int, list[float]] = {}
        for shift, prob, pending_prob in outcomes:
            total = mass.setdefault(shift, [0.0, 0.0])
            total[0] += prob
            total[1] += pending_prob
        best = max(mass, key=lambda shift: mass[shift][0])  # first of equals wins
        labels[k] = (bins[k] + best) % N_BINS + 1
        probabilities[k] = mass[best][0]
        observed = mass.get(_wrapped(bins[k + 1] - bins[k]), [0.0, 0.0])
        if observed[0] <= 0.0:
            raise InputError(f"pointer delay run: the reading at trial {k} is impossible")
        pending, previous = observed[1] / observed[0], turn
    return OraclePrediction(labels, probabilities)


def _wrapped(shift: int) -> int:
    return (shift + N_BINS // 2) % N_BINS - N_BINS // 2


def noise_kernel(error_deg: float, cell_deg: float) -> tuple[int, np.ndarray]:
    """Cell-shift probabilities of a U[-e, e] move from a position uniform within a cell.

    Returns ``(first_shift, probabilities)``: ``probabilities[i]`` is the chance of landing
    ``first_shift + i`` cells away.
    """
    if error_deg == 0:
        return 0, np.ones(1)
    reach = int(np.ceil(error_deg / cell_deg)) + 1
    edges = np.arange(-reach, reach + 2) * cell_deg
    integral = _noise_cdf_integral(edges, error_deg) - _noise_cdf_integral(edges - cell_deg,
                                                                             error_deg)
    cdf = integral / cell_deg  # CDF of the landing position at the cell edges
    return -reach, np.diff(cdf)


def _noise_cdf_integral(y: np.ndarray, e: float) -> np.ndarray:
    """``integral of F(t) dt`` from -inf to ``y``, F the CDF of U[-e, e]."""
    inside = (np.clip(y, -e, e) + e) ** 2 / (4 * e)
    return inside + np.maximum(y - e, 0.0)


def _error_filter(run: PointerRun, cells: int) -> OraclePrediction:
    first, kernel = noise_kernel(run.config.error_deg, BIN_DEG / cells)
    bins = run.positions.astype(np.int64) - 1
    turns = command_directions(run.commands, run.config).tolist()
    labels = np.empty(len(turns), dtype=np.int16)
    probabilities = np.empty(len(turns))
    belief = np.zeros(cells)
    centre = belief[(cells - 1) // 2:cells // 2 + 1]  # the start: one cell, or the two at its edge
    centre[:] = 1.0 / len(centre)
    bin_index = {turn: (np.arange(cells + len(kernel) - 1) + first + turn * cells) // cells
                 for turn in (-1, 1)}
    for k, turn in enumerate(turns):
        spread = np.convolve(belief, kernel)
        per_bin = np.bincount(bin_index[turn] + _REACH, weights=spread, minlength=2 * _REACH + 1)
        best = int(np.argmax(per_bin))
        labels[k] = (bins[k] + best - _REACH) % N_BINS + 1
        probabilities[k] = per_bin[best]
        shift = _wrapped(bins[k + 1] - bins[k])
        belief = _condition(spread, shift * cells - first - turn * cells, cells)
        if belief is None:
            raise InputError(f"pointer error run: the reading at trial {k} is impossible")
    return OraclePrediction(labels, probabilities)


def _condition(spread: np.ndarray, start: int, cells: int) -> np.ndarray | None:
    """The part of ``spread`` from index ``start`` over one bin, normalized (None if empty)."""
    part = np.zeros(cells)
    low, high = max(start, 0), min(start + cells, len(spread))
    if low < high:
        part[low - start:high - start] = spread[low:high]
    total = part.sum()
    return part / total if total > 0 else None
