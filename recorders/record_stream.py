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

Episodes: each sequence (a line, an SPMF ``-2`` sequence, a run of CSV/JSONL rows with
one ``episode`` value; an episode that resumes after another began is refused) becomes
one episode. All go into one MCAP file, one after the other in time (each starts
one tick after the previous one ends), each started by an episode marker on
``/slearn/episode`` (:mod:`slearn.io.episodes`), so learn and replay parse them one by one.
With ``per_file=True`` the whole file is one episode (no markers). Tick ``k`` of a
sequence is at log time ``k * tick_ns`` from the sequence's start.

Roles: ``roles={channel: role}`` wins over a ``role`` column; otherwise a channel is an
observation. The output holds one JSON channel per channel name
(:data:`~slearn.recorders.live.EVENT_SCHEMA`, role in the channel metadata) and a
``slearn.core.stream`` metadata record (source, format, number of sequences); each episode
marker names the source line its sequence starts on.

Memory: the file is read twice, event by event (the first pass finds the channels, their
roles and each sequence's time span; the second writes), so it does not grow with the
file: only a line of a token or SPMF file is held whole.
"""

from __future__ import annotations

import csv
import json
import os
import re
from array import array
from dataclasses import asdict, dataclass
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
_NO_EPISODE = object()


@dataclass(slots=True)
class Event:
    """One parsed event: log time, channel, value, role if the file says, source line, and
    the sequence (episode) it belongs to, counted from 0 over the sequences with events."""

    time_ns: int
    channel: str
    value: Any
    role: str | None
    line: int
    sequence: int = 0


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

    def events() -> Iterator[Event]:
        return read_events(source, fmt, channel=channel, tick_ns=tick_ns)

    layout = scan_events(events(), source, fmt, roles or {})
    path = output_path(Path(output), source)
    check_output(path, overwrite, inputs=[source])
    marked = layout.sequences > 1 and not per_file
    _write_episodes(events(), source, layout, tick_ns, marked, path, overwrite,
                    {"source": source.name, "format": fmt, "sequences": str(layout.sequences),
                     "slearn_version": __version__})
    return StreamSummary(str(source), fmt, [str(path)], layout.roles, layout.events,
                         path.stat().st_size, layout.sequences if marked else 1)


@dataclass
class Layout:
    """What the first pass over a sequence file found: each channel's role, and each
    sequence's first source line and earliest and latest event time (a few numbers per
    sequence: the events themselves are read again to be written, so memory does not grow
    with the file)."""

    roles: dict[str, str]
    lines: array
    lows: array
    highs: array
    events: int

    @property
    def sequences(self) -> int:
        return len(self.lows)

    def starts(self, tick_ns: int) -> Iterator[int]:
        """Each sequence's start: one tick after the previous one ends (the first at its own)."""
        end = None
        for low, high in zip(self.lows, self.highs):
            start = low if end is None else end + tick_ns
            yield start
            end = start + high - low


def scan_events(events: Iterable[Event], path: Path, fmt: str, roles: dict[str, str]) -> Layout:
    """The :class:`Layout` of the events of ``path``, a file of format ``fmt``;
    ``roles`` are the ones given (``--role``), over the file's.

    Raises:
        InputError: no events, a malformed line (named), or a role conflict.
    """
    for name, role in roles.items():
        check_role(name, role)
    found: dict[str, tuple[str | None, int]] = {}
    lines, lows, highs, count = array("q"), array("q"), array("q"), 0
    for event in events:
        count += 1
        if event.sequence == len(lows):
            lines.append(event.line)
            lows.append(event.time_ns)
            highs.append(event.time_ns)
        else:
            lows[-1], highs[-1] = min(lows[-1], event.time_ns), max(highs[-1], event.time_ns)
        role, line = found.setdefault(event.channel, (None, 0))
        if event.role is None or event.role == role or event.channel in roles:
            continue
        if role is not None:
            raise InputError(f"{path}:{event.line}: channel {event.channel!r} is {event.role} "
                             f"here but {role} on line {line}: give one role per channel")
        found[event.channel] = (event.role, event.line)
    if not count:
        raise InputError(f"{path}: no events found (is it a {fmt} file?)")
    unknown = sorted(set(roles) - set(found))
    if unknown:
        raise InputError(f"{path}: --role names channel {unknown[0]!r}, which has no event "
                         f"(channels: {', '.join(list(found)[:12])})")
    channel_roles = {name: roles.get(name) or role or DEFAULT_ROLE for name, (role, _) in found.items()}
    return Layout(channel_roles, lines, lows, highs, count)


def read_events(path: Path, fmt: str, *, channel: str = DEFAULT_CHANNEL,
                tick_ns: int = TICK_NS) -> Iterator[Event]:
    """The events of a file of format ``fmt`` (not ``auto``), in file order, one at a time."""
    readers = {"tokens": _token_events, "spmf": _spmf_events,
               "csv": _csv_events, "jsonl": _jsonl_events}
    return readers[fmt](path, channel, tick_ns)


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


def output_path(output: Path, source: Path) -> Path:
    """The MCAP file a conversion writes (see :func:`convert_stream`)."""
    return output / f"{source.stem}.mcap" if output.is_dir() else output


def _known_format(fmt: str) -> str:
    if fmt not in FORMATS:
        raise InputError(f"format {fmt!r} is unknown: use one of {', '.join(FORMATS)}")
    return fmt


def _write_episodes(events: Iterable[Event], source: Path, layout: Layout, tick_ns: int, marked: bool,
                    path: Path, overwrite: bool, metadata: dict[str, str]) -> None:
    """Write the events of ``source`` (read again) with each sequence shifted to its start,
    after an episode marker when ``marked``."""
    start_of = layout.starts(tick_ns)
    current, offset, written = -1, 0, 0
    with EventFile(path, overwrite=overwrite, metadata={METADATA_NAME: metadata}) as out:
        for name, role in layout.roles.items():  # every channel up front: one spec reads all
            out.register(name, role)
        for event in events:
            if event.sequence != current:
                current = event.sequence
                if current >= layout.sequences:
                    raise _changed(source)
                start = next(start_of)
                offset = start - layout.lows[current]
                if marked:
                    out.mark_episode(start, current, f"{metadata['source']}:{layout.lines[current]}")
            if event.channel not in layout.roles:
                raise _changed(source)
            out.write(event.channel, event.time_ns + offset, event.value)
            written += 1
        if written != layout.events:
            raise _changed(source)


def _changed(source: Path) -> InputError:
    return InputError(f"{source}: the file changed while it was being converted (it is read twice): "
                      "convert it again once nothing writes it")


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


def _token_event(token: str, tick: int, channel: str, tick_ns: int, line: int, sequence: int) -> Event:
    name, eq, value = token.partition("=")
    if eq and name and value:
        return Event(tick * tick_ns, name, _token_value(value), None, line, sequence)
    return Event(tick * tick_ns, channel, _token_value(token), None, line, sequence)


def _token_events(path: Path, channel: str, tick_ns: int) -> Iterator[Event]:
    sequence = 0
    for number, line in enumerate(_lines(path), 1):
        tokens = line.split()
        if not tokens or tokens[0].startswith("#"):
            continue
        for k, token in enumerate(tokens):
            yield _token_event(token, k, channel, tick_ns, number, sequence)
        sequence += 1


def _spmf_events(path: Path, channel: str, tick_ns: int) -> Iterator[Event]:
    """SPMF's events: ``-2`` or the end of a line ends a sequence; one without items is none."""
    names: dict[str, str] = {}
    sequence = 0
    for number, line in enumerate(_lines(path), 1):
        text = line.strip()
        if text.startswith("@ITEM=") and text.count("=") >= 2:
            _, item, name = text.split("=", 2)
            names[item] = name
        elif text and text[0] not in "#%@":
            tick, items = 0, 0
            for token in text.split():
                if token == "-2":
                    sequence, tick, items = sequence + (items > 0), 0, 0
                elif token == "-1":
                    tick += 1
                elif _SPMF_TIME.match(token):
                    tick = int(token[1:-1])
                else:
                    yield _token_event(names.get(token, token), tick, channel, tick_ns, number, sequence)
                    items += 1
            sequence += items > 0


def _number(text: str) -> int | float | str:
    if _INT.match(text):
        return int(text)
    try:
        return float(text)
    except ValueError:
        return text


def _csv_events(path: Path, channel: str, tick_ns: int) -> Iterator[Event]:
    reader = csv.reader(_lines(path), delimiter="\t" if path.suffix.lower() == ".tsv" else ",")
    header = next(reader, None)
    if header is None:
        return
    columns = [c.strip().lower() for c in header]
    _check_columns(columns, path)

    def rows() -> Iterator[tuple[int, dict]]:
        for row in reader:
            if not row or all(not c.strip() for c in row):
                continue
            where = f"{path}:{reader.line_num}"
            if len(row) != len(columns):
                raise InputError(f"{where}: {len(row)} fields, but the header has {len(columns)}")
            record = dict(zip(columns, (c.strip() for c in row)))
            record["value"] = _number(record["value"]) if record["value"] != "" else None
            yield reader.line_num, record
    yield from _row_events(rows(), path)


def _jsonl_events(path: Path, channel: str, tick_ns: int) -> Iterator[Event]:
    def rows() -> Iterator[tuple[int, dict]]:
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
            yield number, {k.lower(): v for k, v in record.items()}
    yield from _row_events(rows(), path)


def _check_columns(columns: list[str], path: Path, line: int = 1) -> None:
    missing = [c for c in ("channel", "value") if c not in columns]
    if "time" not in columns and "time_ns" not in columns:
        missing.append("time (seconds) or time_ns")
    if missing:
        raise InputError(f"{path}:{line}: missing {', '.join(missing)}: "
                         "each event needs time, channel and value")


def _row_events(rows: Iterable[tuple[int, dict]], path: Path) -> Iterator[Event]:
    """Rows as events, a sequence per run of rows with one ``episode`` value (no column: one
    sequence). An episode's rows come together: one that resumes after another began is
    refused, since the file is converted as it is read."""
    finished: set = set()
    current: Any = _NO_EPISODE
    sequence = -1
    for number, record in rows:
        event = _row_event(record, f"{path}:{number}", number)
        key = record.get("episode")
        try:
            hash(key)
        except TypeError:
            raise InputError(f"{path}:{number}: episode {key!r} is not a name or a number") from None
        if key != current:
            if key in finished:
                raise InputError(f"{path}:{number}: episode {key!r} resumes after other episodes began: "
                                 "give each episode's rows together (sort the file by episode, keeping "
                                 "each episode's order)")
            if current is not _NO_EPISODE:
                finished.add(current)
            current, sequence = key, sequence + 1
        event.sequence = sequence
        yield event


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
