"""Convert categorical sequence files into MCAP episodes (``slearn record stream``).

Formats (``fmt="auto"`` picks one from the file name, then the content):

- ``tokens``: one sequence per line, tokens separated by whitespace, one token per tick.
  A token ``NAME=VALUE`` is an event of channel ``NAME``; any other token is an event of
  the default channel. Blank lines and lines starting with ``#`` are skipped.
- ``spmf``: SPMF sequence databases: items separated by spaces, ``-1`` ends an itemset
  (its items share one tick), ``-2`` ends a sequence. ``<T>`` before an itemset sets its
  tick to ``T``; the end of a line also ends a sequence. ``@ITEM=ID=NAME`` lines name
  items; other lines starting with ``@``, ``#`` or ``%`` are skipped. Auto-detection picks
  ``spmf`` when the first line has a ``-2`` (or starts with ``@``): a token file whose
  values include ``-2`` needs ``fmt="tokens"``.
- ``csv``: a header row with ``channel``, ``value`` and ``time`` (seconds) or ``time_ns``
  (integer nanoseconds), optionally ``role`` and ``episode``.
- ``jsonl``: one JSON object per line with the same keys.

Values that read as integers become integers (``"17"`` -> 17); in CSV also numbers
(``"0.5"`` -> 0.5) so that numeric specs can bin them; everything else is text.

Episodes: each sequence (a line, an SPMF ``-2`` sequence, a CSV/JSONL ``episode`` value)
becomes one episode. All go into one MCAP file, one after the other in time (each starts
one tick after the previous one ends), each started by an episode marker on
``/slearn/episode`` (:mod:`slearn.io.episodes`), so learn and replay parse them one by one.
With ``per_file=True`` the whole file is one episode (no markers). Tick ``k`` of a
sequence is at log time ``k * tick_ns`` from the sequence's start.

Roles: ``roles={channel: role}`` wins over a ``role`` column; otherwise a channel is an
observation. The output holds one JSON channel per channel name
(:data:`~slearn.recorders.live.EVENT_SCHEMA`, role in the channel metadata) and a
``slearn.core.stream`` metadata record (source, format, number of sequences); each episode
marker names the source line its sequence starts on.
"""

from __future__ import annotations

import csv
import json
import os
import re
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Iterable, Iterator

from slearn import __version__
from slearn.core.vocabulary import ROLES
from slearn.errors import InputError
from slearn.io.files import check_output
from slearn.io.spec import Spec
from slearn.recorders.live import EventFile, check_role, event_value, events_spec

FORMATS = ("auto", "tokens", "spmf", "csv", "jsonl")
DEFAULT_CHANNEL = "/stream/event"
DEFAULT_ROLE = "observation"
TICK_NS = 100_000_000
METADATA_NAME = "slearn.stream"
_NS_PER_S = 1_000_000_000
_INT = re.compile(r"[+-]?\d+\Z")
_SPMF_TIME = re.compile(r"<(\d+)>\Z")


@dataclass
class Event:
    """One parsed event: log time, channel, value, role if the file says, source line."""

    time_ns: int
    channel: str
    value: Any
    role: str | None
    line: int


@dataclass
class Sequence:
    """The events of one episode and the line it starts on."""

    line: int
    events: list[Event] = field(default_factory=list)


@dataclass(frozen=True)
class StreamSummary:
    """What a conversion wrote."""

    source: str
    format: str
    paths: list[str]
    channels: dict[str, str]
    events: int
    size_bytes: int
    episodes: int = 1

    def to_dict(self) -> dict:
        """A JSON-ready dict."""
        return asdict(self)


def convert_stream(source: str | os.PathLike, output: str | os.PathLike, *, fmt: str = "auto",
                   per_file: bool = False, roles: dict[str, str] | None = None,
                   channel: str = DEFAULT_CHANNEL, tick_ns: int = TICK_NS,
                   overwrite: bool = False) -> StreamSummary:
    """Convert one sequence file into one MCAP file of episodes.

    Args:
        source: the sequence file.
        output: the MCAP file; an existing folder receives ``SOURCESTEM.mcap``.
        fmt: one of :data:`FORMATS`.
        per_file: make the whole file one episode.
        roles: ``{channel: "action" | "observation"}``, over any ``role`` column.
        channel: the channel of tokens without ``NAME=``.
        tick_ns: log time between ticks of token and SPMF sequences.
        overwrite: replace existing outputs (refused otherwise, before anything is written;
            an output that is ``source`` itself is always refused).

    Raises:
        InputError: unreadable file, a malformed line (named), a role conflict, or an
            existing output without ``overwrite``.
    """
    source = Path(source)
    fmt = detect_format(source) if fmt == "auto" else _known_format(fmt)
    sequences = read_sequences(source, fmt, channel=channel, tick_ns=tick_ns)
    channel_roles = resolve_roles(sequences, roles or {}, source)
    path = output_path(Path(output), source)
    check_output(path, overwrite, inputs=[source])
    starts = _lay_out(sequences, tick_ns)
    marked = len(sequences) > 1 and not per_file
    _write_episodes(sequences, starts, marked, path, channel_roles, overwrite,
                    {"source": source.name, "format": fmt, "sequences": str(len(sequences)),
                     "slearn_version": __version__})
    return StreamSummary(str(source), fmt, [str(path)], channel_roles,
                         sum(len(s.events) for s in sequences), path.stat().st_size,
                         len(sequences) if marked else 1)


def stream_spec(summary: StreamSummary) -> Spec:
    """The spec that learns the files of a conversion (every message an event)."""
    return events_spec(summary.channels, source=summary.source)


def detect_format(path: Path) -> str:
    """``csv``/``jsonl`` by extension, else ``jsonl`` or ``spmf`` or ``tokens`` by content."""
    suffix = path.suffix.lower()
    if suffix in (".csv", ".tsv"):
        return "csv"
    if suffix in (".jsonl", ".ndjson"):
        return "jsonl"
    for line in _lines(path):
        text = line.strip()
        if not text or text[0] in "#%":
            continue
        if text.startswith("{"):
            return "jsonl"
        return "spmf" if text.startswith("@") or "-2" in text.split() else "tokens"
    return "tokens"


def read_sequences(path: Path, fmt: str, *, channel: str = DEFAULT_CHANNEL,
                   tick_ns: int = TICK_NS) -> list[Sequence]:
    """Parse a file of format ``fmt`` (not ``auto``) into its sequences, in file order."""
    readers = {"tokens": _token_sequences, "spmf": _spmf_sequences,
               "csv": _csv_sequences, "jsonl": _jsonl_sequences}
    sequences = [s for s in readers[fmt](path, channel, tick_ns) if s.events]
    if not sequences:
        raise InputError(f"{path}: no events found (is it a {fmt} file?)")
    return sequences


def resolve_roles(sequences: list[Sequence], roles: dict[str, str], path: Path) -> dict[str, str]:
    """Each channel's role, in first-seen order: option, else the file's, else observation."""
    for name, role in roles.items():
        check_role(name, role)
    found: dict[str, tuple[str | None, int]] = {}
    for event in (e for s in sequences for e in s.events):
        role, line = found.setdefault(event.channel, (None, 0))
        if event.role is None or event.role == role or event.channel in roles:
            continue
        if role is not None:
            raise InputError(f"{path}:{event.line}: channel {event.channel!r} is {event.role} "
                             f"here but {role} on line {line}: give one role per channel")
        found[event.channel] = (event.role, event.line)
    unknown = sorted(set(roles) - set(found))
    if unknown:
        raise InputError(f"{path}: --role names channel {unknown[0]!r}, which has no event "
                         f"(channels: {', '.join(list(found)[:12])})")
    return {name: roles.get(name) or role or DEFAULT_ROLE for name, (role, _) in found.items()}


def output_path(output: Path, source: Path) -> Path:
    """The MCAP file a conversion writes (see :func:`convert_stream`)."""
    return output / f"{source.stem}.mcap" if output.is_dir() else output


def _known_format(fmt: str) -> str:
    if fmt not in FORMATS:
        raise InputError(f"format {fmt!r} is unknown: use one of {', '.join(FORMATS)}")
    return fmt


def _write_episodes(sequences: list[Sequence], starts: list[int], marked: bool, path: Path,
                    roles: dict[str, str], overwrite: bool, metadata: dict[str, str]) -> None:
    """Write each sequence shifted to its start, after an episode marker when ``marked``."""
    with EventFile(path, overwrite=overwrite, metadata={METADATA_NAME: metadata}) as out:
        for name, role in roles.items():  # every channel up front: one spec reads all
            out.register(name, role)
        for k, (sequence, start) in enumerate(zip(sequences, starts)):
            offset = start - min(e.time_ns for e in sequence.events)
            if marked:
                out.mark_episode(start, k, f"{metadata['source']}:{sequence.line}")
            for event in sequence.events:
                out.write(event.channel, event.time_ns + offset, event.value)


def _lay_out(sequences: list[Sequence], tick_ns: int) -> list[int]:
    """Start time of each sequence: one tick after the previous one ends (the first at its own)."""
    starts, end = [], None
    for sequence in sequences:
        first = min(e.time_ns for e in sequence.events)
        start = first if end is None else end + tick_ns
        starts.append(start)
        end = start + max(e.time_ns for e in sequence.events) - first
    return starts


# --- reading ------------------------------------------------------------------------------

def _lines(path: Path) -> Iterator[str]:
    try:
        with open(path, encoding="utf-8", newline="") as f:
            yield from f
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except UnicodeDecodeError as err:
        raise InputError(f"{path}: not UTF-8 text ({err.reason} at byte {err.start})") from None
    except OSError as err:
        raise InputError(f"{path}: cannot read: {err.strerror or err}") from None


def _token_value(text: str) -> int | str:
    return int(text) if _INT.match(text) else text


def _token_event(token: str, tick: int, channel: str, tick_ns: int, line: int) -> Event:
    name, eq, value = token.partition("=")
    if eq and name and value:
        return Event(tick * tick_ns, name, _token_value(value), None, line)
    return Event(tick * tick_ns, channel, _token_value(token), None, line)


def _token_sequences(path: Path, channel: str, tick_ns: int) -> Iterator[Sequence]:
    for number, line in enumerate(_lines(path), 1):
        tokens = line.split()
        if not tokens or tokens[0].startswith("#"):
            continue
        yield Sequence(number, [_token_event(t, k, channel, tick_ns, number)
                                for k, t in enumerate(tokens)])


def _spmf_sequences(path: Path, channel: str, tick_ns: int) -> Iterator[Sequence]:
    names: dict[str, str] = {}
    for number, line in enumerate(_lines(path), 1):
        text = line.strip()
        if text.startswith("@ITEM=") and text.count("=") >= 2:
            _, item, name = text.split("=", 2)
            names[item] = name
        elif text and text[0] not in "#%@":
            yield from _spmf_line(text.split(), names, channel, tick_ns, number)


def _spmf_line(tokens: list[str], names: dict[str, str], channel: str, tick_ns: int,
               number: int) -> Iterator[Sequence]:
    """The sequences of one SPMF line: ``-2`` or the end of the line ends a sequence."""
    sequence, tick = Sequence(number), 0
    for token in tokens:
        if token == "-2":
            yield sequence
            sequence, tick = Sequence(number), 0
        elif token == "-1":
            tick += 1
        elif _SPMF_TIME.match(token):
            tick = int(token[1:-1])
        else:
            sequence.events.append(_token_event(names.get(token, token), tick, channel,
                                                tick_ns, number))
    yield sequence


def _number(text: str) -> int | float | str:
    if _INT.match(text):
        return int(text)
    try:
        return float(text)
    except ValueError:
        return text


def _csv_sequences(path: Path, channel: str, tick_ns: int) -> Iterator[Sequence]:
    reader = csv.reader(_lines(path), delimiter="\t" if path.suffix.lower() == ".tsv" else ",")
    header = next(reader, None)
    if header is None:
        return
    columns = [c.strip().lower() for c in header]
    _check_columns(columns, path)
    rows = []
    for row in reader:
        if not row or all(not c.strip() for c in row):
            continue
        where = f"{path}:{reader.line_num}"
        if len(row) != len(columns):
            raise InputError(f"{where}: {len(row)} fields, but the header has {len(columns)}")
        record = dict(zip(columns, (c.strip() for c in row)))
        record["value"] = _number(record["value"]) if record["value"] != "" else None
        rows.append((reader.line_num, record))
    yield from _episodes(rows, path)


def _jsonl_sequences(path: Path, channel: str, tick_ns: int) -> Iterator[Sequence]:
    rows = []
    for number, line in enumerate(_lines(path), 1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
        except json.JSONDecodeError as err:
            raise InputError(f"{path}:{number}: not JSON ({err.msg})") from None
        if not isinstance(record, dict):
            raise InputError(f"{path}:{number}: expected a JSON object with time, channel, value")
        _check_columns([k.lower() for k in record], path, number)
        rows.append((number, {k.lower(): v for k, v in record.items()}))
    yield from _episodes(rows, path)


def _check_columns(columns: list[str], path: Path, line: int = 1) -> None:
    missing = [c for c in ("channel", "value") if c not in columns]
    if "time" not in columns and "time_ns" not in columns:
        missing.append("time (seconds) or time_ns")
    if missing:
        raise InputError(f"{path}:{line}: missing {', '.join(missing)}: "
                         "each event needs time, channel and value")


def _episodes(rows: Iterable[tuple[int, dict]], path: Path) -> Iterator[Sequence]:
    """Rows grouped by their ``episode`` (first-seen order); no column: one episode."""
    episodes: dict[Any, Sequence] = {}
    for number, record in rows:
        event = _row_event(record, f"{path}:{number}", number)
        key = record.get("episode")
        episodes.setdefault(key, Sequence(number)).events.append(event)
    yield from episodes.values()


def _row_event(record: dict, where: str, number: int) -> Event:
    channel = record.get("channel")
    if not isinstance(channel, str) or not channel:
        raise InputError(f"{where}: channel must be a non-empty name, not {channel!r}")
    if record.get("value") is None:
        raise InputError(f"{where}: channel {channel!r} has no value")
    role = record.get("role") or None
    if role is not None and role not in ROLES:
        raise InputError(f"{where}: role must be \"action\" or \"observation\", not {role!r}")
    return Event(_row_time(record, where), channel, event_value(record["value"], where), role, number)


def _row_time(record: dict, where: str) -> int:
    if "time_ns" in record:
        value, scale = record["time_ns"], 1
    else:
        value, scale = record["time"], _NS_PER_S
    try:
        number = int(value) if scale == 1 and not isinstance(value, float) else float(value)
    except (TypeError, ValueError):
        raise InputError(f"{where}: time {value!r} is not a number") from None
    time_ns = round(number * scale)
    if not 0 <= time_ns < 1 << 64:
        raise InputError(f"{where}: time {value!r} is out of range (log times are >= 0)")
    return time_ns
