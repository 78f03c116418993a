"""Prediction from a history: what each view observes next, given the actions just issued.

:class:`Predictor` answers from a frozen library (nothing changes, not even the scoring
weights: learning trained them). The history is replayed on scratch view streams, exactly
as the library's own streams would have seen it, and every view gets a prediction for the
step after it. Tokens the library never saw match no context.

One query costs one compiled call: the steps are turned into tokens through a dictionary
kept by the predictor (not one table probe per tuple), the history only moves the view
streams, and the step loop of :mod:`slearn.core.online` predicts the last step alone.
:meth:`Predictor.predict_batch` answers many queries of one episode in one call, as arrays.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from slearn.core._jit import helper, kernel
from slearn.core.context_tree import Tree
from slearn.core.mixer import KINDS, Mixer
from slearn.core.online import Reports, Run, _hold_silent, new_reports, run_codes
from slearn.core.stream import Episode, Step
from slearn.core.tokens import ACTION, OBSERVATION
from slearn.core.views import NO_TOKEN, UNKNOWN, StepCodes, ViewState, new_view_state
from slearn.errors import ParameterError


@dataclass(frozen=True)
class ViewPrediction:
    """One view's prediction.

    Attributes:
        view: the view's index; ``name`` its channel (``"*"``: all observation channels).
        observations: the predicted observation symbols, ``None`` when abstaining.
        score: the chosen context's share behind the prediction.
        length: the chosen context's length in tokens (-1 when abstaining).
        kind: which expert spoke (``frequent``, ``recent``, ``fresh``; ``""`` abstaining).
        ranked: ``(observations, share)`` best first.
    """

    view: int
    name: str
    observations: tuple[int, ...] | None
    score: float
    length: int
    kind: str
    ranked: list[tuple[tuple[int, ...], float]] = field(default_factory=list)

    @property
    def abstained(self) -> bool:
        return self.observations is None


@dataclass(frozen=True)
class Prediction:
    """Every view's prediction for one step."""

    views: list[ViewPrediction]

    @property
    def observations(self) -> tuple[int, ...] | None:
        """The predicted symbols of all views that did not abstain, or ``None``."""
        said = [v.observations for v in self.views if v.observations is not None]
        return tuple(s for symbols in said for s in symbols) if said else None

    @property
    def abstained(self) -> bool:
        return all(v.abstained for v in self.views)


class BatchPrediction(NamedTuple):
    """Many queries' predictions as arrays, query ``i`` and view ``v`` at ``[i, v]``.

    ``token`` is the predicted observation token (-1: abstained), ``score``, ``length`` and
    ``kind`` as in :class:`ViewPrediction` (``kind`` indexes ``slearn.core.mixer.KINDS``, -1),
    ``top``/``top_p`` the ranked tokens (-1 padded) and their shares. A token's symbols are
    ``library.tokens.symbols(token)``; :meth:`Predictor.prediction` gives one query as a
    :class:`Prediction`.
    """

    token: np.ndarray   # int32 (queries, views)
    score: np.ndarray   # float64 (queries, views)
    length: np.ndarray  # int32 (queries, views)
    kind: np.ndarray    # int8 (queries, views)
    top: np.ndarray     # int32 (queries, views, top_k)
    top_p: np.ndarray   # float64 (queries, views, top_k)

    def __len__(self) -> int:
        return len(self.token)


class Predictor:
    """Frozen predictions from a library (:class:`~slearn.core.library.PatternLibrary` or
    :class:`~slearn.core.literal.LiteralLibrary`)."""

    def __init__(self, library, top_k: int = 3) -> None:
        if isinstance(top_k, bool) or not isinstance(top_k, int) or not 1 <= top_k <= 1000:
            raise ParameterError(f"top_k must be an integer in 1..1000, not {top_k!r}")
        self.library = library
        self.top_k = top_k
        self._arrays = None  # what the token dictionaries were built for
        self._known: tuple[int, ...] = ()
        self._state: tuple = (None, None)  # the library's tree and mixer, and as plain tuples
        self._token_of: dict[tuple[int, tuple[int, ...]], int] = {}
        self._symbols_of: dict[int, tuple[int, ...]] = {}

    def predict(self, history: list[Step], actions: tuple[int, ...] = ()) -> Prediction:
        """Predict the observations that follow ``actions`` after the steps in ``history``.

        ``history`` is a list of ``(actions, observations)`` steps of symbols, oldest first.
        """
        return self.predict_unknown(list(history) + [(tuple(actions), ())])

    def predict_unknown(self, steps: list[Step], unknown_views: np.ndarray | None = None) -> Prediction:
        """Predict the observations of the last step of ``steps`` (its observations are
        ignored). Symbols past the vocabulary are values never seen; ``unknown_views``
        gives the view of each (factored libraries)."""
        if self.library.clock == 0 or not self.library.view_names:
            return self._silent()
        if getattr(self.library, "streams", None) is None:
            return self._literal(steps)
        self._refresh()
        codes = self._encode_steps(steps, unknown_views)
        out = self._run_queries(codes, np.zeros(1, np.int64), np.array([len(steps) - 1], np.int64),
                                self._single)
        return self._prediction(out, 0)

    def predict_batch(self, episode: Episode, starts, ends) -> BatchPrediction:
        """Predict step ``ends[i]`` of ``episode`` from its steps ``starts[i]..ends[i] - 1``,
        for every ``i`` in one compiled call: query ``i`` is ``predict(episode.steps()[
        starts[i]:ends[i]], episode.step(ends[i])[0])`` (step ``ends[i]``'s observations
        are ignored), and the answers are the same."""
        starts, ends = np.asarray(starts, np.int64), np.asarray(ends, np.int64)
        if starts.shape != ends.shape or starts.ndim != 1:
            raise ParameterError("starts and ends must be two 1-D sequences of the same length")
        if len(ends) and (starts.min() < 0 or np.any(starts > ends) or ends.max() >= len(episode)):
            raise ParameterError(f"queries need 0 <= starts <= ends < {len(episode)} (the episode's steps)")
        library = self.library
        if library.clock == 0 or not library.view_names or getattr(library, "streams", None) is None:
            return self._batch_of_singles(episode, starts, ends)
        self._refresh()
        codes = library.encode(episode, intern=False)
        out = self._run_queries(codes, starts, ends, _buffers(library, len(ends), self.top_k))
        return _batch(out, len(ends), self._n_views(), self.top_k)

    def prediction(self, batch: BatchPrediction, i: int) -> Prediction:
        """Query ``i`` of a batch as a :class:`Prediction`."""
        names = self.library.view_names
        return Prediction([self._view_of(v, names[v], int(batch.token[i, v]), float(batch.score[i, v]),
                                         int(batch.length[i, v]), int(batch.kind[i, v]),
                                         batch.top[i, v], batch.top_p[i, v])
                           for v in range(self._n_views())])

    # --- internals ----------------------------------------------------------------------
    def _n_views(self) -> int:
        return len(self.library.view_names)

    def _silent(self) -> Prediction:
        return Prediction([ViewPrediction(v, name, None, 0.0, -1, "")
                           for v, name in enumerate(self.library.view_names)])

    def _run_queries(self, codes: StepCodes, starts: np.ndarray, ends: np.ndarray,
                     buffers: tuple) -> Reports:
        """Every view's report at step ``ends[i]`` after replaying ``starts[i]..``: row
        ``i * views + v`` of ``buffers``' reports (``_buffers``; one query's are kept by
        the predictor: allocating them costs more than the query)."""
        library = self.library
        scratch, out, q_view, q_token, run = buffers
        span = int((ends - starts).max()) + 2 if len(ends) else 2
        if library.tree is not self._state[0] or library.mixer is not self._state[1]:
            self._state = (library.tree, library.mixer, tuple(library.tree), tuple(library.mixer))
        # Plain tuples: numba types a NamedTuple argument in Python, microseconds per call.
        _predict_queries(self._state[2], self._state[3], scratch, codes.action, codes.offsets,
                         codes.view, codes.token, starts, ends, q_view, q_token,
                         np.zeros(span, np.int64), library.clock_array, *run, tuple(out))
        return out

    def _prediction(self, out: Reports, i: int) -> Prediction:
        names, n_views = self.library.view_names, self._n_views()
        return Prediction([self._view_of(v, names[v], int(out.predicted[i * n_views + v]),
                                         float(out.score[i * n_views + v]),
                                         int(out.length[i * n_views + v]), int(out.kind[i * n_views + v]),
                                         out.top[i * n_views + v], out.top_p[i * n_views + v])
                           for v in range(n_views)])

    def _view_of(self, v: int, name: str, token: int, score: float, length: int, kind: int,
                 top: np.ndarray, top_p: np.ndarray) -> ViewPrediction:
        if token < 0:
            return ViewPrediction(v, name, None, 0.0, -1, "")
        symbols = self._symbols
        ranked = [(symbols(t), p) for t, p in zip(top.tolist(), top_p.tolist()) if t >= 0]
        return ViewPrediction(v, name, symbols(token), score, length, KINDS[kind], ranked)

    def _symbols(self, token: int) -> tuple[int, ...]:
        found = self._symbols_of.get(token)
        if found is None:
            found = self._symbols_of[token] = self.library.tokens.symbols(token)
        return found

    def _batch_of_singles(self, episode: Episode, starts: np.ndarray, ends: np.ndarray) -> BatchPrediction:
        """Libraries without view streams (the literal rule), or empty: query by query."""
        steps, n_views, k = episode.steps(), self._n_views(), self.top_k
        out = new_reports(len(ends) * n_views, k)
        table = self.library.tokens
        for i, (s, e) in enumerate(zip(starts.tolist(), ends.tolist())):
            prediction = self.predict(steps[s:e], steps[e][0])
            for v, view in enumerate(prediction.views):
                r = i * n_views + v
                if view.abstained:
                    continue
                out.predicted[r] = table.find(OBSERVATION, view.observations)
                out.score[r], out.length[r] = view.score, view.length
                out.kind[r] = KINDS.index(view.kind)
                for j, (symbols, share) in enumerate(view.ranked[:k]):
                    out.top[r, j], out.top_p[r, j] = table.find(OBSERVATION, symbols), share
        return _batch(out, len(ends), n_views, k)

    # --- steps to tokens ----------------------------------------------------------------
    def _token(self, kind: int, symbols: tuple[int, ...]) -> int:
        """The token of a tuple (``UNKNOWN``: never seen). Only tokens the library holds are
        remembered, so the dictionary stays as small as the token table whatever is asked."""
        key = (kind, symbols)
        found = self._token_of.get(key)
        if found is None:
            found = self.library.tokens.find(kind, symbols)
            if found < 0:
                return UNKNOWN
            self._token_of[key] = found
        return found

    def _refresh(self) -> None:
        """Forget the dictionaries when the library learned tokens or views since."""
        library = self.library
        arrays, known = library.tokens.arrays, (len(library.tokens), len(library.view_names))
        if arrays is not self._arrays or known != self._known:
            library.prepare()
            self._arrays, self._known, self._token_of, self._symbols_of = arrays, known, {}, {}
            self._single = _buffers(library, 1, self.top_k)

    def _encode_steps(self, steps: list[Step], unknown_views: np.ndarray | None) -> StepCodes:
        """``library.encode(Episode.from_steps(steps), intern=False)`` with the last step's
        observations dropped, through the token dictionary."""
        library = self.library
        steps = [(tuple(a), tuple(o)) for a, o in steps[:-1]] + [(tuple(steps[-1][0]), ())]
        if not library.has_actions and any(a for a, _ in steps):
            raise ParameterError("this library learned a stream without actions; an episode with "
                                 "actions needs a library made with has_actions=True")
        if library.vocabulary is None:
            _check_joint(steps)
            view_of = None
        else:
            view_of = library._factored_mapping()
            if unknown_views is not None and len(unknown_views):
                view_of = np.concatenate((view_of, np.asarray(unknown_views, np.int32)))
            _check_vocabulary(steps, len(view_of))
            view_of = view_of.tolist()
        return self._codes_of(steps, view_of)

    def _codes_of(self, steps: list[Step], view_of) -> StepCodes:
        """Steps as codes; ``view_of`` maps symbols to views (``None``: one joint view)."""
        token, known = self._token, self._token_of.get
        actions, offsets, views, tokens = [], [0], [], []
        for acts, obs in steps:
            key = (ACTION, acts)
            t = known(key)
            actions.append(t if t is not None else token(*key))
            if obs:
                for v, group in ((0, obs),) if view_of is None else _by_view(obs, view_of):
                    key = (OBSERVATION, group)
                    t = known(key)
                    views.append(v)
                    tokens.append(t if t is not None else token(*key))
            offsets.append(len(views))
        return StepCodes(np.array(actions, np.int32), np.array(offsets, np.int64),
                         np.array(views, np.int32), np.array(tokens, np.int32))

    def _literal(self, steps: list[Step]) -> Prediction:
        library = self.library
        codes = library.encode(Episode.from_steps(steps[:-1] + [(tuple(steps[-1][0]), ())]), intern=False)
        n_views = self._n_views()
        offsets = codes.offsets.copy()
        offsets[-1] = offsets[-2] + n_views  # the last step reports every view, truth unknown
        codes = StepCodes(codes.action, offsets,
                          np.concatenate((codes.view[: offsets[-2]], np.arange(n_views, dtype=np.int32))),
                          np.concatenate((codes.token[: offsets[-2]], np.full(n_views, UNKNOWN, np.int32))))
        out = library.run(codes, learn=False, record=True, top_k=self.top_k)
        first = int(codes.offsets[-2])
        return Prediction([self._view_of(v, library.view_names[v], int(out.predicted[first + v]),
                                         float(out.score[first + v]), int(out.length[first + v]),
                                         int(out.kind[first + v]), out.top[first + v], out.top_p[first + v])
                           for v in range(n_views)])


def _check_joint(steps: list[Step]) -> None:
    """Without a vocabulary every observation symbol is view 0: no symbol may be both an
    action and an observation (``views.joint_mapping``)."""
    acted = {s for a, _ in steps for s in a}
    if acted and any(s in acted for _, o in steps for s in o):
        raise ParameterError("a symbol is used both as an action and as an observation: "
                             "give the library a vocabulary")


def _check_vocabulary(steps: list[Step], known: int) -> None:
    top = max((s for a, o in steps for s in (*a, *o)), default=-1)
    if top >= known:
        raise ParameterError(f"symbol {top} is not in the library's vocabulary")


def _by_view(obs: tuple[int, ...], view_of) -> list[tuple[int, tuple[int, ...]]]:
    """A step's observations grouped by view, views in order (``views._encode``)."""
    groups: dict[int, list[int]] = {}
    for s in obs:
        v = view_of[s]
        if v >= 0:
            groups.setdefault(v, []).append(s)
    return [(v, tuple(groups[v])) for v in sorted(groups)]


def _buffers(library, queries: int, top_k: int) -> tuple:
    """Scratch streams, reports, the last steps' report layout and the run's scalars."""
    n_views = len(library.view_names)
    n = queries * n_views
    run = (library.has_actions, library.empty_action, library.empty_observation)
    return (tuple(new_view_state(n_views, library.max_context, library.streams.root)), new_reports(n, top_k),
            np.tile(np.arange(n_views, dtype=np.int32), queries), np.full(n, UNKNOWN, np.int32), run)


def _batch(out: Reports, queries: int, n_views: int, top_k: int) -> BatchPrediction:
    shape = (queries, n_views)
    return BatchPrediction(out.predicted.reshape(shape), out.score.reshape(shape),
                           out.length.reshape(shape), out.kind.reshape(shape),
                           out.top.reshape(shape + (top_k,)), out.top_p.reshape(shape + (top_k,)))


_NO_BOUND = np.iinfo(np.int64).max  # frozen runs add no entries


@kernel
def _predict_queries(tree_arrays, mixer_arrays, scratch_arrays, action, offsets, view, token, starts,
                     ends, q_view, q_token, q_offsets, clock, has_actions, empty_action,
                     empty_observation, out_arrays):
    """For query ``i``: replay steps ``starts[i]..ends[i] - 1`` on fresh scratch streams, then
    run step ``ends[i]`` (its action; every view reporting ``q_token``) through ``run_codes``,
    as if the query's steps were an episode of their own. Rows ``i * views ..`` of ``out``.
    State comes as plain tuples of arrays (the fields of ``Tree``, ``Mixer``, ``ViewState``,
    ``Reports``)."""
    tree, mixer, scratch = Tree(*tree_arrays), Mixer(*mixer_arrays), ViewState(*scratch_arrays)
    out = Reports(*out_arrays)
    run = Run(has_actions, empty_action, empty_observation, _NO_BOUND, False, True, False, True)
    recent, filled, held = scratch.recent, scratch.filled, scratch.held
    n_views = len(filled)
    for i in range(len(starts)):
        s, e = starts[i], ends[i]
        filled[:] = 0
        held[:] = NO_TOKEN
        for step in range(s, e):
            _replay_step(recent, filled, held, action[step], step > s, view, token, offsets[step],
                         offsets[step + 1], run.has_actions, run.empty_action, run.empty_observation)
        j = e - s
        q_action = action[s:e + 1]
        q_offsets[j] = i * n_views
        q_offsets[j + 1] = (i + 1) * n_views
        _abstain(out, i * n_views, (i + 1) * n_views)
        run_codes(tree, mixer, scratch, q_action, q_offsets[:j + 2], q_view, q_token, j, clock, run, out)


@helper
def _abstain(out, r0, r1):
    """Rows ``r0..r1`` of ``out`` as ``new_reports`` makes them (buffers are reused)."""
    for r in range(r0, r1):
        out.predicted[r] = -1
        out.length[r] = -1
        out.kind[r] = -1
        out.score[r] = 0.0
        out.truth_p[r] = 0.0
        out.context[r] = False
        out.markov[r] = -1
        out.frequency[r] = -1
        out.persistence[r] = -1
        for k in range(out.top.shape[1]):
            out.top[r, k] = -1
            out.top_p[r, k] = 0.0


@helper
def _replay_step(recent, filled, held, a, later, view, token, r0, r1, has_actions, empty_action,
                 empty_observation):
    """One history step on the view streams, as ``run_codes`` moves them without learning
    or recording (the first step of an episode pushes no empty action)."""
    K = recent.shape[1]
    push_action = has_actions and (later or a != empty_action)
    if push_action:
        for v in range(len(filled)):
            recent[v, filled[v] % K] = a
            filled[v] += 1
    for r in range(r0, r1):
        v = view[r]
        recent[v, filled[v] % K] = token[r]
        filled[v] += 1
        held[v] = token[r]
    if push_action:
        _hold_silent(recent, filled, held, view, r0, r1, empty_observation)
