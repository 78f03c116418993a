"""``SequenceModel``: S-learning on plain Python sequences, without files or specs.

Two forms, fixed by the first call that learns:

* sequences of hashable items (``learn(seq)``, ``predict(history)``): one sequence is one
  episode, the items one observation channel named ``item``;
* steps of actions and observations (``learn_steps(steps)``, ``predict_step(history,
  actions)``): a step is ``(actions, observations)``, two mappings ``{channel: value}``,
  as the recorders produce them; each observation channel is predicted on its own.

Prediction never changes the model; learning trains the counts and the scoring weights.
Items and values the model never saw match no context: a history that ends with one
abstains (``None``), unless the actions alone say something. Values must be hashable.
"""

from __future__ import annotations

import os
import warnings
from contextlib import contextmanager
from typing import AbstractSet, Any, Hashable, Iterable, Iterator, Mapping, Sequence

import numpy as np

from slearn.core.library import DEFAULT_MAX_LENGTH, PatternLibrary, check_parameters, check_scopes
from slearn.core.literal import LiteralLibrary
from slearn.core.online import REPORT_KINDS
from slearn.core.predictor import Predictor, check_top_k
from slearn.core.stream import Episode
from slearn.core.vocabulary import ACTION, OBSERVATION, STORABLE, Vocabulary, storable
from slearn.errors import DataWarning, ParameterError

ITEM = "item"
_RANKED_KEPT = 1 << 14  # rankings a model remembers by their prediction
_ROWS_KEPT = 1 << 16   # steps a model remembers the symbols of (symbols never change)
_PREDICTORS_KEPT = 4    # predictors a model keeps, one per k asked (each remembers answers;
#                         a predictor follows the library as it learns)
SCORINGS = ("adaptive", "literal")
_HOLD = REPORT_KINDS.index("hold")
_NONE = object()  # (a channel the prediction has no value of)
Step = tuple[Mapping[str, Hashable], Mapping[str, Hashable]]


def _holds_nan(value: Any) -> bool:
    """Whether ``value`` is a NaN (float, complex, NumPy's) or a tuple holding one."""
    if isinstance(value, tuple):
        return any(_holds_nan(v) for v in value)
    return isinstance(value, (float, complex, np.floating, np.complexfloating)) and value != value


_FORMS = {"sequence": "sequences of items", "steps": "steps of actions and observations"}
_METHODS = {"sequence": "learn, predict, rank and predict_many",
            "steps": "learn_steps, predict_step and rank_step"}


class SequenceModel:
    """Learns sequences (or steps with actions) and predicts what comes next.

    Args:
        max_length: steps of history a context spans at most.
        scoring: ``"adaptive"`` (every occurrence counted, contexts weighed by their
            record; the default) or ``"literal"`` (the paper's rule, ``max_length`` 5).
        max_patterns: forget the rarest, oldest patterns beyond this many.
        action_scopes: the step form's ``{observation channel: [action channels]}``: that
            channel is predicted from the step's actions on those channels only (a joint
            from its own command), not from the tuple of every action, which rarely repeats
            when many channels are commanded at once. Other channels see every action.
    """

    def __init__(self, max_length: int = DEFAULT_MAX_LENGTH, scoring: str = "adaptive",
                 max_patterns: int | None = None,
                 action_scopes: Mapping[str, Iterable[str]] | None = None) -> None:
        if scoring not in SCORINGS:
            raise ParameterError(f"scoring must be one of {', '.join(SCORINGS)}, not {scoring!r}")
        check_parameters(max_length, max_patterns)
        if action_scopes and scoring == "literal":
            raise ParameterError("action scopes need the adaptive scoring (the literal rule "
                                 "predicts a step's observations together)")
        if action_scopes is not None and not isinstance(action_scopes, Mapping):
            raise ParameterError("action_scopes must map observation channel names to lists of "
                                 "action channel names")
        self._scopes = check_scopes({k: tuple(v) if isinstance(v, (list, tuple, set, frozenset)) else v
                                     for k, v in (action_scopes or {}).items()}, Vocabulary())
        self.vocabulary = Vocabulary()
        self.scoring = scoring
        self._form: str | None = None
        self._params = (max_length, max_patterns)
        self.library: PatternLibrary | LiteralLibrary | None = None
        self._predictors: dict[int, Predictor] = {}  # top_k -> a predictor of self.library
        self._steps_for: Vocabulary | None = None  # the vocabulary _item_steps was made from
        self._item_steps: dict = {}   # item -> its step, see _known_steps
        self._ranked_of: dict = {}    # id(prediction) -> (prediction, k, rankings), see _named_of
        self._rows_of: dict = {}      # a step's (actions, observations) items -> its symbols,
        self._rows_for: Vocabulary | None = None  # in this vocabulary
        self._unstorable_said = False  # whether learning warned of a value files cannot store

    # --- the sequence form --------------------------------------------------------------
    def learn(self, sequence: Iterable[Hashable]) -> None:
        """Learn one sequence of hashable items (one episode). A call that raises leaves
        the model as it was."""
        self._use("sequence", learning=False)
        items = list(_iterable(sequence, "a sequence of items"))
        if not items:
            return
        with self._registering():
            self.vocabulary.add_channel(ITEM, OBSERVATION)
            symbols = [self._symbol(ITEM, item, learn=True) for item in items]
        self._use("sequence")
        self._learn(Episode.from_steps([((), (s,)) for s in symbols]))

    def predict(self, history: Sequence[Hashable]) -> Hashable | None:
        """The most likely next item after ``history``, or ``None``."""
        library = self.library
        if library is not None and self._form == "sequence" and type(history) in (str, list, tuple):
            try:  # items seen before: their steps, without the general path's calls
                step_of = self._item_steps if self._steps_for is self.vocabulary else self._steps_of_items()
                steps = [step_of[item] for item in history[-library.max_length:]]
            except (KeyError, TypeError):
                pass
            else:
                predictor = self._predictors.get(1)
                if predictor is None or predictor.library is not library:
                    predictor = self._predictor_for(1)
                prediction = predictor.predict(steps, ())
                made = self._ranked_of.get(id(prediction))  # (_named_of, read inline)
                named = made[2] if made is not None and made[0] is prediction and made[1] == 1 \
                    else self._named_of(prediction, 1)
                top = named.get(ITEM)
                return top[0][0] if top else None
        ranked = self.rank(history, k=1)
        return ranked[0][0] if ranked else None

    def rank(self, history: Sequence[Hashable], k: int = 3) -> list[tuple[Hashable, float]]:
        """Up to ``k`` next items with their probabilities: the prediction first (what
        :meth:`predict` says), then the others by probability (PPM's method C from the
        prediction's context down to shorter ones; they sum to at most 1). A ``recent``
        expert's prediction can carry less probability than the item after it."""
        self._use("sequence", learning=False)
        check_top_k(k, "k")
        tail = self._tail(history)
        steps = self._known_steps(tail)
        if steps is None:  # an item never seen: the general path gives it a symbol of its own
            return list(self._query([({}, {ITEM: item}) for item in tail], {}, k).get(ITEM, []))
        # the predictor's path for steps it may have seen (it remembers their codes)
        return self._ranked_items(self._predictor_for(k).predict(steps, ()), k)

    def predict_many(self, histories: Iterable[Sequence[Hashable]]) -> list[Hashable | None]:
        """:meth:`predict` for many histories, in one compiled call (the same answers)."""
        self._use("sequence", learning=False)
        histories = _iterable(histories, "histories")
        if self.library is None:
            return [None for _ in histories]
        # The episode _lookup_steps would make of ({}, {ITEM: item}) steps, each history
        # followed by an empty query step, built as arrays: a value never seen gets a symbol
        # past the vocabulary (one per occurrence), in the item view if the library has one.
        tails = [self._tail(history) for history in histories]
        if not tails:
            return []
        items = [item for tail in tails for item in tail]
        try:
            item_symbols = self._item_symbols(items)
        except TypeError:
            for item in items:
                self._symbol(ITEM, item, learn=False)  # raises for the one not hashable
            raise
        unknown: list[int] = []
        if None in item_symbols:
            item_view = {name: i for i, name in enumerate(self.library.view_names)}.get(ITEM, -1)
            known = len(self.vocabulary)
            for i, found in enumerate(item_symbols):
                if found is None:
                    item_symbols[i] = known + len(unknown)
                    unknown.append(item_view)
        lengths = np.array([len(tail) for tail in tails], np.int64)
        ends = np.cumsum(lengths + 1) - 1
        starts = ends - lengths
        sizes = np.ones(int(ends[-1]) + 1, np.int64)
        sizes[ends] = 0  # the query steps
        episode = Episode(np.array(item_symbols, np.int32), np.concatenate(([0], np.cumsum(sizes))),
                          np.zeros(len(sizes), np.int32))
        predictor = self._predictor_for(1)
        batch = predictor.predict_batch(episode, starts, ends, np.asarray(unknown, np.int32))
        names = self.library.view_names
        view = next((i for i, name in enumerate(names) if name in (ITEM, "*")), None)
        if view is None:
            return [None] * len(ends)
        # What _named reads from predictor.prediction(batch, i), without building it: the
        # first ranked outcome of a view that did not abstain (nor hold), if it is one item.
        out: list[Hashable | None] = []
        item_of: dict[int, Hashable | None] = {}
        for token, top, kind in zip(batch.token[:, view].tolist(), batch.top[:, view, 0].tolist(),
                                    batch.kind[:, view].tolist()):
            if token < 0 or top < 0 or kind == _HOLD:
                out.append(None)
                continue
            if top not in item_of:
                symbols = self.library.tokens.symbols(top)
                item_of[top] = self.vocabulary.name(symbols[0])[1] if len(symbols) == 1 else None
            out.append(item_of[top])
        return out

    # --- the step form ------------------------------------------------------------------
    def learn_steps(self, steps: Iterable[Step]) -> None:
        """Learn one episode of ``(actions, observations)`` steps (mappings channel -> value;
        the order of a mapping's keys does not matter). A call that raises leaves the model
        as it was."""
        self._use("steps", learning=False)
        steps = list(_iterable(steps, "steps"))
        if not steps:
            return
        with self._registering():
            rows = [self._step_symbols(step, learn=True) for step in steps]
        self._use("steps")
        self._learn(Episode.from_steps(rows))
        if self._scopes and self.library is not None and self.library.clock == len(rows):
            self._warn_unseen_scope_channels()  # once, after the first episode

    def _warn_unseen_scope_channels(self) -> None:
        roles = self.vocabulary.roles
        unseen = sorted({n for view, names in self._scopes.items() for n in (view, *names) if n not in roles})
        if unseen:
            warnings.warn(f"action_scopes name channels no step of the first episode has: "
                          f"{', '.join(map(repr, unseen))} (a view sees only the actions of the "
                          f"channels its scope names): check the names", DataWarning, stacklevel=3)

    def predict_step(self, history: Sequence[Step], actions: Mapping[str, Hashable]) -> dict:
        """``{channel: value}``: each observation channel's most likely next value."""
        if self._form == "steps" and self.library is not None and type(history) in (list, tuple):
            named = self._known_step_query(history, actions, 1)
            if named is not None:
                return {c: ranked[0][0] for c, ranked in named.items() if ranked}
        return {c: ranked[0][0] for c, ranked in self.rank_step(history, actions, k=1).items()
                if ranked}

    def rank_step(self, history: Sequence[Step], actions: Mapping[str, Hashable],
                  k: int = 3) -> dict[str, list[tuple[Hashable, float]]]:
        """Per observation channel, up to ``k`` next values with their probabilities, the
        prediction first (as :meth:`rank`)."""
        self._use("steps", learning=False)
        check_top_k(k, "k")
        if not isinstance(actions, Mapping):
            raise ParameterError(f"actions must be a mapping channel -> value, not {actions!r}")
        history = list(_iterable(history, "a history of steps"))
        named = self._known_step_query(history, actions, k) if self.library is not None else None
        if named is not None:
            return {channel: list(ranked) for channel, ranked in named.items()}
        return self._query(history, actions, k)

    def _known_step_query(self, history, actions, k: int) -> dict | None:
        """What :meth:`_query` answers (shared lists: copy before handing them out), when
        every step is a pair of dicts of channels in their roles with values seen before,
        by the predictor's path for steps it may have seen (it remembers their codes);
        otherwise ``None``, and the general path answers or refuses."""
        if self._rows_for is not self.vocabulary:
            self._rows_for, self._rows_of = self.vocabulary, {}
        known, row_of, rows = self.vocabulary.known_symbols, self._rows_of, []
        for step in history:
            if type(step) is not tuple or len(step) != 2 or type(step[0]) is not dict \
                    or type(step[1]) is not dict:
                return None
            key = (tuple(step[0].items()), tuple(step[1].items()))
            try:
                row = row_of.get(key)
            except TypeError:  # a value not hashable
                return None
            if row is None:
                acts, obs = known(step[0], ACTION), known(step[1], OBSERVATION)
                if acts is None or obs is None:
                    return None
                if len(row_of) >= _ROWS_KEPT:
                    self._rows_of = row_of = {}
                row = row_of[key] = (acts, obs)
            rows.append(row)
        acts = known(actions, ACTION) if type(actions) is dict else None
        if acts is None:
            return None
        return self._named_of(self._predictor_for(k).predict(rows, acts), k)

    # --- files --------------------------------------------------------------------------
    def save(self, path: str | os.PathLike, overwrite: bool = False) -> None:
        """Write the model as a library file (Parquet), atomically."""
        from slearn.io.library_file import save_library

        path = _path(path)
        if self.library is None:
            raise ParameterError("the model has learned nothing yet: nothing to save")
        if not overwrite and os.path.lexists(path):
            raise ParameterError(f"{os.fspath(path)} already exists: pass overwrite=True to replace it")
        save_library(path, self.library, self.vocabulary, spec=None, params={"form": self._form},
                     provenance={}, overwrite=overwrite)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "SequenceModel":
        """A model saved by :meth:`save` (or any library file learned from logs)."""
        from slearn.io.library_file import load_library

        loaded = load_library(_path(path))
        model = cls(loaded.library.max_length, loaded.params.get("scoring", "adaptive"),
                    loaded.library.max_patterns)
        model.vocabulary, model.library = loaded.vocabulary, loaded.library
        model._scopes = getattr(loaded.library, "action_scopes", {})
        model._form = loaded.params.get("form") or "steps"
        return model

    # --- internals ----------------------------------------------------------------------
    def _use(self, form: str, learning: bool = True) -> None:
        if self._form is None and learning:
            self._form = form
        if self._form is not None and self._form != form:
            methods = _METHODS[self._form]
            raise ParameterError(f"this model learned {_FORMS[self._form]}: use {methods} "
                                 f"(the matching methods), or a new SequenceModel for {_FORMS[form]}")

    @contextmanager
    def _registering(self) -> Iterator[None]:
        """Symbols registered inside are forgotten again when it raises (a learning call
        that fails part-way leaves the vocabulary as it was); after it, one warning when a
        value is new that a library file cannot store."""
        vocabulary = self.vocabulary
        symbols, channels = len(vocabulary), len(vocabulary.roles)
        try:
            yield
        except BaseException:
            vocabulary.truncate(symbols, channels)
            raise
        if not self._unstorable_said:
            for channel, value in vocabulary.names(symbols):
                if not storable(value):
                    self._unstorable_said = True
                    warnings.warn(f"{channel} value {value!r} ({type(value).__name__}) cannot be saved in a "
                                  f"library file, which stores {STORABLE}: map the values to these to save "
                                  f"the model", DataWarning, stacklevel=4)
                    break

    def _new_library(self) -> PatternLibrary | LiteralLibrary:
        max_length, max_patterns = self._params
        if self.scoring == "literal":
            return LiteralLibrary(max_length, max_patterns)
        return PatternLibrary(max_length, max_patterns, vocabulary=self.vocabulary,
                              action_scopes=self._scopes)

    def _learn(self, episode: Episode) -> None:
        if self.library is None:
            self.library = self._new_library()
        self.library.learn(episode)

    def _symbol(self, channel: str, value: Any, learn: bool) -> int:
        try:
            hash(value)
        except TypeError:
            raise ParameterError(f"{channel} value {value!r} is not hashable: use tuples, "
                                 f"strings or numbers") from None
        known = self.vocabulary.get_symbol(channel, value)
        if not learn:
            return -1 if known is None else known
        if known is not None:
            return known
        if _holds_nan(value):
            raise ParameterError(f"{channel} value {value!r} is or holds a NaN, which never equals "
                                 f"itself, so each NaN would be a value of its own: replace missing "
                                 f"values with None or a label first")
        return self.vocabulary.symbol(channel, value)

    def _step_symbols(self, step: Step, learn: bool) -> tuple[tuple[int, ...], tuple[int, ...]]:
        out = []
        for role, mapping in _roles(step):
            for channel in mapping:
                self.vocabulary.add_channel(str(channel), role) if learn else None
            pairs = self.vocabulary.in_channel_order((str(c), v) for c, v in mapping.items())
            out.append(tuple(self._symbol(c, v, learn) for c, v in pairs))
        return out[0], out[1]

    def _known_steps(self, items: Sequence[Hashable]) -> list | None:
        """The items as the predictor's steps, ``((), (symbol,))`` each (the same tuples every
        time), or ``None`` when one was never seen, is not hashable, or nothing was learned."""
        if self.library is None:
            return None
        step_of = self._steps_of_items()
        try:
            return [step_of[item] for item in items]
        except KeyError:
            pass
        except TypeError:  # not hashable: the general path says so
            return None
        if None in self._item_symbols(items):  # (which remembers the steps of the others)
            return None
        return [step_of[item] for item in items]

    def _item_symbols(self, items: Sequence[Hashable]) -> list[int | None]:
        """The items' symbols (``None``: never seen), through a dictionary of their steps
        that every item seen fills; ``TypeError`` for an item that is not hashable."""
        step_of = self._steps_of_items()
        try:
            return [step_of[item][1][0] for item in items]
        except KeyError:
            pass
        out: list[int | None] = []
        for item in items:
            step = step_of.get(item)
            if step is None:
                symbol = self.vocabulary.get_symbol(ITEM, item)
                if symbol is not None:
                    step = step_of[item] = ((), (symbol,))
            out.append(None if step is None else step[1][0])
        return out

    def _steps_of_items(self) -> dict:
        """Item -> its step ``((), (symbol,))``, for the items seen so far (of this vocabulary)."""
        if self._steps_for is not self.vocabulary:
            self._steps_for, self._item_steps = self.vocabulary, {}
        return self._item_steps

    def _ranked_items(self, prediction, k: int) -> list[tuple[Hashable, float]]:
        """The item view's ranking of ``prediction`` as ``(item, share)`` pairs; a new list
        each call."""
        return list(self._named_of(prediction, k).get(ITEM, []))

    def _named_of(self, prediction, k: int) -> dict:
        """``_named(prediction, k)``, the one made before for the same prediction object if
        any (a predictor hands out the same object for the same answer). Shared: copy what
        is handed out."""
        made = self._ranked_of.get(id(prediction))
        if made is None or made[0] is not prediction or made[1] != k:
            made = (prediction, k, self._named(prediction, k))
            if len(self._ranked_of) >= _RANKED_KEPT:
                self._ranked_of = {}
            self._ranked_of[id(prediction)] = made  # (the entry keeps the object, so its id)
        return made[2]

    def _tail(self, history: Sequence[Hashable]) -> Sequence[Hashable]:
        keep = self.library.max_length if self.library is not None else 1
        if type(history) in (str, list, tuple):  # (a slice of these is their last items)
            return history[-keep:]
        return list(_iterable(history, "a history of items"))[-keep:]

    def _query(self, history: list, actions: Mapping[str, Hashable], k: int) -> dict:
        if self.library is None:
            return {}
        steps, unknown = self._lookup_steps(self.library, history + [(actions, {})])
        prediction = self._predictor_for(k).predict_unknown(steps, unknown)
        return self._named(prediction, k)

    def _predictor_for(self, k: int) -> Predictor:
        if self.library is None:
            raise ParameterError("the model has learned nothing yet")
        predictor = self._predictors.get(k)
        if predictor is None or predictor.library is not self.library:
            if len(self._predictors) >= _PREDICTORS_KEPT:
                self._predictors = {}
            predictor = self._predictors[k] = Predictor(self.library, top_k=k)
        return predictor

    def _lookup_steps(self, library: PatternLibrary | LiteralLibrary, steps: list) -> tuple[list, np.ndarray]:
        """Steps as symbols; a value never seen gets a symbol past the vocabulary."""
        view_of = {name: i for i, name in enumerate(library.view_names)}
        unknown: list[int] = []
        rows = []
        roles = self.vocabulary.roles
        for step in steps:
            row = []
            for role, mapping in _roles(step):
                symbols = []
                for channel, value in self.vocabulary.in_channel_order((str(c), v) for c, v in mapping.items()):
                    if roles.get(channel) != role:
                        raise ParameterError(_unknown_channel(channel, role, roles))
                    s = self._symbol(channel, value, learn=False)
                    if s == -1:
                        s = len(self.vocabulary) + len(unknown)
                        unknown.append(view_of.get(channel, -1) if role == OBSERVATION else -1)
                    symbols.append(s)
                row.append(tuple(symbols))
            rows.append((row[0], row[1]))
        return rows, np.asarray(unknown, np.int32)

    def _named(self, prediction, k: int) -> dict:
        """Per observation channel, ``[(value, probability), ...]`` (empty: it abstains). A
        plain sequence has no held reading: a hold there is an abstention. A view of every
        observation channel (the literal rule) ranks whole steps: each channel gets the
        values of its ranked steps, the predicted one first, then by the probabilities of
        the steps that have them, summed."""
        out: dict[str, list] = {}
        name = self.vocabulary.name
        for view in prediction.views:
            abstains = view.abstained or (view.kind == "hold" and self._form == "sequence")
            ranked = () if abstains else view.ranked[:k]
            if view.name != "*":
                out[view.name] = [(name(symbols[0])[1], p) for symbols, p in ranked if len(symbols) == 1]
                continue
            channels = [ITEM] if self._form == "sequence" else \
                [c for c, role in self.vocabulary.roles.items() if role == OBSERVATION]
            shares: dict[str, dict] = {channel: {} for channel in channels}
            for symbols, p in ranked:
                for symbol in symbols:
                    channel, value = name(symbol)
                    values = shares.setdefault(channel, {})
                    values[value] = values.get(value, 0.0) + p
            said = dict(name(s) for s in ranked[0][0]) if ranked else {}  # channel -> predicted value
            for channel, values in shares.items():
                first = said.get(channel, _NONE)
                order = sorted(values, key=lambda value: (value != first, -values[value]))
                out[channel] = [(value, values[value]) for value in order[:k]]
        return out


def _path(path) -> str | os.PathLike:
    """``path`` if it names a file (``str`` or ``os.PathLike`` of text), or a one-line error."""
    if isinstance(path, str) or (isinstance(path, os.PathLike) and isinstance(os.fspath(path), str)):
        return path
    raise ParameterError(f"a model's path must be a str or an os.PathLike, not {type(path).__name__}")


def _iterable(value, what: str):
    """``iter(value)``, or a one-line error saying what was expected: an ordered iterable
    (a set or a mapping has no order a sequence could be read in)."""
    if isinstance(value, (AbstractSet, Mapping)):
        raise ParameterError(f"{what} must be ordered (a list, tuple, str or iterator), "
                             f"not a {type(value).__name__}")
    try:
        return iter(value)
    except TypeError:
        raise ParameterError(f"{what} must be iterable, not {type(value).__name__}") from None


def _roles(step) -> tuple[tuple[str, Mapping], tuple[str, Mapping]]:
    """A step's ``(role, mapping)`` pairs, actions first, or a one-line error."""
    try:
        actions, observations = step
    except (TypeError, ValueError):
        raise ParameterError(f"a step is (actions, observations), two mappings; got {step!r}") from None
    for role, mapping in ((ACTION, actions), (OBSERVATION, observations)):
        if not isinstance(mapping, Mapping):
            raise ParameterError(f"step {role}s must be a mapping channel -> value, not {mapping!r}")
    return (ACTION, actions), (OBSERVATION, observations)


def _unknown_channel(channel: str, role: str, roles: Mapping[str, str]) -> str:
    """Why a query may not use ``channel`` as ``role``: it was learned in another role, or never."""
    if channel in roles:
        return f"channel {channel!r} was learned as an {roles[channel]} channel, not as an {role} channel"
    known = sorted(c for c, r in roles.items() if r == role)
    return (f"{role} channel {channel!r} was never learned (the model's {role} channels: "
            f"{', '.join(map(repr, known)) or 'none'})")
