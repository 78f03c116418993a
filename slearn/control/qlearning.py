"""A tabular Q-learning baseline (Watkins), for the paper's argument against it.

"In Q-learning, the goal or reward states must remain constant for learning to take
place. If the goal is changed, all previous experience is rendered obsolete." The learner
here gets reward 1 on reaching its goal state (which ends the episode) and 0 otherwise;
it learns offline by replaying logged transitions, then acts epsilon-greedily and keeps
learning online from whatever goal it is given. Pure: numpy only, seeded generators.
"""

from __future__ import annotations

import numpy as np

from slearn.core._jit import kernel


class QLearner:
    """A Q-table over ``n_states`` observation states and ``n_actions`` actions.

    Args:
        n_states: states are ``0..n_states-1``.
        n_actions: actions are ``0..n_actions-1``.
        alpha: learning rate.
        discount: reward discount per step.
        epsilon: chance of a random action when acting.
    """

    def __init__(self, n_states: int, n_actions: int, alpha: float = 0.5, discount: float = 0.9,
                 epsilon: float = 0.05) -> None:
        if n_states < 1 or n_actions < 1:
            raise ValueError("Q-learning needs at least one state and one action")
        self.q = np.zeros((n_states, n_actions))
        self.alpha = alpha
        self.discount = discount
        self.epsilon = epsilon

    def update(self, state: int, action: int, next_state: int, goal: int) -> None:
        """One Q-learning update for ``state --action--> next_state`` toward ``goal``."""
        if next_state == goal:
            target = 1.0
        else:
            target = self.discount * float(self.q[next_state].max())
        self.q[state, action] += self.alpha * (target - self.q[state, action])

    def train(self, states: np.ndarray, actions: np.ndarray, next_states: np.ndarray, goal: int,
              sweeps: int = 30) -> None:
        """Replay logged transitions ``sweeps`` times with the reward of ``goal``."""
        _replay(self.q, np.asarray(states, np.int64), np.asarray(actions, np.int64),
                np.asarray(next_states, np.int64), goal, sweeps, self.alpha, self.discount)

    def act(self, state: int, rng: np.random.Generator) -> int:
        """Epsilon-greedy action; ties among the best go to a random one."""
        values = self.q[state]
        if rng.random() < self.epsilon:
            return int(rng.integers(len(values)))
        best = np.flatnonzero(values >= values.max() - 1e-12)
        return int(best[rng.integers(len(best))])


@kernel
def _replay(q, states, actions, next_states, goal, sweeps, alpha, discount):
    for _ in range(sweeps):
        for i in range(len(states)):
            s, a, s2 = states[i], actions[i], next_states[i]
            if s == goal:
                continue
            target = 1.0 if s2 == goal else discount * q[s2].max()
            q[s, a] += alpha * (target - q[s, a])
