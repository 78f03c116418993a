"""Which actions drive each observation channel: action scopes chosen from data.

A view of an action scope (:mod:`slearn.core.views`) sees only the step's actions on its
scope's channels. When a robot commands many joints at once, the tuple of every command
rarely repeats, while each joint's own (command, reading) pairs do; a joint's scope is then
its own command. :func:`suggest_scopes` finds the scopes in recorded steps, for a spec to
declare (``slearn info --suggest-spec``).

For each observation channel it models the channel's reading from its previous reading
and the step's values of a set of action channels (counts of every (previous reading,
actions) context, most likely outcome per context), and chooses the set by forward
selection on the Bayesian information criterion (Schwarz 1978): start from no action,
add the action channel that raises ``log-likelihood - (parameters / 2) ln N`` most, stop
when none raises it. Parameters are ``(outcomes - 1)`` per context seen, so an action
joins only when what it explains outweighs the contexts it splits the data into. No
constant is tuned: the penalty is BIC's own.
"""

from __future__ import annotations

import math
from typing import Iterable

import numpy as np

from slearn.core.stream import Episode
from slearn.core.vocabulary import ACTION, OBSERVATION, Vocabulary

MAX_STEPS = 50_000
"""Steps the choice reads at most (the first ones): counting is linear in them."""


def suggest_scopes(episodes: Iterable[Episode], vocabulary: Vocabulary,
                   max_steps: int = MAX_STEPS) -> dict[str, tuple[str, ...]]:
    """``{observation channel: the action channels that drive it}`` for each observation
    channel whose chosen set is not every action channel (those need no scope)."""
    actions = [c for c, role in vocabulary.roles.items() if role == ACTION]
    observations = [c for c, role in vocabulary.roles.items() if role == OBSERVATION]
    if not actions or not observations:
        return {}
    columns = _step_columns(episodes, vocabulary, actions, observations, max_steps)
    if columns is None:
        return {}
    acted, read, before = columns
    scopes = {}
    for j, name in enumerate(observations):
        rows = (read[:, j] >= 0) & (before[:, j] >= 0)
        chosen = _forward_selection(before[rows, j], acted[rows], read[rows, j])
        if len(chosen) < len(actions):
            scopes[name] = tuple(sorted(actions[i] for i in chosen))
    return scopes


def _step_columns(episodes: Iterable[Episode], vocabulary: Vocabulary, actions: list[str],
                  observations: list[str], max_steps: int):
    """Per step (at most ``max_steps``): each action channel's symbol (-1: none), each
    observation channel's reading (-1: none) and its reading before the step (-1: none yet
    in the episode)."""
    column = {name: i for i, name in enumerate(actions)}
    column.update({name: i for i, name in enumerate(observations)})
    channel_of = [column[c] for _, c, _ in vocabulary.items()]
    acted_rows, read_rows, before_rows, total = [], [], [], 0
    for episode in episodes:
        n = min(len(episode), max_steps - total)
        if n <= 0:
            break
        acted = np.full((n, len(actions)), -1, np.int64)
        read = np.full((n, len(observations)), -1, np.int64)
        offsets, symbols = episode.step_offsets, episode.symbols
        for s in range(n):
            split = offsets[s] + episode.n_actions[s]
            for i in range(offsets[s], offsets[s + 1]):
                x = int(symbols[i])
                (acted if i < split else read)[s, channel_of[x]] = x
        before = np.full_like(read, -1)
        for j in range(len(observations)):  # the last reading before each step, held
            seen = read[:, j] >= 0
            last = np.maximum.accumulate(np.where(seen, np.arange(n), -1))
            before[1:, j] = np.where(last[:-1] >= 0, read[last[:-1].clip(0), j], -1)
        acted_rows.append(acted)
        read_rows.append(read)
        before_rows.append(before)
        total += n
    if not total:
        return None
    return np.concatenate(acted_rows), np.concatenate(read_rows), np.concatenate(before_rows)


def _forward_selection(before: np.ndarray, acted: np.ndarray, outcome: np.ndarray) -> list[int]:
    """The action columns chosen for ``outcome`` given ``before`` (see the module doc)."""
    n = len(outcome)
    if n == 0:
        return list(range(acted.shape[1]))
    outcome = np.unique(outcome, return_inverse=True)[1].ravel()
    n_outcomes = int(outcome.max()) + 1
    context = np.unique(before, return_inverse=True)[1].ravel()
    best, chosen = _bic(context, outcome, n_outcomes), list[int]()
    while len(chosen) < acted.shape[1]:
        trials = []
        for a in range(acted.shape[1]):
            if a in chosen:
                continue
            values = np.unique(acted[:, a], return_inverse=True)[1].ravel()
            joined = np.unique(context * (int(values.max()) + 1) + values, return_inverse=True)[1].ravel()
            trials.append((_bic(joined, outcome, n_outcomes), -a, joined))
        score, minus_a, joined = max(trials, key=lambda t: (t[0], t[1]))
        if score <= best:
            break
        best, context = score, joined
        chosen.append(-minus_a)
    return chosen


def _bic(context: np.ndarray, outcome: np.ndarray, n_outcomes: int) -> float:
    """``log-likelihood - (parameters / 2) ln N`` of the outcome given dense context ids."""
    pairs, counts = np.unique(context * n_outcomes + outcome, return_counts=True)
    totals = np.bincount(pairs // n_outcomes, weights=counts)
    loglik = float(np.sum(counts * np.log(counts / totals[pairs // n_outcomes])))
    contexts = int(np.count_nonzero(totals))
    return loglik - 0.5 * contexts * (n_outcomes - 1) * math.log(len(outcome))
