"""Goal-seeking control from a pattern library (paper section II, last paragraph).

"When a new goal is presented, the S-learning algorithm searches past sequences for series
of actions that moved the system from its current state to the desired state." The
planner reads a transition model off the library's context tree (:mod:`slearn.core.context_tree`)
and searches it:

* **States** are short contexts: the current observation and the ``order`` steps before
  it (``p a o`` for ``order=1``), as tokens. A longer context tells more (how far an
  ``error`` move carried the pointer inside its bin, whether a ``delay`` command is still
  pending) and separates a changed world from the old one: after the pointer's command
  reversal, ``5 R 4`` is a context the library has never seen.
* **Transitions**: for a state and a candidate action, the outcomes after the context's
  suffixes of order 0 to ``order`` (the view's contexts that start at an observation), blended
  from short to long: each level is its own counts plus ``prior`` pseudo-counts of the
  shorter level's distribution, a share ``novelty`` of which goes to *unknown*. What the
  library has never seen is unknown; a context seen often speaks for itself.
* **Search**: value iteration over the states reachable within ``horizon`` steps, goal
  observations absorbing with value 1, each step discounted by ``discount`` (fewer steps
  win). An unknown outcome counts as a step lost in place (worth ``curiosity`` times the
  value of staying), so a route the library saw only once still beats an action it never
  saw; untried actions get their turn through curiosity (below). The
  probability reported is the library's probability of reaching the goal within the
  horizon with the plan's closed-loop policy.
* **Optimism**: when no known route reaches the goal, the search is run again with every
  action never tried from a state worth the goal (``optimism``): the plan heads for the
  nearest untried action or unvisited state (directed exploration, as R-max does), not
  back and forth where it is. Only when nothing untried is in reach either, the action
  tried least often from the current observation is taken (curiosity).
* **Change**: after the library's change detector raised an alarm (:mod:`slearn.core.mixer`),
  counts from before it weigh at most ``stale`` sightings (default none): trust shifts to
  what was seen since, and what was not seen since is untried again; from then on untried
  actions are worth the goal even when a known route exists, so the changed world is
  relearned where it matters before old routes are trusted again.

Closed loop: call :meth:`Planner.plan` again after every observed step. The planner is
pure (no I/O); its search runs in compiled kernels over the tree's arrays. It plans in
one view of the library (by default the first: the pointer's position).
"""

from __future__ import annotations

import math
from collections import namedtuple
from dataclasses import dataclass
from typing import Iterable, Sequence, cast

import numpy as np

from slearn.core import context_tree, hashtrie
from slearn.core._jit import helper, kernel
from slearn.core.context_tree import path_hash, root_path
from slearn.core.hashtrie import child, child_or_add
from slearn.core.library import PatternLibrary
from slearn.core.stream import Step
from slearn.core.tokens import ACTION, OBSERVATION
from slearn.core.views import ViewState

_NO_STATE = -1


@dataclass(frozen=True)
class Plan:
    """What the library says to do next.

    Attributes:
        actions: the planned action tuples, the one to issue now first (empty when the
            goal is already observed); the most likely path, replanned every step.
        observations: the most likely observations after each planned action (``()``
            where an unknown outcome is likelier than any the library knows).
        probability: the library's probability of reaching the goal within the horizon
            with this plan's closed-loop policy (1.0 when already there).
        value: the discounted value the search maximised (probability, fewer steps).
        explore: no known route: the first action was chosen by curiosity.
    """

    actions: tuple[tuple[int, ...], ...]
    observations: tuple[tuple[int, ...], ...]
    probability: float
    value: float
    explore: bool = False

    @property
    def action(self) -> tuple[int, ...] | None:
        """The action tuple to issue now, ``None`` when the goal is already observed."""
        return self.actions[0] if self.actions else None

    @property
    def reached(self) -> bool:
        """Whether the goal is the current observation."""
        return not self.actions and self.probability == 1.0


REACHED = Plan((), (), 1.0, 1.0)


@dataclass(frozen=True)
class PlannerSettings:
    """How the planner reads the library and searches (see the module docstring).

    Args:
        order: steps of history in a state (0 = the current observation only).
        horizon: steps searched ahead.
        discount: value kept per step (below 1: fewer steps win).
        prior: pseudo-counts of the shorter context in a longer one's distribution.
        novelty: share of those pseudo-counts that stands for an unknown outcome.
        curiosity: value of an unknown outcome, as a share of the value of staying put.
        optimism: value of an action never tried from a state (1: as good as the goal) when
            no known route reaches the goal, so exploration heads for the nearest untried
            action or unvisited state instead of dithering; a known route is taken first.
        stale: after the library's change detector raised an alarm, counts from before it
            weigh at most this many sightings per outcome (trust shifts to recent steps).
        half_life: fade weights with this half-life in steps (0: never).
        min_probability: below this probability of reaching the goal there is no route.
        max_states: states searched at most (the rest count as failures).
    """

    order: int = 1
    horizon: int = 64
    discount: float = 0.95
    prior: float = 1.0
    novelty: float = 0.5
    curiosity: float = 1.0
    min_probability: float = 0.01
    max_states: int = 20_000
    half_life: float = 0.0
    optimism: float = 1.0
    stale: float = 0.0

    @property
    def fade_rate(self) -> float:
        """Per-step fading of the library's weights (0 when ``half_life`` is 0)."""
        return math.log(2.0) / self.half_life if self.half_life > 0 else 0.0

    def __post_init__(self) -> None:
        if not 0 <= self.order <= 8:
            raise ValueError("order must be between 0 and 8")
        if self.horizon < 1 or self.max_states < 1:
            raise ValueError("horizon and max_states must be positive")
        if not 0.0 < self.discount <= 1.0:
            raise ValueError("discount must be in (0, 1]")
        if self.prior <= 0.0 or not 0.0 <= self.novelty <= 1.0:
            raise ValueError("prior must be positive and novelty in [0, 1]")


class Planner:
    """Plans action sequences toward goal observations from a :class:`PatternLibrary`.

    Args:
        library: the library (it may keep learning between calls).
        actions: candidate action tuples; default every non-empty action the library knows.
        settings: search settings.
    """

    def __init__(self, library: PatternLibrary, actions: Iterable[Sequence[int]] | None = None,
                 settings: PlannerSettings | None = None, view: int = 0) -> None:
        self.library = library
        self.view = view
        self.settings = settings or PlannerSettings()
        self._actions = None if actions is None else [tuple(int(s) for s in a) for a in actions]
        if self._actions is not None and not self._actions:
            raise ValueError("the planner needs at least one candidate action")
        width = 2 * self.settings.order + 1
        self._states = hashtrie.new_trie(self.settings.max_states * width + 2)
        self._node_state = np.full(len(self._states.parent), _NO_STATE, np.int32)
        self._goal_cache: tuple[frozenset, int, np.ndarray] | None = None
        self._graph: _Graph | None = None

    @property
    def actions(self) -> list[tuple[int, ...]]:
        """The candidate action tuples."""
        if self._actions is not None:
            return self._actions
        table = self.library.tokens
        return [table.symbols(t) for t in range(len(table))
                if table.kind(t) == ACTION and table.symbols(t)]

    def plan(self, history: Sequence[Step], goal: int | Iterable[int]) -> Plan:
        """The best plan from the end of ``history`` to an observation holding ``goal``.

        Args:
            history: ``(actions, observations)`` steps, oldest first; the last step's
                observations are the current ones (only the last ``order + 1`` are read).
            goal: an observation symbol, or several (any of them will do).
        """
        if not history:
            raise ValueError("the planner needs at least the current observation")
        goals = frozenset([goal] if isinstance(goal, (int, np.integer)) else (int(g) for g in goal))
        if goals & set(history[-1][1]):
            return REACHED
        actions = self.actions
        action_tokens = np.array([self.library.tokens.find(ACTION, a) for a in actions], np.int32)
        start = self._state_tokens(history)
        if start is None or not len(actions):
            return self._blind(actions, action_tokens)
        s = self.settings
        index = (self.library.tree, self._root())
        graph = self._search_graph(index, start, action_tokens, self._goal_mask(goals))
        relearning = self._epoch() > 0  # after a change, what was not seen since is retested first
        q, reach = _values(graph, len(action_tokens), s.horizon, s.discount, s.curiosity,
                           s.optimism if relearning else 0.0)
        if s.optimism > 0.0 and reach[_best_action(q[: len(actions)], reach[: len(actions)])] < s.min_probability:
            # no known route: only now are untried actions worth the goal (explore, then exploit)
            q, reach = _values(graph, len(action_tokens), s.horizon, s.discount, s.curiosity, s.optimism)
        return self._plan_from(graph, q, reach, actions, action_tokens, index, start)

    def _root(self) -> int:
        self.library.prepare()
        return int(cast(ViewState, self.library.streams).root[self.view])  # prepared above

    def _search_graph(self, index, start, action_tokens, goal_mask) -> _Graph:
        s = self.settings
        tree, root = index
        while True:
            graph = self._graph_for(len(action_tokens))
            self._reset_states()
            if _build(tree, root, self._states, self._node_state, graph, start, action_tokens,
                      goal_mask, s.order, s.prior, s.novelty, self.library.clock, s.fade_rate,
                      self._epoch(), s.stale, s.horizon):
                return graph
            self._graph = _new_graph(s.max_states, 2 * s.order + 1, len(action_tokens), 2 * len(graph.nxt))

    def _graph_for(self, n_actions: int) -> _Graph:
        s = self.settings
        if self._graph is None or len(self._graph.offsets) != s.max_states * n_actions + 1:
            self._graph = _new_graph(s.max_states, 2 * s.order + 1, n_actions, 16 * 1024)
        return self._graph

    def _plan_from(self, graph, q, reach, actions, action_tokens, index, start) -> Plan:
        best = _best_action(q[: len(actions)], reach[: len(actions)])
        routeless = reach[best] < self.settings.min_probability
        if routeless and q[best] <= 0.0:
            return self._curious(actions, action_tokens, index, start, float(q[best]))
        steps, outcomes = _path(graph, q, reach, len(actions), self.settings.horizon)
        table = self.library.tokens
        return Plan(tuple(actions[j] for j in steps),
                    tuple(table.symbols(int(o)) if o >= 0 else () for o in outcomes),
                    float(reach[best]), float(q[best]), explore=bool(routeless))

    def _epoch(self) -> int:
        """The planned view's count of change alarms (0: none, all counts are trusted)."""
        mixer = self.library.mixer
        return int(mixer.epoch[self.view]) if mixer is not None and len(mixer.epoch) > self.view else 0

    def _curious(self, actions, action_tokens, index, start, value) -> Plan:
        tried = _tried(index[0], index[1], start, action_tokens)
        j = int(np.argmin(tried))  # ties: the first candidate
        return Plan((actions[j],), ((),), 0.0, value, explore=True)

    def _blind(self, actions, action_tokens) -> Plan:
        """No state (the current observation was never seen): try the least known action."""
        if not actions:
            raise ValueError("the library knows no action and none were given")
        known = action_tokens >= 0
        j = int(np.argmin(known))
        return Plan((actions[j],), ((),), 0.0, 0.0, explore=True)

    def _state_tokens(self, history: Sequence[Step]) -> np.ndarray | None:
        """``o``, ``p a o``, ... for the last ``order`` steps, stopping at unknown tokens."""
        table = self.library.tokens
        tokens = []
        for i in range(len(history) - 1, max(len(history) - 2 - self.settings.order, -1), -1):
            obs = table.find(OBSERVATION, history[i][1])
            if obs < 0:
                break
            tokens.append(obs)
            act = table.find(ACTION, history[i][0]) if i > 0 else -1
            if act < 0 or len(tokens) > self.settings.order:
                break
            tokens.append(act)
        if len(tokens) % 2 == 0 and tokens:
            tokens.pop()
        return np.asarray(tokens[::-1], np.int32) if tokens else None

    def _goal_mask(self, goals: frozenset) -> np.ndarray:
        """Per token: an observation holding one of the goal symbols."""
        n = len(self.library.tokens)
        cached = self._goal_cache
        if cached is not None and cached[0] == goals and cached[1] == n:
            return cached[2]
        offsets, symbols, kinds = self.library.tokens.export()
        hit = np.isin(symbols, np.fromiter(goals, np.int32, len(goals))).astype(np.int64)
        per_token = np.add.reduceat(np.append(hit, 0), offsets[:-1])  # the 0 ends an empty last token
        per_token[offsets[:-1] == offsets[1:]] = 0  # reduceat on empty tokens reads the next one
        mask = (per_token > 0) & (kinds == OBSERVATION)
        self._goal_cache = (goals, n, mask)
        return mask

    def _reset_states(self) -> None:
        trie = self._states
        used = int(trie.size[0])
        self._node_state[:used] = _NO_STATE
        hashtrie.clear(trie)


def _best_action(q: np.ndarray, reach: np.ndarray) -> int:
    """Highest value; ties go to the higher probability, then the first candidate."""
    order = np.lexsort((np.arange(len(q)), -reach, -np.round(q, 12)))
    return int(order[0])


@helper
def _child(tree, node, tok, h):
    """The child of ``node`` along ``tok`` (``h``: its path hash), or -1."""
    return context_tree.child(tree.node_slots, tree.parent, tree.token, node, tok, h)


@helper
def _contexts(tree, root, tokens, obs_pos, action, levels, cand):
    """Contexts that start at an observation, order 0 (no earlier step) first: the nodes of
    ``tokens[..obs_pos] + action`` read backwards at even depths."""
    h = path_hash(root_path(root), action)
    node = _child(tree, root, action, h)
    n = 0
    i = obs_pos
    while node >= 0 and i >= 0 and n < levels:
        h = path_hash(h, tokens[i])
        node = _child(tree, node, tokens[i], h)
        if node < 0 or tree.first[node] == -1:
            break
        cand[n] = node
        n += 1
        if i == 0:
            break
        h = path_hash(h, tokens[i - 1])
        node = _child(tree, node, tokens[i - 1], h)
        i -= 2
    return n


@helper
def _weights(tree, node, outcomes, k, out, clock, rate, epoch, stale):
    """Total weight after the context ``node`` and the weight of each of ``outcomes[:k]``.

    Weights fade with the age of their newest sighting (``rate`` per step, 0 = never).
    After the view's change detector raised an alarm (``epoch`` > 0), trust shifts to the
    counts since the alarm: older counts weigh at most ``stale`` sightings per outcome.
    """
    out[:k] = 0.0
    total = 0.0
    e = tree.first[node]
    current = epoch > 0 and tree.epoch[node] == epoch
    while e != -1:
        w = float(tree.count[e])
        if epoch > 0:
            recent = float(tree.fresh[e]) if current else 0.0
            w = recent + min(w - recent, stale)
        w *= np.exp(-rate * (clock - tree.last_seen[e]))
        total += w
        for i in range(k):
            if outcomes[i] == tree.outcome[e]:
                out[i] = w
        e = tree.next[e]
    return total


@kernel
def distribution(tree, root, tokens, obs_pos, action, levels, prior, novelty, clock, rate, epoch,
                 stale, cand, outcomes, probs, work):
    """Outcome probabilities after ``action`` in the context ending at ``tokens[obs_pos]``.

    Blends contexts of order 0 to ``levels - 1`` (see the module docstring). Fills
    ``outcomes[:k]`` and ``probs[:k]``; returns ``(k, unknown probability)``.
    """
    if action < 0:
        return 0, 1.0
    n = _contexts(tree, root, tokens, obs_pos, action, levels, cand)
    if n == 0:
        return 0, 1.0
    k = 0
    e = tree.first[cand[0]]
    while e != -1 and k < len(outcomes):
        outcomes[k] = tree.outcome[e]
        k += 1
        e = tree.next[e]
    total = _weights(tree, cand[0], outcomes, k, probs, clock, rate, epoch, stale)
    probs[:k] /= total + prior
    unknown = prior / (total + prior)
    keep = prior * (1.0 - novelty)
    for level in range(1, levels):
        total = (_weights(tree, cand[level], outcomes, k, work, clock, rate, epoch, stale)
                 if level < n else 0.0)
        for i in range(k):
            probs[i] = (work[i] * (level < n) + keep * probs[i]) / (total + prior)
        unknown = (keep * unknown + prior * novelty) / (total + prior)
    return k, unknown


_Graph = namedtuple("_Graph", "tok length depth goal offsets unknown nxt prob size")
"""The searched states and transitions. Per state: its tokens ``tok[s, :length[s]]``, its
``depth`` from the start and whether it is a ``goal``. Per (state, action) ``s * A + j``:
the ``unknown`` probability and the transitions ``offsets[sa]:offsets[sa + 1]`` into
``nxt``/``prob``. ``size`` int64[2]: states and transitions in use."""


def _new_graph(max_states: int, width: int, n_actions: int, transitions: int) -> _Graph:
    return _Graph(np.full((max_states, width), -1, np.int32), np.zeros(max_states, np.int32),
                  np.zeros(max_states, np.int32), np.zeros(max_states, np.bool_),
                  np.zeros(max_states * n_actions + 1, np.int64), np.zeros(max_states * n_actions),
                  np.zeros(transitions, np.int32), np.zeros(transitions), np.zeros(2, np.int64))


@kernel
def _state_id(states, node_state, tokens, length, graph):
    """The id of the state ``tokens[:length]``, registered if new; -1 when out of room."""
    n = graph.size[0]
    node = 0
    for i in range(length):
        found = child(states, node, tokens[i])
        if found < 0:
            if n >= len(graph.length):
                return -1
            found = child_or_add(states, node, tokens[i])
        node = found
    if node_state[node] == -1 and n < len(graph.length):
        node_state[node] = n
        graph.tok[n, :length] = tokens[:length]
        graph.tok[n, length:] = -1
        graph.length[n] = length
        graph.size[0] = n + 1
    return node_state[node]


@kernel
def _build(tree, root, states, node_state, graph, start, actions, goal_mask, order, prior, novelty,
           clock, rate, epoch, stale, horizon):
    """Expand every state reachable within ``horizon`` steps from ``start`` (breadth first).

    Returns False when the transition arrays ran out of room (grow them and build again).
    """
    n_act = len(actions)
    n_tok = len(goal_mask)
    scratch = (np.zeros(order + 1, np.int32), np.zeros(n_tok, np.int32), np.zeros(n_tok), np.zeros(n_tok),
               np.zeros(2 * order + 3, np.int32))
    graph.size[:] = 0
    graph.offsets[0] = 0
    _state_id(states, node_state, start, len(start), graph)
    graph.depth[0] = 0
    graph.goal[0] = False
    s = 0
    while s < graph.size[0]:
        for j in range(n_act):
            graph.unknown[s * n_act + j] = 0.0
            if not graph.goal[s] and graph.depth[s] < horizon:
                if not _expand(tree, root, states, node_state, graph, s, s * n_act + j, actions[j],
                               goal_mask, order, prior, novelty, clock, rate, epoch, stale, scratch):
                    return False
            graph.offsets[s * n_act + j + 1] = graph.size[1]
        s += 1
    return True


@kernel
def _expand(tree, root, states, node_state, graph, s, sa, action, goal_mask, order, prior, novelty,
            clock, rate, epoch, stale, scratch):
    """Add the transitions of state ``s`` under an action (``sa`` = its (state, action) slot).

    Returns False when the transition arrays are out of room.
    """
    cand, outcomes, probs, work, buf = scratch
    length = graph.length[s]
    levels = min(order, (length - 1) // 2) + 1
    k, graph.unknown[sa] = distribution(tree, root, graph.tok[s], length - 1, action, levels,
                                        prior, novelty, clock, rate, epoch, stale, cand, outcomes, probs,
                                        work)
    buf[:length] = graph.tok[s, :length]
    buf[length] = action
    keep = min(length + 2, 2 * order + 1)
    first = length + 2 - keep
    for i in range(k):
        if probs[i] <= 0.0:
            continue
        if graph.size[1] >= len(graph.nxt):
            return False
        buf[length + 1] = outcomes[i]
        fresh = graph.size[0]
        t = _state_id(states, node_state, buf[first:], keep, graph)
        if t < 0:
            continue  # out of states: the mass is lost
        if t == fresh:
            graph.depth[t] = graph.depth[s] + 1
            graph.goal[t] = goal_mask[outcomes[i]]
        graph.nxt[graph.size[1]] = t
        graph.prob[graph.size[1]] = probs[i]
        graph.size[1] += 1
    return True


@helper
def _q(offsets, nxt, prob, unknown, value, reach, s, sa, discount, curiosity, optimism):
    """Value and probability of reaching the goal after action ``sa`` from state ``s``.

    An unknown outcome counts as a step lost in place, worth ``curiosity`` times staying;
    an action never tried from the state is worth ``optimism`` (as if it reached the goal).
    """
    if unknown[sa] >= 1.0:
        return discount * max(optimism, curiosity * value[s]), reach[s]
    v, r = 0.0, 0.0
    for e in range(offsets[sa], offsets[sa + 1]):
        v += prob[e] * value[nxt[e]]
        r += prob[e] * reach[nxt[e]]
    return discount * (v + unknown[sa] * curiosity * value[s]), r + unknown[sa] * reach[s]


@kernel
def _values(graph, n_act, horizon, discount, curiosity, optimism):
    """Value iteration; returns ``(q, reach)`` per (state, action) of the final sweep."""
    n, goal, offsets, nxt, prob, unknown = (graph.size[0], graph.goal, graph.offsets, graph.nxt,
                                            graph.prob, graph.unknown)
    value = np.where(goal[:n], 1.0, 0.0)
    reach = value.copy()
    q = np.zeros(n * n_act)
    r = np.zeros(n * n_act)
    for _ in range(horizon):
        new_value = value.copy()
        new_reach = reach.copy()
        for s in range(n):
            if goal[s]:
                continue
            best, best_r = -1.0, -1.0
            for j in range(n_act):
                v, p = _q(offsets, nxt, prob, unknown, value, reach, s, s * n_act + j, discount, curiosity,
                          optimism)
                q[s * n_act + j], r[s * n_act + j] = v, p
                if v > best + 1e-12 or (v > best - 1e-12 and p > best_r):
                    best, best_r = v, p
            new_value[s], new_reach[s] = best, best_r
        value, reach = new_value, new_reach
    return q, r


@kernel
def _path(graph, q, r, n_act, horizon):
    """The greedy policy's most likely path from state 0: action indices and outcomes."""
    n, goal, offsets, nxt, prob, unknown = (graph.size[0], graph.goal, graph.offsets, graph.nxt,
                                            graph.prob, graph.unknown)
    steps = np.zeros(horizon, np.int32)
    outcomes = np.zeros(horizon, np.int32)
    seen = np.zeros(n, np.bool_)
    s, length = 0, 0
    while length < horizon and not goal[s] and not seen[s]:
        seen[s] = True
        best = 0
        for j in range(1, n_act):
            a, b = q[s * n_act + j], q[s * n_act + best]
            if a > b + 1e-12 or (a > b - 1e-12 and r[s * n_act + j] > r[s * n_act + best]):
                best = j
        sa = s * n_act + best
        top, top_p = -1, unknown[sa]
        for e in range(offsets[sa], offsets[sa + 1]):
            if prob[e] > top_p:
                top, top_p = nxt[e], prob[e]
        steps[length] = best
        outcomes[length] = graph.tok[top, graph.length[top] - 1] if top >= 0 else -1
        length += 1
        if top < 0:
            break
        s = top
    return steps[:length], outcomes[:length]


@kernel
def _tried(tree, root, start, actions):
    """How often each action was taken from the current observation (order-0 weight)."""
    out = np.zeros(len(actions))
    for j in range(len(actions)):
        if actions[j] < 0:
            continue
        h = path_hash(root_path(root), actions[j])
        node = _child(tree, root, actions[j], h)
        if node >= 0:
            node = _child(tree, node, start[len(start) - 1], path_hash(h, start[len(start) - 1]))
        if node < 0:
            continue
        e = tree.first[node]
        while e != -1:
            out[j] += tree.count[e]
            e = tree.next[e]
    return out
