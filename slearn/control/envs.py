"""Discrete systems to control: a small protocol, the simulated pointer and Gymnasium.

A :class:`DiscreteEnv` has a fixed set of actions ``0..n_actions-1`` and reports one
discrete observation (an ``int``) after every action; there is no reward, because goals
are observations chosen by the caller. The control loop (:mod:`slearn.control.closed_loop`) only
calls :meth:`~DiscreteEnv.step` and reads :attr:`~DiscreteEnv.observation`.

Episodes that end: a Gymnasium environment whose episode terminated (a hole of the
frozen lake, the lake's goal, a delivered taxi passenger) reports that last observation,
then the next step ignores its action and reports the observation after a reset. So the
stream is one long run, and the learners see "from a hole every action leads back to the
start". Time limits are removed (``max_episode_steps=None``): the goal budget bounds a run.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Protocol, runtime_checkable

import numpy as np

from slearn.errors import InputError
from slearn.recorders.pointer import (
    COMMAND_CHANNEL,
    COMMAND_NAMES,
    CONDITIONS,
    FULL_TURN_DEG,
    MAX_ERROR_DEG,
    N_BINS,
    POSITION_CHANNEL,
    R,
)

MAX_BINS = 720


@runtime_checkable
class DiscreteEnv(Protocol):
    """What the control loop needs from a system."""

    name: str
    n_actions: int
    n_observations: int  # observations are 0..n_observations-1 (the pointer's labels 1..bins)
    action_channel: str
    observation_channel: str

    @property
    def observation(self) -> int:
        """The current observation."""

    def step(self, action: int) -> int:
        """Issue ``action``; return the observation read afterwards."""

    def action_value(self, action: int):
        """How ``action`` is written on :attr:`action_channel` (``"L"``, ``2``, ...)."""

    def describe(self, observation: int) -> str:
        """A short human reading of an observation (``"row 3, col 4"``)."""


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
        start_bin: start in this bin (0..bins-1) instead of a random one.
        bins: sensor bins (36 in the paper; 10 to 720).
    """

    n_actions = 2
    action_channel = COMMAND_CHANNEL
    observation_channel = POSITION_CHANNEL

    def __init__(self, condition: str, seed: int = 0, *, error_deg: float = 5.0,
                 delay_prob: float = 0.5, start_bin: int | None = None, bins: int = N_BINS) -> None:
        check_pointer(condition, seed, error_deg, delay_prob, bins)
        # the simulator's streams (start, permutation, policy, dynamics); no policy here
        start, permutation, _, dynamics = (np.random.default_rng(s)
                                           for s in np.random.SeedSequence(seed).spawn(4))
        first = int(start.integers(bins)) if start_bin is None else int(start_bin)
        self.condition = condition
        self.bins = bins
        self.bin_deg = FULL_TURN_DEG / bins
        self.name = f"pointer {condition}" + (f" ({bins} bins)" if bins != N_BINS else "")
        self.n_observations = bins + 1  # labels 1..bins
        self.angle_deg = (first + 0.5) * self.bin_deg
        self.error_deg = float(error_deg)
        self.delay_prob = float(delay_prob)
        self.switched = False
        self.steps = 0
        self._labels = permutation.permutation(np.arange(1, bins + 1))
        self._rng = dynamics
        self._pending = 0

    @property
    def bin(self) -> int:
        """The true bin index, 0..bins-1."""
        return int(math.floor(self.angle_deg / self.bin_deg)) % self.bins

    @property
    def label(self) -> int:
        """The position label the sensor reports, 1..bins."""
        if self.switched and self.condition == "scramble":
            return int(self._labels[self.bin])
        return self.bin + 1

    observation = label

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
            self._turn(moves * self.bin_deg)
        elif self.condition == "error":
            self._turn(direction * (self.bin_deg + self._rng.uniform(-self.error_deg, self.error_deg)))
        elif self.condition == "hardstop":
            target = self.bin + direction
            if 0 <= target < self.bins:  # else the move would cross the stop at 0 degrees
                self.angle_deg = (target + 0.5) * self.bin_deg
        else:
            self._turn(direction * self.bin_deg)
        self.steps += 1
        return self.label

    def _turn(self, degrees: float) -> None:
        self.angle_deg = math.fmod(self.angle_deg + degrees, FULL_TURN_DEG)
        if self.angle_deg < 0.0:
            self.angle_deg += FULL_TURN_DEG
        if self.angle_deg >= FULL_TURN_DEG:
            self.angle_deg = 0.0

    def action_value(self, action: int) -> str:
        """``"L"`` or ``"R"``."""
        return COMMAND_NAMES[action]

    def describe(self, observation: int) -> str:
        """``"label 17"``."""
        return f"label {observation}"

    def goal_candidates(self) -> list[int]:
        """Every label."""
        return list(range(1, self.bins + 1))

    def bin_of_label(self, label: int) -> int:
        """The true bin the sensor reports as ``label`` now."""
        if self.switched and self.condition == "scramble":
            return int(np.flatnonzero(self._labels == label)[0])
        return label - 1

    def shortest(self, goal: tuple[int, ...]) -> int:
        """The fewest nominal moves from the current bin to one reported as a label of ``goal``."""
        best = self.bins
        for label in goal:
            gap = abs(self.bin_of_label(label) - self.bin)
            best = min(best, gap if self.condition == "hardstop" else min(gap, self.bins - gap))
        return best


def check_pointer(condition: str, seed: int, error_deg: float, delay_prob: float,
                  bins: int = N_BINS) -> None:
    """Refuse pointer parameters the simulator does not support (one-line errors)."""
    if condition not in CONDITIONS:
        raise InputError(f"pointer condition {condition!r} is unknown: use one of {', '.join(CONDITIONS)}")
    if seed < 0:
        raise InputError(f"seed must be an integer >= 0, not {seed}")
    if not 10 <= bins <= MAX_BINS:
        raise InputError(f"pointer bins must be 10 to {MAX_BINS}, not {bins}")
    if not 0.0 <= error_deg <= min(MAX_ERROR_DEG, FULL_TURN_DEG / bins) or not 0.0 <= delay_prob <= 1.0:
        raise InputError(f"error_deg must be in [0, {MAX_ERROR_DEG:g}] (and at most one bin) "
                         "and delay_prob in [0, 1]")


class GymnasiumEnv:
    """A Gymnasium environment whose observation and action spaces are ``Discrete``.

    Args:
        env_id: a registered id, e.g. ``"FrozenLake-v1"``.
        kwargs: keyword arguments of ``gymnasium.make`` (``map_name="8x8"``).
        seed: seeds the first reset (later resets continue its generator).
    """

    action_channel = "/env/action"
    observation_channel = "/env/observation"

    def __init__(self, env_id: str, kwargs: dict | None = None, seed: int = 0) -> None:
        self.env = _make_gymnasium(env_id, dict(kwargs or {}))
        self.name = env_id
        self.kwargs = dict(kwargs or {})
        self.n_actions = int(self.env.action_space.n)
        self.n_observations = int(self.env.observation_space.n)
        self._obs_start = int(self.env.observation_space.start)
        self._act_start = int(self.env.action_space.start)
        self.done = False
        self.failed = False
        self.steps = 0
        first, _ = self.env.reset(seed=seed)
        self._observation = int(first) - self._obs_start

    @property
    def observation(self) -> int:
        """The current observation, ``0..n_observations-1``."""
        return self._observation

    def step(self, action: int) -> int:
        """Issue ``action``; after a terminated episode, reset instead (the action is ignored)."""
        self.steps += 1
        if self.done:
            obs, _ = self.env.reset()
            self.done = self.failed = False
        else:
            obs, reward, terminated, truncated, _ = self.env.step(int(action) + self._act_start)
            self.done = bool(terminated or truncated)
            self.failed = bool(terminated) and float(reward) <= 0.0
        self._observation = int(obs) - self._obs_start
        return self._observation

    def action_value(self, action: int) -> int:
        """The action number."""
        return int(action)

    def describe(self, observation: int) -> str:
        """The grid cell for toy-text grids (``"row 2, col 3 'H'"``), else the number."""
        desc = getattr(self.env.unwrapped, "desc", None)
        shape = getattr(self.env.unwrapped, "shape", None) or (np.shape(desc) if desc is not None else None)
        if shape is None or len(shape) != 2 or shape[0] * shape[1] != self.n_observations:
            return f"state {observation}"
        row, col = divmod(observation, shape[1])
        cell = f" {desc[row][col].decode()!r}" if desc is not None else ""
        return f"row {row}, col {col}{cell}"

    def model(self) -> dict | None:
        """The true transition table ``P[s][a] = [(p, s', reward, terminated)]`` if the env has one."""
        return getattr(self.env.unwrapped, "P", None)

    def shortest(self, goal: tuple[int, ...]) -> int | None:
        """Fewest steps from here to a goal observation by the true model (``None``: no model)."""
        return _gym_shortest(self, goal)

    def goal_candidates(self) -> list[int] | None:
        """Cells that are not holes (``'H'``) for grids with a map; ``None``: any observation."""
        desc = getattr(self.env.unwrapped, "desc", None)
        flat = np.asarray(desc).reshape(-1) if desc is not None else None
        if flat is None or len(flat) != self.n_observations:
            return None
        return [int(i) for i in np.flatnonzero(flat != b"H")]

    def close(self) -> None:
        """Close the Gymnasium environment."""
        self.env.close()


def _make_gymnasium(env_id: str, kwargs: dict):
    try:
        import gymnasium
    except ImportError:
        raise InputError("gymnasium is not installed: pip install 'slearn[gym]'") from None
    try:
        spec = dataclasses.replace(gymnasium.spec(env_id), max_episode_steps=None)
        env = gymnasium.make(spec, disable_env_checker=True, **kwargs)
    except gymnasium.error.Error as e:
        raise InputError(f"gymnasium environment {env_id!r}: {_one_line(e)}") from None
    except (TypeError, ValueError, KeyError, IndexError, AssertionError) as e:  # an unknown keyword, a bad value
        given = ", ".join(f"{k}={v!r}" for k, v in kwargs.items())
        raise InputError(f"gymnasium environment {env_id!r} rejects its arguments ({given}): "
                         f"{type(e).__name__}: {_one_line(e)}; see its documentation for the values "
                         f"it takes") from None
    for what, space in (("observation", env.observation_space), ("action", env.action_space)):
        if not isinstance(space, gymnasium.spaces.Discrete):
            env.close()
            raise InputError(f"gymnasium environment {env_id!r} has a {type(space).__name__} {what} "
                             "space: slearn control needs Discrete observations and actions")
    return env


def _one_line(error: Exception) -> str:
    return " ".join(str(error).split())


def parse_env_args(pairs: list[str]) -> dict:
    """``["map_name=8x8", "is_slippery=true"]`` -> keyword arguments (ints, floats, booleans)."""
    out = {}
    for pair in pairs:
        key, sep, text = pair.partition("=")
        if not sep or not key.isidentifier():
            raise InputError(f"--env-arg {pair!r}: write NAME=VALUE")
        out[key] = _value(text)
    return out


def _value(text: str):
    lowered = text.lower()
    if lowered in ("true", "false"):
        return lowered == "true"
    if lowered in ("none", "null"):
        return None
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def make_env(spec: str, kwargs: dict | None = None, seed: int = 0):
    """The environment named by ``spec``: ``pointer:CONDITION`` or ``gymnasium:ID``."""
    kind, sep, name = spec.partition(":")
    if not sep or kind not in ("pointer", "gymnasium") or not name:
        raise InputError(f"--env {spec!r}: use pointer:CONDITION or gymnasium:ID (e.g. gymnasium:FrozenLake-v1)")
    if kind == "gymnasium":
        return GymnasiumEnv(name, kwargs, seed)
    args = dict(kwargs or {})
    known = {"error_deg", "delay_prob", "bins", "start_bin"}
    if set(args) - known:
        unknown = ", ".join(sorted(set(args) - known))
        raise InputError(f"pointer arguments are {', '.join(sorted(known))}, not {unknown}")
    return PointerEnv(name, seed, **args)


def _gym_shortest(env: GymnasiumEnv, goal: tuple[int, ...]) -> int | None:
    """Fewest steps to a goal observation over transitions the true model allows (``None``:
    no model, or unreachable). After a terminal observation the next step resets."""
    model = env.model()
    if model is None:
        return None
    starts = np.flatnonzero(np.asarray(getattr(env.env.unwrapped, "initial_state_distrib", [])) > 0)
    targets = set(goal)
    frontier, seen = [(env.observation, env.done)], {(env.observation, env.done)}
    for depth in range(1, 10 * env.n_observations + 2):
        nxt = []
        for state, done in frontier:
            moves = ([(int(s), False) for s in starts] if done else
                     [(int(s2), bool(term)) for a in model[state] for p, s2, _, term in model[state][a] if p > 0])
            for move in moves:
                if move[0] in targets:
                    return depth
                if move not in seen:
                    seen.add(move)
                    nxt.append(move)
        if not nxt:
            return None
        frontier = nxt
    return None

