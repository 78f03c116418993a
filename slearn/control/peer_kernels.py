"""Compiled kernels of the control peers (:mod:`slearn.control.agents`)."""

from __future__ import annotations

import numpy as np

from slearn.core._jit import kernel


@kernel
def replay_for_goal(q, states, actions, next_states, goal, sweeps, alpha, discount):
    """Q-learning replay of a log ``sweeps`` times; reward 1 on entering a ``goal`` state."""
    for _ in range(sweeps):
        for i in range(len(states)):
            s, a, s2 = states[i], actions[i], next_states[i]
            if goal[s]:
                continue
            target = 1.0 if goal[s2] else discount * q[s2].max()
            q[s, a] += alpha * (target - q[s, a])


@kernel
def value_iteration(offsets, nxt, prob, totals, goal, n_act, discount):
    """``Q[s * n_act + a]`` by value iteration over sparse transitions (goal states worth 1;
    a pair never tried is worth ``discount``, as if the goal were one step away)."""
    n_s = len(goal)
    value = np.where(goal, 1.0, 0.0)
    q = np.zeros(n_s * n_act)
    for _ in range(4 * n_s + 50):
        change = 0.0
        for s in range(n_s):
            best = 0.0
            for a in range(n_act):
                sa = s * n_act + a
                if totals[sa] == 0.0:
                    v = discount  # untried: as good as the goal one step away
                else:
                    v = 0.0
                    for e in range(offsets[sa], offsets[sa + 1]):
                        v += prob[e] * value[nxt[e]]
                    v *= discount
                q[sa] = v
                best = max(best, v)
            if not goal[s]:
                change = max(change, abs(best - value[s]))
                value[s] = best
        if change < 1e-9:
            break
    return q
