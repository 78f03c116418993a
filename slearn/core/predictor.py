"""Prediction from a history: what each view observes next, given the actions just issued.

:class:`Predictor` answers from a frozen library (nothing changes, not even the scoring
weights: learning trained them). The history is replayed on scratch view streams, exactly
as the library's own streams would have seen it, and every view gets a prediction for the
step after it. Tokens the library never saw match no context.

One query costs one compiled call of three scalars: the steps are turned into tokens
through a dictionary kept by the predictor (not one table probe per tuple) and copied to a
buffer the call's address table points to; the history only moves the view streams, and
the last step is predicted as the step loop of :mod:`slearn.core.online` predicts it.
:meth:`Predictor.predict_batch` answers many queries of one episode in one call, as arrays.
Since nothing changes while the library does not learn, answers are remembered: per query
(a stream's queries repeat), per view's context and per chosen context's ranking
(:class:`Memo`); learning empties them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from slearn.core._jit import helper, kernel
from slearn.core.addresses import address_table, cube, matrix, vector
from slearn.core.context_tree import Tree, child
from slearn.core.mixer import KINDS, N_KINDS, Mixer, select
from slearn.core.online import Reports, candidates, hold_silent, new_reports, record_prediction
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
    ranked: tuple[tuple[tuple[int, ...], float], ...] = ()

    @property
    def abstained(self) -> bool:
        return self.observations is None


@dataclass(frozen=True)
class Prediction:
    """Every view's prediction for one step (immutable: a predictor hands the same object
    to every query it was asked before)."""

    views: tuple[ViewPrediction, ...]

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
        self._single: Buffers  # one query's buffers (made by _refresh)
        self._flat_bytes = memoryview(b"")  # their flat codes' bytes, written by _run_flat
        self._single_state: tuple = (None, None)  # the tree and mixer its table points to
        self._single_table = np.zeros(0, np.int64)
        self._token_of: dict[tuple[int, tuple[int, ...]], int] = {}
        self._symbols_of: dict[int, tuple[int, ...]] = {}
        self._step_codes: dict = {}  # step -> its flat codes' bytes, see _step_code
        self._answers: dict = {}     # (history, actions) -> Prediction, for the library's clock
        self._made: dict = {}        # reports -> Prediction, see _single_prediction
        self._clock = -1
        self._acted: set = set()     # symbols the cached steps use as actions,
        self._observed: set = set()  # and as observations

    def predict(self, history: list[Step], actions: tuple[int, ...] = ()) -> Prediction:
        """Predict the observations that follow ``actions`` after the steps in ``history``.

        ``history`` is a list of ``(actions, observations)`` steps of symbols, oldest first.
        """
        library = self.library
        if library.clock and library.view_names and getattr(library, "streams", None) is not None:
            self._refresh()
            actions = actions if type(actions) is tuple else tuple(actions)
            key: tuple | None = (tuple(history), actions) if len(history) <= _KEY_STEPS else None
            try:
                said = self._answers.get(key) if key is not None else None
            except TypeError:  # steps of lists: not a key
                key, said = None, None
            if said is not None:
                return said
            flat = self._cached_codes(history, actions)
            if flat is not None:
                said = self._single_prediction(self._run_flat(flat))
                if key is not None:
                    self._answers = _kept(self._answers, key, said, self._n_views())
                return said
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
        return self._single_prediction(self._run_flat(self._encode_steps(steps, unknown_views)))

    def predict_batch(self, episode: Episode, starts, ends,
                      unknown_views: np.ndarray | None = None) -> BatchPrediction:
        """Predict step ``ends[i]`` of ``episode`` from its steps ``starts[i]..ends[i] - 1``,
        for every ``i`` in one compiled call: query ``i`` is ``predict(episode.steps()[
        starts[i]:ends[i]], episode.step(ends[i])[0])`` (step ``ends[i]``'s observations
        are ignored), and the answers are the same. Symbols past the vocabulary are values
        never seen, as in :meth:`predict_unknown`, with ``unknown_views`` their views."""
        starts, ends = np.asarray(starts, np.int64), np.asarray(ends, np.int64)
        if starts.shape != ends.shape or starts.ndim != 1:
            raise ParameterError("starts and ends must be two 1-D sequences of the same length")
        if len(ends) and (starts.min() < 0 or np.any(starts > ends) or ends.max() >= len(episode)):
            raise ParameterError(f"queries need 0 <= starts <= ends < {len(episode)} (the episode's steps)")
        library = self.library
        if library.clock == 0 or not library.view_names or getattr(library, "streams", None) is None:
            return self._batch_of_singles(episode, starts, ends, unknown_views)
        self._refresh()
        codes = library.encode(episode, intern=False, unknown_views=unknown_views)
        out = self._run(codes, starts, ends, _buffers(library, len(ends), self.top_k))
        return _batch(out, len(ends), self._n_views(), self.top_k)

    def prediction(self, batch: BatchPrediction, i: int) -> Prediction:
        """Query ``i`` of a batch as a :class:`Prediction`."""
        return self._prediction_of(*(a[i].tolist() for a in batch))

    # --- internals ----------------------------------------------------------------------
    def _n_views(self) -> int:
        return len(self.library.view_names)

    def _silent(self) -> Prediction:
        return Prediction(tuple(ViewPrediction(v, name, None, 0.0, -1, "")
                                for v, name in enumerate(self.library.view_names)))

    def _run_flat(self, flat: bytes) -> Reports:
        """The last step of the flat codes of ``_cached_codes`` predicted from the steps
        before it: one compiled call of three scalar arguments (the codes are copied into
        the single query's buffer, which its kept address table points to)."""
        size = len(flat) // 4
        if size > len(self._single.query.flat):
            self._single = self._single._replace(query=_single_query(self._single.query.run, size))
            self._single_state, self._flat_bytes = (None, None), self._single.query.flat.data.cast("B")
        library = self.library
        if library.tree is not self._single_state[0] or library.mixer is not self._single_state[1]:
            self._single_table = _state_table((library.tree, library.mixer), self._single)
            self._single_state = (library.tree, library.mixer)
        self._flat_bytes[:len(flat)] = flat
        _predict_queries(self._single_table, size, True)
        return self._single.out

    def _run(self, codes: StepCodes, starts: np.ndarray, ends: np.ndarray, buffers: Buffers) -> Reports:
        """Every view's report at step ``ends[i]`` after replaying ``starts[i]..``: row
        ``i * views + v`` of the reports of ``buffers`` (new ones, ``_buffers``)."""
        library = self.library
        query = buffers.query._replace(action=codes.action, offsets=codes.offsets, view=codes.view,
                                       token=codes.token, starts=starts, ends=ends)
        table = _state_table((library.tree, library.mixer), buffers._replace(query=query))
        _predict_queries(table, -1, False)
        return buffers.out

    def _single_prediction(self, out: Reports) -> Prediction:
        """``out``'s reports, one per view (the single-query buffers), as a
        :class:`Prediction`: the one made before for the same reports, if any (queries
        that differ often get the same answer, and an answer is many small objects)."""
        said = (out.predicted, out.score, out.length, out.kind, out.top, out.top_p)
        key = b"".join([a.tobytes() for a in said])
        made = self._made.get(key)
        if made is None:
            made = self._prediction_of(*(a.tolist() for a in said))
            self._made = _kept(self._made, key, made, self._n_views())
        return made

    def _prediction_of(self, token: list, score: list, length: list, kind: list, top: list,
                       top_p: list) -> Prediction:
        """A :class:`Prediction` from per-view lists: the predicted token (-1: abstained),
        its share, context length and expert kind, and the ranked tokens and shares."""
        symbols, names = self._symbols, self.library.view_names
        views = []
        for v, (t, share, n, k, ranked, shares) in enumerate(zip(token, score, length, kind, top, top_p)):
            if t < 0:
                views.append(_view_prediction(v, names[v], None, 0.0, -1, "", ()))
            else:
                views.append(_view_prediction(v, names[v], symbols(t), share, n, KINDS[k],
                                              tuple([(symbols(x), p) for x, p in zip(ranked, shares) if x >= 0])))
        return _prediction(tuple(views))

    def _symbols(self, token: int) -> tuple[int, ...]:
        found = self._symbols_of.get(token)
        if found is None:
            found = self._symbols_of[token] = self.library.tokens.symbols(token)
        return found

    def _batch_of_singles(self, episode: Episode, starts: np.ndarray, ends: np.ndarray,
                          unknown_views: np.ndarray | None = None) -> BatchPrediction:
        """Libraries without view streams (the literal rule), or empty: query by query."""
        steps, n_views, k = episode.steps(), self._n_views(), self.top_k
        out = new_reports(len(ends) * n_views, k)
        table = self.library.tokens
        for i, (s, e) in enumerate(zip(starts.tolist(), ends.tolist())):
            prediction = self.predict_unknown(steps[s:e] + [(steps[e][0], ())], unknown_views)
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
        """Forget the answers when the library learned since, and the dictionaries when it
        learned tokens or views."""
        library = self.library
        clock = library.clock
        arrays, known = library.tokens.arrays, (len(library.tokens), len(library.view_names))
        if arrays is not self._arrays or known != self._known:
            library.prepare()
            self._arrays, self._known, self._token_of, self._symbols_of = arrays, known, {}, {}
            self._made = {}
            self._step_codes, self._acted, self._observed = {}, set(), set()
            self._single = _buffers(library, 1, self.top_k, _SINGLE_MEMO)
            self._single = self._single._replace(query=_single_query(self._single.query.run, 64))
            self._single_state, self._flat_bytes = (None, None), self._single.query.flat.data.cast("B")
            self._clock = -1
        if clock != self._clock:
            self._clock, self._answers = clock, {}
            forget(self._single.memo)

    def _encode_steps(self, steps: list[Step], unknown_views: np.ndarray | None) -> bytes:
        """``library.encode(Episode.from_steps(steps), intern=False)`` with the last step's
        observations dropped, through the token dictionary, as flat codes (``_codes_of``)."""
        steps = [(tuple(a), tuple(o)) for a, o in steps[:-1]] + [(tuple(steps[-1][0]), ())]
        return self._checked_codes(steps, unknown_views)

    def _checked_codes(self, steps: list[Step], unknown_views: np.ndarray | None) -> bytes:
        """Steps of tuples as flat codes, after the checks every query gets: actions only for a
        library that learned them, symbols the library's views know (or ``unknown_views``
        places), no symbol both an action and an observation without a vocabulary."""
        library = self.library
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

    def _cached_codes(self, history, actions: tuple) -> bytes | None:
        """``_encode_steps(history + [(actions, ())])`` as the bytes of flat ``int32`` codes
        (per step its action token, its number of observations, then a view and a token
        for each; ``_predict_queries`` reads them), through a dictionary of steps already
        encoded (a stream's steps repeat), or ``None`` when a step is not a tuple of tuples
        (then the general path encodes it). Checks what ``_encode_steps`` checks: an unseen
        step on entry; a symbol used both as an action and as an observation across the
        steps only while the cached steps do so at all (otherwise no query of them can)."""
        cache = self._step_codes
        last = (actions, ())
        parts = []
        for step in (*history, last):
            try:
                code = cache.get(step)
            except TypeError:  # lists: not a key
                return None
            if code is None:
                if type(step) is not tuple or len(step) != 2 or type(step[0]) is not tuple \
                        or type(step[1]) is not tuple:
                    return None
                code = self._step_code(step)
            parts.append(code)
        if self.library.vocabulary is None and not self._acted.isdisjoint(self._observed):
            _check_joint([*history, last])
        return b"".join(parts)

    def _step_code(self, step: Step) -> bytes:
        """One step's codes (its action token, its number of observations, then a view and
        a token for each) as the bytes of ``int32``s, checked as ``_encode_steps`` checks
        them, and cached (joining bytes is the cheapest way to one array)."""
        acts, obs = step
        code = self._checked_codes([step], None)
        if len(self._step_codes) >= _STEP_CODES:
            self._step_codes, self._acted, self._observed = {}, set(), set()
        self._step_codes[step] = code
        self._acted.update(acts)
        self._observed.update(obs)
        return code

    def _codes_of(self, steps: list[Step], view_of) -> bytes:
        """Steps as flat codes, the bytes of ``int32``s: per step its action token, its
        number of observation tokens, then a view and a token for each; ``view_of`` maps
        symbols to views (``None``: one joint view)."""
        token, known = self._token, self._token_of.get
        flat: list[int] = []
        for acts, obs in steps:
            key = (ACTION, acts)
            t = known(key)
            flat.append(t if t is not None else token(*key))
            groups = (((0, obs),) if view_of is None else _by_view(obs, view_of)) if obs else ()
            flat.append(len(groups))
            for v, group in groups:
                key = (OBSERVATION, group)
                t = known(key)
                flat += (v, t if t is not None else token(*key))
        return np.array(flat, np.int32).tobytes()

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
        return self._single_prediction(Reports(*(a[first:first + n_views] for a in out)))


def _view_prediction(view: int, name: str, observations: tuple[int, ...] | None, score: float,
                     length: int, kind: str, ranked: tuple) -> ViewPrediction:
    """``ViewPrediction(view, name, ...)``, made in a quarter of the time: a frozen
    dataclass's ``__init__`` sets each field through ``object.__setattr__`` (1.2 us of a
    query's 5); this fills the new instance's dictionary directly (0.3 us), the same object."""
    made = _new(ViewPrediction)
    fields = made.__dict__
    fields["view"] = view
    fields["name"] = name
    fields["observations"] = observations
    fields["score"] = score
    fields["length"] = length
    fields["kind"] = kind
    fields["ranked"] = ranked
    return made


def _prediction(views: tuple[ViewPrediction, ...]) -> Prediction:
    """``Prediction(views)``, made as :func:`_view_prediction` makes a view's."""
    made = _new(Prediction)
    made.__dict__["views"] = views
    return made


_new = object.__new__


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


class Memo(NamedTuple):
    """Answers a query run remembers, in direct-mapped slots: by a view's context (its last
    tokens, ``window[slot] = (view, tokens...)``, ``depth`` -1 when empty; the answer in
    row ``slot``), and rankings by the chosen context and expert (``rank_key``, -1 when
    empty; the answer in row ``slots + slot``). Frozen, an answer whose outcome is unknown
    is a function of the view's context alone: it fixes the contexts found, the experts'
    candidates, the choice (the weights do not move) and the ranking."""

    depth: np.ndarray      # int32 (slots,)
    window: np.ndarray     # int32 (slots, max_context + 1)
    rank_key: np.ndarray   # int64 (slots,)
    predicted: np.ndarray  # the answers, as in Reports (2 * slots rows)
    length: np.ndarray
    kind: np.ndarray
    score: np.ndarray
    top: np.ndarray
    top_p: np.ndarray


def new_memo(slots: int, max_context: int, top_k: int) -> Memo:
    """An empty memo of ``slots`` (a power of two)."""
    said = new_reports(2 * slots, top_k)
    return Memo(np.full(slots, -1, np.int32), np.zeros((slots, max_context + 1), np.int32),
                np.full(slots, -1, np.int64), said.predicted, said.length, said.kind, said.score, said.top,
                said.top_p)


def forget(memo: Memo) -> None:
    """Empty every slot (the library learned)."""
    memo.depth.fill(-1)
    memo.rank_key.fill(-1)


class Query(NamedTuple):
    """What a query run asks: the run's scalars (``has_actions``, ``empty_action``,
    ``empty_observation``), then either a single query's flat codes (see
    ``Predictor._codes_of``) or encoded steps and each query's bounds."""

    run: np.ndarray      # int32[3]
    flat: np.ndarray     # int32
    action: np.ndarray   # int32 per step
    offsets: np.ndarray  # int64 per step + 1
    view: np.ndarray     # int32 per observation
    token: np.ndarray    # int32 per observation
    starts: np.ndarray   # int64 per query
    ends: np.ndarray     # int64 per query


class Buffers(NamedTuple):
    """Everything a query run works in besides the library's own state."""

    scratch: ViewState  # streams the history is replayed on
    out: Reports
    q_token: np.ndarray  # the outcome of each report (unknown)
    memo: Memo
    query: Query


_MEMO = 1 << 14        # slots of a batch's memo at most (one per query and view up to it)
_SINGLE_MEMO = 1 << 10  # slots of the memo a predictor keeps for its single queries
_NO_I32, _NO_I64 = np.zeros(0, np.int32), np.zeros(0, np.int64)


def _buffers(library, queries: int, top_k: int, slots: int | None = None) -> Buffers:
    """The buffers of ``queries`` queries, with a memo of ``slots`` (else one per query and
    view up to ``_MEMO``)."""
    n_views = len(library.view_names)
    n = queries * n_views
    run = np.array([library.has_actions, library.empty_action, library.empty_observation], np.int32)
    if slots is None:
        slots = 1 << max(0, min(n, _MEMO) - 1).bit_length()
    return Buffers(new_view_state(n_views, library.max_context, library.streams.root), new_reports(n, top_k),
                   np.full(n, UNKNOWN, np.int32), new_memo(slots, library.max_context, max(top_k, 1)),
                   Query(run, _NO_I32, _NO_I32, _NO_I64, _NO_I32, _NO_I32, _NO_I64, _NO_I64))


def _single_query(run: np.ndarray, size: int) -> Query:
    """A single query's buffers for ``size`` flat codes at least (capacity doubles): its
    steps take fewer entries than its codes."""
    n = 1 << max(size - 1, 1).bit_length()
    return Query(run, np.zeros(n, np.int32), np.zeros(n, np.int32), np.zeros(n + 1, np.int64),
                 np.zeros(n, np.int32), np.zeros(n, np.int32), np.zeros(1, np.int64), np.zeros(1, np.int64))


def _batch(out: Reports, queries: int, n_views: int, top_k: int) -> BatchPrediction:
    shape = (queries, n_views)
    return BatchPrediction(out.predicted.reshape(shape), out.score.reshape(shape),
                           out.length.reshape(shape), out.kind.reshape(shape),
                           out.top.reshape(shape + (top_k,)), out.top_p.reshape(shape + (top_k,)))


_STEP_CODES = 1 << 16    # steps a predictor remembers the codes of
_ANSWER_CACHE = 1 << 14  # views' answers a predictor remembers, per query and per answer
_KEY_STEPS = 64          # the longest history whose answer is remembered (memory: a query
#                          remembered keeps its steps; a longer history is rarely asked again)


def _kept(cache: dict, key, value, n_views: int) -> dict:
    """``cache`` with ``key: value``, emptied first when full: when it holds the answers of
    ``_ANSWER_CACHE`` views (an answer of many views is as large as many answers). What was
    asked recently comes back soon in a stream."""
    if len(cache) * max(n_views, 1) >= _ANSWER_CACHE:
        cache = {}
    cache[key] = value
    return cache


def _state_table(state: tuple, buffers: Buffers) -> np.ndarray:
    """The arrays of a query run as one address table, in the order ``_predict_queries``
    reads them: the tree's fields, the mixer's, the scratch streams', the reports',
    ``q_token``, the memo's, then the query's. The caller keeps them alive."""
    tree, mixer = state
    scratch, out, q_token, memo, query = buffers
    return address_table((*tree, *mixer, *scratch, *out, q_token, *memo, *query))


_TREE, _MIXER, _SCRATCH, _OUT = 0, len(Tree._fields), len(Tree._fields) + len(Mixer._fields), \
    len(Tree._fields) + len(Mixer._fields) + len(ViewState._fields)
_QUERY = _OUT + len(Reports._fields)
_MEMO_AT = _QUERY + 1
_QUERY_AT = _MEMO_AT + len(Memo._fields)


@kernel
def _predict_queries(table, n_flat, reused):
    """For query ``i`` of the table's :class:`Query`: replay steps ``starts[i]..ends[i] - 1``
    on fresh scratch streams, as if they were an episode of their own, then predict every view at step ``ends[i]`` (its
    action pushed) as ``run_codes`` does frozen: rows ``i * views ..`` of ``out``, with
    ``q_token`` as the outcome. ``n_flat >= 0``: one query, the first ``n_flat`` flat
    codes. ``out`` holds abstentions (``new_reports``) unless ``reused`` (then each query's
    rows are reset first). Answers with an unknown outcome are remembered in the table's
    :class:`Memo`, which stays valid while the library does not learn. Everything comes
    as one address table (``_state_table``): numba wraps every array argument on every
    call, which cost more than a small query; for the same reason the query step is walked
    here, not by a call of ``run_codes``."""
    i32, i64, f64 = np.int32, np.int64, np.float64
    t, m, sc, o = _TREE, _MIXER, _SCRATCH, _OUT
    tree = Tree(vector(table, t, i32), vector(table, t + 1, i32), vector(table, t + 2, i32),
                vector(table, t + 3, i32), vector(table, t + 4, i32), vector(table, t + 5, i32),
                vector(table, t + 6, i32), vector(table, t + 7, i32), vector(table, t + 8, i32),
                vector(table, t + 9, i32), vector(table, t + 10, i64), vector(table, t + 11, i64),
                vector(table, t + 12, i64), vector(table, t + 13, i32), vector(table, t + 14, i32),
                vector(table, t + 15, i64))
    mixer = Mixer(cube(table, m, f64), matrix(table, m + 1, f64), vector(table, m + 2, i32))
    scratch = ViewState(matrix(table, sc, i32), vector(table, sc + 1, i64), vector(table, sc + 2, i32),
                        vector(table, sc + 3, i32))
    out = Reports(vector(table, o, i32), vector(table, o + 1, i32), vector(table, o + 2, np.int8),
                  vector(table, o + 3, f64), vector(table, o + 4, f64), matrix(table, o + 5, i32),
                  matrix(table, o + 6, f64), vector(table, o + 7, np.bool_), vector(table, o + 8, i32),
                  vector(table, o + 9, i32), vector(table, o + 10, i32))
    q_token = vector(table, _QUERY, i32)
    parent, tok_of, first, best, newest = tree.parent, tree.token, tree.first, tree.best, tree.newest
    fresh_best, node_epoch, node_slots = tree.fresh_best, tree.epoch, tree.node_slots
    outcome, count, last_seen, fresh, nxt = tree.outcome, tree.count, tree.last_seen, tree.fresh, tree.next
    weights, epoch = mixer.weight, mixer.epoch
    recent, filled, held, root = scratch.recent, scratch.filled, scratch.held, scratch.root
    K = recent.shape[1]
    n_views = len(filled)
    nodes = np.empty(K + 1, np.int32)
    cand = np.full((K + 1, N_KINDS), -1, np.int32)
    top_k = out.top.shape[1]
    ranked = np.empty(top_k, np.int32)
    mm = _MEMO_AT  # answers remembered (see Memo)
    memo_depth, memo_window, rank_key = vector(table, mm, i32), matrix(table, mm + 1, i32), vector(table, mm + 2, i64)
    memo_said, memo_length, memo_kind = vector(table, mm + 3, i32), vector(table, mm + 4, i32), \
        vector(table, mm + 5, np.int8)
    memo_score, memo_top, memo_p = vector(table, mm + 6, f64), matrix(table, mm + 7, i32), matrix(table, mm + 8, f64)
    size = len(memo_depth)
    qa = _QUERY_AT
    run = vector(table, qa, i32)
    has_actions, empty_action, empty_observation = run[0] != 0, run[1], run[2]
    action, offsets, view, token = vector(table, qa + 2, i32), vector(table, qa + 3, i64), \
        vector(table, qa + 4, i32), vector(table, qa + 5, i32)
    starts, ends = vector(table, qa + 6, i64), vector(table, qa + 7, i64)
    n_queries = len(starts)
    if n_flat >= 0:  # one query: its steps into the buffers, which hold as many codes
        _steps_of(vector(table, qa + 1, i32), n_flat, action, offsets, view, token, starts, ends)
        n_queries = 1
    for i in range(n_queries):
        s, e = starts[i], ends[i]
        filled[:] = 0
        held[:] = NO_TOKEN
        for step in range(s, e):  # as run_codes moves the streams, without learning or recording
            a = action[step]  # (written out here: a helper's call per step was a quarter of a batch)
            push_action = has_actions and (step > s or a != empty_action)
            if push_action:
                for v in range(n_views):
                    recent[v, filled[v] % K] = a
                    filled[v] += 1
            first_obs, end_obs = offsets[step], offsets[step + 1]
            for r in range(first_obs, end_obs):
                v = view[r]
                recent[v, filled[v] % K] = token[r]
                filled[v] += 1
                held[v] = token[r]
            if push_action and end_obs - first_obs < n_views:  # a view was silent (views are distinct)
                hold_silent(recent, filled, held, view, first_obs, end_obs, empty_observation)
        r0 = i * n_views
        if reused:
            _abstain(out, r0, r0 + n_views)
        a = action[e]
        if has_actions and (e > s or a != empty_action):
            for v in range(n_views):
                recent[v, filled[v] % K] = a
                filled[v] += 1
        for v in range(n_views):
            depth = min(filled[v], K)
            if depth == 0:
                continue
            r = r0 + v
            out.context[r] = True
            truth_unknown = q_token[r] == UNKNOWN
            slot = _window_slot(recent, filled, v, depth, size)
            recalled, keep = -1, -1  # memo rows: the answer's, and a ranking's to keep
            if truth_unknown and _same_window(recent, filled, v, depth, memo_depth, memo_window, slot):
                recalled = slot
            else:
                node, n = root[v], 0
                for k in range(1, depth + 1):
                    node = child(node_slots, parent, tok_of, node, recent[v, (filled[v] - k) % K])
                    if node < 0:
                        break
                    nodes[k] = node
                    n = k
                found = candidates(first, best, newest, fresh_best, node_epoch, outcome, nodes, n, epoch[v], cand)
                if found > 0:
                    k_sel, kind = select(weights, v, cand, found)
                    key = np.int64(nodes[k_sel]) * N_KINDS + kind
                    rank_slot = key & (size - 1)
                    if truth_unknown and rank_key[rank_slot] == key:
                        recalled = size + rank_slot
                    else:  # the chosen context and the shorter ones first: they fill the ranking
                        record_prediction(out, r, nodes[k_sel], kind, k_sel, cand[k_sel, kind], q_token[r],
                                          first, nxt, count, fresh, last_seen, outcome, nodes, k_sel, ranked)
                        if out.top[r, top_k - 1] >= 0:  # then they alone fix the answer (a longer
                            if truth_unknown:  # context's counted outcomes are its suffixes': test_library)
                                rank_key[rank_slot] = key
                                keep = size + rank_slot
                        elif found > k_sel:  # a fresh expert ranks by fresh counts: longer contexts
                            record_prediction(out, r, nodes[k_sel], kind, k_sel, cand[k_sel, kind], q_token[r],
                                              first, nxt, count, fresh, last_seen, outcome, nodes, found, ranked)
            # (the copies are written out: a helper's call with a dozen arrays cost a tenth of a batch)
            if recalled >= 0:
                out.predicted[r], out.length[r], out.kind[r] = memo_said[recalled], memo_length[recalled], \
                    memo_kind[recalled]
                out.score[r] = memo_score[recalled]
                for k in range(top_k):
                    out.top[r, k], out.top_p[r, k] = memo_top[recalled, k], memo_p[recalled, k]
            if truth_unknown and recalled != slot:
                _keep_window(recent, filled, v, depth, memo_depth, memo_window, slot)
                for row in (slot, keep):
                    if row >= 0:
                        memo_said[row], memo_length[row], memo_kind[row] = out.predicted[r], out.length[r], \
                            out.kind[r]
                        memo_score[row] = out.score[r]
                        for k in range(top_k):
                            memo_top[row, k], memo_p[row, k] = out.top[r, k], out.top_p[r, k]


@helper
def _window_slot(recent, filled, v, depth, size):
    """The memo slot of view ``v``'s last ``depth`` tokens (``size`` a power of two)."""
    K = recent.shape[1]
    h = np.int64(v) * 1000003 + depth
    at = (filled[v] - 1) % K  # the newest token, then back (no division per token)
    for _ in range(depth):
        h = h * 1000003 + recent[v, at]
        at = at - 1 if at > 0 else K - 1
    return (h ^ (h >> 29)) & (size - 1)


@helper
def _same_window(recent, filled, v, depth, memo_depth, memo_window, slot):
    """Whether ``slot`` holds view ``v``'s last ``depth`` tokens (of this view)."""
    if memo_depth[slot] != depth or memo_window[slot, 0] != v:
        return False
    K = recent.shape[1]
    at = (filled[v] - 1) % K
    for k in range(1, depth + 1):
        if memo_window[slot, k] != recent[v, at]:
            return False
        at = at - 1 if at > 0 else K - 1
    return True


@helper
def _keep_window(recent, filled, v, depth, memo_depth, memo_window, slot):
    """Mark ``slot`` as holding view ``v``'s last ``depth`` tokens."""
    K = recent.shape[1]
    memo_depth[slot] = depth
    memo_window[slot, 0] = v
    at = (filled[v] - 1) % K
    for k in range(1, depth + 1):
        memo_window[slot, k] = recent[v, at]
        at = at - 1 if at > 0 else K - 1


@helper
def _steps_of(flat, n_flat, action, offsets, view, token, starts, ends):
    """The first ``n_flat`` flat codes (``Predictor._cached_codes``) as the steps of one
    query (actions, offsets, views, tokens) and its bounds: every step but the last is its
    history."""
    j, r, step = 0, 0, 0
    offsets[0] = 0
    while j < n_flat:
        action[step] = flat[j]
        for k in range(flat[j + 1]):
            view[r] = flat[j + 2 + 2 * k]
            token[r] = flat[j + 3 + 2 * k]
            r += 1
        offsets[step + 1] = r
        j += 2 + 2 * flat[j + 1]
        step += 1
    starts[0] = 0
    ends[0] = step - 1


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
