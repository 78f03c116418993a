"""Agents that steer a discrete system (:mod:`slearn.control.envs`) to goal observations.

Every agent has the same two calls, usable from any loop::

    action = agent.act(observation, goal)   # goal: a tuple of observations, any will do
    observation = env.step(action)
    agent.observe(observation)              # learn the step just taken

* :class:`SlearnAgent`: S-learning. A :class:`~slearn.core.library.PatternLibrary` learns every
  step; the :class:`~slearn.control.planner.Planner` searches it before every step.
* Honest peers, trained on the same exploration transitions:

  - :class:`GoalQAgent`: goal-conditioned tabular Q-learning (Kaelbling 1993). Q-learning
    is off-policy, so every logged transition is replayed for every goal the agent is
    given (a table per goal, built from the whole log when the goal first appears, then
    updated by every new step).
  - :class:`CountModelAgent`: a count model of ``(observation, action) -> observation``
    with value iteration before every step (Dyna-Q with full planning). Untried actions
    are worth the goal (optimism, R-max style), and an outcome never seen after a pair
    that always did the same thing at least ``reset_after`` times resets that pair's
    counts (a change of the world).
  - :class:`SingleGoalQAgent`: plain Q-learning trained for one goal, then given new
    goals: the paper's argument ("if the goal is changed, all previous experience is
    rendered obsolete"), kept as such, not as a fair peer.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass

import numpy as np

from slearn.control.peer_kernels import replay_for_goal as _replay
from slearn.control.peer_kernels import value_iteration as _value_iteration
from slearn.control.planner import Planner, PlannerSettings
from slearn.control.qlearning import QLearner
from slearn.core.library import PatternLibrary
from slearn.core.stream import Episode
from slearn.core.vocabulary import Vocabulary

Goal = tuple[int, ...]


@dataclass
class Transitions:
    """A run of steps: ``observations[0]``, then ``actions[i]`` led to ``observations[i + 1]``."""

    observations: np.ndarray
    actions: np.ndarray

    def __len__(self) -> int:
        return len(self.actions)

    @property
    def states(self) -> np.ndarray:
        """The observation before each action."""
        return self.observations[:-1]

    @property
    def next_states(self) -> np.ndarray:
        """The observation after each action."""
        return self.observations[1:]


def explore(env, steps: int, rng: np.random.Generator) -> Transitions:
    """``steps`` uniformly random actions in ``env`` (the exploration all learners share)."""
    actions = rng.integers(env.n_actions, size=steps)
    observations = np.empty(steps + 1, np.int64)
    observations[0] = env.observation
    for i, action in enumerate(actions):
        observations[i + 1] = env.step(int(action))
    return Transitions(observations, actions.astype(np.int64))


def explore_directed(env, log: Transitions, guide: "CountModelAgent", steps: int) -> Transitions:
    """Extend ``log`` by at most ``steps`` actions that ``guide`` (an optimistic model with no
    goal) takes toward untried actions; stop once none is reachable."""
    observations, actions = list(log.observations), list(log.actions)
    for _ in range(steps):
        guide.state = env.observation
        values = guide.q_values(())[guide.state]
        if values.max() <= 0.0:
            break
        best = np.flatnonzero(values >= values.max() - 1e-9)
        guide.action = int(best[guide.rng.integers(len(best))])
        actions.append(guide.action)
        observations.append(env.step(guide.action))
        guide.observe(observations[-1])
    return Transitions(np.asarray(observations, np.int64), np.asarray(actions, np.int64))


class SlearnAgent:
    """Plans every step from a pattern library and learns every step into it.

    Args:
        library: the library (learned offline, loaded, or empty); it keeps learning.
        vocabulary: its vocabulary; the env's channels are added if missing.
        env: the system (for its channels and action values).
        settings: planner settings.
    """

    name = "slearn"

    def __init__(self, library: PatternLibrary, vocabulary: Vocabulary, env,
                 settings: PlannerSettings | None = None) -> None:
        if library._has_actions is None:  # an empty library: its first episode may be one reading
            library._has_actions = True
        self.library = library
        self.vocabulary = vocabulary
        self.settings = settings or PlannerSettings()
        vocabulary.add_channel(env.action_channel, "action")
        vocabulary.add_channel(env.observation_channel, "observation")
        self._channel = env.observation_channel
        self.actions = [vocabulary.symbol(env.action_channel, env.action_value(a))
                        for a in range(env.n_actions)]
        self.planner = Planner(library, [(s,) for s in self.actions], self.settings)
        self.history: deque = deque(maxlen=self.settings.order + 2)
        self.action = 0
        self.curious = False
        self.plan_seconds = 0.0
        self.plans = 0

    def symbol(self, observation: int) -> int:
        """The library symbol of an observation (registered on first sight)."""
        return self.vocabulary.symbol(self._channel, int(observation))

    def learn(self, transitions: Transitions) -> None:
        """Learn a run of steps offline (one episode)."""
        obs = [self.symbol(o) for o in transitions.observations]
        acts = [self.actions[int(a)] for a in transitions.actions]
        self.library.learn(Episode.from_pairs(obs[:1], acts, obs[1:]))

    def act(self, observation: int, goal: Goal) -> int:
        """The action to take now toward any observation of ``goal``."""
        current = (self.symbol(observation),)
        if not self.history or self.history[-1][1] != current:  # a new episode starts here
            self.history.clear()
            self.history.append(((), current))
            self.library.learn(Episode.from_steps([((), current)]))
        began = time.perf_counter()
        plan = self.planner.plan(list(self.history), [self.symbol(g) for g in goal])
        self.plan_seconds += time.perf_counter() - began
        self.plans += 1
        self.action = self.actions.index(plan.action[0]) if plan.action is not None else 0
        self.curious = plan.explore
        return self.action

    def observe(self, observation: int) -> None:
        """Learn the step just taken."""
        step = ((self.actions[self.action],), (self.symbol(observation),))
        self.library.learn(Episode.from_steps([step]), new_episode=False)
        self.history.append(step)


class GoalQAgent:
    """Goal-conditioned tabular Q-learning: every transition replayed for every goal.

    Args:
        n_states, n_actions: table size (observations ``0..n_states-1``).
        transitions: the exploration log, replayed for each new goal.
        rng: tie-breaking and exploration.
        epsilon: chance of a random action.
    """

    name = "goal-q"

    def __init__(self, n_states: int, n_actions: int, transitions: Transitions,
                 rng: np.random.Generator, *, alpha: float = 0.5, discount: float = 0.95,
                 epsilon: float = 0.05, sweeps: int = 30) -> None:
        self.shape = (n_states, n_actions)
        self.alpha, self.discount, self.epsilon, self.sweeps = alpha, discount, epsilon, sweeps
        self.rng = rng
        self.log_s = list(transitions.states)
        self.log_a = list(transitions.actions)
        self.log_s2 = list(transitions.next_states)
        self.tables: dict[frozenset, tuple[np.ndarray, np.ndarray]] = {}
        self.state = 0
        self.action = 0

    def table(self, goal: Goal) -> np.ndarray:
        """The goal's Q-table, replayed from the whole log on first use."""
        key = frozenset(goal)
        if key not in self.tables:
            mask = np.zeros(self.shape[0], np.bool_)
            mask[[g for g in goal if 0 <= g < self.shape[0]]] = True
            q = np.zeros(self.shape)
            _replay(q, np.asarray(self.log_s, np.int64), np.asarray(self.log_a, np.int64),
                    np.asarray(self.log_s2, np.int64), mask, self.sweeps, self.alpha, self.discount)
            self.tables[key] = (q, mask)
        return self.tables[key][0]

    def act(self, observation: int, goal: Goal) -> int:
        """Epsilon-greedy on the goal's table; ties go to a random best action."""
        self.state = int(observation)
        values = self.table(goal)[self.state]
        if self.rng.random() < self.epsilon:
            self.action = int(self.rng.integers(len(values)))
        else:
            best = np.flatnonzero(values >= values.max() - 1e-12)
            self.action = int(best[self.rng.integers(len(best))])
        return self.action

    def observe(self, observation: int) -> None:
        """Log the step and update every goal's table with it."""
        s, a, s2 = self.state, self.action, int(observation)
        self.log_s.append(s)
        self.log_a.append(a)
        self.log_s2.append(s2)
        for q, mask in self.tables.values():
            if not mask[s]:
                target = 1.0 if mask[s2] else self.discount * q[s2].max()
                q[s, a] += self.alpha * (target - q[s, a])
        self.state = s2


class CountModelAgent:
    """Value iteration on empirical transition counts, optimistic for untried actions.

    Args:
        n_states, n_actions: model size.
        transitions: the exploration log (counted once).
        rng: tie-breaking.
        discount: value kept per step.
        reset_after: a pair that led to one outcome this many times and then to another
            is reset (the world changed); 0 never resets.
        learn: update the counts with every step (``False`` for a fixed, given model).
    """

    name = "count-model"

    def __init__(self, n_states: int, n_actions: int, transitions: Transitions | None,
                 rng: np.random.Generator, *, discount: float = 0.95, reset_after: int = 10,
                 learn: bool = True) -> None:
        self.counts = np.zeros((n_states, n_actions, n_states))
        if transitions is not None:
            np.add.at(self.counts, (transitions.states, transitions.actions, transitions.next_states), 1.0)
        self.rng = rng
        self.discount = discount
        self.reset_after = reset_after
        self.learning = learn
        self._support: tuple[np.ndarray, np.ndarray] | None = None  # sparse rows, built on demand
        self._totals = np.zeros(0)
        self.state = 0
        self.action = 0
        self.resets = 0

    def q_values(self, goal: Goal) -> np.ndarray:
        """``Q[s, a]``: the discounted value of reaching ``goal`` (goal observations are worth 1)."""
        n_s, n_a, _ = self.counts.shape
        flat = self.counts.reshape(n_s * n_a, n_s)
        if self._support is None:
            rows, cols = np.nonzero(flat)
            self._support = (cols.astype(np.int64), np.searchsorted(rows, np.arange(n_s * n_a + 1)))
            self._totals = flat.sum(axis=1)
        cols, offsets = self._support
        rows = np.repeat(np.arange(n_s * n_a), np.diff(offsets))
        goal_mask = np.zeros(n_s, np.bool_)
        goal_mask[[g for g in goal if 0 <= g < n_s]] = True
        return _value_iteration(offsets, cols, flat[rows, cols] / self._totals[rows], self._totals,
                                goal_mask, n_a, self.discount).reshape(n_s, n_a)

    def act(self, observation: int, goal: Goal) -> int:
        """The best action by the model (ties: a random one)."""
        self.state = int(observation)
        values = self.q_values(goal)[self.state]
        best = np.flatnonzero(values >= values.max() - 1e-9)
        self.action = int(best[self.rng.integers(len(best))])
        return self.action

    def observe(self, observation: int) -> None:
        """Count the step (resetting the pair when it contradicts a settled outcome)."""
        if self.learning:
            row = self.counts[self.state, self.action]
            s2 = int(observation)
            if (self.reset_after and row[s2] == 0 and row.max() >= self.reset_after
                    and np.count_nonzero(row) == 1):
                row[:] = 0.0
                self.resets += 1
                self._support = None
            self._count(self.state * self.counts.shape[1] + self.action, s2, row)
        self.state = int(observation)

    def _count(self, sa: int, s2: int, row: np.ndarray) -> None:
        """Add one sighting, keeping the sparse support in step (an insertion, not a rebuild)."""
        if self._support is not None:
            cols, offsets = self._support
            if row[s2] == 0:
                cols = np.insert(cols, offsets[sa + 1], s2)
                offsets[sa + 1:] += 1
                self._support = (cols, offsets)
            self._totals[sa] += 1.0
        row[s2] += 1.0

class SingleGoalQAgent:
    """Q-learning trained on the exploration log for one goal, then given new goals.

    It learns online from the reward of whatever goal it is given (the paper's Q-learner).
    """

    name = "q-one-goal"

    def __init__(self, n_states: int, n_actions: int, transitions: Transitions, trained_goal: int,
                 rng: np.random.Generator) -> None:
        self.learner = QLearner(n_states, n_actions)
        self.learner.train(transitions.states, transitions.actions, transitions.next_states, trained_goal)
        self.trained_goal = trained_goal
        self.rng = rng
        self.state = 0
        self.action = 0
        self.goal: Goal = (trained_goal,)

    def act(self, observation: int, goal: Goal) -> int:
        """Epsilon-greedy on the one table."""
        self.state, self.goal = int(observation), goal
        self.action = self.learner.act(self.state, self.rng)
        return self.action

    def observe(self, observation: int) -> None:
        """Update the table with the current goal's reward."""
        self.learner.update(self.state, self.action, int(observation), self.goal[0])
        self.state = int(observation)


def true_model_agent(env, rng: np.random.Generator, discount: float = 0.95) -> CountModelAgent | None:
    """Value iteration on a Gymnasium toy-text env's true model (``env.unwrapped.P``), with
    the loop's episode semantics (after a terminal step, any action resets); ``None``
    without a model."""
    model = env.model()
    start = getattr(env.env.unwrapped, "initial_state_distrib", None)
    if model is None or start is None:
        return None
    n_s, n_a = env.n_observations, env.n_actions
    counts = np.zeros((n_s, n_a, n_s))
    terminal = np.zeros(n_s, np.bool_)
    for s in range(n_s):
        for a in range(n_a):
            for p, s2, _, term in model[s][a]:
                counts[s, a, int(s2)] += p
                terminal[int(s2)] |= bool(term)
    counts[terminal] = np.asarray(start, float)[None, :]
    agent = CountModelAgent(n_s, n_a, None, rng, discount=discount, learn=False)
    agent.counts[:] = counts
    agent.name = "true-model"
    return agent
