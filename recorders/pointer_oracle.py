"""The ceiling: an optimal predictor of the pointer that knows its dynamics.

Before trial ``k``'s outcome is read, the oracle has seen every earlier label and command
and the command just issued. It predicts the label of largest predictive probability
(the Bayes-optimal guess under 0/1 loss), so its hit rate is the best any predictor can
reach in expectation. It knows every parameter of the run: the bin count, the switch
trials, the reversal, the scramble permutation, the stop, the noise half-width of every
command and the delay probability. A label read through the scramble gives the true bin
through the inverse permutation, so the filters below work on true bins. Derivation:

- No ``error`` and no ``delay``: the angle is always a bin centre and the next bin is a
  function of the current bin and command: the ceiling is 100 %.
- ``delay`` without ``error``: the bin is read exactly; the hidden state is whether a
  command is pending, and a pending command can only be the previous one. With ``b`` =
  P(pending), ``p`` = ``delay_prob``, previous turn ``u`` and current turn ``d``, the pointer
  makes the moves ``u`` then ``d`` w.p. ``b(1-p)``, ``u`` w.p. ``bp`` (``d`` now pending),
  ``d`` w.p. ``(1-b)(1-p)``, none w.p. ``(1-b)p`` (``d`` now pending); each move is
  blocked at the stop under ``hardstop``. The reading gives the resulting bin, and ``b``
  for the next trial is the pending share of its probability. With ``p = 0.5`` the best
  bin always has probability 1/2: the ceiling is 50 %. Ties (frequent at ``p = 0.5``) go
  to the first of that list, deterministically.
- ``error`` (with any other effects): the hidden state is the continuous angle (and, under
  ``delay``, whether a command is pending). The posterior after each reading is confined to
  the read bin, so the filter keeps a density over the offset inside that bin on a grid of
  ``cells_per_bin`` cells (0.05 degrees by default), one per pending state, starting as a
  point at the bin centre with nothing pending. Predict: each move shifts by its commanded
  bin and convolves with its command's noise, ``U[-e, e]``, discretized exactly for a
  position uniform within a cell; a landing beyond the stop stays where it was (``hardstop``);
  the four delay cases above mix the results. Summing the mass per bin gives the predictive
  distribution of the label. Update: keep the mass inside the bin read, renormalize. The
  ceiling of the paper's ``error`` is about 75 %.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slearn.errors import InputError
from slearn.recorders.pointer import PointerRun, command_directions, scrambled_readings, sense

DEFAULT_CELLS_PER_BIN = 200


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
    effects = run.config.effects
    if "error" in effects:
        return _GridFilter(run, cells_per_bin).predict()
    if "delay" in effects:
        return _delay_filter(run)
    return _deterministic(run)


def _true_bins(run: PointerRun) -> np.ndarray:
    bins = run.positions.astype(np.int64) - 1
    first, end = scrambled_readings(run.config)
    bins[first:end] = np.argsort(run.sensor_labels)[bins[first:end]]
    return bins


def _labels(run: PointerRun, predicted_bins: np.ndarray) -> np.ndarray:
    """The labels the sensor reports for predicted true bins of readings ``1..trials``."""
    aligned = np.concatenate(([0], predicted_bins))  # index j is reading j
    return sense(aligned, run.config, run.sensor_labels)[1:]


def _step(bin_: int, turn: int, n_bins: int, hardstop: bool) -> int:
    target = bin_ + turn
    if hardstop and not 0 <= target < n_bins:
        return bin_
    return target % n_bins


def _deterministic(run: PointerRun) -> OraclePrediction:
    config = run.config
    bins = _true_bins(run)[:-1]
    targets = bins + command_directions(run.commands, config)
    if "hardstop" in config.effects:
        targets = np.where((targets < 0) | (targets >= config.bins), bins, targets)
    labels = _labels(run, targets % config.bins)
    return OraclePrediction(labels, np.ones(len(labels)))


def _delay_filter(run: PointerRun) -> OraclePrediction:
    config = run.config
    p, n_bins, stop = config.delay_prob, config.bins, "hardstop" in config.effects
    bins = _true_bins(run).tolist()
    turns = command_directions(run.commands, config).tolist()
    best_bins = np.empty(len(turns), dtype=np.int64)
    probabilities = np.empty(len(turns))
    pending, previous = 0.0, 0
    for k, turn in enumerate(turns):
        after_previous = _step(bins[k], previous, n_bins, stop)
        outcomes = ((_step(after_previous, turn, n_bins, stop), pending * (1 - p), 0.0),
                    (after_previous, pending * p, pending * p),
                    (_step(bins[k], turn, n_bins, stop), (1 - pending) * (1 - p), 0.0),
                    (bins[k], (1 - pending) * p, (1 - pending) * p))
        mass: dict[int, list[float]] = {}
        for bin_, prob, pending_prob in outcomes:
            total = mass.setdefault(bin_, [0.0, 0.0])
            total[0] += prob
            total[1] += pending_prob
        best = max(mass, key=lambda b: mass[b][0])  # first of equals wins
        best_bins[k], probabilities[k] = best, mass[best][0]
        observed = mass.get(bins[k + 1], [0.0, 0.0])
        if observed[0] <= 0.0:
            raise InputError(f"pointer {config.condition} run: the reading at trial {k} is impossible")
        pending, previous = observed[1] / observed[0], turn
    return OraclePrediction(_labels(run, best_bins), probabilities)


def _wrapped(shift: int, n_bins: int) -> int:
    return (shift + n_bins // 2) % n_bins - n_bins // 2


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


class _GridFilter:
    """The grid filter of the module docstring over one run (``error``, any other effects).

    Densities live in a window of cells around the bin read last: window cell ``i`` is
    ``i - origin`` cells from that bin's lower edge. A trial moves at most ``reach`` bins
    (two moves of at most two bins under ``delay``), and one bin of margin each side keeps
    every kernel tail inside the window.
    """

    def __init__(self, run: PointerRun, cells: int) -> None:
        config = run.config
        self.run, self.cells, self.n_bins = run, cells, config.bins
        self.delay = "delay" in config.effects
        self.stop = "hardstop" in config.effects
        self.p = config.delay_prob if self.delay else 0.0
        self.reach = 4 if self.delay else 2
        self.origin = (self.reach + 1) * cells
        self.width = (2 * self.reach + 3) * cells
        self.window_bins = np.arange(self.width) // cells
        self.cell_deg = config.bin_deg / cells
        self.amplitudes = config.error_amplitudes().tolist()
        self.kernels: dict[float, tuple[int, np.ndarray]] = {}

    def predict(self) -> OraclePrediction:
        bins = _true_bins(self.run).tolist()
        turns = command_directions(self.run.commands, self.run.config).tolist()
        best_bins = np.empty(len(turns), dtype=np.int64)
        probabilities = np.empty(len(turns))
        free = np.zeros(self.cells)
        centre = free[(self.cells - 1) // 2:self.cells // 2 + 1]  # one cell, or two at its edge
        centre[:] = 1.0 / len(centre)
        pending = np.zeros(self.cells)
        for k, turn in enumerate(turns):
            out_free, out_pending = self._spread(k, bins[k], turns[k - 1] if k else 0, turn,
                                                 free, pending)
            per_bin = np.bincount(self.window_bins, weights=out_free + out_pending
                                  if self.delay else out_free)
            best = int(np.argmax(per_bin))
            best_bins[k] = (bins[k] + best - self.reach - 1) % self.n_bins
            probabilities[k] = per_bin[best]
            free, pending = self._condition(out_free, out_pending,
                                            _wrapped(bins[k + 1] - bins[k], self.n_bins), k)
        return OraclePrediction(_labels(self.run, best_bins), probabilities)

    def _spread(self, k: int, bin_: int, previous: int, turn: int, free: np.ndarray,
                pending: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Predicted densities over the window with nothing pending / the current command pending."""
        out_free = np.zeros(self.width)
        out_pending = np.zeros(self.width) if self.delay else out_free
        base = (bin_ - self.reach - 1) * self.cells  # absolute cell of window cell 0
        now = self._move(self.origin, free, turn, self.amplitudes[k], base)
        _add(out_free, now, 1.0 - self.p)
        if self.delay:
            _add(out_pending, (self.origin, free), self.p)
            if k > 0 and pending.any():
                ran = self._move(self.origin, pending, previous, self.amplitudes[k - 1], base)
                _add(out_pending, ran, self.p)
                _add(out_free, self._move(*ran, turn, self.amplitudes[k], base), 1.0 - self.p)
        return out_free, out_pending

    def _move(self, start: int, values: np.ndarray, turn: int, amplitude: float,
              base: int) -> tuple[int, np.ndarray]:
        """One move of a density segment starting at window cell ``start``."""
        first, kernel = self._kernel(amplitude)
        offset = first + turn * self.cells
        spread = np.convolve(values, kernel)
        if not self.stop:
            return start + offset, spread
        return self._blocked(start, values, start + offset, spread, kernel, offset, base)

    def _blocked(self, start, values, landed, spread, kernel, offset, base):
        """Send the landings beyond the stop back to where they came from."""
        total = self.n_bins * self.cells
        low, high = -(base + landed), total - (base + landed)  # valid spread indices
        if low <= 0 and high >= len(spread):
            return landed, spread
        spread = spread.copy()
        spread[:max(low, 0)] = 0.0
        spread[max(high, 0):] = 0.0
        source = base + start + np.arange(len(values)) + offset  # landing cell of kernel[0]
        cdf = np.concatenate(([0.0], np.cumsum(kernel)))
        crossing = (cdf[np.clip(-source, 0, len(kernel))]
                    + cdf[-1] - cdf[np.clip(total - source, 0, len(kernel))])
        joined_start = min(start, landed)
        end = max(start + len(values), landed + len(spread))
        joined = np.zeros(end - joined_start)
        joined[landed - joined_start:landed - joined_start + len(spread)] += spread
        joined[start - joined_start:start - joined_start + len(values)] += values * crossing
        return joined_start, joined

    def _kernel(self, amplitude: float) -> tuple[int, np.ndarray]:
        if amplitude not in self.kernels:
            self.kernels[amplitude] = noise_kernel(amplitude, self.cell_deg)
        return self.kernels[amplitude]

    def _condition(self, out_free: np.ndarray, out_pending: np.ndarray, shift: int,
                   k: int) -> tuple[np.ndarray, np.ndarray]:
        """The densities inside the bin read, normalized over both pending states."""
        low = self.origin + shift * self.cells
        inside = abs(shift) <= self.reach
        free = out_free[low:low + self.cells] if inside else np.zeros(self.cells)
        pending = (out_pending[low:low + self.cells] if inside and self.delay
                   else np.zeros(self.cells))
        total = free.sum() + pending.sum() if self.delay else free.sum()
        if total <= 0:
            raise InputError(f"pointer {self.run.config.condition} run: the reading at trial "
                             f"{k} is impossible")
        return free / total, pending / total


def _add(out: np.ndarray, segment: tuple[int, np.ndarray], weight: float) -> None:
    start, values = segment
    out[start:start + len(values)] += weight * values
