"""The rotary pointer of the paper's section III: a simulator with six conditions.

The pointer turns in a circle; a sensor reports which of 36 bins of 10 degrees it is in
(label ``k`` covers ``[10(k-1), 10k)`` degrees, ``k = 1..36``). Commands are ``R``
(+10 degrees) and ``L`` (-10 degrees); inside, the angle is continuous. One trial is the
sensed position, a command, the resulting sensed position, so ``N`` trials give ``N``
commands and ``N + 1`` positions. Index ``j`` of ``positions`` is read at the end of trial
``j - 1`` (index 0 before the first trial).

Conditions:

- ``simple``: every command moves exactly 10 degrees.
- ``hardstop``: a stop at 0 degrees, between bins 36 and 1; a move that would cross it is
  blocked and the pointer stays where it is.
- ``scramble``: from trial ``switch_trial`` on, the sensor reports labels through a seeded
  random permutation (the readings taken in those trials: ``positions[switch_trial + 1:]``).
- ``reversal``: from trial ``switch_trial`` on, ``R`` turns -10 degrees and ``L`` +10.
- ``error``: each move is 10 degrees plus uniform noise in ``[-error_deg, +error_deg]``.
- ``delay``: each command is delayed with probability ``delay_prob``. In trial ``k``, when
  command ``k`` is issued, first the command delayed in trial ``k - 1`` (if any) executes,
  then command ``k`` executes unless it is delayed itself, then the sensor is read. So 0, 1
  or 2 moves happen per trial; a command delayed in the last trial never executes.

The pointer starts at the centre of a random bin; the exploration policy draws ``L``/``R``
uniformly. Randomness comes from independent child streams of ``SeedSequence(seed)`` (start,
permutation, commands, dynamics), so one seed gives the same start and the same commands
in every condition, and no global random state is touched.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from typing import Callable

import numpy as np

from slearn.errors import InputError
from slearn.stream import Episode
from slearn.vocabulary import ACTION, OBSERVATION, Vocabulary

CONDITIONS = ("simple", "hardstop", "scramble", "reversal", "error", "delay")
N_BINS = 36
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
        condition: one of :data:`CONDITIONS`.
        trials: number of trials (commands), 1 to :data:`MAX_TRIALS`.
        seed: non-negative seed of all randomness.
        switch_trial: first trial of the changed dynamics (``scramble``, ``reversal``).
        error_deg: half-width of the uniform move noise (``error``), 0 to 10.
        delay_prob: probability that a command is delayed by one trial (``delay``).
    """

    condition: str
    trials: int = 10_000
    seed: int = 0
    switch_trial: int = 5_000
    error_deg: float = 5.0
    delay_prob: float = 0.5

    def __post_init__(self) -> None:
        _validate(self)

    def parameters(self) -> dict[str, str]:
        """All fields as strings (for MCAP metadata)."""
        return {
            "condition": self.condition,
            "trials": str(self.trials),
            "seed": str(self.seed),
            "switch_trial": str(self.switch_trial),
            "error_deg": repr(float(self.error_deg)),
            "delay_prob": repr(float(self.delay_prob)),
        }


def _validate(config: PointerConfig) -> None:
    if config.condition not in CONDITIONS:
        raise InputError(f"pointer condition {config.condition!r} is unknown: "
                         f"use one of {', '.join(CONDITIONS)}")
    _check_int("trials", config.trials, minimum=1, maximum=MAX_TRIALS)
    _check_int("seed", config.seed, minimum=0)
    _check_int("switch_trial", config.switch_trial, minimum=0, maximum=MAX_TRIALS)
    if config.condition in ("scramble", "reversal") and config.switch_trial >= config.trials:
        raise InputError(f"pointer {config.condition}: switch_trial {config.switch_trial} is not "
                         f"below trials {config.trials}, so the switch would never happen; "
                         "lower switch_trial or raise trials")
    _check_range("error_deg", config.error_deg, 0.0, MAX_ERROR_DEG)
    _check_range("delay_prob", config.delay_prob, 0.0, 1.0)


def _check_int(name: str, value: object, minimum: int, maximum: int | None = None) -> None:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < minimum \
            or maximum is not None and value > maximum:
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
        positions: ``int16`` labels 1..36 as the sensor reports them, length ``trials + 1``.
        angles: ``float64`` ground-truth angle in degrees, ``[0, 360)``, length ``trials + 1``.
        executed: ``uint8`` per trial, how many commands executed in it (0, 1 or 2 under
            ``delay``, else 1; a move blocked by the hard stop counts as executed).
        sensor_labels: ``int16`` of length 36, the label reported for true bin ``k`` at
            ``sensor_labels[k - 1]`` from the switch on (identity unless ``scramble``).
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


def pointer_vocabulary() -> Vocabulary:
    """The fixed pointer vocabulary: ``L`` = 0, ``R`` = 1, position label ``k`` = ``k + 1``."""
    vocabulary = Vocabulary()
    vocabulary.add_channel(COMMAND_CHANNEL, ACTION)
    for name in COMMAND_NAMES:
        vocabulary.symbol(COMMAND_CHANNEL, name)
    vocabulary.add_channel(POSITION_CHANNEL, OBSERVATION)
    for label in range(1, N_BINS + 1):
        vocabulary.symbol(POSITION_CHANNEL, label)
    return vocabulary


def simulate(config: PointerConfig) -> PointerRun:
    """Simulate one episode of ``config.trials`` trials; deterministic in ``config``."""
    start, permutation, policy, dynamics = (
        np.random.default_rng(child) for child in np.random.SeedSequence(config.seed).spawn(4))
    start_angle = (int(start.integers(N_BINS)) + 0.5) * BIN_DEG
    sensor_labels = _sensor_labels(config, permutation)
    commands = policy.integers(0, 2, size=config.trials, dtype=np.uint8)
    directions = command_directions(commands, config)
    angles, executed = _DYNAMICS[config.condition](start_angle, directions, config, dynamics)
    positions = sense(bin_of(angles), config, sensor_labels)
    return PointerRun(config, commands, positions, angles, executed, sensor_labels)


def command_directions(commands: np.ndarray, config: PointerConfig) -> np.ndarray:
    """The turn of each command: +1 for +10 degrees, -1 for -10 degrees (reversal applied)."""
    directions = commands.astype(np.int8) * 2 - 1
    if config.condition == "reversal":
        directions[config.switch_trial:] *= -1
    return directions


def bin_of(angles: np.ndarray) -> np.ndarray:
    """The true bin index 0..35 of each angle in degrees."""
    return (np.floor(angles / BIN_DEG).astype(np.int64) % N_BINS).astype(np.int16)


def sense(bins: np.ndarray, config: PointerConfig, sensor_labels: np.ndarray) -> np.ndarray:
    """The labels the sensor reports for the bins of indices ``0..trials``."""
    labels = bins.astype(np.int16) + 1
    if config.condition == "scramble":
        after = config.switch_trial + 1
        labels[after:] = sensor_labels[bins[after:]]
    return labels


def _sensor_labels(config: PointerConfig, rng: np.random.Generator) -> np.ndarray:
    identity = np.arange(1, N_BINS + 1, dtype=np.int16)
    if config.condition != "scramble":
        return identity
    return rng.permutation(identity)


def _walk(start_angle: float, moves_deg: np.ndarray) -> np.ndarray:
    angles = np.empty(len(moves_deg) + 1)
    angles[0] = start_angle
    np.cumsum(moves_deg, out=angles[1:])
    angles[1:] += start_angle
    angles = np.mod(angles, FULL_TURN_DEG)
    angles[angles >= FULL_TURN_DEG] = 0.0  # mod of a tiny negative rounds up to 360
    return angles


def _once(directions: np.ndarray) -> np.ndarray:
    return np.ones(len(directions), dtype=np.uint8)


def _exact_moves(start_angle, directions, config, rng):
    return _walk(start_angle, directions * BIN_DEG), _once(directions)


def _hardstop_moves(start_angle, directions, config, rng):
    bins = np.empty(len(directions) + 1, dtype=np.int64)
    current = bins[0] = int(start_angle // BIN_DEG)
    for i, step in enumerate(directions.tolist()):
        target = current + step
        if 0 <= target < N_BINS:  # else the move would cross the stop at 0 degrees
            current = target
        bins[i + 1] = current
    return (bins + 0.5) * BIN_DEG, _once(directions)


def _noisy_moves(start_angle, directions, config, rng):
    noise = rng.uniform(-config.error_deg, config.error_deg, size=len(directions))
    return _walk(start_angle, directions * (BIN_DEG + noise)), _once(directions)


def _delayed_moves(start_angle, directions, config, rng):
    delayed = rng.random(len(directions)) < config.delay_prob
    now = np.where(delayed, 0, directions)
    carried = np.zeros_like(now)
    carried[1:] = np.where(delayed[:-1], directions[:-1], 0)
    executed = (~delayed).astype(np.uint8)
    executed[1:] += delayed[:-1]
    return _walk(start_angle, (now + carried) * BIN_DEG), executed


_Dynamics = Callable[[float, np.ndarray, PointerConfig, np.random.Generator],
                     tuple[np.ndarray, np.ndarray]]
_DYNAMICS: dict[str, _Dynamics] = {
    "simple": _exact_moves,
    "hardstop": _hardstop_moves,
    "scramble": _exact_moves,
    "reversal": _exact_moves,
    "error": _noisy_moves,
    "delay": _delayed_moves,
}
