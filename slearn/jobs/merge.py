"""Merging libraries learned separately, as if their episodes had been learned in one run.

``merge_libraries(a, b)`` is the library of learning ``a``'s episodes, then ``b``'s, in one
run. Episodes are never glued together, so every occurrence counted in ``a`` or ``b`` is
counted once in the run and nothing else is: counts add, and recency is ``b``'s last
occurrence on the run's clock (``a``'s clock plus ``b``'s) where ``b`` saw the pattern,
else ``a``'s. Patterns come in the run's order: ``a``'s, then those new in ``b`` in ``b``'s
order; vocabularies and token tables likewise. So counts, recency and order are exactly
those of one run (a property test checks it against the run).

The scoring state depends on the order of predictions, so it follows a rule:

* the expert weights, the persistence specialists, the change detector and the rounds
  of a view (the weights' age, :mod:`slearn.core.mixer`) are ``b``'s when ``b`` predicted
  anything in the view (they were trained on the latest data), else ``a``'s (a new
  library's, where ``a`` does not have the view either);
* the detector's calibration counts (hits and trials per cell, over all time) add, as
  they would in one run (the predictions behind them differ in ``b``, which started
  from empty);
* fresh counts: when ``b``'s detector raised an alarm in a view, the run's current epoch
  began inside ``b``, so the view's fresh counts are ``b``'s and its epoch is the sum of
  both; otherwise the epoch that was current at the end of ``a`` went on through ``b``,
  and fresh counts add.

The held-out accuracy of a merged library against the one-run library is measured by
``bench/bench_ray.py`` (its ``--merge-tree`` run, against one process). With forgetting
(``max_patterns``) the merge keeps every pattern of both, then forgets down to the bound
(which one run would have done earlier).
Literal libraries (the paper's parse rule) merge their parse counts the same way; their
parses are not those of one run.
"""

from __future__ import annotations

import os
import warnings
from typing import cast

import numpy as np

from slearn import __version__
from slearn.core.library import FORGET_TO, PatternLibrary
from slearn.core.literal import LiteralLibrary
from slearn.core.mixer import Mixer, new_mixer
from slearn.core.tokens import TokenTable
from slearn.core.vocabulary import Vocabulary
from slearn.errors import DataWarning, InputError, SpecError
from slearn.io.files import check_output
from slearn.io.library_file import LoadedLibrary, SaveSummary, file_record, load_library, save_library


def merge_libraries(a: LoadedLibrary, b: LoadedLibrary, *, consume: bool = False) -> LoadedLibrary:
    """The library of learning ``a``'s episodes, then ``b``'s (see the module docstring).

    ``consume``: ``a``'s library becomes the merged one (extended in place, not rebuilt: a
    chain of merges then costs what each added library costs); do not use ``a`` after.

    Raises:
        SpecError: the libraries are incompatible (spec, channels, roles, parameters).
    """
    names = f"{a.path or 'library A'} and {b.path or 'library B'}"
    reason = _incompatibility(a, b)
    if reason:
        raise SpecError(f"cannot merge {names}: {reason}: only libraries learned with the same spec and "
                        "options merge; learn one again with the other's (`slearn info --json` shows them)")
    overflow = _overflow(a.library, b.library)
    if overflow:
        raise InputError(f"cannot merge {names}: {overflow}; no library learned from logs counts "
                         "that high, so one of them was edited: re-create it with slearn learn")
    vocabulary, symbol_map = _merged_vocabulary(a.vocabulary, b.vocabulary)
    tokens, token_map = _merged_tokens(a.library.tokens, b.library.tokens, symbol_map)
    library: PatternLibrary | LiteralLibrary
    if isinstance(a.library, LiteralLibrary):  # both are: _incompatibility checked the scoring
        library = _merged_literal(a.library, cast(LiteralLibrary, b.library), tokens, token_map)
    else:
        library = _merged_occurrences(a.library, cast(PatternLibrary, b.library), tokens, token_map, vocabulary,
                                      consume)
    library.forgotten = a.library.forgotten + b.library.forgotten
    if library.max_patterns is not None and len(library) > library.max_patterns:
        library.forget(int(library.max_patterns * FORGET_TO))
    return LoadedLibrary(library, vocabulary, a.spec if a.spec is not None else b.spec,
                         dict(a.params), _merged_provenance(a.provenance, b.provenance))


def merge_files(paths: list[str | os.PathLike], output: str | os.PathLike, *,
                overwrite: bool = False) -> SaveSummary:
    """Merge library files in order (``((A + B) + C) ...``) into ``output``.

    Provenance lists every input log of every library and, under ``merged_from``, the
    library files themselves (path, size, sha256).

    Raises:
        InputError: fewer than two libraries, ``output`` exists without ``overwrite``, or
            ``output`` is one of the libraries (refused even with ``overwrite``).
        LibraryFormatError, SpecError: as :func:`load_library` and :func:`merge_libraries`.
    """
    if len(paths) < 2:
        raise InputError("merge needs at least two libraries")
    check_output(output, overwrite, inputs=paths)
    merged = load_library(paths[0])
    for path in paths[1:]:
        merged = merge_libraries(merged, load_library(path), consume=True)
    merged.provenance["merged_from"] = [file_record(p) for p in paths]
    for message in _double_counts(merged.provenance):
        warnings.warn(DataWarning(message), stacklevel=2)
    return save_library(output, merged.library, merged.vocabulary, spec=merged.spec,
                        params=merged.params, provenance=merged.provenance, overwrite=overwrite)


def _overflow(a: PatternLibrary | LiteralLibrary, b: PatternLibrary | LiteralLibrary) -> str | None:
    """What of ``a`` and ``b`` would sum past its integer type in the merge (counts,
    fresh counts, the clock, alarms, calibration), else ``None``: merging then writes
    no library that loading would refuse."""
    sums = [("clocks", a.clock, b.clock, np.int64), ("forgotten counts", a.forgotten, b.forgotten, np.int64)]
    for name, x, y in _largest(a, b):
        sums.append((name, x, y, np.int64))
    ma, mb = getattr(a, "mixer", None), getattr(b, "mixer", None)
    if ma is not None and mb is not None:
        sums += [("alarm counts", int(ma.epoch.max(initial=0)), int(mb.epoch.max(initial=0)), ma.epoch.dtype),
                 ("calibration counts", int(ma.calibration.max(initial=0)), int(mb.calibration.max(initial=0)),
                  np.int64)]
    for name, x, y, kind in sums:
        if int(x) + int(y) > np.iinfo(kind).max:
            return f"their {name} would sum past {np.iinfo(kind).max:,} ({int(x):,} + {int(y):,})"
    return None


def _largest(a: PatternLibrary | LiteralLibrary, b: PatternLibrary | LiteralLibrary) -> list[tuple[str, int, int]]:
    """The largest pattern count (and fresh count) of each library."""
    def largest(library) -> tuple[int, int]:
        if isinstance(library, LiteralLibrary):
            return library.max_count(), 0
        n = int(library.tree.size[1])
        return int(library.tree.count[:n].max(initial=0)), int(library.tree.fresh[:n].max(initial=0))
    (ca, fa), (cb, fb) = largest(a), largest(b)
    return [("pattern counts", ca, cb), ("fresh counts", fa, fb)]


def _incompatibility(a: LoadedLibrary, b: LoadedLibrary) -> str | None:
    for key in ("scoring", "max_length", "max_patterns", "factored", "has_actions", "action_scopes"):
        if a.params.get(key) != b.params.get(key):
            return f"{key} {a.params.get(key)!r} vs {b.params.get(key)!r}"
    if (a.spec is None) != (b.spec is None):
        return "one library has a spec and the other has none"
    if a.spec is not None and b.spec is not None:
        reason = _spec_difference(a.spec.to_dict(), b.spec.to_dict())
        if reason:
            return reason
    for channel, role in b.vocabulary.roles.items():
        if a.vocabulary.roles.get(channel, role) != role:
            return f"channel {channel!r} is {a.vocabulary.roles[channel]} in one and {role} in the other"
    return None


def _spec_difference(a: dict, b: dict) -> str | None:
    for key in ("mode", "tick_ns"):
        if a.get(key) != b.get(key):
            return f"spec {key} {a.get(key)!r} vs {b.get(key)!r}"
    names_a = [c["name"] for c in a["channel"]]
    names_b = [c["name"] for c in b["channel"]]
    if names_a != names_b:
        return f"different channels: {names_a} vs {names_b}"
    for ca, cb in zip(a["channel"], b["channel"]):
        for key in sorted(set(ca) | set(cb)):
            if ca.get(key) != cb.get(key):
                what = "bins" if key in ("edges", "range", "count", "width", "origin", "quantiles", "wrap") else key
                return f"channel {ca['name']!r}: {what} differ ({key} {ca.get(key)!r} vs {cb.get(key)!r})"
    return None


def _merged_vocabulary(a: Vocabulary, b: Vocabulary) -> tuple[Vocabulary, np.ndarray]:
    merged = Vocabulary()
    for channel, role in [*a.roles.items(), *b.roles.items()]:
        merged.add_channel(channel, role)
    for _, channel, value in a.items():
        merged.symbol(channel, value)
    symbol_map = np.array([merged.symbol(c, v) for _, c, v in b.items()], dtype=np.int32)
    return merged, symbol_map


def _merged_tokens(a: TokenTable, b: TokenTable, symbol_map: np.ndarray) -> tuple[TokenTable, np.ndarray]:
    merged = TokenTable.from_export(*a.export())
    offsets, symbols, kinds = b.export()
    remapped = symbol_map[symbols] if len(symbols) else symbols
    token_map = np.array([merged.intern(int(kinds[t]), remapped[offsets[t]:offsets[t + 1]])
                          for t in range(len(kinds))], dtype=np.int32)
    return merged, token_map


def _rows(offsets: np.ndarray, tokens: np.ndarray, lead: np.ndarray, width: int) -> np.ndarray:
    """Patterns as a padded matrix ``[lead, tokens..., -1, ...]`` (one row per pattern)."""
    lengths = np.diff(offsets)
    rows = np.full((len(lengths), width + 1), -1, np.int64)
    rows[:, 0] = lead
    which = np.repeat(np.arange(len(lengths)), lengths)
    rows[which, 1 + np.arange(len(tokens)) - np.repeat(offsets[:-1], lengths)] = tokens
    return rows


def _union(rows_a: np.ndarray, rows_b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(rows of the union in run order, index of each a row, index of each b row)``."""
    rows = np.concatenate([rows_a, rows_b])
    if len(rows) == 0:
        return rows, np.zeros(0, np.int64), np.zeros(0, np.int64)
    order = np.lexsort(rows.T[::-1])
    new_group = np.ones(len(rows), bool)
    new_group[1:] = np.any(rows[order][1:] != rows[order][:-1], axis=1)
    group = np.empty(len(rows), np.int64)
    group[order] = np.cumsum(new_group) - 1
    first = np.full(int(group.max()) + 1, len(rows), np.int64)
    np.minimum.at(first, group, np.arange(len(rows)))
    rank = np.empty(len(first), np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(len(first))
    where = rank[group]
    return rows[np.sort(first)], where[: len(rows_a)], where[len(rows_a):]


def _unpadded(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    mask = rows[:, 1:] >= 0
    offsets = np.concatenate([[0], np.cumsum(mask.sum(axis=1))]).astype(np.int64)
    return offsets, rows[:, 1:][mask].astype(np.int32)


def _summed(n: int, where_a, where_b, values_a, values_b) -> np.ndarray:
    out = np.zeros(n, np.int64)
    np.add.at(out, where_a, values_a)
    np.add.at(out, where_b, values_b)
    return out


def _recency(n: int, where_a, where_b, seen_a, seen_b, shift: int) -> np.ndarray:
    out = np.zeros(n, np.int64)
    out[where_a] = seen_a
    out[where_b] = seen_b + shift  # b is later: its occurrence, where it has one, is the last
    return out


def _merged_occurrences(a: PatternLibrary, b: PatternLibrary, tokens: TokenTable,
                        token_map: np.ndarray, vocabulary: Vocabulary, consume: bool = False) -> PatternLibrary:
    """``a`` (or, unless ``consume``, a copy of it) rebased onto the merged tokens, views and
    scoring state, then ``b``'s patterns counted into it (``PatternLibrary.add_export``): the
    union in run order, counts summed, recency on one clock. In the views where ``b`` raised
    an alarm the merged epoch is past ``a``'s, so ``a``'s fresh counts there end (they belong
    to an epoch that ended)."""
    names = list(a.view_names) + [v for v in b.view_names if v not in a.view_names]
    view_map = np.array([names.index(v) for v in b.view_names], np.int32)
    eb, shift = b.export(), a.clock
    mixer = _merged_mixer(a, b, names, view_map)
    merged = a if consume else PatternLibrary.from_export(
        a.export(), tokens=a.tokens, clock=a.clock, view_names=a.view_names,
        mixer=a.mixer if a.mixer is not None else new_mixer(len(a.view_names), a.max_context),
        max_length=a.max_length, max_patterns=a.max_patterns, vocabulary=a.vocabulary,
        has_actions=a.has_actions, action_scopes=a.action_scopes)
    merged.rebase(tokens=tokens, clock=a.clock + b.clock, view_names=names, mixer=mixer,
                  vocabulary=vocabulary if a.factored else None)
    if len(eb["view"]):
        eb = {**eb, "view": view_map[eb["view"]], "pattern_tokens": token_map[eb["pattern_tokens"]]}
    merged.add_export(eb, shift=shift)
    return merged


def _merged_mixer(a: PatternLibrary, b: PatternLibrary, names: list[str],
                  view_map: np.ndarray) -> Mixer:
    """The views' scoring state: weights, persistence specialists and test of the later
    library where it trained them, alarms (so epochs) and calibration counts summed."""
    ma, mb = a.mixer, b.mixer
    n, k = len(names), a.max_context
    weights, detector, epoch, calibration, rounds, persist = new_mixer(n, k)  # untrained where neither trained
    if ma is not None:
        na = len(a.view_names)
        weights[:na], detector[:na], epoch[:na] = ma.weight[:na], ma.detector[:na], ma.epoch[:na]
        calibration[:na], rounds[:na], persist[:na] = ma.calibration[:na], ma.rounds[:na], ma.persist[:na]
    if mb is not None:
        for i, j in enumerate(view_map.tolist()):
            if mb.rounds[i] > 0:  # b predicted in the view: its weights are the latest
                weights[j], detector[j], rounds[j] = mb.weight[i], mb.detector[i], mb.rounds[i]
                persist[j] = mb.persist[i]
            epoch[j] += mb.epoch[i]
            calibration[j] += mb.calibration[i]
    return Mixer(weights, detector, epoch, calibration, rounds, persist)


def _merged_literal(a: LiteralLibrary, b: LiteralLibrary, tokens: TokenTable,
                    token_map: np.ndarray) -> LiteralLibrary:
    ea, eb = a.export(), b.export()
    width = 2 * a.max_length + 1
    tokens_b = token_map[eb["pattern_tokens"]] if len(eb["pattern_tokens"]) else eb["pattern_tokens"]
    rows, wa, wb = _union(_rows(ea["pattern_offsets"], ea["pattern_tokens"], np.zeros(len(ea["count"])), width),
                          _rows(eb["pattern_offsets"], tokens_b, np.zeros(len(eb["count"])), width))
    offsets, flat = _unpadded(rows)
    arrays = {"pattern_offsets": offsets, "pattern_tokens": flat,
              "count": _summed(len(rows), wa, wb, ea["count"], eb["count"]),
              "last_seen": _recency(len(rows), wa, wb, ea["last_seen"], eb["last_seen"], a.clock)}
    return LiteralLibrary.from_export(arrays, tokens, a.clock + b.clock, a.max_length, a.max_patterns)


def _double_counts(provenance: dict) -> list[str]:
    """Warnings for a library file given twice (or a copy of one) and for a log that more
    than one of the libraries learned (its time counts double, as ``learn`` warns)."""
    from slearn.jobs.learn import repeated_inputs

    seen: dict[str, str] = {}
    for record in provenance["merged_from"]:
        first = seen.get(record["sha256"])
        if first is not None:
            what = "given twice" if first == record["path"] else f"the bytes of {first}"
            return [f"{record['path']}: {what}: its counts count double (give each library once)"]
        seen[record["sha256"]] = record["path"]
    return [m.replace(" into this library", " by another of the merged libraries")
            for m in repeated_inputs(provenance.get("inputs", []))]


def _merged_provenance(a: dict, b: dict) -> dict:
    time_a, time_b = a.get("time_unix", 0), b.get("time_unix", 0)
    newest = a if time_a >= time_b else b
    return {"slearn_version": __version__, "inputs": [*a.get("inputs", []), *b.get("inputs", [])],
            "time": newest.get("time"), "time_unix": max(time_a, time_b),
            "time_source": "newest of the merged libraries"}
