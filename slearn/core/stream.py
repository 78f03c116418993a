"""Event streams: an episode is a sequence of steps, a step is actions then observations."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Sequence

import numpy as np

from slearn.errors import ParameterError

Step = tuple[tuple[int, ...], tuple[int, ...]]
"""``(actions, observations)``: the action events issued at one tick, then the observations."""


@dataclass(frozen=True, eq=False)
class Episode:
    """One episode as flat arrays (cheap to hand to compiled kernels).

    Attributes:
        symbols: every event symbol in stream order, ``int32``.
        step_offsets: ``int64`` of length ``n_steps + 1``; step ``i`` is
            ``symbols[step_offsets[i]:step_offsets[i + 1]]``.
        n_actions: ``int32`` per step; the first ``n_actions[i]`` symbols of step ``i``
            are its actions, the rest its observations.
    """

    symbols: np.ndarray
    step_offsets: np.ndarray
    n_actions: np.ndarray

    def __post_init__(self) -> None:
        if len(self.step_offsets) != len(self.n_actions) + 1:
            raise ParameterError("step_offsets must have one entry more than n_actions")
        if len(self.step_offsets) and self.step_offsets[-1] != len(self.symbols):
            raise ParameterError("step_offsets must end at len(symbols)")

    @classmethod
    def from_steps(cls, steps: Iterable[Step]) -> "Episode":
        """Build an episode from ``(actions, observations)`` pairs of integer symbols."""
        symbols: list[int] = []
        offsets = [0]
        n_actions: list[int] = []
        for actions, observations in steps:
            symbols.extend(actions)
            symbols.extend(observations)
            offsets.append(len(symbols))
            n_actions.append(len(actions))
        return cls(
            np.asarray(symbols, dtype=np.int32),
            np.asarray(offsets, dtype=np.int64),
            np.asarray(n_actions, dtype=np.int32),
        )

    @classmethod
    def from_pairs(cls, first_observation: Sequence[int], actions: Sequence[int],
                   observations: Sequence[int]) -> "Episode":
        """Single-channel shortcut: ``o0, (a1, o1), (a2, o2), ...`` built with numpy."""
        n = len(actions)
        if len(observations) != n:
            raise ParameterError("actions and observations must have the same length")
        symbols = np.empty(len(first_observation) + 2 * n, dtype=np.int32)
        head = len(first_observation)
        symbols[:head] = first_observation
        symbols[head::2] = actions
        symbols[head + 1::2] = observations
        offsets = np.concatenate(([0], head + 2 * np.arange(n + 1, dtype=np.int64)))
        n_actions = np.ones(n + 1, dtype=np.int32)
        n_actions[0] = 0
        return cls(symbols, offsets, n_actions)

    def __len__(self) -> int:
        return len(self.n_actions)

    @property
    def n_events(self) -> int:
        """Number of events (symbols) in the episode."""
        return len(self.symbols)

    def step(self, i: int) -> Step:
        """Step ``i`` as ``(actions, observations)``."""
        start, end = int(self.step_offsets[i]), int(self.step_offsets[i + 1])
        split = start + int(self.n_actions[i])
        return tuple(self.symbols[start:split].tolist()), tuple(self.symbols[split:end].tolist())

    def slice_steps(self, start: int, stop: int) -> "Episode":
        """Steps ``start..stop - 1`` as an episode of their own (its symbols and actions are
        views of this one's arrays)."""
        offsets = self.step_offsets[start:stop + 1]
        return Episode(self.symbols[offsets[0]:offsets[-1]], offsets - offsets[0], self.n_actions[start:stop])

    def steps(self) -> list[Step]:
        """All steps as ``(actions, observations)`` tuples."""
        return [self.step(i) for i in range(len(self))]
