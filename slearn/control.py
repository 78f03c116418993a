"""Closed-loop goal seeking on the simulated pointer, with a Q-learning baseline next to it.

A run learns a library offline from random trials (or takes one), then drives a step-by-step
pointer (:class:`PointerEnv`) toward a sequence of random goal positions: before each step
the :class:`~slearn.planner.Planner` plans from the recent history, the chosen command is
issued, and the library learns the step online. For ``reversal`` and ``scramble`` the
offline trials are the unchanged pointer and the world changes halfway through the goals,
so the per-block results show control recovering as the library relearns.

The baseline is a tabular :class:`~slearn.qlearning.QLearner` trained on the same random
trials for one goal, then given the same new goals in its own pointer (same seed); it keeps
learning online from each new goal's reward.
"""

from __future__ import annotations

import copy
import math
import os
import time
from collections import deque
from dataclasses import asdict, dataclass, field
from typing import Protocol

import numpy as np

from slearn import __version__
from slearn.errors import InputError
from slearn.library import PatternLibrary
from slearn.planner import Planner, PlannerSettings
from slearn.qlearning import QLearner
from slearn.recorders.mcap_episode import EpisodeWriter
from slearn.recorders.record_pointer import (ANGLE_CHANNEL, ANGLE_SCHEMA, COMMAND_SCHEMA,
                                             POSITION_SCHEMA, SENSE_DELAY_NS, TRIAL_NS)
from slearn.recorders.pointer import (BIN_DEG, COMMAND_CHANNEL, COMMAND_NAMES, CONDITIONS,
                                      FULL_TURN_DEG, MAX_ERROR_DEG, N_BINS, POSITION_CHANNEL, R,
                                      PointerConfig, PointerRun, bin_of, pointer_vocabulary,
                                      simulate)
from slearn.stream import Episode
from slearn.vocabulary import Vocabulary

SWITCHING = ("reversal", "scramble")
OFFLINE_TRIALS = 10_000
DEFAULT_BUDGET = 100
TRAINED_GOAL_EPISODES = 20


class PointerEnv:
    """The pointer of :mod:`slearn.recorders.pointer`, one command at a time.

    Same dynamics as :func:`~slearn.recorders.pointer.simulate` (start at the centre of a
    random bin; ``error``, ``delay``, ``hardstop``), except that ``reversal`` and
    ``scramble`` change when :meth:`switch` is called rather than at a fixed trial.

    Args:
        condition: one of :data:`~slearn.recorders.pointer.CONDITIONS`.
        seed: seed of the start, the scramble permutation and the dynamics' noise.
        error_deg: half-width of the move noise (``error``).
        delay_prob: chance that a command is delayed by one step (``delay``).
        start_bin: start in this bin (0..35) instead of a random one.
    """

    def __init__(self, condition: str, seed: int = 0, *, error_deg: float = 5.0,
                 delay_prob: float = 0.5, start_bin: int | None = None) -> None:
        _check_pointer(condition, seed, error_deg, delay_prob)
        # the simulator's streams (start, permutation, policy, dynamics); no policy here
        start, permutation, _, dynamics = (np.random.default_rng(s)
                                           for s in np.random.SeedSequence(seed).spawn(4))
        first = int(start.integers(N_BINS)) if start_bin is None else int(start_bin)
        self.condition = condition
        self.angle_deg = (first + 0.5) * BIN_DEG
        self.error_deg = float(error_deg)
        self.delay_prob = float(delay_prob)
        self.switched = False
        self.steps = 0
        self._labels = permutation.permutation(np.arange(1, N_BINS + 1))
        self._rng = dynamics
        self._pending = 0

    @property
    def bin(self) -> int:
        """The true bin index, 0..35."""
        return int(bin_of(np.array([self.angle_deg]))[0])

    @property
    def label(self) -> int:
        """The position label the sensor reports, 1..36."""
        if self.switched and self.condition == "scramble":
            return int(self._labels[self.bin])
        return self.bin + 1

    def switch(self) -> None:
        """Reverse the commands (``reversal``) or permute the labels (``scramble``)."""
        self.switched = True

    def step(self, command: int) -> int:
        """Issue ``command`` (0 = ``L``, 1 = ``R``); return the label read afterwards."""
        direction = 1 if command == R else -1
        if self.switched and self.condition == "reversal":
            direction = -direction
        if self.condition == "delay":
            moves, self._pending = self._pending, 0
            if self._rng.random() < self.delay_prob:
                self._pending = direction
            else:
                moves += direction
            self._turn(moves * BIN_DEG)
        elif self.condition == "error":
            self._turn(direction * (BIN_DEG + self._rng.uniform(-self.error_deg, self.error_deg)))
        elif self.condition == "hardstop":
            target = self.bin + direction
            if 0 <= target < N_BINS:  # else the move would cross the stop at 0 degrees
                self.angle_deg = (target + 0.5) * BIN_DEG
        else:
            self._turn(direction * BIN_DEG)
        self.steps += 1
        return self.label

    def _turn(self, degrees: float) -> None:
        self.angle_deg = math.fmod(self.angle_deg + degrees, FULL_TURN_DEG)
        if self.angle_deg < 0.0:
            self.angle_deg += FULL_TURN_DEG
        if self.angle_deg >= FULL_TURN_DEG:
            self.angle_deg = 0.0

    def bin_of_label(self, label: int) -> int:
        """The true bin the sensor reports as ``label`` now."""
        if self.switched and self.condition == "scramble":
            return int(np.flatnonzero(self._labels == label)[0])
        return label - 1

    def shortest(self, label: int) -> int:
        """The fewest nominal moves from the current bin to the one reported as ``label``."""
        gap = abs(self.bin_of_label(label) - self.bin)
        return gap if self.condition == "hardstop" else min(gap, N_BINS - gap)


def _check_pointer(condition: str, seed: int, error_deg: float, delay_prob: float) -> None:
    if condition not in CONDITIONS:
        raise InputError(f"pointer condition {condition!r} is unknown: use one of {', '.join(CONDITIONS)}")
    if seed < 0:
        raise InputError(f"seed must be an integer >= 0, not {seed}")
    if not 0.0 <= error_deg <= MAX_ERROR_DEG or not 0.0 <= delay_prob <= 1.0:
        raise InputError(f"error_deg must be in [0, {MAX_ERROR_DEG:g}] and delay_prob in [0, 1]")


@dataclass(frozen=True)
class PointerSymbols:
    """The library symbols of the pointer's commands (``L``, ``R``) and labels 1..36."""

    commands: tuple[int, int]
    labels: tuple[int, ...]

    @classmethod
    def from_vocabulary(cls, vocabulary: Vocabulary) -> "PointerSymbols":
        """Look the pointer channels up; the library must have been learned from the pointer."""
        commands = [vocabulary.get_symbol(COMMAND_CHANNEL, name) for name in COMMAND_NAMES]
        labels = [vocabulary.get_symbol(POSITION_CHANNEL, k) for k in range(1, N_BINS + 1)]
        if None in commands or None in labels:
            raise InputError(f"the library's vocabulary lacks {COMMAND_CHANNEL} L/R or "
                             f"{POSITION_CHANNEL} 1..{N_BINS}: learn it from pointer logs")
        return cls(tuple(commands), tuple(labels))

    def label_of(self, symbol: int) -> int:
        """The label of a position symbol."""
        return self.labels.index(symbol) + 1


@dataclass(frozen=True)
class ControlConfig:
    """One closed-loop run.

    Attributes:
        condition: pointer condition.
        goals: number of random goals (ignored when ``goal`` is set: one goal).
        seed: seed of everything (offline trials, pointer, goals).
        budget: steps allowed per goal.
        goal: a fixed goal label instead of random ones.
        switch_goal: for ``reversal``/``scramble``, the goal at which the world changes
            (default: halfway).
        blocks: goals are reported in this many blocks.
        trials: random trials learned offline when no library is given (and the
            Q-learner's exploration data).
        error_deg, delay_prob: pointer parameters.
        qlearning: run the Q-learning baseline too.
        planner: planner settings.
    """

    condition: str
    goals: int = 100
    seed: int = 0
    budget: int = DEFAULT_BUDGET
    goal: int | None = None
    switch_goal: int | None = None
    blocks: int = 10
    trials: int = OFFLINE_TRIALS
    error_deg: float = 5.0
    delay_prob: float = 0.5
    qlearning: bool = True
    planner: PlannerSettings = field(default_factory=PlannerSettings)

    def __post_init__(self) -> None:
        _check_pointer(self.condition, self.seed, self.error_deg, self.delay_prob)
        if self.goals < 1 or self.budget < 1 or self.blocks < 1 or self.trials < 1:
            raise InputError("goals, budget, blocks and trials must be at least 1")
        if self.goal is not None and not 1 <= self.goal <= N_BINS:
            raise InputError(f"goal must be a position label 1..{N_BINS}, not {self.goal}")

    @property
    def n_goals(self) -> int:
        return 1 if self.goal is not None else self.goals

    @property
    def switch_at(self) -> int | None:
        """The goal index at which the world changes, or ``None``."""
        if self.condition not in SWITCHING:
            return None
        return self.n_goals // 2 if self.switch_goal is None else self.switch_goal

    @property
    def offline_condition(self) -> str:
        """Offline trials see the world before any switch."""
        return "simple" if self.condition in SWITCHING else self.condition


@dataclass(frozen=True)
class GoalOutcome:
    """One goal: where it started, the fewest moves possible, what it took."""

    goal: int
    start: int
    shortest: int
    steps: int
    reached: bool
    explored: int = 0

    def within(self, factor: float) -> bool:
        """Reached in at most ``factor`` times the fewest moves."""
        return self.reached and self.steps <= factor * self.shortest


@dataclass(frozen=True)
class Summary:
    """Results over goals (goals that started at their target are left out)."""

    goals: int
    success: float
    within_1_1x: float
    within_2x: float
    within_3x: float
    steps_ratio: float
    mean_steps: float
    mean_shortest: float
    explored_steps: int

    @classmethod
    def of(cls, outcomes: list[GoalOutcome]) -> "Summary":
        real = [o for o in outcomes if o.shortest > 0]
        reached = [o for o in real if o.reached]
        n = len(real) or math.nan  # no goal to reach: rates are undefined
        ratio = float(np.mean([o.steps / o.shortest for o in reached])) if reached else math.nan
        return cls(len(real), len(reached) / n, sum(o.within(1.1) for o in real) / n,
                   sum(o.within(2) for o in real) / n, sum(o.within(3) for o in real) / n, ratio,
                   float(np.mean([o.steps for o in reached])) if reached else math.nan,
                   float(np.mean([o.shortest for o in reached])) if reached else math.nan,
                   sum(o.explored for o in real))


@dataclass(frozen=True)
class Block:
    """One block of consecutive goals (slearn's results), and the library size after it."""

    first_goal: int
    summary: Summary
    patterns: int
    after_switch: bool


@dataclass(frozen=True)
class QLearningResult:
    """The baseline: success toward the goal it was trained for, then on the new goals."""

    trained_goal: int
    trained_goal_success: float
    new_goals: Summary


@dataclass(frozen=True)
class Trace:
    """What the slearn pointer did, step by step (for recording)."""

    start_label: int
    start_angle_deg: float
    commands: list[int]
    labels: list[int]
    angles_deg: list[float]
    goal_steps: list[int]
    goal_labels: list[int]


@dataclass(frozen=True)
class ControlResult:
    """One closed-loop run."""

    config: ControlConfig
    library_source: str
    slearn: Summary
    outcomes: list[GoalOutcome]
    blocks: list[Block]
    patterns_before: int
    patterns_after: int
    steps: int
    plan_ms_per_step: float
    qlearning: QLearningResult | None
    trace: Trace

    def to_dict(self) -> dict:
        """A JSON-ready dict (without the step trace)."""
        out = asdict(self)
        out.pop("trace")
        out["config"]["planner"] = asdict(self.config.planner)
        return _finite(out)


def _finite(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_finite(v) for v in value]
    return value


def offline_library(config: ControlConfig) -> tuple[PatternLibrary, PointerRun]:
    """A library learned from ``config.trials`` random trials (before any switch)."""
    run = exploration_run(config)
    library = PatternLibrary()
    library.learn(run.to_episode())
    return library, run


def exploration_run(config: ControlConfig) -> PointerRun:
    """The random trials both learners start from."""
    return simulate(PointerConfig(config.offline_condition, config.trials, config.seed,
                                  error_deg=config.error_deg, delay_prob=config.delay_prob))


class _Agent(Protocol):
    def act(self, goal: int) -> tuple[int, bool]: ...

    def observe(self, command: int, label: int) -> None: ...


class SlearnAgent:
    """Plans every step from the library and learns every step into it."""

    def __init__(self, library: PatternLibrary, symbols: PointerSymbols, label: int,
                 settings: PlannerSettings) -> None:
        self.library = library
        self.symbols = symbols
        self.planner = Planner(library, [(c,) for c in symbols.commands], settings)
        self.history: deque = deque([((), (symbols.labels[label - 1],))], maxlen=settings.order + 2)
        self.plan_seconds = 0.0
        self.plans = 0
        self.warm = False
        library.learn(Episode.from_steps([((), (symbols.labels[label - 1],))]))

    def act(self, goal: int) -> tuple[int, bool]:
        """The command to issue toward ``goal`` and whether it was a curious one."""
        began = time.perf_counter()
        plan = self.planner.plan(list(self.history), self.symbols.labels[goal - 1])
        if self.warm:  # the first call may compile the kernels
            self.plan_seconds += time.perf_counter() - began
            self.plans += 1
        self.warm = True
        return self.symbols.commands.index(plan.action[0]), plan.explore

    def observe(self, command: int, label: int) -> None:
        """Learn the step just taken."""
        step = ((self.symbols.commands[command],), (self.symbols.labels[label - 1],))
        self.library.learn(Episode.from_steps([step]), new_episode=False)
        self.history.append(((self.symbols.commands[command],), (self.symbols.labels[label - 1],)))

    def close(self) -> None:
        """Nothing to do: every step was learned as it came."""


class QAgent:
    """Acts on a Q-table and updates it with the current goal's reward."""

    def __init__(self, learner: QLearner, label: int, rng: np.random.Generator,
                 learn: bool = True) -> None:
        self.learner = learner
        self.label = label
        self.rng = rng
        self.learn = learn
        self.goal = 0

    def act(self, goal: int) -> tuple[int, bool]:
        """The epsilon-greedy command from the current label (``goal`` is only remembered)."""
        self.goal = goal
        return self.learner.act(self.label - 1, self.rng), False

    def observe(self, command: int, label: int) -> None:
        """Update the Q-table with the current goal's reward (when learning)."""
        if self.learn:
            self.learner.update(self.label - 1, command, label - 1, self.goal - 1)
        self.label = label


def pursue(agent: _Agent, env: PointerEnv, goal: int, budget: int,
           trace: Trace | None = None) -> GoalOutcome:
    """Drive ``env`` toward ``goal`` for at most ``budget`` steps."""
    start, shortest = env.label, env.shortest(goal)
    steps = explored = 0
    while env.label != goal and steps < budget:
        command, curious = agent.act(goal)
        label = env.step(command)
        agent.observe(command, label)
        steps += 1
        explored += curious
        if trace is not None:
            trace.commands.append(command)
            trace.labels.append(label)
            trace.angles_deg.append(env.angle_deg)
    return GoalOutcome(goal, start, shortest, steps, env.label == goal, explored)


def goal_sequence(config: ControlConfig, first_label: int) -> list[int]:
    """Random goal labels, each different from the one before (seeded)."""
    if config.goal is not None:
        return [config.goal]
    rng = np.random.default_rng(np.random.SeedSequence(config.seed).spawn(5)[4])
    goals, last = [], first_label
    for _ in range(config.goals):
        goal = int(rng.integers(1, N_BINS))
        goal += goal >= last  # uniform over the other labels
        goals.append(goal)
        last = goal
    return goals


def run_control(config: ControlConfig, library: PatternLibrary | None = None,
                vocabulary: Vocabulary | None = None, library_source: str | None = None) -> ControlResult:
    """Run the closed loop (and the Q-learning baseline) as ``config`` says.

    Args:
        config: the run.
        library: a library to start from (it keeps learning); default: learned offline.
        vocabulary: the library's vocabulary (default: the pointer's).
        library_source: how the library was obtained, for the report.
    """
    source = library_source or "given"
    if library is None:
        library, _ = offline_library(config)
        source = f"learned offline from {config.trials} random {config.offline_condition} trials"
    symbols = PointerSymbols.from_vocabulary(vocabulary or pointer_vocabulary())
    env = _env(config)
    goals = goal_sequence(config, env.label)
    before = len(library)
    agent = SlearnAgent(library, symbols, env.label, config.planner)
    trace = Trace(env.label, env.angle_deg, [], [], [], [], [])
    outcomes, blocks = _run_goals(agent, env, goals, config, trace)
    agent.close()
    q = _run_qlearning(config, goals) if config.qlearning else None
    return ControlResult(config, source, Summary.of(outcomes), outcomes, blocks, before, len(library),
                         env.steps, 1000 * agent.plan_seconds / max(agent.plans, 1), q, trace)


def _env(config: ControlConfig, start_bin: int | None = None) -> PointerEnv:
    return PointerEnv(config.condition, config.seed, error_deg=config.error_deg,
                      delay_prob=config.delay_prob, start_bin=start_bin)


def _run_goals(agent: SlearnAgent, env: PointerEnv, goals: list[int], config: ControlConfig,
               trace: Trace) -> tuple[list[GoalOutcome], list[Block]]:
    size = max(1, math.ceil(len(goals) / config.blocks))
    outcomes: list[GoalOutcome] = []
    blocks: list[Block] = []
    for i, goal in enumerate(goals):
        if i == config.switch_at:
            env.switch()
        trace.goal_steps.append(env.steps)
        trace.goal_labels.append(goal)
        outcomes.append(pursue(agent, env, goal, config.budget, trace))
        if (i + 1) % size == 0 or i + 1 == len(goals):
            first = (i // size) * size
            switch = config.switch_at
            blocks.append(Block(first, Summary.of(outcomes[first:]), len(agent.library),
                                switch is not None and first >= switch))
    return outcomes, blocks


def _run_qlearning(config: ControlConfig, goals: list[int]) -> QLearningResult:
    """Train on the exploration trials for one goal; measure it there, then on ``goals``."""
    run = exploration_run(config)
    rng = np.random.default_rng(np.random.SeedSequence(config.seed).spawn(7)[6])
    trained_goal = int(rng.integers(1, N_BINS + 1))
    learner = QLearner(N_BINS, len(COMMAND_NAMES))
    positions = run.positions.astype(np.int64) - 1
    learner.train(positions[:-1], run.commands, positions[1:], trained_goal - 1)
    trained = _trained_goal_success(copy.deepcopy(learner), config, trained_goal, rng)
    env = _env(config)
    agent = QAgent(learner, env.label, rng)
    outcomes = []
    for i, goal in enumerate(goals):
        if i == config.switch_at:
            env.switch()
        outcomes.append(pursue(agent, env, goal, config.budget))
    return QLearningResult(trained_goal, trained, Summary.of(outcomes))


def _trained_goal_success(learner: QLearner, config: ControlConfig, goal: int,
                          rng: np.random.Generator) -> float:
    """Success toward the trained goal from random starts (the world before any switch)."""
    reached = 0
    for episode in range(TRAINED_GOAL_EPISODES):
        start = int(rng.integers(N_BINS - 1))
        start += start >= goal - 1  # any bin but the goal's
        env = PointerEnv(config.offline_condition, config.seed + episode, error_deg=config.error_deg,
                         delay_prob=config.delay_prob, start_bin=start)
        reached += pursue(QAgent(learner, env.label, rng, learn=False), env, goal, config.budget).reached
    return reached / TRAINED_GOAL_EPISODES


GOAL_CHANNEL = "/pointer/goal"
GOAL_SCHEMA = {
    "title": "slearn.pointer.Goal",
    "description": "The position label the controller is steering the pointer to.",
    "type": "object",
    "properties": {"goal": {"type": "integer", "minimum": 1, "maximum": N_BINS}},
    "required": ["goal"],
}
METADATA_NAME = "slearn.control"


def write_control_mcap(result: ControlResult, path: str | os.PathLike, *,
                       overwrite: bool = False) -> int:
    """Write the slearn pointer's run as one MCAP episode, atomically; returns messages written.

    Channels are those of :mod:`slearn.recorders.record_pointer` plus ``/pointer/goal``
    (``{"goal": 17}`` each time a goal is set), with the same timing (step ``i`` issues its
    command at ``i * 100 ms`` and reads the position 50 ms later).
    """
    trace = result.trace
    with EpisodeWriter(path, overwrite=overwrite) as out:
        out.add_metadata(METADATA_NAME, _control_metadata(result))
        channels = [out.register_channel(topic, schema["title"], schema, {"role": role})
                    for topic, schema, role in _RECORDED]
        command, position, angle, goal = channels
        out.write(position, 0, {"position": trace.start_label})
        out.write(angle, 0, {"angle_deg": trace.start_angle_deg})
        for step, label in zip(trace.goal_steps, trace.goal_labels):
            out.write(goal, step * TRIAL_NS, {"goal": label})
        for i, (cmd, label, deg) in enumerate(zip(trace.commands, trace.labels, trace.angles_deg)):
            out.write(command, i * TRIAL_NS, {"command": COMMAND_NAMES[cmd]})
            out.write(position, i * TRIAL_NS + SENSE_DELAY_NS, {"position": label})
            out.write(angle, i * TRIAL_NS + SENSE_DELAY_NS, {"angle_deg": deg})
    return 2 + len(trace.goal_steps) + 3 * len(trace.commands)


_RECORDED = ((COMMAND_CHANNEL, COMMAND_SCHEMA, "action"),
             (POSITION_CHANNEL, POSITION_SCHEMA, "observation"),
             (ANGLE_CHANNEL, ANGLE_SCHEMA, "ground_truth"),
             (GOAL_CHANNEL, GOAL_SCHEMA, "goal"))


def _control_metadata(result: ControlResult) -> dict[str, str]:
    config = result.config
    return {"condition": config.condition, "seed": str(config.seed), "goals": str(config.n_goals),
            "budget": str(config.budget), "switch_goal": str(config.switch_at),
            "error_deg": repr(config.error_deg), "delay_prob": repr(config.delay_prob),
            "library": result.library_source, "simulator": "slearn.control.PointerEnv",
            "slearn_version": __version__}
