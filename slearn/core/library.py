"""The pattern library: every occurrence of every context, and the weights that read it.

S-learning (Rohrer & Hulet) keeps a library of observed runs of events, each with a count
and a recency, and predicts from the runs that contain the recent history. This library
stores, for every observation of every view (:mod:`slearn.core.views`), all the contexts of up
to ``max_length`` steps before it, with how often each outcome followed each context
(every occurrence, not only those at a parse boundary), when it last did, and how often
since the view's current epoch (:mod:`slearn.core.context_tree`). A context and one of its
outcomes is a pattern: the run of events ``context + outcome`` with its count and
recency. The weights of :mod:`slearn.core.mixer` decide which context speaks; learning trains
them (:mod:`slearn.core.online`), so a library learned offline predicts with its full scoring.
``max_patterns`` bounds the patterns kept: when a step leaves the library at the bound,
the rarest, oldest patterns are forgotten down to 90 % of it (so while learning it never
holds more than the bound plus one step's new patterns, and never more than the bound
after a call).

The paper's literal rule (counting only at parse boundaries, the longest match first)
is :mod:`slearn.core.literal`.

Counts and recency merge exactly: learning two sets of episodes separately and
merging (:func:`merge`) gives the counts and recency of learning them in one run, in
that order. The scoring state (weights, detectors, fresh counts) follows the documented
rule of :func:`slearn.jobs.merge.merge_libraries`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np

from slearn.core import context_tree, views
from slearn.core._jit import kernel
from slearn.core.context_tree import Tree
from slearn.core.hashtable import rebuild
from slearn.core.mixer import Mixer, new_mixer, with_views
from slearn.core.online import Past, Reports, Run, new_past, new_reports, run_codes
from slearn.core.stream import Episode
from slearn.core.tokens import ACTION, OBSERVATION, TokenTable
from slearn.core.views import NO_VIEW, StepCodes, ViewState
from slearn.core.vocabulary import OBSERVATION as OBSERVATION_ROLE
from slearn.core.vocabulary import Vocabulary
from slearn.errors import ParameterError

DEFAULT_MAX_LENGTH = 6
"""Steps of history a context spans at most (an action and an observation each)."""

MAX_MAX_LENGTH = 64
MAX_PATTERNS = (1 << 31) - 1  # entries are int32-indexed
FORGET_TO = 0.9
_IMPORT_PIECE = 1 << 13  # patterns imported per compiled call
JOINT = "*"
"""The view name of a library without a vocabulary: every observation channel at once."""


@dataclass(frozen=True)
class Pattern:
    """One pattern: a view's context (oldest token first) and the outcome after it."""

    view: int
    context: tuple[int, ...]
    outcome: int
    count: int
    last_seen: int
    fresh: int


class PatternLibrary:
    """Occurrence statistics of every context, per view, with their scoring weights.

    Args:
        max_length: steps of history a context spans at most (``2 * max_length`` tokens
            of a stream with actions, ``max_length`` of one without).
        max_patterns: forgetting bound on patterns; ``None`` keeps every pattern.
        vocabulary: names the channels; each observation channel becomes a view. Without
            one, a step's observations are predicted together as one view.
        has_actions: whether the stream has action channels (a stream without them is a
            sequence of observations); ``None`` decides from the vocabulary, or else from
            the first episode learned.
        action_scopes: ``{observation channel: action channels}``: that channel's view sees
            the step's actions on those channels only (:mod:`slearn.core.views`; none: no
            action token at all, its stream holds its own readings); the other views see
            every action. Needs a vocabulary.
    """

    def __init__(self, max_length: int = DEFAULT_MAX_LENGTH, max_patterns: int | None = None,
                 vocabulary: Vocabulary | None = None, has_actions: bool | None = None,
                 action_scopes: dict[str, tuple[str, ...]] | None = None) -> None:
        check_parameters(max_length, max_patterns)
        self.action_scopes = check_scopes(action_scopes, vocabulary)
        # scope c: its action channels (a view that sees none needs no scope's tokens)
        self._scopes = sorted(set(self.action_scopes.values()) - {()})
        self._in_scope = np.zeros((len(self._scopes), 0), np.uint8)  # see scope_masks
        self.max_length = int(max_length)
        self.max_patterns = None if max_patterns is None else int(max_patterns)
        self.vocabulary = vocabulary
        self.tokens = TokenTable()
        self.empty_action = self.tokens.intern(ACTION, ())
        self.empty_observation = self.tokens.intern(OBSERVATION, ())
        self.clock_array = np.zeros(1, np.int64)
        self.forgotten = 0
        self.tree = context_tree.new_tree()
        self.view_names: list[str] = []
        self._has_actions = has_actions
        self.mixer: Mixer | None = None
        self.streams: ViewState | None = None
        self.past: Past | None = None
        self._view_of_symbol = np.zeros(0, np.int32)

    # --- shape ------------------------------------------------------------------------
    def __len__(self) -> int:
        return int(self.tree.size[1])

    @property
    def clock(self) -> int:
        """Steps learned so far: the time base of ``last_seen``."""
        return int(self.clock_array[0])

    @property
    def has_actions(self) -> bool:
        return bool(self._has_actions)

    @property
    def max_context(self) -> int:
        """Tokens a context holds at most."""
        return 2 * self.max_length if self._has_actions else self.max_length

    @property
    def n_scopes(self) -> int:
        """Distinct action scopes of the views (0: every view sees every action)."""
        return len(self._scopes)

    def scope_masks(self, n_symbols: int) -> np.ndarray:
        """``in_scope[c, s]``: whether symbol ``s`` (of ``n_symbols``) is an action in scope ``c``
        (:func:`slearn.core.views.encode`). Symbols past the vocabulary are values never seen:
        they are in every scope, so a step's scoped actions holding one match no context."""
        vocabulary = self.vocabulary
        known = 0 if vocabulary is None else len(vocabulary)
        if self._in_scope.shape[1] != known:
            mask = np.zeros((len(self._scopes), known), np.uint8)
            for symbol, channel, _ in (vocabulary.items() if self._scopes and vocabulary else ()):
                for c, names in enumerate(self._scopes):
                    if channel in names:
                        mask[c, symbol] = 1
            self._in_scope = mask
        if n_symbols <= known:
            return self._in_scope
        return np.concatenate((self._in_scope, np.ones((len(self._scopes), n_symbols - known), np.uint8)), axis=1)

    def scope_of_view(self, name: str) -> int:
        """The scope a view's stream shows (``ALL_ACTIONS``, ``NO_ACTIONS`` or an index of
        ``StepCodes.scoped``'s columns)."""
        names = self.action_scopes.get(name)
        if names is None:
            return views.ALL_ACTIONS
        return views.NO_ACTIONS if not names else self._scopes.index(names)

    @property
    def factored(self) -> bool:
        """Whether each observation channel is a view of its own."""
        return self.vocabulary is not None

    # --- views ------------------------------------------------------------------------
    def _factored_mapping(self) -> np.ndarray:
        """The view of every symbol of the vocabulary (``NO_VIEW`` for actions)."""
        vocabulary = cast(Vocabulary, self.vocabulary)  # only a factored library maps its symbols
        if len(self._view_of_symbol) == len(vocabulary):
            return self._view_of_symbol
        names = [c for c, role in vocabulary.roles.items() if role == OBSERVATION_ROLE]
        self._ensure_views(names)
        index = {name: i for i, name in enumerate(self.view_names)}
        mapping = np.full(len(vocabulary), NO_VIEW, np.int32)
        for symbol, channel, _ in vocabulary.items():
            mapping[symbol] = index.get(channel, NO_VIEW)
        self._view_of_symbol = mapping
        return mapping

    def prepare(self) -> None:
        """Create the views (and their weights and streams) the vocabulary calls for."""
        if self._has_actions is None and self.vocabulary is not None:
            self._has_actions = any(role != OBSERVATION_ROLE for role in self.vocabulary.roles.values())
        if self.vocabulary is None:
            self._ensure_views([JOINT])
        else:
            self._factored_mapping()
        self._ensure_state()

    def _ensure_views(self, names: list[str]) -> None:
        for name in names:
            if name not in self.view_names:
                self.view_names.append(name)
        self._ensure_state()

    def _ensure_state(self) -> None:
        if self._has_actions is None:
            return
        n = len(self.view_names)
        if self.mixer is None:
            self.mixer = new_mixer(n, self.max_context)
        self.mixer = with_views(self.mixer, n)
        have = 0 if self.streams is None else len(self.streams.root)
        if have < n or self.streams is None:
            self.tree = context_tree.ensure_room(self.tree, n - have, 0)
            roots = np.array([context_tree.add_root(self.tree, v) for v in range(have, n)], np.int32)
            old = self.streams
            self.streams = views.new_view_state(n, self.max_context, np.concatenate(
                (old.root if old is not None else np.zeros(0, np.int32), roots)),
                np.array([self.scope_of_view(name) for name in self.view_names], np.int32))
            if old is not None:
                self.streams.recent[:have] = old.recent
                self.streams.filled[:have] = old.filled
                self.streams.held[:have] = old.held
        if self.past is None or len(self.past.filled) < n:
            old_past, self.past = self.past, new_past(n)
            if old_past is not None:
                for mine, theirs in zip(self.past, old_past):
                    mine[:len(theirs)] = theirs

    # --- learning and predicting ------------------------------------------------------
    def encode(self, episode: Episode, intern: bool = True,
               unknown_views: np.ndarray | None = None) -> StepCodes:
        """The episode as the views see it; ``intern`` adds the tokens never seen (else
        they are ``UNKNOWN``, and the library is left as it is). Symbols past the
        vocabulary are values it never saw: ``unknown_views`` gives their views, in order."""
        if self._has_actions is None:
            if not intern:
                raise ParameterError("the library has learned nothing yet")
            self._has_actions = bool(np.any(episode.n_actions > 0)) if self.vocabulary is None \
                else any(role != OBSERVATION_ROLE for role in self.vocabulary.roles.values())
        if not self._has_actions and np.any(episode.n_actions > 0):
            raise ParameterError("this library learned a stream without actions; an episode with "
                                 "actions needs a library made with has_actions=True")
        self.prepare()
        if self.vocabulary is None:
            mapping = views.joint_mapping(episode)
        else:
            mapping = self._factored_mapping()
            if unknown_views is not None:
                mapping = np.concatenate((mapping, np.asarray(unknown_views, np.int32)))
            if episode.n_events and int(episode.symbols.max()) >= len(mapping):
                raise ParameterError(f"symbol {int(episode.symbols.max())} is not in the "
                                     "library's vocabulary")
        self._ensure_state()
        return views.encode(self.tokens, episode, mapping, intern,
                            self.scope_masks(len(mapping)) if self._scopes else None)

    def learn(self, episode: Episode, new_episode: bool = True) -> None:
        """Learn one episode (its own streams: episodes are never glued together).

        ``new_episode=False`` continues the previous episode (a log read in chunks).
        """
        self.run(self.encode(episode), learn=True, record=False, new_episode=new_episode)

    def run(self, codes: StepCodes, *, learn: bool, record: bool = True, top_k: int = 3,
            new_episode: bool = True, streams: ViewState | None = None,
            baselines: bool = False) -> Reports:
        """Predict (``record``) and/or learn every step of encoded steps.

        ``streams`` runs on other view streams than the library's own (prediction from a
        given history); frozen runs (``learn=False``) change nothing in the library.
        ``baselines`` records the simple rules of :class:`~slearn.core.online.Reports` too.
        """
        out = new_reports(codes.n_reports if (record or baselines) else 0, top_k)
        if len(codes) == 0:
            return out
        self.prepare()
        if self._has_actions is None:
            raise ParameterError("encode an episode with this library before running it")
        state = cast(ViewState, self.streams if streams is None else streams)  # prepared above
        # The reports kept for a new epoch belong to the library's own streams.
        past = cast(Past, self.past) if streams is None else new_past(len(state.filled))
        if new_episode:
            views.restart(state)
            past.filled[:] = 0
            past.since[:] = 0
        run = Run(self.has_actions, self.empty_action, self.empty_observation,
                  self._entry_bound(), learn, record, baselines, new_episode, self.factored)
        step = 0
        while step < len(codes):
            step = run_codes(self.tree, self.mixer, state, past, codes.action, codes.scoped, codes.offsets, codes.view,
                             codes.token, step, self.clock_array, run, out)
            if step < len(codes):
                self._make_room(int(codes.offsets[step + 1] - codes.offsets[step]))
        if learn and self.max_patterns is not None and len(self) > self.max_patterns:
            self.forget(int(self.max_patterns * FORGET_TO))
        return out

    def _entry_bound(self) -> int:
        return np.iinfo(np.int64).max if self.max_patterns is None else self.max_patterns

    def _make_room(self, reports: int) -> None:
        need = self.max_context * max(reports, 1)
        if self.max_patterns is not None and len(self) >= self.max_patterns:
            self.forget(int(self.max_patterns * FORGET_TO))
        self.tree = context_tree.ensure_room(self.tree, need + 64, need + 64)

    # --- forgetting -------------------------------------------------------------------
    def forget(self, keep: int) -> None:
        """Drop the rarest, oldest patterns (longest contexts first on ties) down to ``keep``,
        and every context left without patterns."""
        tree = self.tree
        n_nodes, n_entries = int(tree.size[0]), int(tree.size[1])
        if n_entries <= keep:
            return
        depth = _depths(tree.parent, n_nodes)
        owner = tree.owner[:n_entries]
        order = np.lexsort((np.arange(n_entries), -depth[owner], tree.last_seen[:n_entries],
                            tree.count[:n_entries]))
        alive = np.ones(n_entries, bool)
        alive[order[: n_entries - keep]] = False
        self.forgotten += n_entries - keep
        if self.past is not None:
            self.past.filled[:] = 0  # its nodes are renumbered
        self.tree = _compacted(tree, alive, depth)

    # --- export -----------------------------------------------------------------------
    def patterns(self) -> list[Pattern]:
        """Every pattern, in the order it was first seen."""
        data = self.export()
        out = []
        for i in range(len(data["count"])):
            flat = data["pattern_tokens"][data["pattern_offsets"][i]:data["pattern_offsets"][i + 1]]
            out.append(Pattern(int(data["view"][i]), tuple(flat[:-1].tolist()), int(flat[-1]),
                               int(data["count"][i]), int(data["last_seen"][i]),
                               int(data["fresh"][i])))
        return out

    def export(self) -> dict[str, np.ndarray]:
        """Patterns as flat arrays, in the order they were first seen: ``view``,
        ``pattern_offsets``/``pattern_tokens`` (context oldest first, then the outcome),
        ``count``, ``last_seen``, ``fresh`` (0 where the context's fresh counts belong to an
        older epoch)."""
        tree = self.tree
        m = int(tree.size[1])
        epochs = self.mixer.epoch if self.mixer is not None else np.zeros(0, np.int32)
        offsets, flat, view, fresh = _export(tree.parent, tree.token, tree.epoch, tree.owner,
                                             tree.outcome, tree.fresh, epochs, m,
                                             self.max_context + 1)
        return {"view": view, "pattern_offsets": offsets, "pattern_tokens": flat,
                "count": tree.count[:m].copy(), "last_seen": tree.last_seen[:m].copy(),
                "fresh": fresh}

    @classmethod
    def from_export(cls, arrays: dict[str, np.ndarray], *, tokens: TokenTable, clock: int,
                    view_names: list[str], mixer: Mixer, max_length: int,
                    max_patterns: int | None = None, vocabulary: Vocabulary | None = None,
                    has_actions: bool = True, action_scopes: dict | None = None) -> "PatternLibrary":
        """Rebuild a library from :meth:`export` output, its tokens, views and weights."""
        library = cls(max_length, max_patterns, vocabulary, has_actions, action_scopes)
        library.tokens = tokens
        library.empty_action = tokens.intern(ACTION, ())
        library.empty_observation = tokens.intern(OBSERVATION, ())
        library.clock_array[0] = int(clock)
        library.view_names = list(view_names)
        library.mixer = with_views(mixer, len(view_names))
        library._ensure_state()
        library.add_export(arrays)
        return library

    def rebase(self, *, tokens: TokenTable, clock: int, view_names: list[str], mixer: Mixer,
               vocabulary: Vocabulary | None = None) -> None:
        """Give this library ``tokens`` (a superset keeping its token ids), ``view_names`` (its
        own first), ``mixer`` and ``clock``, keeping its patterns, and restart its streams: a
        merge extends its first library so (:mod:`slearn.jobs.merge`), and merging ``n``
        libraries in turn costs what their own patterns cost, not ``n`` rebuilds of the
        growing union. A view whose epoch ``mixer`` advances has its fresh counts end as
        after an alarm in learning: they are reset when a context is next counted
        (:func:`slearn.core.context_tree.refresh`), and read as none before."""
        if tokens.intern(ACTION, ()) != self.empty_action or tokens.intern(OBSERVATION, ()) != self.empty_observation:
            raise ValueError("rebase needs a token table that keeps this library's token ids")
        self.tokens, self.clock_array[0] = tokens, int(clock)
        if vocabulary is not None:
            self.vocabulary = vocabulary
            self._view_of_symbol = np.zeros(0, np.int32)
            self._in_scope = np.zeros((len(self._scopes), 0), np.uint8)
        self.view_names = list(view_names)
        self.mixer = with_views(mixer, len(view_names))
        self._ensure_state()  # roots, weights and reports for the views new here
        if self.streams is not None:
            self.streams = views.new_view_state(len(view_names), self.max_context, self.streams.root,
                                                self.streams.scope)
            self.past = new_past(len(view_names))

    def add_export(self, arrays: dict[str, np.ndarray], shift: int = 0) -> None:
        """Count the patterns of another library's :meth:`export` (in this library's tokens
        and views) into this one: counts and fresh counts add, a pattern's last occurrence
        becomes ``last_seen + shift`` (the other library ran ``shift`` steps after this one
        began: its occurrences are the later ones), and patterns new here are appended in
        the export's order. So a library rebuilt from one export and then added another is
        the union :mod:`slearn.jobs.merge` defines, in one pass over the patterns."""
        offsets = np.asarray(arrays["pattern_offsets"], np.int64)
        view, flat = np.asarray(arrays["view"], np.int32), np.asarray(arrays["pattern_tokens"], np.int32)
        counts, seen = np.asarray(arrays["count"], np.int64), np.asarray(arrays["last_seen"], np.int64)
        fresh = np.asarray(arrays["fresh"], np.int64)
        n = len(offsets) - 1
        if int(self.tree.size[1]) == 0:  # a library rebuilt: every pattern is an entry, room at once
            self.tree = context_tree.ensure_room(self.tree, 64, n + 64)
        # In pieces, each given room for a new node per token at most: the tree grows with
        # the nodes it really holds (shared prefixes), not with the patterns' total length.
        for lo in range(0, n, _IMPORT_PIECE):
            hi = min(lo + _IMPORT_PIECE, n)
            self.tree = context_tree.ensure_room(self.tree, int(offsets[hi] - offsets[lo]) + 64, hi - lo + 64)
            tree = self.tree
            _import(tree.parent, tree.token, tree.first, tree.best, tree.newest, tree.fresh_best, tree.fresh_total,
                    tree.fresh_outcomes, tree.epoch, tree.node_slots, tree.owner, tree.outcome, tree.count,
                    tree.last_seen, tree.fresh, tree.next, tree.entry_slots, tree.size,
                    cast(ViewState, self.streams).root, cast(Mixer, self.mixer).epoch, view, offsets, flat, counts,
                    seen, fresh, shift, lo, hi)
        tree = self.tree
        _derive_best(tree.first, tree.next, tree.count, tree.last_seen, tree.fresh, tree.outcome,
                     tree.best, tree.newest, tree.fresh_best, tree.fresh_total, tree.fresh_outcomes,
                     int(tree.size[0]))

    def nbytes(self) -> int:
        """Bytes held by the library's arrays (tree, weights, streams, the reports kept for
        a new epoch; not the tokens)."""
        extra = 0 if self.mixer is None else sum(a.nbytes for a in self.mixer)
        extra += 0 if self.streams is None else sum(a.nbytes for a in self.streams)
        extra += 0 if self.past is None else sum(a.nbytes for a in self.past)
        return context_tree.nbytes(self.tree) + extra


def check_scopes(scopes, vocabulary: Vocabulary | None) -> dict[str, tuple[str, ...]]:
    """``scopes`` (``{observation channel: action channels}``, or ``None``) checked and
    normalized: each scope's channels sorted, without repeats.

    Raises:
        ParameterError: scopes without a vocabulary, or not a mapping of channel names to
            lists of channel names, or naming a channel the vocabulary gives another role.
    """
    if not scopes:
        return {}
    if vocabulary is None:
        raise ParameterError("action scopes need a vocabulary: they name channels")
    if not isinstance(scopes, dict) or not all(
            isinstance(k, str) and isinstance(v, (list, tuple)) and all(isinstance(n, str) for n in v)
            for k, v in scopes.items()):
        raise ParameterError("action scopes must map observation channel names to lists of "
                             "action channel names")
    out = {}
    for view, names in scopes.items():
        for name, role in ((view, OBSERVATION_ROLE), *((n, "action") for n in names)):
            if vocabulary.roles.get(name, role) != role:
                raise ParameterError(f"action scope of {view!r}: channel {name!r} has the role "
                                     f"{vocabulary.roles[name]}, not {role}")
        out[view] = tuple(sorted(set(names)))
    return dict(sorted(out.items()))


def check_parameters(max_length: int, max_patterns: int | None) -> None:
    """Refuse parameters no library can work with, naming the limit."""
    if isinstance(max_length, bool) or not isinstance(max_length, (int, np.integer)) \
            or not 1 <= max_length <= MAX_MAX_LENGTH:
        raise ParameterError(f"max_length must be an integer in 1..{MAX_MAX_LENGTH}, "
                             f"not {max_length!r}")
    if max_patterns is not None and (isinstance(max_patterns, bool)
                                     or not isinstance(max_patterns, (int, np.integer))
                                     or not 16 <= max_patterns <= MAX_PATTERNS):
        raise ParameterError(f"max_patterns must be an integer in 16..{MAX_PATTERNS:,}, "
                             f"not {max_patterns!r}")


@kernel
def _depths(parent, n):
    depth = np.zeros(n, np.int32)
    for node in range(n):
        if parent[node] >= 0:
            depth[node] = depth[parent[node]] + 1
    return depth


def _compacted(tree: Tree, alive: np.ndarray, depth: np.ndarray) -> Tree:
    """The tree without the dead entries and the nodes left with neither entries nor children."""
    n_nodes, n_entries = int(tree.size[0]), int(tree.size[1])
    keep_node = np.zeros(n_nodes, bool)
    keep_node[tree.owner[:n_entries][alive]] = True
    keep_node[tree.parent[:n_nodes] < 0] = True
    _keep_ancestors(tree.parent, keep_node)
    node_id = np.cumsum(keep_node) - 1
    kept_nodes, kept_entries = np.flatnonzero(keep_node), np.flatnonzero(alive)
    out = context_tree.new_tree(max(2 * len(kept_nodes), 1024), max(2 * len(kept_entries), 1024))
    parents = tree.parent[kept_nodes]
    out.parent[: len(kept_nodes)] = np.where(parents < 0, -1, node_id[np.maximum(parents, 0)])
    out.token[: len(kept_nodes)] = tree.token[kept_nodes]
    out.epoch[: len(kept_nodes)] = tree.epoch[kept_nodes]
    out.owner[: len(kept_entries)] = node_id[tree.owner[kept_entries]]
    for name in ("outcome", "count", "last_seen", "fresh"):
        getattr(out, name)[: len(kept_entries)] = getattr(tree, name)[kept_entries]
    out.size[:] = (len(kept_nodes), len(kept_entries))
    out.first[: len(kept_nodes)] = -1
    _link_entries(out.owner, out.first, out.next, len(kept_entries))
    _derive_best(out.first, out.next, out.count, out.last_seen, out.fresh, out.outcome, out.best,
                 out.newest, out.fresh_best, out.fresh_total, out.fresh_outcomes, len(kept_nodes))
    context_tree.rebuild_nodes(out.node_slots, out.parent, out.token, len(kept_nodes))
    rebuild(out.entry_slots, out.owner, out.outcome, 0, len(kept_entries))
    return out


@kernel
def _keep_ancestors(parent, keep):
    for node in range(len(keep) - 1, -1, -1):
        if keep[node] and parent[node] >= 0:
            keep[parent[node]] = True


@kernel
def _link_entries(owner, first, nxt, m):
    for e in range(m):  # newest-added entry first, as when learning
        nxt[e] = first[owner[e]]
        first[owner[e]] = e


@kernel
def _derive_best(first, nxt, count, last_seen, fresh, outcome, best, newest, fresh_best, fresh_total,
                 fresh_outcomes, n):
    """Recompute each node's best, newest and freshest entry and its fresh sums from the
    entries' numbers."""
    for node in range(n):
        b, w, f = -1, -1, -1
        total, outcomes = 0, 0
        e = first[node]
        while e != -1:
            total += fresh[e]
            outcomes += 1 if fresh[e] > 0 else 0
            if b == -1 or count[e] > count[b] or (count[e] == count[b] and last_seen[e] > last_seen[b]):
                b = e
            if w == -1 or last_seen[e] > last_seen[w]:
                w = e
            if fresh[e] > 0 and (f == -1 or fresh[e] > fresh[f]
                                 or (fresh[e] == fresh[f] and last_seen[e] > last_seen[f])):
                f = e
            e = nxt[e]
        best[node], newest[node], fresh_best[node] = b, w, f
        fresh_total[node] = min(total, context_tree.SATURATED)
        fresh_outcomes[node] = outcomes


@kernel
def _export(parent, token, node_epoch, owner, outcome, fresh, view_epoch, m, max_tokens):
    offsets = np.zeros(m + 1, np.int64)
    flat = np.empty(m * max_tokens, np.int32)
    view = np.empty(m, np.int32)
    fresh_out = np.zeros(m, np.int64)
    pos = 0
    path = np.empty(max_tokens, np.int32)
    for e in range(m):
        node = owner[e]
        n = 0
        while parent[node] >= 0:
            path[n] = token[node]
            n += 1
            node = parent[node]
        v = token[node]  # the root holds its view
        view[e] = v
        for i in range(n):  # the context, oldest token first (the deepest node holds it)
            flat[pos + i] = path[i]
        flat[pos + n] = outcome[e]
        pos += n + 1
        offsets[e + 1] = pos
        if node_epoch[owner[e]] == view_epoch[v]:
            fresh_out[e] = fresh[e]
    return offsets, flat[:pos].copy(), view, fresh_out


@kernel
def _import(parent, token, first, best, newest, fresh_best, fresh_total, fresh_outcomes, node_epoch, node_slots,
            owner, outcome, count,
            last_seen, fresh, nxt, entry_slots, size, roots, view_epoch, view, offsets, flat, counts, seen,
            fresh_in, shift, lo, hi):
    for i in range(lo, hi):
        start, end = offsets[i], offsets[i + 1]
        node = roots[view[i]]
        h = context_tree.root_path(node)
        for j in range(end - 2, start - 1, -1):  # newest context token first
            h = context_tree.path_hash(h, flat[j])
            node = context_tree.child_or_add(node_slots, parent, token, first, best, newest, fresh_best,
                                            node_epoch, size, node, flat[j], h)
            context_tree.refresh(first, nxt, fresh, fresh_best, fresh_total, fresh_outcomes, node_epoch, node,
                                 view_epoch[view[i]])  # an older epoch's fresh counts end here, as in learning
        e = context_tree.entry_or_add(entry_slots, owner, outcome, count, last_seen, fresh, nxt, first, size,
                                     node, flat[end - 1])
        count[e] += counts[i]
        last_seen[e] = seen[i] + shift
        fresh[e] += fresh_in[i]
