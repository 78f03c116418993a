"""The rotary pointer of the paper's section III: a simulator with six conditions and their variants.

The pointer turns in a circle; a sensor reports which of ``bins`` bins it is in (36 bins of
10 degrees by default: label ``k`` covers ``[10(k-1), 10k)`` degrees, ``k = 1..36``).
Commands are ``R`` (one bin forward) and ``L`` (one bin back); inside, the angle is
continuous. One trial is the sensed position, a command, the resulting sensed position, so
``N`` trials give ``N`` commands and ``N + 1`` positions. Index ``j`` of ``positions`` is
read at the end of trial ``j - 1`` (index 0 before the first trial).

Conditions (the paper's six; ``bin`` is the bin width, 10 degrees by default):

- ``simple``: every command moves exactly one bin.
- ``hardstop``: a stop at 0 degrees, between the last bin and bin 1; a move that would
  cross it is blocked and the pointer stays where it is.
- ``scramble``: from trial ``switch_trial`` on, the sensor reports labels through a seeded
  random permutation (the readings taken in those trials: ``positions[switch_trial + 1:]``).
- ``reversal``: from trial ``switch_trial`` on, ``R`` turns one bin back and ``L`` forward.
- ``error``: each move is one bin plus uniform noise in ``[-error_deg, +error_deg]``.
- ``delay``: each command is delayed with probability ``delay_prob``. In trial ``k``, when
  command ``k`` is issued, first the command delayed in trial ``k - 1`` (if any) executes,
  then command ``k`` executes unless it is delayed itself, then the sensor is read. So 0, 1
  or 2 moves happen per trial; a command delayed in the last trial never executes.

Variants (the defaults give the paper's runs, identical to earlier versions seed for seed):

- ``bins``: any bin count from 10 to 720 (``error_deg`` is then at most one bin).
- Effects combine: ``condition`` may join ``hardstop``, ``scramble``, ``reversal``,
  ``error`` and ``delay`` with ``+`` (``"error+delay"``, ``"reversal+error"``). Each move
  is checked against the stop on its own, a delayed command keeps the turn and the noise
  it was issued with, and the sensor is read after the trial's moves.
- ``switch_back_trial``: the switched dynamics (``scramble``, ``reversal``) end at that
  trial and the original ones return.
- ``error_end_deg``: the noise half-width drifts linearly from ``error_deg`` (first
  command) to ``error_end_deg`` (last command).

The pointer starts at the centre of a random bin; the exploration policy draws ``L``/``R``
uniformly. Randomness comes from independent child streams of ``SeedSequence(seed)`` (start,
permutation, commands, dynamics), so one seed gives the same start and the same commands
in every condition, and no global random state is touched. The dynamics stream draws the
delays first (``delay``), then the noise (``error``), one value per command each.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np

from slearn.core.stream import Episode
from slearn.core.vocabulary import ACTION, OBSERVATION, Vocabulary
from slearn.errors import InputError

CONDITIONS = ("simple", "hardstop", "scramble", "reversal", "error", "delay")
EFFECTS = CONDITIONS[1:]
SWITCHING = ("scramble", "reversal")
N_BINS = 36
MIN_BINS, MAX_BINS = 10, 720
BIN_DEG = 10.0
FULL_TURN_DEG = 360.0
L, R = 0, 1
COMMAND_NAMES = ("L", "R")
COMMAND_CHANNEL = "/pointer/command"
POSITION_CHANNEL = "/pointer/position"
MAX_ERROR_DEG = 10.0
MAX_TRIALS = 10_000_000  # a run is held in memory (about 12 bytes a trial)


@dataclass(frozen=True)
class PointerConfig:
    """One pointer episode's parameters; checked on construction.

    Attributes:
        condition: one of :data:`CONDITIONS`, or effects of :data:`EFFECTS` joined by
            ``+`` (``"error+delay"``).
        trials: number of trials (commands), 1 to :data:`MAX_TRIALS`.
        seed: non-negative seed of all randomness.
        switch_trial: first trial of the changed dynamics (``scramble``, ``reversal``).
        error_deg: half-width of the uniform move noise (``error``), 0 to one bin.
        delay_prob: probability that a command is delayed by one trial (``delay``).
        bins: number of sensor bins, :data:`MIN_BINS` to :data:`MAX_BINS`.
        switch_back_trial: first trial after the changed dynamics, or ``None`` (they last).
        error_end_deg: the noise half-width of the last command (a linear drift from
            ``error_deg``), or ``None`` (constant).
    """

    condition: str
    trials: int = 10_000
    seed: int = 0
    switch_trial: int = 5_000
    error_deg: float = 5.0
    delay_prob: float = 0.5
    bins: int = N_BINS
    switch_back_trial: int | None = None
    error_end_deg: float | None = None

    def __post_init__(self) -> None:
        _validate(self)

    @property
    def effects(self) -> frozenset[str]:
        """The effects in play (empty for ``simple``)."""
        return frozenset(self.condition.split("+")) - {"simple"}

    @property
    def bin_deg(self) -> float:
        """Width of one bin in degrees (one command's nominal turn)."""
        return FULL_TURN_DEG / self.bins

    def switched(self) -> tuple[int, int]:
        """``(first, end)`` trials of the switched dynamics (empty without a switching effect)."""
        if not self.effects & set(SWITCHING):
            return self.trials, self.trials
        end = self.trials if self.switch_back_trial is None else self.switch_back_trial
        return self.switch_trial, end

    def error_amplitudes(self) -> np.ndarray:
        """The noise half-width of every command in degrees (``float64``, length ``trials``)."""
        if self.error_end_deg is None:
            return np.full(self.trials, float(self.error_deg))
        return np.linspace(float(self.error_deg), float(self.error_end_deg), self.trials)

    def parameters(self) -> dict[str, str]:
        """All fields as strings (for MCAP metadata); the variant fields only when set, so
        the paper's runs keep their metadata."""
        out = {
            "condition": self.condition,
            "trials": str(self.trials),
            "seed": str(self.seed),
            "switch_trial": str(self.switch_trial),
            "error_deg": repr(float(self.error_deg)),
            "delay_prob": repr(float(self.delay_prob)),
        }
        if self.bins != N_BINS:
            out["bins"] = str(self.bins)
        if self.switch_back_trial is not None:
            out["switch_back_trial"] = str(self.switch_back_trial)
        if self.error_end_deg is not None:
            out["error_end_deg"] = repr(float(self.error_end_deg))
        return out


def _validate(config: PointerConfig) -> None:
    _check_condition(config.condition)
    _check_int("trials", config.trials, minimum=1, maximum=MAX_TRIALS)
    _check_int("seed", config.seed, minimum=0)
    _check_int("switch_trial", config.switch_trial, minimum=0, maximum=MAX_TRIALS)
    _check_int("bins", config.bins, minimum=MIN_BINS, maximum=MAX_BINS)
    effects = config.effects
    if effects & set(SWITCHING) and config.switch_trial >= config.trials:
        raise InputError(f"pointer {config.condition}: switch_trial {config.switch_trial} is not "
                         f"below trials {config.trials}, so the switch would never happen; "
                         "lower switch_trial or raise trials")
    if config.switch_back_trial is not None:
        _check_switch_back(config, effects)
    _check_range("error_deg", config.error_deg, 0.0, config.bin_deg)
    if config.error_end_deg is not None:
        if "error" not in effects:
            raise InputError(f"pointer {config.condition}: error_end_deg drifts the error "
                             "noise; add the error effect (e.g. condition error) or drop it")
        _check_range("error_end_deg", config.error_end_deg, 0.0, config.bin_deg)
    _check_range("delay_prob", config.delay_prob, 0.0, 1.0)


def _check_condition(condition: object) -> None:
    parts = condition.split("+") if isinstance(condition, str) else [None]
    known = all(part in EFFECTS for part in parts) and len(set(parts)) == len(parts)
    if not (condition in CONDITIONS or known):
        raise InputError(f"pointer condition {condition!r} is unknown: use one of "
                         f"{', '.join(CONDITIONS)}, or distinct effects of "
                         f"{', '.join(EFFECTS)} joined by '+' (e.g. error+delay)")


def _check_switch_back(config: PointerConfig, effects: frozenset[str]) -> None:
    if not effects & set(SWITCHING):
        raise InputError(f"pointer {config.condition}: switch_back_trial ends a switch; add "
                         "reversal or scramble to the condition or drop it")
    _check_int("switch_back_trial", config.switch_back_trial, minimum=config.switch_trial + 1)
    if config.switch_back_trial >= config.trials:
        raise InputError(f"pointer switch_back_trial {config.switch_back_trial} is not below "
                         f"trials {config.trials}, so the switch back would never happen; "
                         "lower it or raise trials")


def _check_int(name: str, value: object, minimum: int, maximum: int | None = None) -> None:
    if (isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < minimum
            or (maximum is not None and value > maximum)):
        bound = f"from {minimum} to {maximum:,}" if maximum is not None else f">= {minimum}"
        raise InputError(f"pointer {name} must be an integer {bound}, not {value!r}")


def _check_range(name: str, value: object, low: float, high: float) -> None:
    ok = isinstance(value, numbers.Real) and not isinstance(value, bool)
    if not ok or not math.isfinite(value) or not low <= value <= high:
        raise InputError(f"pointer {name} must be a number in [{low:g}, {high:g}], not {value!r}")


@dataclass(frozen=True, eq=False)
class PointerRun:
    """One simulated episode.

    Attributes:
        config: the parameters it was made with.
        commands: ``uint8`` per trial, 0 = ``L``, 1 = ``R`` (as issued, before any reversal).
        positions: ``int16`` labels 1..bins as the sensor reports them, length ``trials + 1``.
        angles: ``float64`` ground-truth angle in degrees, ``[0, 360)``, length ``trials + 1``.
        executed: ``uint8`` per trial, how many commands executed in it (0, 1 or 2 under
            ``delay``, else 1; a move blocked by the hard stop counts as executed).
        sensor_labels: ``int16`` of length ``bins``, the label reported for true bin ``k``
            at ``sensor_labels[k - 1]`` while scrambled (identity unless ``scramble``).
    """

    config: PointerConfig
    commands: np.ndarray
    positions: np.ndarray
    angles: np.ndarray
    executed: np.ndarray
    sensor_labels: np.ndarray

    def __len__(self) -> int:
        return len(self.commands)

    def to_episode(self) -> Episode:
        """The run as an episode in the layout of :func:`pointer_vocabulary`."""
        return Episode.from_pairs([int(self.positions[0]) + 1], self.commands,
                                  self.positions[1:].astype(np.int32) + 1)


def pointer_vocabulary(bins: int = N_BINS) -> Vocabulary:
    """The fixed pointer vocabulary: ``L`` = 0, ``R`` = 1, position label ``k`` = ``k + 1``."""
    vocabulary = Vocabulary()
    vocabulary.add_channel(COMMAND_CHANNEL, ACTION)
    for name in COMMAND_NAMES:
        vocabulary.symbol(COMMAND_CHANNEL, name)
    vocabulary.add_channel(POSITION_CHANNEL, OBSERVATION)
    for label in range(1, bins + 1):
        vocabulary.symbol(POSITION_CHANNEL, label)
    return vocabulary


def simulate(config: PointerConfig) -> PointerRun:
    """Simulate one episode of ``config.trials`` trials; deterministic in ``config``."""
    start, permutation, policy, dynamics = (
        np.random.default_rng(child) for child in np.random.SeedSequence(config.seed).spawn(4))
    start_angle = (int(start.integers(config.bins)) + 0.5) * config.bin_deg
    sensor_labels = _sensor_labels(config, permutation)
    commands = policy.integers(0, 2, size=config.trials, dtype=np.uint8)
    directions = command_directions(commands, config)
    delayed = (dynamics.random(config.trials) < config.delay_prob
               if "delay" in config.effects else np.zeros(config.trials, bool))
    moves = directions * _move_sizes(config, dynamics)
    now = np.where(delayed, 0.0, moves)
    carried = np.zeros_like(now)  # the command delayed in the previous trial runs first
    carried[1:] = np.where(delayed[:-1], moves[:-1], 0.0)
    if "hardstop" in config.effects:
        angles = _stopped_walk(start_angle, carried, now)
    else:
        angles = _walk(start_angle, now + carried)
    executed = (~delayed).astype(np.uint8)
    executed[1:] += delayed[:-1]
    positions = sense(bin_of(angles, config.bins), config, sensor_labels)
    return PointerRun(config, commands, positions, angles, executed, sensor_labels)


def command_directions(commands: np.ndarray, config: PointerConfig) -> np.ndarray:
    """The turn of each command: +1 for one bin forward, -1 for one bin back (reversal applied)."""
    directions = commands.astype(np.int8) * 2 - 1
    if "reversal" in config.effects:
        first, end = config.switched()
        directions[first:end] *= -1
    return directions


def bin_of(angles: np.ndarray, bins: int = N_BINS) -> np.ndarray:
    """The true bin index ``0..bins-1`` of each angle in degrees."""
    return (np.floor(angles / (FULL_TURN_DEG / bins)).astype(np.int64) % bins).astype(np.int16)


def scrambled_readings(config: PointerConfig) -> tuple[int, int]:
    """``(first, end)`` indices of ``positions`` read through the scramble permutation."""
    if "scramble" not in config.effects:
        return config.trials + 1, config.trials + 1
    first, end = config.switched()
    return first + 1, end + 1


def sense(bins: np.ndarray, config: PointerConfig, sensor_labels: np.ndarray) -> np.ndarray:
    """The labels the sensor reports for the bins of indices ``0..trials``."""
    labels = bins.astype(np.int16) + 1
    first, end = scrambled_readings(config)
    labels[first:end] = sensor_labels[bins[first:end]]
    return labels


def _sensor_labels(config: PointerConfig, rng: np.random.Generator) -> np.ndarray:
    identity = np.arange(1, config.bins + 1, dtype=np.int16)
    if "scramble" not in config.effects:
        return identity
    return rng.permutation(identity)


def _move_sizes(config: PointerConfig, rng: np.random.Generator) -> np.ndarray | float:
    """The size of each command's move in degrees (one bin, plus noise under ``error``)."""
    if "error" not in config.effects:
        return config.bin_deg
    amplitudes = config.error_amplitudes()
    return config.bin_deg + rng.uniform(-amplitudes, amplitudes)


def _walk(start_angle: float, moves_deg: np.ndarray) -> np.ndarray:
    angles = np.empty(len(moves_deg) + 1)
    angles[0] = start_angle
    np.cumsum(moves_deg, out=angles[1:])
    angles[1:] += start_angle
    angles = np.mod(angles, FULL_TURN_DEG)
    angles[angles >= FULL_TURN_DEG] = 0.0  # mod of a tiny negative rounds up to 360
    return angles


def _stopped_walk(start_angle: float, carried: np.ndarray, now: np.ndarray) -> np.ndarray:
    """Angles when each move that would cross the stop at 0 degrees is blocked."""
    angles = np.empty(len(now) + 1)
    angle = angles[0] = start_angle
    for i, (first, second) in enumerate(zip(carried.tolist(), now.tolist())):
        for move in (first, second):
            if move and 0.0 <= angle + move < FULL_TURN_DEG:
                angle += move
        angles[i + 1] = angle
    return angles
