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
(by its codes: a stream's queries repeat), per view's context and per chosen context's ranking
(:class:`~slearn.core.queries.Memo`: one for single queries, one that a predictor's batches
share); learning empties them. A batch encodes only the steps its queries read, and makes
only its reports' and query's addresses: a batch of a few queries costs tens of
microseconds, not a millisecond.
"""

from __future__ import annotations

from array import array
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from slearn.core._jit import direct_call
from slearn.core.online import REPORT_KINDS, Reports, new_reports
from slearn.core.queries import (
    N_FLAT,
    REUSED,
    Buffers,
    forget,
    kept_buffers,
    kept_rows,
    predict_queries,
    run_table,
    single_query,
    state_table,
)
from slearn.core.stream import Episode, Step
from slearn.core.tokens import ACTION, OBSERVATION
from slearn.core.views import UNKNOWN, StepCodes
from slearn.errors import ParameterError


@dataclass(frozen=True)
class ViewPrediction:
    """One view's prediction.

    Attributes:
        view: the view's index; ``name`` its channel (``"*"``: all observation channels).
        observations: the predicted observation symbols, ``None`` when abstaining.
        score: the chosen context's share behind the prediction.
        length: the chosen context's length in tokens (-1 when abstaining).
        kind: which expert spoke (``frequent``, ``recent``, ``fresh``), ``persist`` when the
            view's persistence specialist said its last reading again (it outweighed the
            chosen expert: :func:`slearn.core.mixer.persists`), or ``hold`` when no
            context of the present was ever seen and a spec's channel holds its last reading
            (no share); ``""`` abstaining.
        ranked: ``(observations, probability)``: the prediction first, then the others by
            probability (PPM's method C from the chosen context down, see
            ``online.record_prediction``; they sum to at most 1).
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
    ``kind`` as in :class:`ViewPrediction` (``kind`` indexes ``slearn.core.online.REPORT_KINDS``, -1),
    ``top``/``top_p`` the ranked tokens (-1 padded) and their probabilities (as
    :attr:`ViewPrediction.ranked`). A token's symbols are
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
        check_top_k(top_k)
        self.library = library
        self.top_k = top_k
        self._arrays = None  # what the token dictionaries were built for
        self._known: tuple[int, ...] = ()
        self._single: Buffers  # one query's buffers (made by _refresh)
        self._flat_bytes = memoryview(b"")  # their flat codes' bytes, written by _run_flat
        self._single_run = memoryview(b"")  # their run scalars (Query.run), the same
        self._capacity = 0                  # and how many codes they hold
        self._single_state: tuple = (None, None)  # the tree and mixer its table points to
        self._single_table = np.zeros(0, np.int64)
        self._single_call = predict_queries  # predict_queries for that table (_prepare_single)
        self._batch: Buffers  # the scratch streams and memo of batches (made by _refresh)
        self._batch_state: tuple = (None, None)  # the tree and mixer their rows point to
        self._batch_rows = np.zeros(0, np.int64)
        self._token_of: dict[tuple[int, tuple[int, ...]], int] = {}
        self._view_list: tuple = (None, [])  # the library's symbol -> view mapping, as a list
        self._symbols_of: dict[int, tuple[int, ...]] = {}
        self._step_codes: dict = {}  # step -> its flat codes' bytes, see _step_code
        self._answers: dict = {}     # a query's flat codes -> Prediction, for the library's clock
        self._made: dict = {}        # reports -> Prediction, see _single_prediction
        self._scope_sets: tuple = ((), 0)  # see _scope_sets
        self._clock = -1
        self._ticks = np.full(1, -1, np.int64).data  # the library's clock, read in place
        self._n_tokens = np.zeros(1, np.int64).data  # the token table's count, the same
        self._views = 1                          # the library's views (at least one)
        self._answering = False                  # whether predict's compiled path applies
        self._said = memoryview(b"")             # the single reports' bytes an answer depends on
        self._acted: set = set()     # symbols the cached steps use as actions,
        self._observed: set = set()  # and as observations,
        self._mixed_roles = False    # and whether one is both without a vocabulary (then check)

    def predict(self, history: list[Step], actions: tuple[int, ...] = ()) -> Prediction:
        """Predict the observations that follow ``actions`` after the steps in ``history``.

        ``history`` is a list of ``(actions, observations)`` steps of symbols, oldest first.
        """
        library = self.library
        if self._ticks[0] != self._clock or library.tokens.arrays is not self._arrays \
                or self._n_tokens[0] != self._known[0] or len(library.view_names) != self._known[1]:
            self._refresh()
        if self._answering:
            codes = self._step_codes
            try:  # every step encoded before: the common case, without a call (written out
                # here, with _run_flat's lines below: the calls were 5 % of a query)
                flat = b"".join(map(codes.__getitem__, history)) + codes[(actions, ())]
            except (KeyError, TypeError):
                flat = self._cached_codes(history, actions if type(actions) is tuple else tuple(actions))
            else:
                if self._mixed_roles:
                    _check_joint([*history, (actions, ())])
            if flat is not None:
                said = self._answers.get(flat)
                if said is None:
                    size = len(flat) >> 2
                    if size > self._capacity or library.tree is not self._single_state[0] \
                            or library.mixer is not self._single_state[1]:
                        self._prepare_single(size)
                    self._flat_bytes[:len(flat)] = flat
                    self._single_run[N_FLAT] = size
                    self._single_call(self._single_table)
                    said = self._made.get(bytes(self._said))
                    if said is None:
                        said = self._single_answer()
                    if len(history) <= _KEY_STEPS:
                        if len(self._answers) * self._views >= _ANSWER_CACHE:
                            self._answers = {}
                        self._answers[flat] = said
                return said
        return self.predict_unknown(list(history) + [(tuple(actions), ())])

    def predict_unknown(self, steps: list[Step], unknown_views: np.ndarray | None = None) -> Prediction:
        """Predict the observations of the last step of ``steps`` (its observations are
        ignored). Symbols past the vocabulary are values never seen; ``unknown_views``
        gives the view of each (factored libraries). A view whose context was never seen
        holds its last reading (kind ``hold``), unless that reading is such a value: the
        library has no token to say it with, and the view abstains (replay, which gives
        held-out values tokens of their own, holds them)."""
        if self.library.clock == 0 or not self.library.view_names:
            return self._silent()
        if getattr(self.library, "streams", None) is None:
            return self._literal(steps)
        self._refresh()
        self._run_flat(self._encode_steps(steps, unknown_views))
        return self._single_answer()

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
        if len(ends):  # encode only the steps the queries read
            lo, hi = int(starts.min()), int(ends.max()) + 1
            if lo > 0 or hi < len(episode):
                episode, starts, ends = episode.slice_steps(lo, hi), starts - lo, ends - lo
        codes = library.encode(episode, intern=False, unknown_views=unknown_views)
        out = self._run(codes, starts, ends, new_reports(len(ends) * self._n_views(), self.top_k))
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
        """The last step of flat codes (``_codes_of``) predicted from the steps before it:
        one compiled call of three scalar arguments (the codes are copied into the single
        query's buffer, which its kept address table points to; :meth:`predict` does the
        same inline)."""
        size = len(flat) >> 2
        library = self.library
        if size > self._capacity or library.tree is not self._single_state[0] \
                or library.mixer is not self._single_state[1]:
            self._prepare_single(size)
        self._flat_bytes[:len(flat)] = flat
        self._single_run[N_FLAT] = size
        self._single_call(self._single_table)
        return self._single.out

    def _prepare_single(self, size: int) -> None:
        """Room in the single query's buffers for ``size`` codes, and their address table
        pointing at the library's current tree and mixer."""
        library = self.library
        if size > self._capacity:
            self._use_single(self._single._replace(query=single_query(self._single.query.run, size,
                                                                      library.n_scopes)))
        if library.tree is not self._single_state[0] or library.mixer is not self._single_state[1]:
            self._single_table = state_table((library.tree, library.mixer), self._single)
            self._single_call = direct_call(predict_queries, self._single_table)  # (an int64 vector)
            self._single_state = (library.tree, library.mixer)

    def _use_single(self, buffers: Buffers) -> None:
        """Take ``buffers`` for single queries (their address table is made on first use)."""
        self._single, self._single_state = buffers, (None, None)
        self._single_run = buffers.query.run.data  # its scalars, written in place per query
        self._single_run[REUSED] = 1
        self._flat_bytes = buffers.query.flat.data.cast("B")
        self._capacity = len(buffers.query.flat)

    def _run(self, codes: StepCodes, starts: np.ndarray, ends: np.ndarray, out: Reports) -> Reports:
        """Every view's report at step ``ends[i]`` after replaying ``starts[i]..``: row
        ``i * views + v`` of ``out`` (new reports, ``new_reports``). The scratch streams and
        the memo are the predictor's batch buffers, kept with their table rows; a batch with
        as many reports as the memo has slots fills it anyway, and gets new ones (as every
        batch did before they were kept: just written, they are in the cache)."""
        library = self.library
        if len(out.predicted) >= len(self._batch.memo.depth):
            self._batch, self._batch_state = kept_buffers(library, 0, self.top_k), (None, None)
        work = self._batch
        if library.tree is not self._batch_state[0] or library.mixer is not self._batch_state[1]:
            forget(work.memo)
            self._batch_rows = kept_rows((library.tree, library.mixer), work)
            self._batch_state = (library.tree, library.mixer)
        query = work.query._replace(action=codes.action, scoped=codes.scoped, offsets=codes.offsets, view=codes.view,
                                    token=codes.token, starts=starts, ends=ends)
        query.run[N_FLAT], query.run[REUSED] = -1, 0
        predict_queries(run_table(self._batch_rows, out, query, work.work))
        return out

    def _single_prediction(self, out: Reports) -> Prediction:
        """``out``'s reports, one per view, as a :class:`Prediction` (the literal rule's
        path; compiled queries use :meth:`_single_answer`): the one made before for the
        same reports, if any (queries that differ often get the same answer, and an answer
        is many small objects)."""
        said = (out.predicted, out.score, out.length, out.kind, out.top, out.top_p)
        key = b"".join([a.tobytes() for a in said])
        made = self._made.get(key)
        if made is None:
            made = self._prediction_of(*(a.tolist() for a in said))
            self._made = _kept(self._made, key, made, self._n_views())
        return made

    def _single_answer(self) -> Prediction:
        """The single query's reports as a :class:`Prediction`, the one made before for the
        same reports if any, found by the bytes of the one buffer they share
        (``packed_reports``: one copy instead of six)."""
        key = bytes(self._said)
        made = self._made.get(key)
        if made is None:
            out = self._single.out
            made = self._prediction_of(out.predicted.tolist(), out.score.tolist(), out.length.tolist(),
                                       out.kind.tolist(), out.top.tolist(), out.top_p.tolist())
            self._made = _kept(self._made, key, made, self._views)
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
                views.append(_view_prediction(v, names[v], symbols(t), share, n, REPORT_KINDS[k],
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
                out.kind[r] = REPORT_KINDS.index(view.kind)
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
        learned tokens or views (:meth:`predict` checks the same things inline first)."""
        library = self.library
        compiled = getattr(library, "streams", None) is not None and bool(library.view_names)
        arrays, known = library.tokens.arrays, (len(library.tokens), len(library.view_names))
        if arrays is not self._arrays or known != self._known:
            self._arrays, self._known, self._token_of, self._symbols_of = arrays, known, {}, {}
            self._n_tokens, self._views = arrays.size.data, max(known[1], 1)
            self._made = {}
            self._step_codes, self._acted, self._observed, self._mixed_roles = {}, set(), set(), False
            self._clock = -1
            if compiled:
                library.prepare()
                self._batch = kept_buffers(library, 0, self.top_k)
                self._batch_state = (None, None)
                buffers = kept_buffers(library, 1, self.top_k)
                out, self._said = packed_reports(buffers.out)
                self._use_single(buffers._replace(out=out, query=single_query(buffers.query.run, 64,
                                                                              library.n_scopes)))
                self._scope_sets = _scope_sets(library)
        if library.clock != self._clock:
            self._clock, self._answers = library.clock, {}
            if compiled:
                forget(self._single.memo)
                forget(self._batch.memo)
        ticks = getattr(library, "clock_array", None)  # (a literal library has none)
        self._ticks = (ticks if ticks is not None else np.full(1, self._clock, np.int64)).data
        self._answering = compiled and library.clock > 0

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
            mapping = library._factored_mapping()
            if unknown_views is not None and len(unknown_views):
                view_of = np.concatenate((mapping, np.asarray(unknown_views, np.int32))).tolist()
            else:  # the mapping as a list, made once per mapping (a step's lookups are few)
                if self._view_list[0] is not mapping:
                    self._view_list = (mapping, mapping.tolist())
                view_of = self._view_list[1]
            _check_vocabulary(steps, len(view_of))
        return self._codes_of(steps, view_of)

    def _cached_codes(self, history, actions: tuple) -> bytes | None:
        """``_encode_steps(history + [(actions, ())])`` (flat codes, ``_codes_of``) through the
        dictionary of steps already encoded, the steps not in it encoded and added (:meth:`predict`
        joins the codes itself when every step is in it), or ``None`` when a step is not a
        tuple of tuples (then the general path encodes it). Checks what ``_encode_steps``
        checks: an unseen step on entry; a symbol used both as an action and as an
        observation across the steps only while the cached steps do so at all (otherwise no
        query of them can)."""
        cache, parts = self._step_codes, []
        for step in (*history, (actions, ())):
            try:
                code = cache.get(step)
            except TypeError:  # lists (not keys)
                return None
            if code is None:
                if type(step) is not tuple or len(step) != 2 or type(step[0]) is not tuple \
                        or type(step[1]) is not tuple:
                    return None
                code = self._step_code(step)
            parts.append(code)
        if self._mixed_roles:
            _check_joint([*history, (actions, ())])
        return b"".join(parts)

    def _step_code(self, step: Step) -> bytes:
        """One step's flat codes (``_codes_of``), checked as ``_encode_steps`` checks them,
        and cached (joining cached bytes is the cheapest way to one query's array)."""
        acts, obs = step
        code = self._checked_codes([step], None)
        if len(self._step_codes) >= _STEP_CODES:
            self._step_codes, self._acted, self._observed, self._mixed_roles = {}, set(), set(), False
        self._step_codes[step] = code
        if self.library.vocabulary is None:  # (a vocabulary keeps the roles apart)
            self._acted.update(acts)
            self._observed.update(obs)
            self._mixed_roles = not self._acted.isdisjoint(self._observed)
        return code

    def _codes_of(self, steps: list[Step], view_of) -> bytes:
        """Steps as flat codes, the bytes of ``int32``s: per step its action token, the
        token of its actions in each action scope, its number of observation tokens, then a
        view and a token for each; ``view_of`` maps symbols to views (``None``: one joint
        view)."""
        token, known = self._token, self._token_of.get
        scopes, n_known = self._scope_sets
        flat: list[int] = []
        for acts, obs in steps:
            key = (ACTION, acts)
            t = known(key)
            flat.append(t if t is not None else token(*key))
            for members in scopes:  # (symbols never seen are in every scope: see scope_masks)
                key = (ACTION, tuple(a for a in acts if a in members or a >= n_known))
                t = known(key)
                flat.append(t if t is not None else token(*key))
            groups = (((0, obs),) if view_of is None else _by_view(obs, view_of)) if obs else ()
            flat.append(len(groups))
            for v, group in groups:
                key = (OBSERVATION, group)
                t = known(key)
                flat += (v, t if t is not None else token(*key))
        return array(_INT32, flat).tobytes()  # (half the time of NumPy's for a step's few codes)

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


def _scope_sets(library) -> tuple[list[frozenset], int]:
    """The action symbols of each of ``library``'s action scopes, and how many symbols its
    vocabulary knows (those past it are in every scope)."""
    if not getattr(library, "n_scopes", 0):
        return [], 0
    n_known = len(library.vocabulary)
    masks = library.scope_masks(n_known)
    return [frozenset(np.flatnonzero(row).tolist()) for row in masks], n_known


def check_top_k(top_k, name: str = "top_k") -> None:
    """Refuse a ranking length that is not an integer in 1..1000 (``name`` is the caller's)."""
    if isinstance(top_k, bool) or not isinstance(top_k, (int, np.integer)) or not 1 <= top_k <= 1000:
        raise ParameterError(f"{name} must be an integer in 1..1000, not {top_k!r}")


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


def packed_reports(reports: Reports) -> tuple[Reports, memoryview]:
    """``reports`` copied into one buffer, each field 8-byte aligned, and the bytes of its
    fields up to ``top_p`` (everything a :class:`Prediction` is made of): the key a
    predictor remembers an answer by, read in one copy."""
    sizes = [-(-a.nbytes // 8) * 8 for a in reports]
    buffer = np.zeros(sum(sizes), np.uint8)
    fields, at = [], 0
    for a, size in zip(reports, sizes):
        field = buffer[at:at + a.nbytes].view(a.dtype).reshape(a.shape)
        field[...] = a
        fields.append(field)
        at += size
    return Reports(*fields), buffer.data[:sum(sizes[:Reports._fields.index("top_p") + 1])]


def _batch(out: Reports, queries: int, n_views: int, top_k: int) -> BatchPrediction:
    shape = (queries, n_views)
    return BatchPrediction(out.predicted.reshape(shape), out.score.reshape(shape),
                           out.length.reshape(shape), out.kind.reshape(shape),
                           out.top.reshape(shape + (top_k,)), out.top_p.reshape(shape + (top_k,)))


_INT32 = "i" if array("i").itemsize == 4 else "l"  # the array module's int32
_STEP_CODES = 1 << 16    # steps a predictor remembers the codes of
_ANSWER_CACHE = 1 << 14  # views' answers a predictor remembers, per query and per answer
_KEY_STEPS = 64          # the longest history whose answer is remembered (memory: a query
#                          remembered keeps its codes; a longer history is rarely asked again)


def _kept(cache: dict, key, value, n_views: int) -> dict:
    """``cache`` with ``key: value``, emptied first when full: when it holds the answers of
    ``_ANSWER_CACHE`` views (an answer of many views is as large as many answers). What was
    asked recently comes back soon in a stream."""
    if len(cache) * max(n_views, 1) >= _ANSWER_CACHE:
        cache = {}
    cache[key] = value
    return cache


