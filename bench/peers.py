"""The natural peers of slearn's predictor, on the same stream, online from empty.

An episode (:class:`slearn.core.stream.Episode`) becomes tokens ``O A O A ... O`` through
:meth:`slearn.core.tokens.TokenTable.tokenize` (``O`` the step's observation tuple, ``A`` its
action tuple). Step ``i`` (``1..n``) predicts ``O_i`` from the history ``O_0 A_1 ... O_{i-1}``
and the action just issued ``A_i``, then learns it (prequential: predict, then learn).

A *context of order j* is the action just issued and the ``j`` steps before it:
``O_{i-j} A_{i-j+1} ... O_{i-1} A_i``; order 0 is ``A_i`` alone. Sequences without actions
carry the empty action token everywhere, so order ``j`` is just the last ``j`` items.
Every occurrence of every context up to the model's order is counted, with the
observation that followed it (no parse boundaries, no thresholds), and contexts never
cross episodes. Within a context the prediction is the outcome of largest count; ties go
to the outcome seen most recently. Peers:

- ``VOM(k)``: the longest *seen* context of order at most ``k`` speaks ("longest seen
  context first"): shorter contexts are used only when the longer one was never seen,
  down to order 0; with nothing seen, it abstains (-1).
- ``VOM(k + 1/2)``: the same over events, so a context may also begin at an action:
  ``A_{i-k} O_{i-k} ... O_{i-1} A_i`` (order ``k + 1/2``) sits between orders ``k`` and
  ``k + 1`` in the back-off. On ``delay`` the command before the current position matters
  without the position before it: VOM(1 1/2) beats every step-aligned order.
- ``AKOM(K)``: the all-k-order Markov model of the CPT+ papers (IPredict's
  ``MarkovAllKPredictor``): ``VOM(K)`` without the order-0 fallback (it abstains when no
  context of order 1..K was seen).
- ``PPM-C(K)`` / ``PPM-D(K)``: prediction by partial matching, blending orders ``K..0``
  with exclusion (a symbol seen in a longer context is left out of the shorter ones) and
  an order -1 that is uniform over every observation seen so far plus one novel symbol;
  the prediction is the argmax of the blended distribution (ties: longest context,
  then the outcome first seen most recently). Escape method C: a context with ``n``
  occurrences of ``t`` distinct symbols gives ``c/(n+t)`` to a symbol seen ``c`` times and
  ``t/(n+t)`` to the shorter contexts; method D: ``(2c-1)/(2n)`` and ``t/(2n)``.
- Per channel (:func:`per_channel_correct`): each observation channel is predicted from
  contexts over its own readings (the last one held when it does not report) and the
  actions only, by the same counts; a step is right when every channel that reports in it
  is. This peer is told which channels report.

One count table (:class:`CountModel`) of order ``K`` answers ``VOM(1..K)``,
``VOM(1 1/2 .. K - 1/2)``, ``AKOM(k <= K)`` and ``PPM(k <= K)`` at once, since the counts of a
context do not depend on the largest order kept.

The C reference (``bench/c/vom.c``, :func:`load_c_vom`) is ``VOM(k)`` over the same token
array with its own open-addressing table; it is compiled with the system C compiler when
one is present and gives the same predictions (the speed anchor of issue 12).
"""

from __future__ import annotations

import ctypes
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, NamedTuple

import numba
import numpy as np

from slearn.core.stream import Episode
from slearn.core.tokens import TokenTable
from slearn.core.vocabulary import Vocabulary

_CONTEXT, _OUTCOME = 0, 1
_PPM_METHODS = {"C": 1, "D": 2}
_C_SOURCE = Path(__file__).resolve().parent / "c" / "vom.c"


class Counts(NamedTuple):
    """The count table's arrays (numba reads them into locals once per call).

    ``keys``/``values``: the open-addressing table ``(parent, kind, token) -> id`` (key -1
    empty); a context child is a node, an outcome child an outcome record. Per node:
    ``total`` occurrences, ``distinct`` outcomes, ``best`` outcome (-1 none) and its
    ``best_count``, ``first`` outcome record (-1 none). Per outcome record: ``token``,
    ``count``, ``next`` record of the same context. Per observation token: ``seen``,
    ``mark`` (PPM exclusion stamps); ``alphabet`` lists the tokens seen as outcomes.
    ``sizes``: keys, nodes, outcome records, alphabet, clock (steps learned), PPM stamp.
    """

    keys: np.ndarray
    values: np.ndarray
    total: np.ndarray
    distinct: np.ndarray
    best: np.ndarray
    best_count: np.ndarray
    first: np.ndarray
    token: np.ndarray
    count: np.ndarray
    next: np.ndarray
    seen: np.ndarray
    mark: np.ndarray
    alphabet: np.ndarray
    sizes: np.ndarray


def _new_counts(slots: int, nodes: int, outcomes: int, tokens: int) -> Counts:
    sizes = np.zeros(6, np.int64)
    sizes[1] = 1  # node 0 is the root
    return Counts(np.full(slots, -1, np.int64), np.zeros(slots, np.int32),
                  np.zeros(nodes, np.int64), np.zeros(nodes, np.int32),
                  np.full(nodes, -1, np.int32), np.zeros(nodes, np.int64),
                  np.full(nodes, -1, np.int32), np.zeros(outcomes, np.int32),
                  np.zeros(outcomes, np.int64), np.full(outcomes, -1, np.int32),
                  np.zeros(tokens, np.uint8), np.zeros(tokens, np.int64),
                  np.zeros(tokens, np.int32), sizes)


@dataclass(frozen=True)
class StepPredictions:
    """Per step: ``vom[:, k - 1]`` is VOM(k)'s prediction, ``half[:, k - 1]`` VOM(k + 1/2)'s,
    ``deepest`` the longest seen step-aligned context's order (-1 none), ``ppm`` the PPM
    prediction (-1 abstained or not asked)."""

    vom: np.ndarray
    half: np.ndarray
    deepest: np.ndarray
    ppm: np.ndarray

    def akom(self, order: int) -> np.ndarray:
        """AKOM(order)'s predictions: VOM(order) where a context of order >= 1 was seen."""
        return np.where(self.deepest >= 1, self.vom[:, order - 1], -1).astype(np.int32)


class CountModel:
    """Counts of every context of up to ``max_order`` steps, kept across episodes.

    Args:
        max_order: the longest context, in steps (VOM(1..max_order)).
    """

    def __init__(self, max_order: int = 6) -> None:
        if max_order < 1:
            raise ValueError("max_order must be at least 1")
        self.max_order = int(max_order)
        self.counts = _new_counts(1 << 12, 1 << 10, 1 << 10, 64)

    def run(self, obs: np.ndarray, act: np.ndarray, *, learn: bool = True,
            predict: bool = True, ppm: str | None = "C", ppm_order: int | None = None
            ) -> StepPredictions:
        """Predict (if ``predict``) then count (if ``learn``) every step of one episode.

        ``obs[i]`` is step ``i``'s observation token (``i = 0..n``), ``act[i]`` its action
        token (``act[0]`` unused); tokens are non-negative ints.
        """
        obs = np.ascontiguousarray(obs, np.int32)
        act = np.ascontiguousarray(act, np.int32)
        n = max(len(obs) - 1, 0)
        out = StepPredictions(np.full((n, self.max_order), -1, np.int32),
                              np.full((n, self.max_order - 1), -1, np.int32),
                              np.full(n, -1, np.int32), np.full(n, -1, np.int32))
        self._reserve_tokens(int(obs.max()) + 1 if len(obs) else 0)
        order = self.max_order if ppm_order is None else min(int(ppm_order), self.max_order)
        method = _PPM_METHODS[ppm] if ppm and predict else 0
        path = np.zeros(2 * self.max_order, np.int32)
        chain = np.zeros(self.max_order + 1, np.int32)
        step = 1
        while step <= n:
            step = _run(self.counts, obs, act, step, self.max_order, learn, predict, method,
                        order, path, chain, out.vom, out.half, out.deepest, out.ppm)
            if step <= n:
                self._grow()
        return out

    def learn(self, obs: np.ndarray, act: np.ndarray) -> None:
        """Count every step of one episode without predicting."""
        self.run(obs, act, predict=False, ppm=None)

    def ppm_distribution(self, obs: np.ndarray, act: np.ndarray, method: str = "C",
                         order: int | None = None) -> tuple[np.ndarray, float]:
        """PPM's distribution of the observation after ``obs[-1]`` and ``act[-1]``
        (``len(act) == len(obs) + 1``): ``(probability per token, novel-symbol mass)``."""
        obs = np.ascontiguousarray(obs, np.int32)
        act = np.ascontiguousarray(act, np.int32)
        history = np.concatenate((obs, [0])).astype(np.int32)  # slot of the predicted step
        dist = np.zeros(len(self.counts.seen))
        order = self.max_order if order is None else order
        novel = _distribution(self.counts, history, act, len(obs), self.max_order, order,
                              _PPM_METHODS[method], np.zeros(2 * self.max_order, np.int32),
                              np.zeros(self.max_order + 1, np.int32), dist)
        return dist, float(novel)

    def _reserve_tokens(self, size: int) -> None:
        c = self.counts
        if size <= len(c.seen):
            return
        capacity = max(size, 2 * len(c.seen))
        self.counts = c._replace(seen=_resized(c.seen, capacity, 0),
                                 mark=_resized(c.mark, capacity, 0),
                                 alphabet=_resized(c.alphabet, capacity, 0))

    def _grow(self) -> None:
        c = self.counts
        keys, nodes, outcomes = (int(x) for x in c.sizes[:3])
        margin = 4 * self.max_order + 4
        if nodes + margin > len(c.total):
            n = 2 * len(c.total)
            c = c._replace(total=_resized(c.total, n, 0), distinct=_resized(c.distinct, n, 0),
                           best=_resized(c.best, n, -1), best_count=_resized(c.best_count, n, 0),
                           first=_resized(c.first, n, -1))
        if outcomes + margin > len(c.token):
            n = 2 * len(c.token)
            c = c._replace(token=_resized(c.token, n, 0), count=_resized(c.count, n, 0),
                           next=_resized(c.next, n, -1))
        if keys + margin > len(c.keys) // 2:
            slots = 2 * len(c.keys)
            fresh_keys, fresh_values = np.full(slots, -1, np.int64), np.zeros(slots, np.int32)
            _rehash(c.keys, c.values, fresh_keys, fresh_values)
            c = c._replace(keys=fresh_keys, values=fresh_values)
        self.counts = c


def _resized(array: np.ndarray, size: int, fill: int) -> np.ndarray:
    out = np.full(size, fill, array.dtype)
    out[:len(array)] = array
    return out


@numba.njit(inline="always")
def _slot(key, mask):
    h = np.uint64(key)
    h = (h ^ (h >> np.uint64(31))) * np.uint64(0x7FB5D329728EA185)
    h = (h ^ (h >> np.uint64(27))) * np.uint64(0x81DADEF4BC2DD44D)
    h = h ^ (h >> np.uint64(33))
    return np.int64(h & np.uint64(mask))


@numba.njit(inline="always")
def _key(parent, kind, token):
    return (np.int64(parent) << 32) | (np.int64(kind) << 31) | np.int64(token)


@numba.njit(inline="always")
def _probe(keys, key):
    """The slot holding ``key``, or the empty slot where it would go (linear probing)."""
    mask = len(keys) - 1
    s = _slot(key, mask)
    while keys[s] != -1 and keys[s] != key:
        s = (s + 1) & mask
    return s


@numba.njit(inline="always")
def _find(keys, values, key):
    s = _probe(keys, key)
    return values[s] if keys[s] == key else -1


@numba.njit(inline="always")
def _find_or_add(keys, values, sizes, key, counter):
    """The id stored under ``key``, or a new id from ``sizes[counter]``."""
    s = _probe(keys, key)
    if keys[s] == key:
        return values[s]
    new = sizes[counter]
    sizes[counter] = new + 1
    sizes[0] += 1
    keys[s] = key
    values[s] = new
    return new


@numba.njit(cache=True)
def _rehash(old_keys, old_values, keys, values):
    mask = len(keys) - 1
    for i in range(len(old_keys)):
        if old_keys[i] != -1:
            s = _slot(old_keys[i], mask)
            while keys[s] != -1:
                s = (s + 1) & mask
            keys[s] = old_keys[i]
            values[s] = old_values[i]


@numba.njit(inline="always")
def _walk(keys, values, obs, act, i, max_order, path, chain):
    """The seen contexts at step ``i``, read backwards from ``A_i``: ``path[d]`` is the node
    of the ``d + 1`` newest events (``A_i``, then ``O_{i-1}``, ``A_{i-1}``, ...), and
    ``chain[j]`` that of order ``j`` (``path[0]``, ``path[1]``, ``path[3]``, ...).
    Returns the number of events matched (0: nothing seen)."""
    node = _find(keys, values, _key(0, _CONTEXT, act[i]))
    if node < 0:
        return 0
    path[0] = node
    chain[0] = node
    depth = 1
    for j in range(1, max_order + 1):
        if i - j < 0:
            break
        if j >= 2:
            node = _find(keys, values, _key(node, _CONTEXT, act[i - j + 1]))
            if node < 0:
                break
            path[depth] = node
            depth += 1
        node = _find(keys, values, _key(node, _CONTEXT, obs[i - j]))
        if node < 0:
            break
        path[depth] = node
        chain[j] = node
        depth += 1
    return depth


@numba.njit(inline="always")
def _count(keys, values, sizes, total, distinct, best, best_count, first, token, count, nxt,
           node, outcome):
    """One more occurrence of ``outcome`` after context ``node``; the most frequent outcome,
    ties to the most recent, stays in ``best``."""
    record = _find_or_add(keys, values, sizes, _key(node, _OUTCOME, outcome), 2)
    if count[record] == 0:
        token[record] = outcome
        nxt[record] = first[node]
        first[node] = record
        distinct[node] += 1
    count[record] += 1
    total[node] += 1
    if count[record] >= best_count[node]:
        best_count[node] = count[record]
        best[node] = outcome


@numba.njit(inline="always")
def _learn_step(keys, values, sizes, total, distinct, best, best_count, first, token, count,
                nxt, seen, alphabet, obs, act, i, max_order):
    y = obs[i]
    node = _find_or_add(keys, values, sizes, _key(0, _CONTEXT, act[i]), 1)
    _count(keys, values, sizes, total, distinct, best, best_count, first, token, count, nxt,
           node, y)
    for j in range(1, min(max_order, i) + 1):
        if j >= 2:  # the context of order j - 1/2, which begins at an action
            node = _find_or_add(keys, values, sizes, _key(node, _CONTEXT, act[i - j + 1]), 1)
            _count(keys, values, sizes, total, distinct, best, best_count, first, token,
                   count, nxt, node, y)
        node = _find_or_add(keys, values, sizes, _key(node, _CONTEXT, obs[i - j]), 1)
        _count(keys, values, sizes, total, distinct, best, best_count, first, token, count,
               nxt, node, y)
    if seen[y] == 0:
        seen[y] = 1
        alphabet[sizes[3]] = y
        sizes[3] += 1
    sizes[4] += 1


@numba.njit(inline="always")
def _ppm(first, token, count, nxt, mark, alphabet, sizes, chain, depth, method, dist, write):
    """PPM over the contexts ``chain[depth - 1] .. chain[0]`` (longest first).

    Returns ``(argmax token or -1, novel-symbol mass)``; writes every probability into
    ``dist`` when ``write``.
    """
    stamp = sizes[5] + 1
    sizes[5] = stamp
    weight, best_token, best_p, excluded = 1.0, -1, -1.0, 0
    for level in range(depth - 1, -1, -1):
        n, t = 0, 0
        r = first[chain[level]]
        while r >= 0:
            if mark[token[r]] != stamp:
                n += count[r]
                t += 1
            r = nxt[r]
        if t == 0:
            continue
        denom = (n + t) if method == 1 else 2 * n
        r = first[chain[level]]
        while r >= 0:
            y = token[r]
            if mark[y] != stamp:
                share = count[r] if method == 1 else 2 * count[r] - 1
                p = weight * share / denom
                if write:
                    dist[y] = p
                if p > best_p:
                    best_token, best_p = y, p
                mark[y] = stamp
                excluded += 1
            r = nxt[r]
        weight *= t / denom
    remaining = sizes[3] - excluded
    p = weight / (remaining + 1)
    if remaining > 0:
        for a in range(sizes[3]):
            y = alphabet[a]
            if mark[y] != stamp:
                if write:
                    dist[y] = p
                if p > best_p:
                    best_token, best_p = y, p
    return best_token, p


@numba.njit(cache=True)
def _run(c, obs, act, step, max_order, learn, predict, method, ppm_order, path, chain, vom,
         half, deepest, ppm):
    """Predict then count steps from ``step`` on; returns the next step to do (it stops
    early, before a step, when a table could fill up)."""
    keys, values, sizes, total, distinct = c.keys, c.values, c.sizes, c.total, c.distinct
    best, best_count, first, token, count, nxt = c.best, c.best_count, c.first, c.token, c.count, c.next
    seen, mark, alphabet = c.seen, c.mark, c.alphabet
    n = len(obs) - 1
    margin = 4 * max_order + 4  # nodes, records and keys one step may add
    scratch = np.zeros(0)
    while step <= n:
        if learn and (sizes[0] + margin > len(keys) // 2 or sizes[1] + margin > len(total)
                      or sizes[2] + margin > len(token)):
            return step
        if predict:
            depth = _walk(keys, values, obs, act, step, max_order, path, chain)
            orders = depth // 2 + 1 if depth > 0 else 0  # step-aligned contexts seen
            deepest[step - 1] = orders - 1
            if depth > 0:
                for k in range(1, max_order + 1):
                    vom[step - 1, k - 1] = best[chain[min(k, orders - 1)]]
                for k in range(1, max_order):
                    half[step - 1, k - 1] = best[path[min(2 * k, depth - 1)]]
            if method > 0:
                ppm[step - 1] = _ppm(first, token, count, nxt, mark, alphabet, sizes, chain,
                                     min(orders, ppm_order + 1), method, scratch, False)[0]
        if learn:
            _learn_step(keys, values, sizes, total, distinct, best, best_count, first, token,
                        count, nxt, seen, alphabet, obs, act, step, max_order)
        step += 1
    return step


@numba.njit(cache=True)
def _distribution(c, obs, act, step, max_order, ppm_order, method, path, chain, dist):
    depth = _walk(c.keys, c.values, obs, act, step, max_order, path, chain)
    orders = depth // 2 + 1 if depth > 0 else 0
    return _ppm(c.first, c.token, c.count, c.next, c.mark, c.alphabet, c.sizes, chain,
                min(orders, ppm_order + 1), method, dist, True)[1]


def step_tokens(episode: Episode, table: TokenTable | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(obs, act)`` token arrays of an episode (``act[0]`` is -1: nothing before the start)."""
    tokens = (table or TokenTable()).tokenize(episode)
    act = np.full((len(tokens) + 1) // 2, -1, np.int32)
    act[1:] = tokens[1::2]
    return tokens[0::2].copy(), act


@dataclass(frozen=True)
class PeerCorrect:
    """Per step, whether each peer was right (abstentions count as wrong).

    Attributes:
        vom: ``(steps, max_order)``; column ``k - 1`` is VOM(k).
        half: ``(steps, max_order - 1)``; column ``k - 1`` is VOM(k + 1/2).
        akom: AKOM(``akom_order``).
        ppm: PPM (``ppm`` method, order ``ppm_order``).
    """

    vom: np.ndarray
    half: np.ndarray
    akom: np.ndarray
    ppm: np.ndarray


def prequential_correct(episode: Episode, max_order: int = 6, akom_order: int = 5,
                        ppm: str = "C", ppm_order: int = 5) -> PeerCorrect:
    """Every peer online from empty on one episode: predict each step, then learn it."""
    obs, act = step_tokens(episode)
    found = CountModel(max_order).run(obs, act, ppm=ppm, ppm_order=ppm_order)
    truth = obs[1:]
    return PeerCorrect(found.vom == truth[:, None], found.half == truth[:, None],
                       found.akom(akom_order) == truth, found.ppm == truth)


def channel_map(vocabulary: Vocabulary) -> np.ndarray:
    """``channel_of[symbol]``: the index of each symbol's channel in ``vocabulary.channels()``."""
    channel_of = np.full(len(vocabulary), -1, np.int32)
    for index, channel in enumerate(vocabulary.channels()):
        channel_of[vocabulary.symbols_of(channel)] = index
    return channel_of


@dataclass(frozen=True)
class ChannelCorrect:
    """The per-channel peer on one episode.

    Attributes:
        step: per step, whether every channel reporting in it was predicted right.
        channels: ``{channel index: (steps where it reports, whether it was right there)}``.
    """

    step: np.ndarray
    channels: dict[int, tuple[np.ndarray, np.ndarray]]


def per_channel_correct(episode: Episode, channel_of: np.ndarray, order: int = 2,
                        observation_channels: list[int] | None = None) -> ChannelCorrect:
    """VOM(order) per observation channel, online from empty (see the module docstring)."""
    _, act = step_tokens(episode)
    lead = len(act) - len(episode)  # 1 when the stream starts with an empty observation
    n = len(act) - 1
    step_ok = np.ones(n, bool)
    channels = {}
    for channel, (held, reports) in _held_readings(episode, channel_of, observation_channels,
                                                   lead).items():
        found = CountModel(order).run(held, act, ppm=None)
        ok = found.vom[:, order - 1] == held[1:]
        where = np.flatnonzero(reports[1:])
        channels[channel] = (where, ok[where])
        step_ok[where] &= ok[where]
    return ChannelCorrect(step_ok, channels)


def _held_readings(episode: Episode, channel_of: np.ndarray, observation_channels: list[int] | None,
                   lead: int) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Per observation channel: its last reading at every step (a token past the symbols
    before its first one) and whether it reports in that step; ``lead`` steps of nothing
    first."""
    symbols, offsets, n_actions = episode.symbols, episode.step_offsets, episode.n_actions
    step_of = np.repeat(np.arange(len(episode)), np.diff(offsets))
    is_obs = np.arange(len(symbols)) - offsets[step_of] >= n_actions[step_of]
    wanted = observation_channels or sorted(set(channel_of[symbols[is_obs]].tolist()))
    none = int(symbols.max()) + 1 if len(symbols) else 0
    out = {}
    for channel in wanted:
        mine = is_obs & (channel_of[symbols] == channel)
        reports = np.zeros(len(episode), bool)
        reports[step_of[mine]] = True
        latest = np.full(len(episode), -1, np.int64)
        latest[step_of[mine]] = np.flatnonzero(mine)  # the last reading of a step wins
        held = np.maximum.accumulate(np.concatenate((np.full(lead, -1), latest)))
        out[channel] = (np.where(held >= 0, symbols[np.maximum(held, 0)], none).astype(np.int32),
                        np.concatenate((np.zeros(lead, bool), reports)))
    return out


def load_c_vom(build_dir: str | Path | None = None) -> Callable[[np.ndarray, int], np.ndarray] | None:
    """The C VOM(k) of ``bench/c/vom.c``, compiled now; ``None`` without a C compiler.

    The shared library is built in ``build_dir`` (default: a temporary folder, removed once
    the library is loaded). Returns ``vom(tokens, order) -> predictions``: ``tokens`` an
    int32 ``O A ... O`` array, one prediction per step (-1 = abstained).
    """
    compiler = next((c for c in ("cc", "gcc", "clang") if shutil.which(c)), None)
    if compiler is None:
        return None
    if build_dir is None:
        with tempfile.TemporaryDirectory(prefix="slearn-cvom-") as folder:
            return _compile_and_load(compiler, Path(folder))
    return _compile_and_load(compiler, Path(build_dir))


def _compile_and_load(compiler: str, folder: Path) -> Callable[[np.ndarray, int], np.ndarray]:
    library = folder / "libvom.so"
    subprocess.run([compiler, "-O2", "-shared", "-fPIC", "-o", str(library), str(_C_SOURCE)],
                   check=True, capture_output=True)
    lib = ctypes.CDLL(str(library))
    lib.vom_run.restype = ctypes.c_int64
    lib.vom_run.argtypes = [ctypes.c_void_p, ctypes.c_int64, ctypes.c_int32, ctypes.c_void_p]

    def vom(tokens: np.ndarray, order: int) -> np.ndarray:
        tokens = np.ascontiguousarray(tokens, np.int32)
        out = np.full(max((len(tokens) - 1) // 2, 0), -1, np.int32)
        if lib.vom_run(tokens.ctypes.data, len(tokens), order, out.ctypes.data) < 0:
            raise MemoryError("the C VOM ran out of memory")
        return out

    return vom
