"""Pattern libraries on disk: one Parquet file holds a library, its vocabulary and its spec.

Layout (format ``slearn-library``, version 1). Three tables share one schema; a row
belongs to the table named in its ``table`` column, each table has its own row groups
(written in this order) and the columns of the other tables are null::

    column        type                 table       holds
    table         string               all         "vocabulary" | "token" | "pattern"
    channel       string               vocabulary  row i is symbol i
    role          string               vocabulary  "action" | "observation"
    value_type    string               vocabulary  str | int | bool | float | bin | tuple
    value_int     int64                vocabulary  int, bool (0/1) and bin index values
    value_float   float64              vocabulary  float values
    value_text    string               vocabulary  str values; tuples as JSON lists
    token_kind    int8                 token       row t is token t: 0 observation, 1 action
    token_symbols list<int32>          token       the token's symbols
    pattern       list<int32>          pattern     symbols of the tokens O A O ... O, flattened
    token_sizes   list<int32>          pattern     symbols per token (a step may have 0, 1, many)
    parent        int32                pattern     row of the prefix one step shorter, -1 if none
    count         int64                pattern     times seen
    last_seen     int64                pattern     recency, a step on the library clock

Patterns come in recording order (a prefix before its extensions); ``parent`` only speeds
up loading (each pattern is attached to its prefix instead of walked from the root). The schema's key-value metadata ``slearn`` is a small
JSON document (read cheaply with ``pq.read_schema``): ``format``, ``version``, learner
``params`` (max_length, max_patterns, scoring), ``library`` (clock, forgotten, patterns,
channels with roles, rows per table), ``spec`` (fitted edges included, or null) and
``provenance``. Columns are zstd-compressed; pages carry checksums.

Files are written atomically (temp file in the same folder, fsync, rename, footer read
back) and deterministically: the same library gives the same bytes.
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import os
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Hashable, Iterator

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from slearn import __version__
from slearn.errors import InputError, LibraryFormatError, SpecError
from slearn.files import atomic_write, check_output, regular_file
from slearn.library import PatternLibrary
from slearn.library_header import FORMAT_NAME, FORMAT_VERSION, parse_header
from slearn.spec import Bins, Spec, value_labels
from slearn.tokens import OBSERVATION, TokenTable
from slearn.vocabulary import Vocabulary

METADATA_KEY = b"slearn"
TABLES = ("vocabulary", "token", "pattern")
ROW_GROUP_ROWS = 1 << 20
TOP_PATTERNS = 10
MAX_LISTED_VALUES = 100

_INT32 = pa.list_(pa.field("item", pa.int32(), nullable=False))
SCHEMA = pa.schema([
    ("table", pa.string()),
    ("channel", pa.string()),
    ("role", pa.string()),
    ("value_type", pa.string()),
    ("value_int", pa.int64()),
    ("value_float", pa.float64()),
    ("value_text", pa.string()),
    ("token_kind", pa.int8()),
    ("token_symbols", _INT32),
    ("pattern", _INT32),
    ("token_sizes", _INT32),
    ("parent", pa.int32()),
    ("count", pa.int64()),
    ("last_seen", pa.int64()),
])
_INT64_RANGE = (-(1 << 63), (1 << 63) - 1)


@dataclass
class LoadedLibrary:
    """A library read back from disk, with everything needed to go on using it.

    Attributes:
        library: the pattern library (token ids identical to the saved one).
        vocabulary: symbols and their ``(channel, value)`` names, values typed as saved.
        spec: the spec the library was learned with (fitted edges), or ``None``.
        params: learner parameters (``max_length``, ``max_patterns``, ``scoring``).
        provenance: slearn version, inputs (path, size, sha256), time.
        format_version: the file's format version.
        path: the file it came from (``None`` when built in memory, e.g. by a merge).
    """

    library: PatternLibrary
    vocabulary: Vocabulary
    spec: Spec | None
    params: dict
    provenance: dict
    format_version: int = FORMAT_VERSION
    path: str | None = None


@dataclass(frozen=True)
class SaveSummary:
    """What :func:`save_library` wrote."""

    path: str
    n_patterns: int
    size_bytes: int

    @property
    def bytes_per_pattern(self) -> float:
        """File bytes per pattern (0 for an empty library)."""
        return self.size_bytes / self.n_patterns if self.n_patterns else 0.0

    def to_dict(self) -> dict:
        """Plain JSON-able data."""
        return {"path": self.path, "patterns": self.n_patterns, "bytes": self.size_bytes,
                "bytes_per_pattern": self.bytes_per_pattern}


# --- saving ------------------------------------------------------------------------------

def save_library(path: str | os.PathLike, library: PatternLibrary, vocabulary: Vocabulary, *,
                 spec: Spec | None, params: dict, provenance: dict,
                 overwrite: bool = False) -> SaveSummary:
    """Write a library, its vocabulary, spec, parameters and provenance to one Parquet file.

    ``max_length`` and ``max_patterns`` in the stored parameters are the library's own.
    The write is atomic: an existing file is replaced only by a complete, verified file.

    Raises:
        InputError: ``path`` exists and ``overwrite`` is false, or it cannot be written.
        LibraryFormatError: the written file does not read back.
    """
    path = Path(path)
    check_output(path, overwrite)
    params = {**params, "max_length": library.max_length, "max_patterns": library.max_patterns}
    tables = [_vocabulary_table(vocabulary, spec, path), _token_table(library.tokens),
              _pattern_table(library, path)]
    metadata = _metadata(library, vocabulary, spec, params, provenance, [len(t) for t in tables])
    _write_atomic(path, tables, metadata, overwrite)
    return SaveSummary(str(path), len(library), path.stat().st_size)


def _metadata(library: PatternLibrary, vocabulary: Vocabulary, spec: Spec | None, params: dict,
              provenance: dict, rows: list[int]) -> dict[bytes, bytes]:
    doc = {
        "format": FORMAT_NAME, "version": FORMAT_VERSION, "params": params,
        "library": {"clock": library.clock, "forgotten": library.forgotten, "patterns": len(library),
                    "channels": [[c, r] for c, r in vocabulary.roles.items()],
                    "rows": dict(zip(TABLES, rows))},
        "spec": spec.to_dict() if spec is not None else None,
        "provenance": provenance,
    }
    return {METADATA_KEY: json.dumps(doc, sort_keys=True, separators=(",", ":")).encode()}


def _table(name: str, n: int, columns: dict[str, pa.Array]) -> pa.Table:
    arrays = [pa.repeat(pa.scalar(name, pa.string()), n)]
    arrays += [columns.get(f.name, pa.nulls(n, f.type)) for f in SCHEMA][1:]
    return pa.Table.from_arrays(arrays, schema=SCHEMA)


def _binned_channels(spec: Spec | None) -> set[str]:
    if spec is None:
        return set()
    return {c.name for c in spec.channels if isinstance(c.symbolizer, Bins)}


def _encode_value(channel: str, value: Hashable, binned: bool, path: Path) -> tuple:
    """``(value_type, value_int, value_float, value_text)`` of one vocabulary value."""
    if isinstance(value, (bool, np.bool_)):
        return "bool", int(value), None, None
    if isinstance(value, (int, np.integer)):
        kind = "bin" if binned else "int"
        inside = _INT64_RANGE[0] <= int(value) <= _INT64_RANGE[1]
        return (kind, int(value), None, None) if inside else (kind, None, None, str(int(value)))
    if isinstance(value, (float, np.floating)):
        return "float", None, float(value), None
    if isinstance(value, str):
        return "str", None, None, value
    if isinstance(value, tuple):
        try:
            return "tuple", None, None, json.dumps(value, separators=(",", ":"))
        except TypeError:
            pass
    raise InputError(f"{path}: cannot store value {value!r} of channel {channel!r} "
                     f"({type(value).__name__}): use a spec that makes it a string or a number")


def _vocabulary_table(vocabulary: Vocabulary, spec: Spec | None, path: Path) -> pa.Table:
    binned = _binned_channels(spec)
    items = list(vocabulary.items())
    rows = [_encode_value(c, v, c in binned, path) for _, c, v in items]
    kinds, ints, floats, texts = (list(col) for col in zip(*rows)) if rows else ([], [], [], [])
    return _table("vocabulary", len(items), {
        "channel": pa.array([c for _, c, _ in items], pa.string()),
        "role": pa.array([vocabulary.roles[c] for _, c, _ in items], pa.string()),
        "value_type": pa.array(kinds, pa.string()),
        "value_int": pa.array(ints, pa.int64()),
        "value_float": pa.array(floats, pa.float64()),
        "value_text": pa.array(texts, pa.string()),
    })


def _list_array(offsets: np.ndarray, values: np.ndarray, path: Path) -> pa.ListArray:
    if len(values) > np.iinfo(np.int32).max:
        raise InputError(f"{path}: more than 2**31 symbols in one table; lower --max-patterns")
    return pa.ListArray.from_arrays(pa.array(offsets.astype(np.int32)),
                                    pa.array(values.astype(np.int32, copy=False)), type=_INT32)


def _token_table(tokens: TokenTable) -> pa.Table:
    offsets, symbols, kinds = tokens.export()
    return _table("token", len(kinds), {
        "token_kind": pa.array(kinds, pa.int8()),
        "token_symbols": _list_array(offsets, symbols, Path("<tokens>")),
    })


def _pattern_table(library: PatternLibrary, path: Path) -> pa.Table:
    export = library.export()
    token_offsets, token_symbols, _ = library.tokens.export()
    tokens = export["pattern_tokens"]
    sizes = np.diff(token_offsets)[tokens]
    ends = np.cumsum(sizes, dtype=np.int64)
    starts = ends - sizes
    total = int(ends[-1]) if len(ends) else 0
    symbols = token_symbols[np.repeat(token_offsets[tokens] - starts, sizes) + np.arange(total)]
    symbol_offsets = np.concatenate([[0], ends])[export["pattern_offsets"]]
    return _table("pattern", len(export["count"]), {
        "pattern": _list_array(symbol_offsets, symbols, path),
        "token_sizes": _list_array(export["pattern_offsets"], sizes, path),
        "parent": pa.array(library.pattern_parents().astype(np.int32), pa.int32()),
        "count": pa.array(export["count"], pa.int64()),
        "last_seen": pa.array(export["last_seen"], pa.int64()),
    })


def _write_atomic(path: Path, tables: list[pa.Table], metadata: dict[bytes, bytes],
                  overwrite: bool) -> None:
    rows = sum(len(t) for t in tables)
    with atomic_write(path, overwrite=overwrite) as out:
        _write_parquet(out.file, tables, metadata)
        out.file.flush()
        _verify(out.tmp_path, rows, metadata, path)
    _verify(path, rows, metadata, path)


def _write_parquet(sink, tables: list[pa.Table], metadata: dict[bytes, bytes]) -> None:
    with pq.ParquetWriter(sink, SCHEMA.with_metadata(metadata), compression="zstd",
                          write_page_checksum=True) as writer:
        for table in tables:
            if len(table):
                writer.write_table(table, row_group_size=ROW_GROUP_ROWS)


def _verify(written: Path, rows: int, metadata: dict[bytes, bytes], path: Path) -> None:
    try:
        footer = pq.read_metadata(written)
        found = (footer.num_rows, (footer.metadata or {}).get(METADATA_KEY))
        problem = None if found == (rows, metadata[METADATA_KEY]) else f"{found[0]} rows of {rows}"
    except (pa.ArrowException, OSError) as err:
        problem = _one_line(err)
    if problem:
        raise LibraryFormatError(f"{path}: the file written does not read back ({problem}): "
                                 f"the disk may be full or failing")


# --- loading -----------------------------------------------------------------------------

def _one_line(err: BaseException) -> str:
    return " ".join(str(err).split())


@contextmanager
def _reading(path: Path) -> Iterator[None]:
    """Turn any failure to read a library into a one-line :class:`LibraryFormatError`."""
    try:
        yield
    except LibraryFormatError:
        raise
    except (pa.ArrowException, OSError, ValueError, KeyError, TypeError, IndexError, OverflowError,
            RecursionError) as err:
        raise LibraryFormatError(f"{path}: corrupted pattern library ({type(err).__name__}: "
                                 f"{_one_line(err)[:300]}): re-create it with `slearn learn`") from err


def _open(path: Path) -> tuple[pq.ParquetFile, dict]:
    try:
        regular_file(path, "library file")
    except InputError as err:
        raise LibraryFormatError(str(err)) from err
    try:
        parquet = pq.ParquetFile(path, page_checksum_verification=True)
        raw = (parquet.schema_arrow.metadata or {}).get(METADATA_KEY)
        columns = _columns(parquet)
    except (pa.ArrowException, OSError, ValueError) as err:  # a flipped bit can give UnicodeDecodeError
        raise LibraryFormatError(f"{path}: not a readable Parquet file, truncated or corrupted "
                                 f"({_one_line(err)[:200]}): re-create it with `slearn learn`") from err
    if raw is None:
        raise LibraryFormatError(f"{path}: a Parquet file, but not a slearn pattern library (no "
                                 f"'slearn' metadata): make libraries with `slearn learn`")
    if columns != _stored_columns():  # pyarrow aborts the process on some mislabelled columns
        raise LibraryFormatError(f"{path}: corrupted pattern library (its columns are not the "
                                 f"library's): re-create it with `slearn learn`")
    return parquet, parse_header(raw, path)


def _row_groups(parquet: pq.ParquetFile, doc: dict, path: Path) -> dict[str, list[int]]:
    """Row groups of each table, checked against the row counts and the ``table`` column."""
    counts = [int(doc["library"]["rows"][name]) for name in TABLES]
    bounds = np.cumsum([0] + counts)
    groups: dict[str, list[int]] = {name: [] for name in TABLES}
    start = 0
    for i in range(parquet.metadata.num_row_groups):
        group = parquet.metadata.row_group(i)
        k = int(np.searchsorted(bounds, start, side="right")) - 1
        if k >= len(TABLES) or start + group.num_rows > bounds[k + 1]:
            raise LibraryFormatError(f"{path}: row groups do not match the library's tables")
        _check_group_table(parquet, i, TABLES[k], path)
        groups[TABLES[k]].append(i)
        start += group.num_rows
    if start != bounds[-1]:
        raise LibraryFormatError(f"{path}: {start} rows, but the metadata says {bounds[-1]}")
    return groups


def _columns(parquet: pq.ParquetFile) -> tuple:
    """The Arrow schema and the Parquet columns (path, physical type, levels) of a file."""
    return (parquet.schema_arrow.remove_metadata(),
            [(c.path, c.physical_type, c.max_definition_level, c.max_repetition_level)
             for c in parquet.schema])


@functools.cache
def _stored_columns() -> tuple:
    """:func:`_columns` of a file written with :data:`SCHEMA`."""
    sink = pa.BufferOutputStream()
    pq.write_table(SCHEMA.empty_table(), sink)
    return _columns(pq.ParquetFile(pa.BufferReader(sink.getvalue())))


def _check_group_table(parquet: pq.ParquetFile, i: int, name: str, path: Path) -> None:
    # The column is read, not its statistics: pyarrow aborts the process on some damaged
    # column metadata (row_group(i).column(j)) where reading raises an error.
    if parquet.read_row_group(i, columns=["table"]).column(0).unique().to_pylist() != [name]:
        raise LibraryFormatError(f"{path}: a row group of table {name!r} holds other rows")


def _read(parquet: pq.ParquetFile, groups: list[int], columns: list[str]) -> pa.Table:
    if not groups:
        return pa.Table.from_arrays([pa.array([], SCHEMA.field(c).type) for c in columns],
                                    names=columns)
    return parquet.read_row_groups(groups, columns=columns)


def _list_parts(column: pa.ChunkedArray, name: str, path: Path) -> tuple[np.ndarray, np.ndarray]:
    """``(offsets int64, values int32)`` of a list column, slice offsets honoured."""
    array = column.combine_chunks() if column.num_chunks != 1 else column.chunk(0)
    if array.null_count:
        raise LibraryFormatError(f"{path}: column {name!r} has missing values")
    offsets = np.asarray(array.offsets).astype(np.int64)
    values = np.asarray(array.values)[offsets[0]:offsets[-1]] if len(offsets) else np.zeros(0, np.int32)
    return offsets - offsets[0], values.astype(np.int32, copy=False)


def _numbers(column: pa.ChunkedArray, name: str, path: Path) -> np.ndarray:
    if column.null_count:
        raise LibraryFormatError(f"{path}: column {name!r} has missing values")
    return column.to_numpy()


def _decode_value(kind: str, number: int | None, real: float | None, text: str | None) -> Hashable:
    if kind in ("int", "bin"):
        return number if number is not None else int(text)
    if kind == "bool":
        return bool(number)
    if kind == "float":
        return real
    if kind == "str":
        return text
    if kind == "tuple":
        return _as_tuple(json.loads(text))
    raise ValueError(f"unknown value type {kind!r}")


def _as_tuple(value: Any) -> Any:
    return tuple(_as_tuple(v) for v in value) if isinstance(value, list) else value


def _read_vocabulary(parquet: pq.ParquetFile, groups: list[int], doc: dict, path: Path) -> Vocabulary:
    table = _read(parquet, groups, ["channel", "value_type", "value_int", "value_float", "value_text"])
    vocabulary = Vocabulary()
    for channel, role in doc["library"]["channels"]:
        vocabulary.add_channel(channel, role)
    columns = [table.column(c).to_pylist() for c in table.column_names]
    for i, (channel, *value) in enumerate(zip(*columns)):
        if vocabulary.symbol(channel, _decode_value(*value)) != i:
            raise LibraryFormatError(f"{path}: vocabulary row {i} repeats an earlier value")
    return vocabulary


def _read_tokens(parquet: pq.ParquetFile, groups: list[int], path: Path) -> TokenTable:
    table = _read(parquet, groups, ["token_kind", "token_symbols"])
    offsets, symbols = _list_parts(table.column("token_symbols"), "token_symbols", path)
    kinds = _numbers(table.column("token_kind"), "token_kind", path).astype(np.int8)
    return TokenTable.from_export(offsets, symbols, kinds)


@dataclass
class _PatternColumns:
    symbol_offsets: np.ndarray
    symbols: np.ndarray
    token_offsets: np.ndarray
    sizes: np.ndarray
    count: np.ndarray
    last_seen: np.ndarray
    parent: np.ndarray


def _read_pattern_columns(parquet: pq.ParquetFile, groups: list[int], path: Path) -> _PatternColumns:
    table = _read(parquet, groups, ["pattern", "token_sizes", "count", "last_seen", "parent"])
    symbol_offsets, symbols = _list_parts(table.column("pattern"), "pattern", path)
    token_offsets, sizes = _list_parts(table.column("token_sizes"), "token_sizes", path)
    columns = _PatternColumns(symbol_offsets, symbols, token_offsets, sizes,
                              _numbers(table.column("count"), "count", path).astype(np.int64),
                              _numbers(table.column("last_seen"), "last_seen", path).astype(np.int64),
                              _numbers(table.column("parent"), "parent", path).astype(np.int64))
    ends = np.concatenate([[0], np.cumsum(sizes, dtype=np.int64)])
    if len(sizes) and sizes.min() < 0 or not np.array_equal(ends[token_offsets], symbol_offsets):
        raise LibraryFormatError(f"{path}: pattern token sizes do not add up to the patterns")
    if len(columns.count) and columns.count.min() < 1:
        raise LibraryFormatError(f"{path}: a pattern count is not positive: re-create the library")
    return columns


def _pattern_arrays(columns: _PatternColumns, tokens: TokenTable, max_length: int,
                    path: Path) -> dict[str, np.ndarray]:
    """The columns as :meth:`PatternLibrary.export` arrays (token ids looked up, compiled)."""
    per_pattern = np.diff(columns.token_offsets)
    if len(per_pattern) and (per_pattern.min() < 3 or per_pattern.max() > 2 * max_length + 1
                             or np.any(per_pattern % 2 == 0)):
        raise LibraryFormatError(f"{path}: a pattern is not O A O ... O of at most {max_length} steps")
    position = np.arange(len(columns.sizes)) - np.repeat(columns.token_offsets[:-1], per_pattern)
    kinds = np.where(position % 2 == 0, OBSERVATION, 1 - OBSERVATION).astype(np.int8)
    symbol_offsets = np.concatenate([[0], np.cumsum(columns.sizes, dtype=np.int64)])
    token_ids = tokens.find_all(kinds, columns.symbols, symbol_offsets)
    if len(token_ids) and token_ids.min() < 0:
        raise LibraryFormatError(f"{path}: a pattern holds a step missing from the token table")
    return {"pattern_offsets": columns.token_offsets, "pattern_tokens": token_ids,
            "count": columns.count, "last_seen": columns.last_seen, "pattern_parent": columns.parent}


def load_library(path: str | os.PathLike) -> LoadedLibrary:
    """Read a library written by :func:`save_library` (compiled; no per-pattern Python).

    Raises:
        LibraryFormatError: the file is missing, truncated or corrupted, not a slearn
            library, or from a newer format version; the message says which.
    """
    path = Path(path)
    parquet, doc = _open(path)
    with _reading(path):
        groups = _row_groups(parquet, doc, path)
        params, facts = dict(doc["params"]), doc["library"]
        vocabulary = _read_vocabulary(parquet, groups["vocabulary"], doc, path)
        tokens = _read_tokens(parquet, groups["token"], path)
        columns = _read_pattern_columns(parquet, groups["pattern"], path)
        arrays = _pattern_arrays(columns, tokens, int(params["max_length"]), path)
        library = PatternLibrary.from_export(arrays, tokens, int(facts["clock"]),
                                             int(params["max_length"]), params["max_patterns"])
        library.forgotten = int(facts["forgotten"])
        spec = Spec.from_dict(doc["spec"], str(path)) if doc["spec"] is not None else None
    return LoadedLibrary(library, vocabulary, spec, params, doc["provenance"], doc["version"], str(path))


def read_info(path: str | os.PathLike) -> dict:
    """The small ``slearn`` metadata document of a library file (format, params, provenance, ...).

    Raises:
        LibraryFormatError: as :func:`load_library`.
    """
    return _open(Path(path))[1]


# --- describing --------------------------------------------------------------------------

def describe(path: str | os.PathLike) -> "LibraryDescription":
    """What a library file holds, as plain JSON-able data (for ``slearn info LIB.parquet``).

    Pattern count, length histogram (steps), vocabulary, the most frequent patterns
    decoded to channel names and values, parameters, provenance and bytes per pattern.

    Raises:
        LibraryFormatError: as :func:`load_library`.
    """
    path = Path(path)
    vocabulary = load_library(path).vocabulary  # the checks replay, resume and merge make
    parquet, doc = _open(path)
    with _reading(path):
        groups = _row_groups(parquet, doc, path)
        columns = _read_pattern_columns(parquet, groups["pattern"], path)
    if doc["spec"] is not None:  # bins read as value ranges
        vocabulary.value_labels.update(value_labels(Spec.from_dict(doc["spec"], str(path))))
    size, n = path.stat().st_size, len(columns.count)
    steps = np.diff(columns.token_offsets) // 2
    return LibraryDescription({
        "kind": "library", "path": str(path), "format": doc["format"], "format_version": doc["version"],
        "size_bytes": size, "patterns": n, "bytes_per_pattern": size / n if n else 0.0,
        "clock": doc["library"]["clock"], "forgotten": doc["library"]["forgotten"],
        "total_count": int(columns.count.sum()),
        "length_histogram": {str(k): int(c) for k, c in enumerate(np.bincount(steps)) if c},
        "mean_steps": float(steps.mean()) if n else 0.0,
        "vocabulary": _describe_vocabulary(vocabulary),
        "top_patterns": _top_patterns(columns, vocabulary),
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
                 f"  max length {params.get('max_length')}, max patterns "
                 f"{params.get('max_patterns') or '-'}, scoring {params.get('scoring')}",
                 f"  patterns by steps: {histogram or '-'} (mean {self['mean_steps']:.2f})",
                 f"  vocabulary: {self['vocabulary']['symbols']} symbols"]
        for channel in self["vocabulary"]["channels"]:
            values = ", ".join(map(str, channel.get("labels", channel["values"])[:12]))
            more = " ..." if channel["n_values"] > 12 else ""
            lines.append(f"    {channel['channel']:<32} {channel['role']:<11} {channel['n_values']:>6}  "
                         f"{values}{more}")
        lines.append("  top patterns (count, last seen):")
        lines += [f"    {p['count']:>8,} {p['last_seen']:>10,}  {p['pattern']}" for p in self["top_patterns"]]
        return "\n".join(lines + self._provenance_lines())

    def _provenance_lines(self) -> list[str]:
        provenance = self["provenance"]
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
    shown = {c: [vocabulary.value_labels[c](x) for x in v[:MAX_LISTED_VALUES]] if c in vocabulary.value_labels
             else None for c, v in values.items()}
    return {"symbols": len(vocabulary), "channels": [
        {"channel": c, "role": vocabulary.roles[c], "n_values": len(v),
         "values": [_jsonable(x) for x in v[:MAX_LISTED_VALUES]],
         **({"labels": shown[c]} if shown[c] is not None else {})} for c, v in values.items()]}


def _jsonable(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    return list(value) if isinstance(value, tuple) else value


def _top_patterns(columns: _PatternColumns, vocabulary: Vocabulary) -> list[dict]:
    order = np.lexsort((np.arange(len(columns.count)), -columns.last_seen, -columns.count))
    labels = _short_labels(vocabulary)
    top = []
    for i in order[:TOP_PATTERNS].tolist():
        tokens = _pattern_tokens(columns, i)
        top.append({"pattern": " ".join("+".join(labels[s] for s in t) or "-" for t in tokens),
                    "steps": len(tokens) // 2, "count": int(columns.count[i]),
                    "last_seen": int(columns.last_seen[i]),
                    "tokens": [_token_events(vocabulary, t) for t in tokens]})
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


def _pattern_tokens(columns: _PatternColumns, i: int) -> list[list[int]]:
    symbols = columns.symbols[columns.symbol_offsets[i]:columns.symbol_offsets[i + 1]].tolist()
    sizes = columns.sizes[columns.token_offsets[i]:columns.token_offsets[i + 1]].tolist()
    bounds = np.cumsum([0] + sizes).tolist()
    return [symbols[a:b] for a, b in zip(bounds, bounds[1:])]


def _short_labels(vocabulary: Vocabulary) -> list[str]:
    """``value`` where the value's text belongs to one channel only, else ``channel=value``
    (bins as value ranges)."""
    texts = [(c, vocabulary.value_text(s)) for s, c, _ in vocabulary.items()]
    channels: dict[str, set[str]] = {}
    for channel, text in texts:
        channels.setdefault(text, set()).add(channel)
    return [t if len(channels[t]) == 1 else f"{c}={t}" for c, t in texts]


# --- merging -----------------------------------------------------------------------------

def merge_libraries(a: LoadedLibrary, b: LoadedLibrary) -> LoadedLibrary:
    """Merge two libraries learned separately with the same spec.

    Symbols of ``b`` are remapped by ``(channel, value)`` (first-seen values may have other
    symbols in ``a`` and ``b``), then its tokens. A pattern in both gets the sum of the
    counts and the newer recency. Recency is kept as an age: the merged clock is the sum
    of both clocks and each library's ``last_seen`` is shifted by the other's clock, so
    "steps before the end of learning" is unchanged. ``a``'s parameters are kept.

    Raises:
        SpecError: the libraries are incompatible (different channels, roles, bins or
            max_length); the message gives the reason.
    """
    reason = _incompatibility(a, b)
    if reason:
        raise SpecError(f"cannot merge {a.path or 'library A'} and {b.path or 'library B'}: {reason}")
    vocabulary, symbol_map = _merged_vocabulary(a.vocabulary, b.vocabulary)
    tokens, token_map = _merged_tokens(a.library.tokens, b.library.tokens, symbol_map)
    arrays = _merged_patterns(a.library, b.library, token_map)
    library = PatternLibrary.from_export(arrays, tokens, a.library.clock + b.library.clock,
                                         a.library.max_length, a.library.max_patterns)
    library.forgotten = a.library.forgotten + b.library.forgotten
    return LoadedLibrary(library, vocabulary, a.spec if a.spec is not None else b.spec,
                         dict(a.params), _merged_provenance(a.provenance, b.provenance))


def _incompatibility(a: LoadedLibrary, b: LoadedLibrary) -> str | None:
    if a.library.max_length != b.library.max_length:
        return f"max_length {a.library.max_length} vs {b.library.max_length}"
    if (a.spec is None) != (b.spec is None):
        return "one library has a spec and the other has none"
    if a.spec is not None:
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


def _padded(export: dict[str, np.ndarray], token_map: np.ndarray | None, width: int) -> np.ndarray:
    offsets, tokens = export["pattern_offsets"], export["pattern_tokens"]
    if token_map is not None and len(tokens):
        tokens = token_map[tokens]
    lengths = np.diff(offsets)
    rows = np.full((len(lengths), width), -1, np.int32)
    rows[np.repeat(np.arange(len(lengths)), lengths), np.arange(len(tokens)) - np.repeat(offsets[:-1], lengths)] = tokens
    return rows


def _merged_patterns(a: PatternLibrary, b: PatternLibrary, token_map: np.ndarray) -> dict[str, np.ndarray]:
    width = 2 * a.max_length + 1
    ea, eb = a.export(), b.export()
    rows = np.concatenate([_padded(ea, None, width), _padded(eb, token_map, width)])
    ages_ok = np.concatenate([ea["last_seen"] + b.clock, eb["last_seen"] + a.clock])
    counts = np.concatenate([ea["count"], eb["count"]])
    order = np.lexsort(rows.T[::-1])
    new_group = np.ones(len(rows), bool)
    new_group[1:] = np.any(rows[order][1:] != rows[order][:-1], axis=1)
    group_sorted = np.cumsum(new_group) - 1
    group = np.empty(len(rows), np.int64)
    group[order] = group_sorted
    first = np.full(group_sorted[-1] + 1 if len(rows) else 0, len(rows), np.int64)
    np.minimum.at(first, group, np.arange(len(rows)))
    rank = np.empty(len(first), np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(len(first))
    return _arrays_from_rows(rows[np.sort(first)], rank[group], counts, ages_ok)


def _arrays_from_rows(unique_rows: np.ndarray, which: np.ndarray, counts: np.ndarray,
                      last_seen: np.ndarray) -> dict[str, np.ndarray]:
    n = len(unique_rows)
    count = np.zeros(n, np.int64)
    np.add.at(count, which, counts)
    recency = np.full(n, np.iinfo(np.int64).min, np.int64)
    np.maximum.at(recency, which, last_seen)
    mask = unique_rows >= 0
    offsets = np.concatenate([[0], np.cumsum(mask.sum(axis=1))]).astype(np.int64)
    return {"pattern_offsets": offsets, "pattern_tokens": unique_rows[mask].astype(np.int32),
            "count": count, "last_seen": recency}


def _merged_provenance(a: dict, b: dict) -> dict:
    time_a, time_b = a.get("time_unix", 0), b.get("time_unix", 0)
    newest = a if time_a >= time_b else b
    return {"slearn_version": __version__, "inputs": [*a.get("inputs", []), *b.get("inputs", [])],
            "time": newest.get("time"), "time_unix": max(time_a, time_b),
            "time_source": "newest of the merged libraries"}


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
        merged = merge_libraries(merged, load_library(path))
    merged.provenance["merged_from"] = [file_record(p) for p in paths]
    return save_library(output, merged.library, merged.vocabulary, spec=merged.spec,
                        params=merged.params, provenance=merged.provenance, overwrite=overwrite)


def file_record(path: str | os.PathLike) -> dict:
    """``{"path", "size_bytes", "sha256"}`` of a file, for provenance.

    Raises:
        InputError: the file cannot be read.
    """
    digest = hashlib.sha256()
    try:
        with open(path, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                digest.update(block)
        size = os.stat(path).st_size
    except OSError as err:
        raise InputError(f"{path}: cannot read: {err.strerror or err}") from err
    return {"path": os.fspath(path), "size_bytes": size, "sha256": digest.hexdigest()}
