"""Closed-loop goal seeking on any discrete system, slearn next to honest peers.

A run explores its environment (:mod:`slearn.control.envs`: the simulated pointer, or a
Gymnasium environment with discrete spaces) with ``trials`` random actions, then drives
each agent (:mod:`slearn.control.agents`) toward the same sequence of goal observations, in its
own copy of the environment (same seed): before each step the agent chooses an action,
the environment steps, and the agent learns the step. Every agent starts from the same
exploration log: slearn learns it into a pattern library (or starts from a given one,
plus the log), goal-conditioned Q replays it for every goal, the count model counts it,
and the single-goal Q-learner (the paper's argument) is trained on it for one goal.

For the pointer's ``reversal`` and ``scramble`` the exploration sees the unchanged world
and the world changes at ``switch_goal`` (default halfway), so the per-block results show
each agent recovering. A goal is a tuple of observations (any will do); random goals are
single observations, each different from the one before. Goals on the pointer are all
labels; on a Gymnasium grid, the cells that are not holes and that the true model can
reach; elsewhere, the observations seen while exploring that did not end an episode
without reward.
"""

from __future__ import annotations

import math
import os
from dataclasses import asdict, dataclass

import numpy as np

from slearn import __version__
from slearn.control.agents import (
    CountModelAgent,
    GoalQAgent,
    SingleGoalQAgent,
    SlearnAgent,
    Transitions,
    explore,
    explore_directed,
    true_model_agent,
)
from slearn.control.envs import PointerEnv, make_env
from slearn.control.planner import PlannerSettings
from slearn.core.library import PatternLibrary
from slearn.core.vocabulary import ACTION, OBSERVATION, Vocabulary
from slearn.errors import InputError
from slearn.recorders.mcap_episode import EpisodeWriter
from slearn.recorders.pointer import pointer_vocabulary
from slearn.recorders.record_pointer import COMMAND_SCHEMA, POSITION_SCHEMA, TRIAL_NS

SWITCHING = ("reversal", "scramble")
OFFLINE_TRIALS = 10_000
DEFAULT_BUDGET = 100
MAX_MODEL_CELLS = 50_000_000  # the count model's dense table: 400 MB of float64 at most
AGENTS = ("slearn", "count-model", "goal-q", "q-one-goal")
EXTRA_AGENTS = ("true-model",)
LABELS = {"slearn": "slearn", "count-model": "count model (optimistic VI)",
          "goal-q": "goal-conditioned Q", "q-one-goal": "Q, one goal (paper)",
          "true-model": "VI on the true model"}


@dataclass(frozen=True)
class ControlConfig:
    """One closed-loop run.

    Attributes:
        env: ``pointer:CONDITION`` or ``gymnasium:ID``.
        env_args: keyword arguments of the environment, as ``(name, value)`` pairs.
        goals: number of goals (random ones unless ``goal`` is given).
        seed: seed of everything (exploration, environments, goals, agents).
        budget: steps allowed per goal.
        goal: a fixed goal: any of these observations (pursued ``goals`` times in a row
            when ``repeat_goal``, else once).
        repeat_goal: pursue ``goal`` ``goals`` times (Taxi: deliver passenger after passenger).
        switch_goal: for ``reversal``/``scramble``, the goal at which the world changes.
        blocks: goals are reported in this many blocks.
        trials: random exploration steps shared by every agent.
        directed: then at most this many steps of directed exploration (an optimistic
            count model with no goal heads for the nearest action not tried yet; it stops
            when every reachable action has been tried).
        agents: which agents run, slearn first.
        planner: slearn's planner settings (default: :attr:`planner_settings`).
    """

    env: str = "pointer:simple"
    env_args: tuple = ()
    goals: int = 100
    seed: int = 0
    budget: int = DEFAULT_BUDGET
    goal: tuple[int, ...] | None = None
    repeat_goal: bool = False
    switch_goal: int | None = None
    blocks: int = 10
    trials: int = OFFLINE_TRIALS
    directed: int = 0
    agents: tuple[str, ...] = AGENTS
    planner: PlannerSettings | None = None

    def __post_init__(self) -> None:
        if self.seed < 0:
            raise InputError(f"seed must be an integer >= 0, not {self.seed}")
        if self.goals < 1 or self.budget < 1 or self.blocks < 1 or min(self.trials, self.directed) < 0:
            raise InputError("goals, budget and blocks must be at least 1, trials at least 0")
        unknown = set(self.agents) - set(AGENTS) - set(EXTRA_AGENTS)
        if unknown or not self.agents:
            raise InputError(f"agents are {', '.join(AGENTS + EXTRA_AGENTS)}, not {', '.join(sorted(unknown))}")
        if self.goal is not None and not self.goal:
            raise InputError("a given goal needs at least one observation")

    @property
    def planner_settings(self) -> PlannerSettings:
        """The planner settings in force: given, or searching ``budget`` steps ahead with
        little prior doubt (0.1 pseudo-count) about what was seen; states hold one step of
        history on the pointer (``delay`` hides a pending move) and none on Gymnasium
        environments, whose observation is the whole state."""
        return self.planner or PlannerSettings(horizon=self.budget, prior=0.1,
                                               order=1 if self.condition else 0)

    @property
    def n_goals(self) -> int:
        return self.goals if self.goal is None or self.repeat_goal else 1

    @property
    def condition(self) -> str | None:
        """The pointer condition, ``None`` for other environments."""
        kind, _, name = self.env.partition(":")
        return name if kind == "pointer" else None

    @property
    def switch_at(self) -> int | None:
        """The goal index at which the world changes, or ``None``."""
        if self.condition not in SWITCHING:
            return None
        return self.n_goals // 2 if self.switch_goal is None else self.switch_goal

    def make_env(self):
        """A fresh environment (same seed: every agent meets the same world)."""
        return make_env(self.env, dict(self.env_args), self.seed)


@dataclass(frozen=True)
class GoalOutcome:
    """One goal: where it started, the fewest steps possible (``None``: unknown), what it took."""

    goal: tuple[int, ...]
    start: int
    shortest: int | None
    steps: int
    reached: bool
    explored: int = 0

    def within(self, factor: float) -> bool:
        """Reached in at most ``factor`` times the fewest steps."""
        return self.reached and self.shortest is not None and self.steps <= factor * self.shortest


@dataclass(frozen=True)
class Summary:
    """Results over goals (goals that started at their target are left out)."""

    goals: int
    success: float
    within_1_05x: float
    within_2x: float
    within_3x: float
    steps_ratio: float
    mean_steps: float
    explored_steps: int

    @classmethod
    def of(cls, outcomes: list[GoalOutcome]) -> "Summary":
        real = [o for o in outcomes if o.shortest != 0 and o.steps + (not o.reached) > 0]
        reached = [o for o in real if o.reached]
        n: float = len(real) or math.nan  # no goal to reach: rates are undefined
        sized = [(o.steps, o.shortest) for o in reached if o.shortest]
        ratio = float(np.mean([steps / shortest for steps, shortest in sized])) if sized else math.nan
        return cls(len(real), len(reached) / n, sum(o.within(1.05) for o in real) / n,
                   sum(o.within(2) for o in real) / n, sum(o.within(3) for o in real) / n, ratio,
                   float(np.mean([o.steps for o in reached])) if reached else math.nan,
                   sum(o.explored for o in real))


@dataclass(frozen=True)
class Block:
    """One block of consecutive goals."""

    first_goal: int
    summary: Summary
    after_switch: bool


@dataclass(frozen=True)
class AgentResult:
    """One agent's run over the goals."""

    name: str
    label: str
    summary: Summary
    blocks: list[Block]
    outcomes: list[GoalOutcome]
    ms_per_step: float


@dataclass
class Trace:
    """What slearn's environment did, step by step (for recording)."""

    start: int
    actions: list[int]
    observations: list[int]
    goal_steps: list[int]
    goals: list[tuple[int, ...]]


@dataclass(frozen=True)
class ControlResult:
    """One closed-loop run: every agent on the same goals."""

    config: ControlConfig
    env_name: str
    library_source: str
    exploration_steps: int
    goals: list[tuple[int, ...]]
    agents: list[AgentResult]
    patterns_before: int
    patterns_after: int
    trace: Trace

    def agent(self, name: str) -> AgentResult | None:
        """The result of agent ``name``, if it ran."""
        return next((a for a in self.agents if a.name == name), None)

    @property
    def slearn(self) -> Summary | None:
        found = self.agent("slearn")
        return found.summary if found else None

    def to_dict(self) -> dict:
        """A JSON-ready dict (without the step trace)."""
        out = asdict(self)
        out.pop("trace")
        out["config"]["planner"] = asdict(self.config.planner_settings)
        out["config"]["env_args"] = dict(self.config.env_args)
        return _finite(out)


def _finite(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    return value


def _rng(config: ControlConfig, stream: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(config.seed).spawn(8)[stream])


def exploration(config: ControlConfig) -> Transitions:
    """The steps every agent starts from (in the world before any switch): ``trials``
    random ones, then up to ``directed`` steps toward actions not yet tried."""
    env = config.make_env()
    random_steps = explore(env, config.trials, _rng(config, 5))
    if not config.directed:
        return random_steps
    if env.n_observations ** 2 * env.n_actions > MAX_MODEL_CELLS:
        raise InputError(f"{env.name}: too many observations for directed exploration; use --trials only")
    guide = CountModelAgent(env.n_observations, env.n_actions, random_steps, _rng(config, 3))
    return explore_directed(env, random_steps, guide, config.directed)


def goal_candidates(env, transitions: Transitions) -> list[int]:
    """Observations that may be drawn as goals (see the module docstring)."""
    listed = getattr(env, "goal_candidates", lambda: None)()
    if listed is not None and env.n_observations and getattr(env, "model", lambda: None)() is None:
        return listed  # the pointer: every label
    if listed is not None:
        return [g for g in listed if env.shortest((g,)) is not None]
    seen = set(int(o) for o in transitions.observations)
    return sorted(seen - _failures(env, transitions))


def _failures(env, transitions: Transitions) -> set[int]:
    """Observations after which an episode ended without reward (holes), by the true model."""
    model = getattr(env, "model", lambda: None)()
    if model is None:
        return set()
    return {int(s2) for s in model for a in model[s] for _, s2, reward, term in model[s][a]
            if term and reward <= 0}


def goal_sequence(config: ControlConfig, candidates: list[int], first: int) -> list[tuple[int, ...]]:
    """The goals: the given one, or random candidates, each different from the one before."""
    if config.goal is not None:
        return [tuple(config.goal)] * config.n_goals
    if len(candidates) < 2:
        raise InputError(f"{config.env}: fewer than two goal observations to choose from; "
                         "explore longer (--trials) or give --goal")
    rng = _rng(config, 4)
    goals: list[tuple[int, ...]] = []
    last = first
    for _ in range(config.goals):
        pick = int(rng.integers(len(candidates) - (last in candidates)))
        others = [c for c in candidates if c != last]
        goals.append((others[pick],))
        last = others[pick]
    return goals


def pursue(agent, env, goal: tuple[int, ...], budget: int, trace: Trace | None = None) -> GoalOutcome:
    """Drive ``env`` toward any observation of ``goal`` for at most ``budget`` steps."""
    start, shortest = env.observation, _shortest(env, goal)
    steps = explored = 0
    while env.observation not in goal and steps < budget:
        _step(agent, env, goal, trace)
        explored += bool(getattr(agent, "curious", False))
        steps += 1
    return GoalOutcome(goal, start, shortest, steps, env.observation in goal, explored)


def _step(agent, env, goal: tuple[int, ...], trace: Trace | None) -> None:
    action = agent.act(env.observation, goal)
    observation = env.step(action)
    agent.observe(observation)
    if trace is not None:
        trace.actions.append(action)
        trace.observations.append(observation)


def _shortest(env, goal) -> int | None:
    method = getattr(env, "shortest", None)
    return None if method is None else method(goal)


def _check_fits(vocabulary: Vocabulary, env, own: Vocabulary | None, source: str) -> None:
    """Refuse a library learned on another system: its channels must be the environment's,
    in their roles, and (for the pointer) its readings the environment's bins."""
    roles = vocabulary.roles
    for channel, role in ((env.action_channel, ACTION), (env.observation_channel, OBSERVATION)):
        if roles.get(channel) != role:
            raise InputError(f"{source}: learned channels {', '.join(map(repr, roles)) or 'none'}, not this "
                             f"environment's {role} channel {channel!r}: give a library learned on it")
    if own is not None:
        values = {v for _, c, v in vocabulary.items() if c == env.observation_channel}
        expected = {v for _, c, v in own.items() if c == env.observation_channel}
        if values != expected:
            raise InputError(f"{source}: its {env.observation_channel!r} has {len(values)} values, this "
                             f"pointer {len(expected)} bins: give a library learned with the same bins")


def run_control(config: ControlConfig, library: PatternLibrary | None = None,
                vocabulary: Vocabulary | None = None, library_source: str | None = None,
                warn=None) -> ControlResult:
    """Explore, then run every agent of ``config`` on the same goals.

    Args:
        config: the run.
        library: a library slearn starts from (it learns the exploration too, and keeps
            learning); default: a new one.
        vocabulary: the library's vocabulary (default: the pointer's, or a new one).
        library_source: how the library was obtained, for the report.
        warn: called with a one-line warning (a given goal never observed while exploring:
            the agents search for it, heading for what they have not tried).
    """
    probe = config.make_env()
    transitions = exploration(config)
    goals = goal_sequence(config, goal_candidates(probe, transitions), probe.observation)
    _check_goals(probe, goals)
    if config.goal is not None and warn is not None and not set(config.goal) & set(transitions.observations.tolist()):
        warn(f"slearn control: warning: goal {list(config.goal)} was never observed while exploring; "
             "the agents search for it by trying what they have not tried")
    if library is None:
        library = PatternLibrary()
        library_source = f"learned from {len(transitions)} exploration steps"
    own = pointer_vocabulary(getattr(probe, "bins", 36)) if config.condition else None
    if vocabulary is None:
        vocabulary = own if own is not None else Vocabulary()
    elif library_source is not None:
        _check_fits(vocabulary, probe, own, library_source)
    before = len(library)
    trace = Trace(probe.observation, [], [], [], [])
    results = [_run_agent(name, config, transitions, goals, library, vocabulary, trace)
               for name in config.agents]
    return ControlResult(config, probe.name, library_source or "given", len(transitions), goals,
                         [r for r in results if r is not None], before, len(library), trace)


def _check_goals(env, goals: list[tuple[int, ...]]) -> None:
    for goal in goals[:1]:
        for g in goal:
            if not 0 <= g < env.n_observations or (isinstance(env, PointerEnv) and g < 1):
                low = 1 if isinstance(env, PointerEnv) else 0
                raise InputError(f"goal {g} is not an observation of {env.name}: use {low}..{env.n_observations - 1}")


def _build_agent(name, config, env, transitions, library, vocabulary):
    rng = _rng(config, 6)
    n_s, n_a = env.n_observations, env.n_actions
    if name == "slearn":
        agent = SlearnAgent(library, vocabulary, env, config.planner_settings)
        if len(transitions):
            agent.learn(transitions)
        return agent
    if name in ("count-model", "true-model") and n_s * n_s * n_a > MAX_MODEL_CELLS:
        raise InputError(f"{env.name}: {n_s} observations x {n_a} actions is too large for the "
                         f"{name} peer's dense table; leave it out with --agents")
    if name == "count-model":
        return CountModelAgent(n_s, n_a, transitions, rng)
    if name == "goal-q":
        return GoalQAgent(n_s, n_a, transitions, rng)
    if name == "true-model":
        return true_model_agent(env, rng) if hasattr(env, "model") else None
    trained = int(_rng(config, 7).choice(goal_candidates(env, transitions) or [0]))
    return SingleGoalQAgent(n_s, n_a, transitions, trained, rng)


def _run_agent(name, config, transitions, goals, library, vocabulary, trace) -> AgentResult | None:
    env = config.make_env()
    if len(transitions):  # the agent's world continues from where exploration left it
        _replay_actions(env, transitions)
    agent = _build_agent(name, config, env, transitions, library, vocabulary)
    if agent is None:
        return None
    size = max(1, math.ceil(len(goals) / config.blocks))
    outcomes, blocks = [], []
    for i, goal in enumerate(goals):
        if i == config.switch_at:
            env.switch()
        if name == "slearn":
            if i == 0:
                trace.start = env.observation
            trace.goal_steps.append(len(trace.actions))
            trace.goals.append(goal)
        if getattr(env, "done", False):  # an ended episode: its reset is not part of the next goal
            _step(agent, env, goal, trace if name == "slearn" else None)
        outcomes.append(pursue(agent, env, goal, config.budget, trace if name == "slearn" else None))
        if (i + 1) % size == 0 or i + 1 == len(goals):
            first = (i // size) * size
            switch = config.switch_at
            blocks.append(Block(first, Summary.of(outcomes[first:]), switch is not None and first >= switch))
    plans = getattr(agent, "plans", 0)
    ms = 1000 * agent.plan_seconds / plans if plans else math.nan
    return AgentResult(name, LABELS[name], Summary.of(outcomes), blocks, outcomes, ms)


def _replay_actions(env, transitions: Transitions) -> None:
    for action in transitions.actions:
        env.step(int(action))


METADATA_NAME = "slearn.control"
GOAL_SCHEMA = {
    "title": "slearn.control.Goal",
    "description": "The observations the controller is steering to (any of them will do).",
    "type": "object",
    "properties": {"goal": {"type": "array", "items": {"type": "integer"}}},
    "required": ["goal"],
}
_GENERIC = {
    "action": {"title": "slearn.env.Action", "type": "object",
               "properties": {"action": {"type": "integer"}}, "required": ["action"]},
    "observation": {"title": "slearn.env.Observation", "type": "object",
                    "properties": {"observation": {"type": "integer"}}, "required": ["observation"]},
}


def write_control_mcap(result: ControlResult, env, path: str | os.PathLike, *, overwrite: bool = False) -> int:
    """Write slearn's run (exploration excluded) as one MCAP episode, atomically.

    The action and observation channels are the environment's (the pointer's are those of
    :mod:`slearn.recorders.record_pointer`), plus a goal channel (``{"goal": [17]}``
    whenever a goal is set); step ``i`` acts at ``i * 100 ms`` and reads 50 ms later.
    Returns the messages written.
    """
    trace = result.trace
    pointer = isinstance(env, PointerEnv)
    goal_topic = "/pointer/goal" if pointer else "/env/goal"
    with EpisodeWriter(path, overwrite=overwrite) as out:
        out.add_metadata(METADATA_NAME, _control_metadata(result))
        act_field, obs_field = ("command", "position") if pointer else ("action", "observation")
        act_schema, obs_schema = (COMMAND_SCHEMA, POSITION_SCHEMA) if pointer else (
            _GENERIC["action"], _GENERIC["observation"])
        act = out.register_channel(env.action_channel, act_schema["title"], act_schema, {"role": "action"})
        obs = out.register_channel(env.observation_channel, obs_schema["title"], obs_schema,
                                   {"role": "observation"})
        goal = out.register_channel(goal_topic, GOAL_SCHEMA["title"], GOAL_SCHEMA, {"role": "goal"})
        out.write(obs, 0, {obs_field: trace.start})
        for step, g in zip(trace.goal_steps, trace.goals):
            out.write(goal, step * TRIAL_NS, {"goal": list(g)})
        for i, (a, o) in enumerate(zip(trace.actions, trace.observations)):
            out.write(act, i * TRIAL_NS, {act_field: env.action_value(a)})
            out.write(obs, i * TRIAL_NS + TRIAL_NS // 2, {obs_field: o})
    return 1 + len(trace.goal_steps) + 2 * len(trace.actions)


def _control_metadata(result: ControlResult) -> dict[str, str]:
    config = result.config
    return {"env": config.env, "env_args": repr(dict(config.env_args)), "seed": str(config.seed),
            "goals": str(config.n_goals), "budget": str(config.budget),
            "switch_goal": str(config.switch_at), "library": result.library_source,
            "exploration_steps": str(result.exploration_steps), "slearn_version": __version__}
