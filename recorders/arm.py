"""The pointer arm: 1 to 4 joints, each a rotary pointer of the paper, in one event stream.

Each joint turns in a circle like the paper's pointer (``simple`` condition): its sensor
reports which of 36 bins of 10 degrees it is in (labels 1..36), its commands are ``R``
(+10 degrees) and ``L`` (-10 degrees). Each trial, the exploration policy draws one joint
uniformly and one command for it uniformly; the other joints stand still. One command per
trial, not one per joint, keeps the trial the paper's trial and the action vocabulary
``2 * joints`` (one command per joint per trial would make every action a combination of
``2 ** joints``); the learner has to find out which joint a command moves.

Sensors (``sensors``):

- ``moved``: after a trial, the commanded joint's sensor reports (an event-driven
  encoder); each step is one command and one reading, so the stream is the joints'
  pointer streams interleaved.
- ``all``: after a trial, every joint's sensor reports (like ``/joint_states``); each
  step's observation is the tuple of all joint labels, ``36 ** joints`` possible values.

Conditions (``condition``): ``simple``, every command moves its joint exactly 10 degrees;
``error``, the pointer's ``error``: each move is 10 degrees plus uniform noise in
``[-error_deg, +error_deg]``, so each joint keeps a continuous angle. The ceiling
(:func:`arm_oracle_correct`) is the pointer's exact filter run on each joint's own trials:
the joints not commanded stand still and are known, so a step is predictable exactly when
the moved joint's reading is.

Channels ``/arm/joint{j}/command`` (action) and ``/arm/joint{j}/position`` (observation),
``j = 1..joints``, with the pointer's JSON schemas. Log times as the pointer: trial ``i``
issues its command at ``i * 100 ms`` and reads at ``+50 ms``; all joints report their
start positions at 0. Randomness comes from child streams of ``SeedSequence(seed)``
(start, joint choice, commands, noise).
"""

from __future__ import annotations

import numbers
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from slearn import __version__
from slearn.core.stream import Episode
from slearn.core.vocabulary import ACTION, OBSERVATION, Vocabulary
from slearn.errors import InputError
from slearn.io.serialize import prepare_vocabulary
from slearn.io.spec import Categorical, ChannelSpec, Spec
from slearn.recorders.mcap_episode import EpisodeWriter
from slearn.recorders.pointer import BIN_DEG, COMMAND_NAMES, FULL_TURN_DEG, N_BINS, PointerConfig, PointerRun, bin_of
from slearn.recorders.pointer_oracle import oracle_correct
from slearn.recorders.record_pointer import COMMAND_SCHEMA, POSITION_SCHEMA, SENSE_DELAY_NS, TRIAL_NS, RecordSummary

MAX_JOINTS = 4
SENSORS = ("moved", "all")
ARM_CONDITIONS = ("simple", "error")
METADATA_NAME = "slearn.arm"
_SYMBOLS_PER_JOINT = len(COMMAND_NAMES) + N_BINS


def command_channel(joint: int) -> str:
    """The command topic of joint ``joint`` (1-based)."""
    return f"/arm/joint{joint}/command"


def position_channel(joint: int) -> str:
    """The position topic of joint ``joint`` (1-based)."""
    return f"/arm/joint{joint}/position"


@dataclass(frozen=True)
class ArmConfig:
    """One arm episode's parameters; checked on construction.

    Attributes:
        joints: number of joints, 1 to :data:`MAX_JOINTS`.
        trials: number of trials (one command each), at least 1.
        seed: non-negative seed of all randomness.
        sensors: ``"moved"`` or ``"all"`` (see the module doc).
        condition: ``"simple"`` or ``"error"`` (see the module doc).
        error_deg: half-width of the uniform move noise under ``error``, 0 to 10.
    """

    joints: int = 2
    trials: int = 10_000
    seed: int = 0
    sensors: str = "moved"
    condition: str = "simple"
    error_deg: float = 5.0

    def __post_init__(self) -> None:
        for name, value, low, high in (("joints", self.joints, 1, MAX_JOINTS),
                                       ("trials", self.trials, 1, None),
                                       ("seed", self.seed, 0, None)):
            if (isinstance(value, bool) or not isinstance(value, numbers.Integral)
                    or value < low or (high is not None and value > high)):
                bound = f"in {low}..{high}" if high is not None else f">= {low}"
                raise InputError(f"pointer arm {name} must be an integer {bound}, not {value!r}")
        if self.sensors not in SENSORS:
            raise InputError(f"pointer arm sensors {self.sensors!r} is unknown: "
                             f"use one of {', '.join(SENSORS)}")
        if self.condition not in ARM_CONDITIONS:
            raise InputError(f"pointer arm condition {self.condition!r} is unknown: "
                             f"use one of {', '.join(ARM_CONDITIONS)}")
        error = self.error_deg
        if (isinstance(error, bool) or not isinstance(error, numbers.Real)
                or not 0.0 <= error <= BIN_DEG):
            raise InputError(f"pointer arm error_deg must be a number in [0, {BIN_DEG:g}], "
                             f"not {error!r}")

    def parameters(self) -> dict[str, str]:
        """All fields as strings (for MCAP metadata); the condition only when it is not
        ``simple``, so earlier recordings keep their metadata."""
        out = {"joints": str(self.joints), "trials": str(self.trials), "seed": str(self.seed),
               "sensors": self.sensors}
        if self.condition != "simple":
            out.update(condition=self.condition, error_deg=repr(float(self.error_deg)))
        return out


@dataclass(frozen=True, eq=False)
class ArmRun:
    """One simulated arm episode.

    Attributes:
        config: the parameters it was made with.
        joint: ``uint8`` per trial, the commanded joint (0-based).
        commands: ``uint8`` per trial, 0 = ``L``, 1 = ``R``.
        positions: ``int16`` ``(trials + 1, joints)`` labels 1..36; row 0 is the start.
        angles: ``float64`` ``(trials + 1, joints)`` ground-truth angles in degrees.
    """

    config: ArmConfig
    joint: np.ndarray
    commands: np.ndarray
    positions: np.ndarray
    angles: np.ndarray

    def __len__(self) -> int:
        return len(self.commands)

    def to_episode(self) -> Episode:
        """The run as an episode in the symbols of :func:`arm_vocabulary` (what the
        recorded MCAP file gives under :func:`arm_spec`)."""
        base = self.joint.astype(np.int64) * _SYMBOLS_PER_JOINT
        actions = base + self.commands
        first = (np.arange(self.config.joints) * _SYMBOLS_PER_JOINT + 1
                 + self.positions[0]).tolist()
        if self.config.sensors == "moved":
            moved = self.positions[1:][np.arange(len(self)), self.joint]
            return Episode.from_pairs(first, actions, base + 1 + moved)
        offsets = np.arange(self.config.joints) * _SYMBOLS_PER_JOINT + 1
        readings = self.positions[1:] + offsets
        return Episode.from_steps([((), tuple(first))] + [
            ((a,), tuple(r)) for a, r in zip(actions.tolist(), readings.tolist())])


def simulate_arm(config: ArmConfig) -> ArmRun:
    """Simulate one arm episode; deterministic in ``config``."""
    start, choice, policy, noise = (np.random.default_rng(child)
                                    for child in np.random.SeedSequence(config.seed).spawn(4))
    bins = start.integers(N_BINS, size=config.joints)
    joint = choice.integers(config.joints, size=config.trials, dtype=np.uint8)
    commands = policy.integers(0, 2, size=config.trials, dtype=np.uint8)
    moves = np.zeros((config.trials + 1, config.joints))
    size = BIN_DEG
    if config.condition == "error":
        size = BIN_DEG + noise.uniform(-config.error_deg, config.error_deg, size=config.trials)
    moves[np.arange(1, config.trials + 1), joint] = (commands.astype(np.int64) * 2 - 1) * size
    angles = np.mod(np.cumsum(moves, axis=0) + (bins + 0.5) * BIN_DEG, FULL_TURN_DEG)
    positions = bin_of(angles) + 1
    return ArmRun(config, joint, commands, positions.astype(np.int16), angles)


def arm_oracle_correct(run: ArmRun) -> np.ndarray:
    """Per trial, whether the optimal predictor is right: the pointer's exact filter
    (:mod:`slearn.recorders.pointer_oracle`) on the commanded joint's own trials."""
    correct = np.ones(len(run), bool)
    for j in range(run.config.joints):
        trials = np.flatnonzero(run.joint == j)
        if len(trials) == 0:
            continue
        rows = np.concatenate(([0], trials + 1))
        config = PointerConfig(run.config.condition, trials=len(trials),
                               error_deg=run.config.error_deg)
        joint_run = PointerRun(config, run.commands[trials], run.positions[rows, j],
                               run.angles[rows, j], np.ones(len(trials), np.uint8),
                               np.arange(1, N_BINS + 1, dtype=np.int16))
        correct[trials] = oracle_correct(joint_run)
    return correct


def arm_spec(joints: int) -> Spec:
    """The spec of arm logs: per joint, its command (action) then its position
    (observation), every message an event."""
    channels = []
    for j in range(1, joints + 1):
        channels.append(ChannelSpec(command_channel(j), "command", ACTION, command_channel(j),
                                    Categorical(COMMAND_NAMES)))
        channels.append(ChannelSpec(position_channel(j), "position", OBSERVATION,
                                    position_channel(j), Categorical(tuple(range(1, N_BINS + 1)))))
    return Spec(tuple(channels), mode="message", source=f"arm_spec({joints})")


def arm_vocabulary(joints: int) -> Vocabulary:
    """The arm's vocabulary: joint ``j`` (0-based) has ``L`` = ``38 j``, ``R`` = ``38 j + 1``,
    label ``k`` = ``38 j + 1 + k``."""
    return prepare_vocabulary(arm_spec(joints), Vocabulary())


def record_arm(config: ArmConfig, path: str | os.PathLike, *,
               overwrite: bool = False) -> RecordSummary:
    """Simulate one arm episode and write it to ``path`` (see :func:`write_arm_mcap`)."""
    return write_arm_mcap(simulate_arm(config), path, overwrite=overwrite)


def write_arm_mcap(run: ArmRun, path: str | os.PathLike, *,
                   overwrite: bool = False) -> RecordSummary:
    """Write ``run`` as one MCAP episode at ``path``, atomically.

    Raises:
        InputError: ``path`` exists and ``overwrite`` is false, or its folder is missing.
    """
    joints = run.config.joints
    with EpisodeWriter(path, overwrite=overwrite) as out:
        out.add_metadata(METADATA_NAME, {**run.config.parameters(), "bins": str(N_BINS),
                                         "simulator": "slearn.recorders.arm",
                                         "slearn_version": __version__})
        commands = [out.register_channel(command_channel(j), COMMAND_SCHEMA["title"],
                                         COMMAND_SCHEMA, {"role": "action"})
                    for j in range(1, joints + 1)]
        positions = [out.register_channel(position_channel(j), POSITION_SCHEMA["title"],
                                          POSITION_SCHEMA, {"role": "observation"})
                     for j in range(1, joints + 1)]
        counts = _write_trials(out, run, commands, positions)
    return RecordSummary(str(path), f"arm-{joints}-{run.config.sensors}", run.config.seed,
                         len(run), counts, Path(path).stat().st_size)


def _write_trials(out: EpisodeWriter, run: ArmRun, commands: list[int],
                  positions: list[int]) -> dict[str, int]:
    command_data = [b'{"command":"%s"}' % name.encode() for name in COMMAND_NAMES]
    position_data = [b'{"position":%d}' % label for label in range(N_BINS + 1)]
    counts = {command_channel(j + 1): 0 for j in range(run.config.joints)}
    counts.update({position_channel(j + 1): 1 for j in range(run.config.joints)})
    rows = run.positions.tolist()
    for j, channel in enumerate(positions):
        out.write_encoded(channel, 0, position_data[rows[0][j]])
    every = run.config.sensors == "all"
    for i, (joint, command) in enumerate(zip(run.joint.tolist(), run.commands.tolist())):
        issued_ns = i * TRIAL_NS
        out.write_encoded(commands[joint], issued_ns, command_data[command])
        counts[command_channel(joint + 1)] += 1
        for j in (range(run.config.joints) if every else (joint,)):
            out.write_encoded(positions[j], issued_ns + SENSE_DELAY_NS, position_data[rows[i + 1][j]])
            counts[position_channel(j + 1)] += 1
    return counts
