"""Views: which tokens each predicted channel sees, and an episode encoded for them.

A *view* is a group of observation channels predicted together; by default each
observation channel is a view of its own (factored prediction), and a library built
without a vocabulary has one view holding every observation channel (a step's
observations predicted as one tuple, as in the paper's serialization).

The stream a view sees alternates the actions issued at a step (one token per step, the
tuple of its action symbols, possibly empty) and the view's observation at that step
(one token, the tuple of the view's symbols). A step where the view reports nothing but
an action was issued shows the view's last observation again (sample and hold), so a
joint's last reading stays next to the commands that follow it however many other
joints reported in between; a stream without action channels shows only the view's own
readings. Contexts are runs of this stream just before an observation of the view.

:func:`encode` turns an episode into :class:`StepCodes`: per step the action token, and
the ``(view, observation token)`` pairs of the views that reported.

Action scopes. By default a view's stream shows every action of a step, one tuple. A view
may instead see a *scope*: the step's actions on some action channels only (a joint's own
command), so that a robot commanding many joints at once, whose command tuples rarely
repeat, still repeats each joint's (command, reading) contexts. :func:`encode` then also
gives, per step and scope, the token of the step's actions in that scope.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from slearn.core._jit import helper, kernel
from slearn.core.stream import Episode
from slearn.core.tokens import ACTION, OBSERVATION, TokenTable, _find, _hash, _intern
from slearn.errors import ParameterError

NO_VIEW = -1
NO_TOKEN = -1
"""A view's held observation before its first one."""
UNKNOWN = -2
"""A token the library never saw (prediction from a history): it matches no context."""
ALL_ACTIONS = -1
"""A view's scope (``ViewState.scope``) when it sees every action of a step."""
NO_ACTIONS = -2
"""A view's scope when it sees none: its stream holds its own readings only."""


class StepCodes(NamedTuple):
    """An episode as the views see it.

    ``action[s]`` is step ``s``'s action token; the views that reported at step ``s`` are
    ``view[offsets[s]:offsets[s + 1]]`` with observation tokens ``token[...]``, in view order;
    ``scoped[s, c]`` is the token of step ``s``'s actions in scope ``c`` (no columns when
    the library has no scopes).
    """

    action: np.ndarray   # int32 per step
    offsets: np.ndarray  # int64, steps + 1
    view: np.ndarray     # int32 per report
    token: np.ndarray    # int32 per report
    scoped: np.ndarray = np.zeros((0, 0), np.int32)  # int32 (steps, scopes): see encode

    def __len__(self) -> int:
        return len(self.action)

    @property
    def n_reports(self) -> int:
        """Observations to predict (one per view and step that reported)."""
        return len(self.view)


def encode(table: TokenTable, episode: Episode, view_of_symbol: np.ndarray,
           intern: bool = True, in_scope: np.ndarray | None = None) -> StepCodes:
    """Intern the episode's action and observation tuples and group them by view.

    ``view_of_symbol[s]`` is the view of observation symbol ``s`` (``NO_VIEW`` for actions
    and symbols of no view, which are ignored); it must cover every symbol of the episode.
    ``intern=False`` only looks tokens up (``UNKNOWN`` for a tuple never seen).
    ``in_scope[c, s]`` (``uint8``, covering every symbol) says whether action symbol ``s``
    is in scope ``c``; each scope's tokens go to ``scoped``.
    """
    n_steps = len(episode)
    scopes = np.zeros((0, len(view_of_symbol)), np.uint8) if in_scope is None else in_scope
    n_scopes = len(scopes)
    if intern:
        table.reserve((2 + n_scopes) * n_steps + episode.n_events + 2,
                      (2 + n_scopes) * episode.n_events + 2)
    codes = StepCodes(np.empty(n_steps, np.int32), np.zeros(n_steps + 1, np.int64),
                      np.empty(episode.n_events, np.int32), np.empty(episode.n_events, np.int32),
                      np.empty((n_steps, n_scopes), np.int32))
    used = _encode(table.arrays, episode.symbols, episode.step_offsets, episode.n_actions,
                   np.asarray(view_of_symbol, np.int32), intern, codes.action, codes.offsets,
                   codes.view, codes.token, scopes, codes.scoped)
    return StepCodes(codes.action, codes.offsets, codes.view[:used].copy(), codes.token[:used].copy(),
                     codes.scoped)


@kernel
def _encode(table, symbols, step_offsets, n_actions, view_of, intern, action, offsets, view, token,
            in_scope, scoped):
    buf = np.empty(max(len(symbols), 1), np.int32)
    views = np.empty(max(len(symbols), 1), np.int32)
    n = 0
    for s in range(len(n_actions)):
        start, end = step_offsets[s], step_offsets[s + 1]
        split = start + n_actions[s]
        action[s] = _token(table, ACTION, symbols, start, split, intern)
        for c in range(in_scope.shape[0]):
            m = 0
            for i in range(start, split):
                if in_scope[c, symbols[i]]:
                    buf[m] = symbols[i]
                    m += 1
            scoped[s, c] = _token(table, ACTION, buf, 0, m, intern)
        seen = 0
        for i in range(split, end):  # the step's views, in order of their first symbol
            v = view_of[symbols[i]]
            if v < 0:
                continue
            known = False
            for j in range(seen):
                if views[j] == v:
                    known = True
                    break
            if not known:
                views[seen] = v
                seen += 1
        _sort_small(views, seen)
        for j in range(seen):
            m = 0
            for i in range(split, end):
                if view_of[symbols[i]] == views[j]:
                    buf[m] = symbols[i]
                    m += 1
            view[n] = views[j]
            token[n] = _token(table, OBSERVATION, buf, 0, m, intern)
            n += 1
        offsets[s + 1] = n
    return n


@helper
def _token(table, kind, values, start, end, intern):
    if intern:
        return _intern(table, kind, values, start, end)
    t = _find(table, kind, values, start, end, _hash(kind, values, start, end))
    return t if t >= 0 else UNKNOWN


@helper
def _sort_small(values, n):
    for i in range(1, n):
        x = values[i]
        j = i - 1
        while j >= 0 and values[j] > x:
            values[j + 1] = values[j]
            j -= 1
        values[j + 1] = x


class ViewState(NamedTuple):
    """Where each view's stream stands inside the current episode.

    ``recent[v]`` is a ring of the view's last tokens (``filled[v]`` pushed so far in this
    episode, the newest at ``(filled[v] - 1) & (width - 1)``): its width is the power of two
    at or above the longest context (:func:`ring_width`), so that a token's place is a mask,
    not a division (the divisions by the context length were a fifth of a batch query's
    time); ``held[v]`` its last observation token (-1 before the first); ``root[v]`` its root
    node in the context tree; ``scope[v]`` the scope whose actions its stream shows
    (``StepCodes.scoped``; ``ALL_ACTIONS``: every action of the step, ``NO_ACTIONS``: none,
    so no action token is pushed).
    """

    recent: np.ndarray  # int32 (views, ring_width(max_context))
    filled: np.ndarray  # int64 (views,)
    held: np.ndarray    # int32 (views,)
    root: np.ndarray    # int32 (views,)
    scope: np.ndarray   # int32 (views,)


def ring_width(max_context: int) -> int:
    """The width of a view's ring of tokens: the power of two at or above ``max_context``."""
    return 1 << max(int(max_context) - 1, 0).bit_length()


def new_view_state(views: int, max_context: int, roots: np.ndarray,
                   scope: np.ndarray | None = None) -> ViewState:
    """View streams at the start of an episode (``scope``: see :class:`ViewState`; default
    every view sees every action)."""
    return ViewState(np.zeros((views, ring_width(max_context)), np.int32), np.zeros(views, np.int64),
                     np.full(views, -1, np.int32), np.asarray(roots, np.int32).copy(),
                     np.full(views, -1, np.int32) if scope is None else np.asarray(scope, np.int32).copy())


def restart(state: ViewState) -> None:
    """Forget the streams' tails: a new episode begins (episodes are never glued)."""
    state.filled[:] = 0
    state.held[:] = -1


def joint_mapping(episode: Episode) -> np.ndarray:
    """Without a vocabulary every observation symbol is view 0; actions are none."""
    n = int(episode.symbols.max()) + 1 if episode.n_events else 0
    acts = np.zeros(episode.n_events, np.float64)  # 1 where an event is an action
    starts = episode.step_offsets[:-1]
    for k in range(int(episode.n_actions.max()) if len(episode) else 0):
        acts[starts[episode.n_actions > k] + k] = 1.0
    acted = np.bincount(episode.symbols, weights=acts, minlength=n)  # counts, not masks: 3x faster
    observed = np.bincount(episode.symbols, minlength=n) > acted
    if np.any(observed & (acted > 0)):
        raise ParameterError("a symbol is used both as an action and as an observation: "
                             "give the library a vocabulary")
    return np.where(observed, 0, NO_VIEW).astype(np.int32)


def token_stream(codes: StepCodes, empty_action: int,
                 empty_observation: int) -> tuple[np.ndarray, np.ndarray]:
    """The steps of one joint view as ``O A O A ... O`` tokens (the paper's serialization),
    and per step after the first the report it predicts (-1: the step reported nothing)."""
    n = len(codes)
    if n == 0:
        return np.zeros(0, np.int32), np.zeros(0, np.int64)
    has_report = np.diff(codes.offsets) > 0
    obs = np.full(n, empty_observation, np.int32)
    obs[has_report] = codes.token[codes.offsets[:-1][has_report]]
    report = np.where(has_report, codes.offsets[:-1], -1)
    lead = n > 0 and codes.action[0] != empty_action
    tokens = np.empty(2 * n + 1 if lead else 2 * n - 1, np.int32)
    if lead:
        tokens[0] = empty_observation
        tokens[1::2] = codes.action
        tokens[2::2] = obs
        return tokens, report
    tokens[0] = obs[0]
    tokens[1::2] = codes.action[1:]
    tokens[2::2] = obs[1:]
    return tokens, report[1:]
