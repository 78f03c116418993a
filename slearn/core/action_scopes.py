"""Which actions drive each observation channel: action scopes chosen from data.

A view of an action scope (:mod:`slearn.core.views`) sees only the step's actions on its
scope's channels. When a robot commands many joints at once, the tuple of every command
rarely repeats, while each joint's own (command, reading) pairs do; a joint's scope is then
its own command. :func:`suggest_scopes` finds the scopes in recorded steps, for a spec to
declare (``slearn info --suggest-spec``).

For each observation channel it models the channel's reading from its previous reading
and the step's values of a set of action channels, and chooses the set by forward
selection on a prequential code length (Dawid 1984; Rissanen's predictive MDL): every
step's reading is predicted from the counts of the steps before it in the same context,
``(n(context, reading) + 1 / R) / (n(context) + 1)`` over the ``R`` readings the channel
takes, and a set costs the log-loss of the whole sequence. Start from no action, add the
action channel that shortens the code most, stop when none shortens it. Each context
pays for its first visits (``ln R`` and more before its counts settle), so an action joins
only when what it explains outweighs the contexts it splits the data into; unlike BIC's
``(R - 1) / 2 ln N`` per context, the cost does not grow with values a reading never takes
after a context (36 positions of a joint, of which 3 follow any one). No constant is
tuned: the one prior observation, spread evenly, is the estimator's own.
"""

from __future__ import annotations

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
    uniform = 1.0 / (int(outcome.max()) + 1)  # one prior observation, spread over the readings
    context = np.unique(before, return_inverse=True)[1].ravel()
    p = _prequential(context, outcome, uniform)
    best, chosen = _code_length(p), list[int]()
    while len(chosen) < acted.shape[1]:
        trials = []
        for a in range(acted.shape[1]):
            if a in chosen:
                continue
            values = np.unique(acted[:, a], return_inverse=True)[1].ravel()
            joined = np.unique(context * (int(values.max()) + 1) + values, return_inverse=True)[1].ravel()
            q = _prequential(joined, outcome, uniform)
            trials.append((_code_length(q), a, joined))
        length, a, joined = min(trials, key=lambda t: (t[0], t[1]))
        if length >= best:
            break
        best, context = length, joined
        chosen.append(a)
    return chosen


def _prequential(context: np.ndarray, outcome: np.ndarray, prior: float) -> np.ndarray:
    """Each step's probability of its outcome from the steps before it in its context,
    ``(n(context, outcome) + prior) / (n(context) + 1)``."""
    n_outcomes = int(outcome.max()) + 1
    return (_seen_before(context * n_outcomes + outcome) + prior) / (_seen_before(context) + 1.0)


def _seen_before(keys: np.ndarray) -> np.ndarray:
    """For each position, how many earlier positions hold the same key."""
    order = np.argsort(keys, kind="stable")
    ranked = keys[order]
    starts = np.flatnonzero(np.r_[True, ranked[1:] != ranked[:-1]])
    rank = np.arange(len(keys)) - np.repeat(starts, np.diff(np.r_[starts, len(keys)]))
    out = np.empty(len(keys), np.float64)
    out[order] = rank
    return out


def _code_length(p: np.ndarray) -> float:
    """The sequence's code length in nats."""
    return float(-np.log(p).sum())
