"""What a library file holds, for ``slearn info LIB.parquet``: plain data and a text rendering."""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from slearn.core.tokens import TokenTable
from slearn.core.vocabulary import Vocabulary
from slearn.io.library_file import load_library, read_info
from slearn.io.spec import value_labels

TOP_PATTERNS = 10
MAX_LISTED_VALUES = 100


def describe(path: str | os.PathLike) -> "LibraryDescription":
    """Pattern count, lengths, vocabulary, the most frequent patterns decoded, parameters,
    provenance and bytes per pattern of a library file. The file is loaded whole first: the
    checks are those replay, resume and merge make.

    Raises:
        LibraryFormatError: the file is not a readable library (as :func:`load_library`).
    """
    path = Path(path)
    loaded = load_library(path)
    doc = read_info(path)
    vocabulary, library = loaded.vocabulary, loaded.library
    if loaded.spec is not None:  # bins read as value ranges
        vocabulary.value_labels.update(value_labels(loaded.spec))
    arrays = library.export()
    size, n = path.stat().st_size, len(arrays["count"])
    literal = doc["params"].get("scoring") == "literal"
    lengths = np.diff(arrays["pattern_offsets"])
    context = lengths // 2 if literal else lengths - 1  # literal: steps; else context tokens
    return LibraryDescription({
        "kind": "library", "path": str(path), "format": doc["format"], "format_version": doc["version"],
        "size_bytes": size, "patterns": n, "bytes_per_pattern": size / n if n else 0.0,
        "clock": doc["library"]["clock"], "forgotten": doc["library"]["forgotten"],
        "total_count": int(arrays["count"].sum()),
        "length_unit": "steps" if literal else "context tokens",
        "length_histogram": {str(k): int(c) for k, c in enumerate(np.bincount(context)) if c},
        "mean_length": float(context.mean()) if n else 0.0,
        "views": list(getattr(library, "view_names", [])),
        "vocabulary": _describe_vocabulary(vocabulary),
        "top_patterns": _top_patterns(arrays, library.tokens, vocabulary),
        "params": doc["params"], "spec": doc["spec"], "provenance": doc["provenance"],
    })


class LibraryDescription(dict):
    """The plain data of :func:`describe`, with a text rendering for ``slearn info``."""

    def to_dict(self) -> dict:
        """The plain JSON-able data."""
        return dict(self)

    def render(self) -> str:
        """Human-readable text (several lines)."""
        params = self["params"]
        histogram = ", ".join(f"{k}: {v:,}" for k, v in self["length_histogram"].items())
        lines = [self["path"],
                 f"  pattern library (format {self['format_version']}), {self['patterns']:,} patterns, "
                 f"{self['size_bytes']:,} bytes ({self['bytes_per_pattern']:.1f} bytes/pattern), "
                 f"clock {self['clock']:,} steps, {self['forgotten']:,} forgotten",
                 f"  max length {params.get('max_length')} steps, max patterns "
                 f"{params.get('max_patterns') or '-'}, scoring {params.get('scoring')}",
                 f"  patterns by {self['length_unit']}: {histogram or '-'} "
                 f"(mean {self['mean_length']:.2f})",
                 f"  vocabulary: {self['vocabulary']['symbols']} symbols"]
        for view, actions in (params.get("action_scopes") or {}).items():
            lines.insert(-1, f"  {view} sees the actions of: {', '.join(actions) or 'none'}")
        for channel in self["vocabulary"]["channels"]:
            values = ", ".join(map(str, channel.get("labels", channel["values"])[:12]))
            more = " ..." if channel["n_values"] > 12 else ""
            lines.append(f"    {channel['channel']:<32} {channel['role']:<11} {channel['n_values']:>6}  "
                         f"{values}{more}")
        lines.append("  top patterns (count, last seen):")
        lines += [f"    {p['count']:>8,} {p['last_seen']:>10,}  {p['pattern']}" for p in self["top_patterns"]]
        return "\n".join(lines + self._provenance_lines())

    def _provenance_lines(self) -> list[str]:
        provenance = self["provenance"] or {}
        inputs = provenance.get("inputs", [])
        lines = [f"  learned by slearn {provenance.get('slearn_version')} from {len(inputs)} log(s), "
                 f"time {provenance.get('time')} ({provenance.get('time_source')})"]
        lines += [f"    {i['path']}  {i['size_bytes']:,} bytes  sha256 {i['sha256'][:16]}"
                  for i in inputs[:5]]
        return lines + ([f"    ... {len(inputs) - 5} more"] if len(inputs) > 5 else [])


def _describe_vocabulary(vocabulary: Vocabulary) -> dict:
    values: dict[str, list] = {c: [] for c in vocabulary.channels()}
    for _, channel, value in vocabulary.items():
        values[channel].append(value)
    shown = {c: [vocabulary.value_labels[c](x) for x in v[:MAX_LISTED_VALUES]]
             if c in vocabulary.value_labels else None for c, v in values.items()}
    return {"symbols": len(vocabulary), "channels": [
        {"channel": c, "role": vocabulary.roles[c], "n_values": len(v),
         "values": [_jsonable(x) for x in v[:MAX_LISTED_VALUES]],
         **({"labels": shown[c]} if shown[c] is not None else {})} for c, v in values.items()]}


def _jsonable(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    return list(value) if isinstance(value, tuple) else value


def _top_patterns(arrays: dict, tokens: TokenTable, vocabulary: Vocabulary) -> list[dict]:
    count, seen = arrays["count"], arrays["last_seen"]
    order = np.lexsort((np.arange(len(count)), -seen, -count))
    labels = _short_labels(vocabulary)
    offsets, flat = arrays["pattern_offsets"], arrays["pattern_tokens"]
    top = []
    for i in order[:TOP_PATTERNS].tolist():
        pattern = [list(tokens.symbols(int(t))) for t in flat[offsets[i]:offsets[i + 1]]]
        top.append({"pattern": " ".join("+".join(labels[s] for s in t) or "-" for t in pattern),
                    "length": len(pattern), "count": int(count[i]), "last_seen": int(seen[i]),
                    "tokens": [_token_events(vocabulary, t) for t in pattern]})
    return top


def _token_events(vocabulary: Vocabulary, symbols: list[int]) -> dict:
    """``{channel: value}`` of one token (a list of values when a channel repeats)."""
    events: dict[str, Any] = {}
    for symbol in symbols:
        channel, value = vocabulary.name(symbol)
        value = _jsonable(value)
        events[channel] = [*events[channel], value] if isinstance(events.get(channel), list) else (
            [events[channel], value] if channel in events else value)
    return events


def _short_labels(vocabulary: Vocabulary) -> list[str]:
    """``value`` where the value's text belongs to one channel only, else ``channel=value``
    (bins as value ranges)."""
    texts = [(c, vocabulary.value_text(s)) for s, c, _ in vocabulary.items()]
    channels: dict[str, set[str]] = {}
    for channel, text in texts:
        channels.setdefault(text, set()).add(channel)
    return [t if len(channels[t]) == 1 else f"{c}={t}" for c, t in texts]
