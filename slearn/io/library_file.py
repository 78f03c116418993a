"""Pattern libraries on disk: one Parquet file holds a library, its vocabulary and its spec.

Layout (format ``slearn-library``, version 6; version 5 files, which have no
``view_persist``, version 4 files, which also have no ``view_rounds``, version 3 files,
which also have no ``view_calibration``, and version 2 files, which also have no action
scopes, are read too: their persistence specialists start untrained, their views' rounds
are taken as the library's clock where the weights were trained, their detectors'
calibration starts from none). Four tables share one
schema; a row belongs to the table named in its ``table`` column, each table has its own
row groups (written in this order) and the columns of the other tables are null::

    column          type           table       holds
    table           string         all         "vocabulary" | "token" | "view" | "pattern"
    channel         string         vocabulary  row i is symbol i
                                   view        the view's channel ("*": all observations)
    role            string         vocabulary  "action" | "observation"
    value_type      string         vocabulary  str | int | bool | float | bin | tuple
    value_int       int64          vocabulary  int, bool (0/1) and bin index values
    value_float     float64        vocabulary  float values
    value_text      string         vocabulary  str values; tuples as JSON lists
    token_kind      int8           token       row t is token t: 0 observation, 1 action
    token_symbols   list<int32>    token       the token's symbols
    view_epoch      int32          view        alarms of the view's change detector
    view_detector   list<float64>  view        its test: cusum, misses, trials
    view_weights    list<float64>  view        expert weights over the leader, (context length, kind)
    view_calibration list<int64>   view        the test's hits and trials per calibration cell
    view_rounds     int64          view        the view's weight updates (mixer rounds)
    view_persist    list<float64>  view        persistence specialists over the answer, per context length
    view            int32          pattern     the view the pattern belongs to
    pattern         list<int32>    pattern     tokens: the context, oldest first, then the outcome
    parent          int32          pattern     literal libraries: row of the prefix, -1
    count           int64          pattern     occurrences
    last_seen       int64          pattern     recency, a step on the library clock
    fresh           int64          pattern     occurrences in the view's current epoch

Patterns come in the order they were first seen. A literal library (the paper's rule,
:mod:`slearn.core.literal`) has no view rows; its patterns are ``O A O ... O`` runs counted at
parse boundaries, ``parent`` speeding up loading. The schema's key-value metadata
``slearn`` is a small JSON document (read cheaply with ``pq.read_schema``): ``format``,
``version``, learner ``params`` (max_length, max_patterns, scoring, factored, has_actions,
and from version 3 ``action_scopes`` when a view sees only some action channels),
``library`` (clock, forgotten, patterns, channels with roles, rows per table), ``spec``
(fitted edges included, or null) and ``provenance``. Columns are zstd-compressed; pages
carry checksums. Files are written atomically and deterministically: the same library
gives the same bytes.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Hashable, Iterator, cast

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from slearn.core.library import PatternLibrary, check_scopes
from slearn.core.literal import LiteralLibrary
from slearn.core.mixer import CELLS, Mixer, new_mixer
from slearn.core.tokens import TokenTable
from slearn.core.vocabulary import STORABLE, Vocabulary, storable
from slearn.errors import InputError, LibraryFormatError, ParameterError
from slearn.io.files import atomic_write, check_output, regular_file
from slearn.io.library_header import FORMAT_NAME, FORMAT_VERSION, TABLES, parse_header
from slearn.io.spec import Bins, Spec

METADATA_KEY = b"slearn"
SCORINGS = ("adaptive", "literal")
ROW_GROUP_ROWS = 1 << 20

_INT32 = pa.list_(pa.field("item", pa.int32(), nullable=False))
_FLOAT64 = pa.list_(pa.field("item", pa.float64(), nullable=False))
_INT64 = pa.list_(pa.field("item", pa.int64(), nullable=False))
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
    ("view_epoch", pa.int32()),
    ("view_detector", _FLOAT64),
    ("view_weights", _FLOAT64),
    ("view_calibration", _INT64),
    ("view_rounds", pa.int64()),
    ("view_persist", _FLOAT64),
    ("view", pa.int32()),
    ("pattern", _INT32),
    ("parent", pa.int32()),
    ("count", pa.int64()),
    ("last_seen", pa.int64()),
    ("fresh", pa.int64()),
])
_INT64_RANGE = (-(1 << 63), (1 << 63) - 1)
# columns added after version 2, by the version that added them
_SINCE = {"view_calibration": 4, "view_rounds": 5, "view_persist": 6}


@dataclass
class LoadedLibrary:
    """A library read back from disk, with everything needed to go on using it.

    Attributes:
        library: a :class:`PatternLibrary`, or a :class:`LiteralLibrary` (``scoring``
            ``literal``); token ids identical to the saved ones.
        vocabulary: symbols and their ``(channel, value)`` names, values typed as saved.
        spec: the spec the library was learned with (fitted edges), or ``None``.
        params: learner parameters (``max_length``, ``max_patterns``, ``scoring``, ...).
        provenance: slearn version, inputs (path, size, sha256), time.
        format_version: the file's format version.
        path: the file it came from (``None`` when built in memory, e.g. by a merge).
    """

    library: PatternLibrary | LiteralLibrary
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


def scoring_of(library: PatternLibrary | LiteralLibrary) -> str:
    """``"literal"`` for the paper's rule, else ``"adaptive"``."""
    return "literal" if isinstance(library, LiteralLibrary) else "adaptive"


# --- saving ------------------------------------------------------------------------------

def save_library(path: str | os.PathLike, library: PatternLibrary | LiteralLibrary,
                 vocabulary: Vocabulary, *, spec: Spec | None, params: dict, provenance: dict,
                 overwrite: bool = False) -> SaveSummary:
    """Write a library, its vocabulary, spec, parameters and provenance to one Parquet file.

    The library's own parameters (``max_length``, ``max_patterns``, scoring, views) are
    stored whatever ``params`` says of them. The write is atomic: an existing file is
    replaced only by a complete, verified file.

    Raises:
        InputError: ``path`` exists and ``overwrite`` is false, or it cannot be written.
        LibraryFormatError: the written file does not read back.
    """
    path = Path(path)
    check_output(path, overwrite)
    params = {**params, **library_params(library)}
    tables = [_vocabulary_table(vocabulary, spec, path), _token_table(library.tokens),
              _view_table(library), _pattern_table(library, path)]
    metadata = _metadata(library, vocabulary, spec, params, provenance, [len(t) for t in tables])
    _write_atomic(path, tables, metadata, overwrite)
    return SaveSummary(str(path), len(library), path.stat().st_size)


def library_params(library: PatternLibrary | LiteralLibrary) -> dict:
    """The parameters a library carries itself."""
    params: dict[str, Any] = {"max_length": library.max_length, "max_patterns": library.max_patterns,
                              "scoring": scoring_of(library)}
    if isinstance(library, PatternLibrary):
        params.update(factored=library.factored, has_actions=library.has_actions)
        if library.action_scopes:
            params["action_scopes"] = {view: list(names) for view, names in library.action_scopes.items()}
    return params


def _metadata(library, vocabulary: Vocabulary, spec: Spec | None, params: dict,
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
    arrays += [columns[f.name] if f.name in columns else pa.nulls(n, f.type) for f in SCHEMA][1:]
    return pa.Table.from_arrays(arrays, schema=SCHEMA)


def _binned_channels(spec: Spec | None) -> set[str]:
    if spec is None:
        return set()
    return {c.name for c in spec.channels if isinstance(c.symbolizer, Bins)}


def _encode_value(channel: str, value: Hashable, binned: bool, path: Path) -> tuple:
    """``(value_type, value_int, value_float, value_text)`` of one vocabulary value."""
    if value is None:
        return "none", None, None, None
    if isinstance(value, (bool, np.bool_)):
        return "bool", int(value), None, None
    if isinstance(value, (int, np.integer)):
        kind = "bin" if binned else "int"
        inside = _INT64_RANGE[0] <= int(value) <= _INT64_RANGE[1]
        return (kind, int(value), None, None) if inside else (kind, None, None, str(int(value)))
    if isinstance(value, (float, np.floating)):
        return "float", None, float(value), None
    if isinstance(value, str) and storable(value):
        return "str", None, None, value
    if isinstance(value, tuple) and storable(value):
        return "tuple", None, None, json.dumps(value, separators=(",", ":"), default=_plain_scalar)
    raise InputError(f"{path}: cannot store value {value!r} of channel {channel!r} "
                     f"({type(value).__name__}): a library stores {STORABLE}; map the values "
                     f"to these before learning (in a spec: bins or a field that is text or a number)")


def _plain_scalar(value: Any) -> Any:
    """A NumPy scalar inside a tuple as the Python number JSON writes (equal, with the same hash)."""
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"{type(value).__name__} is not stored")


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


def _list_array(offsets: np.ndarray, values: np.ndarray, path: Path, kind=_INT32) -> pa.ListArray:
    if len(values) > np.iinfo(np.int32).max:
        raise InputError(f"{path}: more than 2**31 values in one table; lower --max-patterns")
    dtype = {_INT32: np.int32, _INT64: np.int64, _FLOAT64: np.float64}[kind]
    return pa.ListArray.from_arrays(pa.array(offsets.astype(np.int32)),
                                    pa.array(values.astype(dtype, copy=False)), type=kind)


def _token_table(tokens: TokenTable) -> pa.Table:
    offsets, symbols, kinds = tokens.export()
    return _table("token", len(kinds), {
        "token_kind": pa.array(kinds, pa.int8()),
        "token_symbols": _list_array(offsets, symbols, Path("<tokens>")),
    })


def _view_table(library) -> pa.Table:
    if isinstance(library, LiteralLibrary) or library.mixer is None:
        return _table("view", 0, {})
    mixer, n = library.mixer, len(library.view_names)
    weights = mixer.weight[:n].reshape(n, mixer.weight.shape[1] * mixer.weight.shape[2])
    return _table("view", n, {
        "channel": pa.array(library.view_names, pa.string()),
        "view_epoch": pa.array(mixer.epoch[:n], pa.int32()),
        "view_detector": _list_array(np.arange(n + 1) * 3, mixer.detector[:n].ravel(),
                                     Path("<views>"), _FLOAT64),
        "view_weights": _list_array(np.arange(n + 1) * weights.shape[1], weights.ravel(),
                                    Path("<views>"), _FLOAT64),
        "view_calibration": _list_array(np.arange(n + 1) * 2 * CELLS, mixer.calibration[:n].ravel(),
                                        Path("<views>"), _INT64),
        "view_rounds": pa.array(mixer.rounds[:n], pa.int64()),
        "view_persist": _list_array(np.arange(n + 1) * mixer.persist.shape[1], mixer.persist[:n].ravel(),
                                    Path("<views>"), _FLOAT64),
    })


def _pattern_table(library, path: Path) -> pa.Table:
    export = library.export()
    n = len(export["count"])
    columns = {
        "pattern": _list_array(export["pattern_offsets"], export["pattern_tokens"], path),
        "count": pa.array(export["count"], pa.int64()),
        "last_seen": pa.array(export["last_seen"], pa.int64()),
    }
    if isinstance(library, LiteralLibrary):
        columns["parent"] = pa.array(library.pattern_parents().astype(np.int32), pa.int32())
    else:
        columns["view"] = pa.array(export["view"], pa.int32())
        columns["fresh"] = pa.array(export["fresh"], pa.int64())
    return _table("pattern", n, columns)


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


def recorded_inputs(path: str | os.PathLike) -> list[str]:
    """The input logs a library's provenance names, as given and from the library's folder,
    whether or not they are still on disk: paths an output must never overwrite (replay
    counts its baselines on them). A file that is not a readable library names none."""
    try:
        _, doc = _open(Path(path))
    except (LibraryFormatError, InputError):
        return []
    provenance = doc.get("provenance")
    entries = provenance.get("inputs") if isinstance(provenance, dict) else None
    folder = os.path.dirname(os.fspath(path))
    return list(dict.fromkeys(p for entry in entries or [] for p in input_places(entry, folder)))


def input_places(entry: Any, library_dir: str) -> list[str]:
    """Where a provenance input ``entry`` may be: its path as given (from the working
    folder), then from the library's folder; none for an entry without a path."""
    if not isinstance(entry, dict) or not isinstance(entry.get("path"), str):
        return []
    return list(dict.fromkeys([entry["path"], os.path.join(library_dir, entry["path"])]))


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
    doc = parse_header(raw, path)  # before the columns: an old format is named as such
    if columns != _stored_columns(doc["version"]):  # pyarrow aborts the process on some mislabelled columns
        raise LibraryFormatError(f"{path}: corrupted pattern library (its columns are not the "
                                 f"library's): re-create it with `slearn learn`")
    return parquet, doc


def _columns(parquet: pq.ParquetFile) -> tuple:
    """The Arrow schema and the Parquet columns (path, physical type, levels) of a file."""
    return (parquet.schema_arrow.remove_metadata(),
            [(c.path, c.physical_type, c.max_definition_level, c.max_repetition_level)
             for c in parquet.schema])


@functools.cache
def _stored_columns(version: int) -> tuple:
    """:func:`_columns` of a file of format ``version`` (:data:`SCHEMA`, without the
    columns added later)."""
    sink = pa.BufferOutputStream()
    pq.write_table(pa.schema([f for f in SCHEMA if _SINCE.get(f.name, 0) <= version]).empty_table(), sink)
    return _columns(pq.ParquetFile(pa.BufferReader(sink.getvalue())))


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
            raise _corrupt(path, "its row groups do not match the library's tables")
        _check_group_table(parquet, i, TABLES[k], path)
        groups[TABLES[k]].append(i)
        start += group.num_rows
    if start != bounds[-1]:
        raise _corrupt(path, f"{start:,} rows, but its header says {bounds[-1]:,}")
    return groups


def _check_group_table(parquet: pq.ParquetFile, i: int, name: str, path: Path) -> None:
    # The column is read, not its statistics: pyarrow aborts the process on some damaged
    # column metadata (row_group(i).column(j)) where reading raises an error.
    if parquet.read_row_group(i, columns=["table"]).column(0).unique().to_pylist() != [name]:
        raise _corrupt(path, f"a row group of table {name!r} holds other rows")


def _read(parquet: pq.ParquetFile, groups: list[int], columns: list[str]) -> pa.Table:
    if not groups:
        return pa.Table.from_arrays([pa.array([], SCHEMA.field(c).type) for c in columns],
                                    names=columns)
    return parquet.read_row_groups(groups, columns=columns)


def _list_parts(column: pa.ChunkedArray, name: str, path: Path) -> tuple[np.ndarray, np.ndarray]:
    """``(offsets int64, values)`` of a list column, slice offsets honoured."""
    array = column.combine_chunks() if column.num_chunks != 1 else column.chunk(0)
    if array.null_count:
        raise _corrupt(path, f"column {name!r} has missing values")
    offsets = np.asarray(array.offsets).astype(np.int64)
    values = np.asarray(array.values)[offsets[0]:offsets[-1]] if len(offsets) else np.zeros(0)
    return offsets - offsets[0], values


def _numbers(column: pa.ChunkedArray, name: str, path: Path) -> np.ndarray:
    if column.null_count:
        raise _corrupt(path, f"column {name!r} has missing values")
    return column.to_numpy()


def _decode_value(kind: str, number: int | None, real: float | None, text: str | None) -> Hashable:
    if kind in ("int", "bin", "tuple") and number is None and text is None:
        raise ValueError(f"a {kind} value has neither a number nor a text")
    if kind in ("int", "bin"):
        return number if number is not None else int(cast(str, text))
    if kind == "none":
        return None
    if kind == "bool":
        return bool(number)
    if kind == "float":
        return real
    if kind == "str":
        return text
    if kind == "tuple":
        return _as_tuple(json.loads(cast(str, text)))
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
            raise _corrupt(path, f"vocabulary row {i} repeats an earlier value")
    return vocabulary


def _read_tokens(parquet: pq.ParquetFile, groups: list[int], n_symbols: int, path: Path) -> TokenTable:
    table = _read(parquet, groups, ["token_kind", "token_symbols"])
    offsets, symbols = _list_parts(table.column("token_symbols"), "token_symbols", path)
    kinds = _numbers(table.column("token_kind"), "token_kind", path).astype(np.int8)
    symbols = symbols.astype(np.int32, copy=False)
    if len(symbols) and (symbols.min() < 0 or symbols.max() >= n_symbols) or np.any(kinds > 1) \
            or np.any(kinds < 0):
        raise _corrupt(path, "the token table names symbols or kinds that do not exist")
    return TokenTable.from_export(offsets, symbols, kinds)


def _read_views(parquet: pq.ParquetFile, groups: list[int], max_context: int, version: int,
                clock: int, path: Path) -> tuple[list[str], Mixer]:
    calibrated, counted = version >= _SINCE["view_calibration"], version >= _SINCE["view_rounds"]
    persisting = version >= _SINCE["view_persist"]
    table = _read(parquet, groups, ["channel", "view_epoch", "view_detector", "view_weights",
                                    *(["view_calibration"] if calibrated else []),
                                    *(["view_rounds"] if counted else []),
                                    *(["view_persist"] if persisting else [])])
    names = table.column("channel").to_pylist()
    n = len(names)
    _, detector = _list_parts(table.column("view_detector"), "view_detector", path)
    _, weights = _list_parts(table.column("view_weights"), "view_weights", path)
    calibration = _list_parts(table.column("view_calibration"), "view_calibration", path)[1] if calibrated \
        else np.zeros(2 * CELLS * n, np.int64)
    if len(detector) != 3 * n or len(weights) != 3 * max_context * n or None in names:
        raise _corrupt(path, f"the view table does not match max_length {max_context}")
    if len(calibration) != 2 * CELLS * n or np.any(calibration < 0) \
            or np.any(calibration[0::2] > calibration[1::2]):
        raise LibraryFormatError(f"{path}: the view table's calibration counts are not hits and trials "
                                 f"of {CELLS} cells per view: re-create the library")
    epoch = _numbers(table.column("view_epoch"), "view_epoch", path).astype(np.int32)
    weights = weights.astype(np.float64).reshape(n, max_context, 3)
    if not np.all((weights >= 0) & (weights <= 1)) or (n and not np.all(weights.max(axis=(1, 2)) > 0)):
        raise LibraryFormatError(f"{path}: the view table's expert weights are not numbers in [0, 1] "
                                 f"with a positive leader per view: re-create the library")
    if not np.all((detector >= 0) & (detector < np.inf)) or np.any(epoch < 0):
        raise LibraryFormatError(f"{path}: the view table's change detectors are not non-negative "
                                 f"numbers: re-create the library")
    if counted:
        rounds = _numbers(table.column("view_rounds"), "view_rounds", path).astype(np.int64)
    else:  # about one prediction per step where the weights were trained: their age
        trained = np.any(weights != new_mixer(1, max_context).weight, axis=(1, 2))
        rounds = np.where(trained, max(clock, 0), 0).astype(np.int64)
    if np.any(rounds < 0):
        raise LibraryFormatError(f"{path}: a view's rounds are negative: re-create the library")
    persist = _list_parts(table.column("view_persist"), "view_persist", path)[1].astype(np.float64) \
        if persisting else new_mixer(n, max_context).persist.ravel()
    if len(persist) != max_context * n or not np.all((persist > 0) & (persist < np.inf)):
        raise LibraryFormatError(f"{path}: the view table's persistence weights are not {max_context} "
                                 f"positive numbers per view: re-create the library")
    return names, Mixer(weights, detector.astype(np.float64).reshape(n, 3), epoch,
                        calibration.astype(np.int64).reshape(n, CELLS, 2), rounds,
                        persist.reshape(n, max_context))


def _read_patterns(parquet: pq.ParquetFile, groups: list[int], literal: bool,
                   n_tokens: int, path: Path) -> dict[str, np.ndarray]:
    extra = ["parent"] if literal else ["view", "fresh"]
    table = _read(parquet, groups, ["pattern", "count", "last_seen", *extra])
    offsets, tokens = _list_parts(table.column("pattern"), "pattern", path)
    tokens = tokens.astype(np.int32, copy=False)
    if len(tokens) and (tokens.min() < 0 or tokens.max() >= n_tokens):
        raise _corrupt(path, "a pattern names a token that does not exist")
    arrays = {"pattern_offsets": offsets, "pattern_tokens": tokens}
    for name in ("count", "last_seen", *extra):
        arrays["pattern_parent" if name == "parent" else name] = _numbers(
            table.column(name), name, path).astype(np.int64)
    if len(arrays["count"]) and arrays["count"].min() < 1:
        raise LibraryFormatError(f"{path}: a pattern count is not positive: re-create the library")
    return arrays


def _corrupt(path: Path, problem: str) -> LibraryFormatError:
    """The one-line error for a library whose tables contradict themselves."""
    return LibraryFormatError(f"{path}: corrupted pattern library ({problem}): re-create it with `slearn learn`")


def load_library(path: str | os.PathLike) -> LoadedLibrary:
    """Read a library written by :func:`save_library` (compiled; no per-pattern Python).

    Raises:
        LibraryFormatError: the file is missing, truncated or corrupted, not a slearn
            library, or from another format version; the message says which and what to do.
    """
    path = Path(path)
    parquet, doc = _open(path)
    with _reading(path):
        groups = _row_groups(parquet, doc, path)
        params, facts = dict(doc["params"]), doc["library"]
        vocabulary = _read_vocabulary(parquet, groups["vocabulary"], doc, path)
        tokens = _read_tokens(parquet, groups["token"], len(vocabulary), path)
        literal = params.get("scoring") == "literal"
        arrays = _read_patterns(parquet, groups["pattern"], literal, len(tokens), path)
        library = (_literal(arrays, tokens, facts, params, path) if literal else
                   _occurrence(parquet, groups, arrays, tokens, vocabulary, facts, params, doc["version"], path))
        library.forgotten = int(facts["forgotten"])
        spec = Spec.from_dict(doc["spec"], str(path)) if doc["spec"] is not None else None
    del arrays, parquet
    pa.default_memory_pool().release_unused()  # Arrow's allocator keeps what the read freed
    return LoadedLibrary(library, vocabulary, spec, params, doc["provenance"], doc["version"], str(path))


def _literal(arrays, tokens: TokenTable, facts: dict, params: dict, path: Path) -> LiteralLibrary:
    lengths = np.diff(arrays["pattern_offsets"])
    max_length = int(params["max_length"])
    if len(lengths) and (lengths.min() < 3 or lengths.max() > 2 * max_length + 1
                         or np.any(lengths % 2 == 0)):
        raise _corrupt(path, f"a pattern is not O A O ... O of at most {max_length} steps")
    return LiteralLibrary.from_export(arrays, tokens, int(facts["clock"]), max_length,
                                      params["max_patterns"])


def _occurrence(parquet, groups, arrays, tokens: TokenTable, vocabulary: Vocabulary, facts: dict,
                params: dict, version: int, path: Path) -> PatternLibrary:
    max_length, has_actions = int(params["max_length"]), bool(params["has_actions"])
    max_context = 2 * max_length if has_actions else max_length
    names, mixer = _read_views(parquet, groups["view"], max_context, int(version), int(facts["clock"]), path)
    lengths = np.diff(arrays["pattern_offsets"])
    views = arrays["view"]
    if len(lengths) and (lengths.min() < 2 or lengths.max() > max_context + 1
                         or views.min() < 0 or views.max() >= len(names)):
        raise _corrupt(path, "a pattern does not fit the library's views and max_length")
    try:
        scopes = check_scopes(params.get("action_scopes"), vocabulary if params.get("factored") else None)
    except ParameterError as err:
        raise LibraryFormatError(f"{path}: field params.action_scopes: {err}: re-create the library "
                                 "with `slearn learn`") from err
    return PatternLibrary.from_export(
        arrays, tokens=tokens, clock=int(facts["clock"]), view_names=names, mixer=mixer,
        max_length=max_length, max_patterns=params["max_patterns"],
        vocabulary=vocabulary if params.get("factored") else None, has_actions=has_actions,
        action_scopes=scopes)


def read_info(path: str | os.PathLike) -> dict:
    """The small ``slearn`` metadata document of a library file (format, params, provenance, ...).

    Raises:
        LibraryFormatError: as :func:`load_library`.
    """
    return _open(Path(path))[1]


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
