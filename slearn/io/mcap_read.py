"""Robust, streaming reading of MCAP files: raw messages in log-time order.

This is the one MCAP reading path of slearn (learn, replay and info share it).

How it reads, and why:

1. **Scan** (pass 1): walk the record headers of the data section with seeks, never
   decompressing. Each ``Chunk`` becomes a *block* (its header gives the first log time);
   runs of messages written outside chunks are grouped into blocks of at most
   ``_BLOCK_MESSAGES`` messages (their log times are read from the message headers).
   Schemas and channels outside chunks (data section and summary) are registered. The
   scan never trusts the summary or its indexes: they are missing, incomplete (channels
   not repeated: ``KeyError`` in ``mcap.reader.SeekingReader`` on 112 conformance
   variants) or gone (truncated files) exactly when they are needed. A record that runs
   past the end of the file, or a missing footer, marks where the file broke.
2. **Merge** (pass 2): a k-way merge of the blocks. Blocks are opened in order of their
   first log time; a block is opened only when the merge frontier reaches it, and its
   messages are sorted inside the block (stable, so ties keep file order). The merge key
   is ``(log_time, block position in the file, position in the block)``: log-time order
   with ties in file order, whatever the file layout.

Memory holds the open blocks only (the chunks whose time ranges overlap the frontier,
plus a small block index), so it does not grow with the length of the log, and it is
bounded whatever the file says: a chunk is decompressed into exactly the size it declares
(more or less data is a damaged chunk), and the open blocks together, records plus their
message index, stay under ``SLEARN_MAX_CHUNK_MB`` (:func:`max_chunk_bytes_setting`). Zero
bytes where a record should start are skipped whole (data section) or end the chunk, never
walked record by record. A chunk or record that cannot be read, or would not fit, is
skipped; what it cost is recorded in a :class:`ReadReport` and, at the end of the pass, a
:class:`~slearn.errors.TruncatedLogWarning` names the file, the messages read and the byte
offset where it broke.
"""

from __future__ import annotations

import heapq
import os
import stat
import struct
import warnings
import zlib
from array import array
from dataclasses import dataclass, field
from typing import Any, BinaryIO, Callable, Iterable, Iterator, NamedTuple

import numpy as np

from slearn.errors import InputError, TruncatedLogWarning

MAGIC = b"\x89MCAP0\r\n"

_OP_HEADER = 0x01
_OP_FOOTER = 0x02
_OP_SCHEMA = 0x03
_OP_CHANNEL = 0x04
_OP_MESSAGE = 0x05
_OP_CHUNK = 0x06
_OP_ATTACHMENT = 0x09
_OP_METADATA = 0x0C
_OP_DATA_END = 0x0F
_OP_INVALID = 0x00  # reserved: zero bytes where a record should be

_RECORD_HEAD = struct.Struct("<BQ")
_LAST_TIME_NS = 2**63 - 1
_MESSAGE_HEAD = struct.Struct("<HIQQ")
_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")
_CHUNK_TIMES = struct.Struct("<QQQI")

_BLOCK_MESSAGES = 4096  # messages outside chunks are merged in blocks of this many
_BLOCK_BYTES = 4 << 20
_SMALL_RECORD = 1 << 24  # schema/channel/header records larger than this are corrupt
_MESSAGE_BYTES = 256  # memory of one message's index entry in an opened block
_COLUMNS = 6  # log time, publish time, sequence, channel id, payload start and end
_SOFT_BYTES = 32 << 20  # above this, open blocks that wait for others are closed
_ZERO_SCAN = 1 << 20
_SCAN_BYTES = 1 << 16  # blocks from this size are walked by the compiled kernel

MAX_CHUNK_ENV = "SLEARN_MAX_CHUNK_MB"
DEFAULT_MAX_CHUNK_MB = 256
_MAX_CHUNK_MB_LIMIT = 1 << 20


@dataclass(frozen=True)
class SchemaInfo:
    """A schema record: ``id``, ``name``, ``encoding`` and the raw schema ``data``."""

    id: int
    name: str
    encoding: str
    data: bytes


@dataclass(frozen=True, eq=False)
class ChannelInfo:
    """A channel record with its schema resolved (``None`` for schemaless channels)."""

    id: int
    topic: str
    message_encoding: str
    schema: SchemaInfo | None
    metadata: dict[str, str] = field(default_factory=dict)

    @property
    def schema_name(self) -> str:
        """The schema name, ``""`` when schemaless."""
        return self.schema.name if self.schema else ""

    @property
    def schema_encoding(self) -> str:
        """The schema encoding, ``""`` when schemaless."""
        return self.schema.encoding if self.schema else ""


UNKNOWN_OFFSET = -1
"""The ``offset`` of a message (or ``broken_at`` of a break) whose byte position a reader
cannot tell (bags read through ``rosbags``, rosbag2 folders of several files)."""


class RawMessage(NamedTuple):
    """One undecoded message; ``data`` is the payload as written, ``offset`` the byte
    offset of its record in the file (of the chunk holding it, for chunked messages), or
    :data:`UNKNOWN_OFFSET`."""

    channel: ChannelInfo
    log_time_ns: int
    publish_time_ns: int
    sequence: int
    data: bytes
    offset: int = UNKNOWN_OFFSET

    @property
    def topic(self) -> str:
        """The topic of the message's channel."""
        return self.channel.topic

    @property
    def channel_id(self) -> int:
        """The id of the message's channel."""
        return self.channel.id


@dataclass
class ReadReport:
    """What one pass over a file read, and where (if anywhere) the file broke.

    Attributes:
        path: the file.
        n_messages: messages yielded (after topic filtering).
        size_bytes: the file size.
        broken_at: byte offset of the first record that could not be read
            (:data:`UNKNOWN_OFFSET` when the reader cannot tell), else ``None``.
        reason: why it broke.
        n_skipped_chunks: chunks skipped as unreadable (corrupt) before the end.
        filtered: the pass read some topics only (``n_messages`` counts those).
        undecodable: messages whose payload did not decode, skipped, per topic (filled in
            by the reader that decodes, e.g. :mod:`slearn.io.serialize`).
        first_undecodable: where the first of them is (byte offset, else its number
            among the messages read) and its error.
    """

    path: str
    n_messages: int = 0
    size_bytes: int = 0
    broken_at: int | None = None
    reason: str | None = None
    n_skipped_chunks: int = 0
    filtered: bool = False
    undecodable: dict[str, int] = field(default_factory=dict)
    first_undecodable: str | None = None

    @property
    def truncated(self) -> bool:
        """True when part of the file could not be read, or messages did not decode."""
        return self.broken_at is not None or bool(self.undecodable)

    def note_break(self, offset: int, reason: str) -> None:
        """Record a break; the first one is kept as the one to report."""
        if self.broken_at is None:
            self.broken_at, self.reason = offset, reason

    def note_undecodable(self, topic: str, offset: int, error: str) -> None:
        """Count a message skipped because its payload does not decode."""
        self.undecodable[topic] = self.undecodable.get(topic, 0) + 1
        if self.first_undecodable is None:
            where = f"byte {offset}" if offset >= 0 else f"message {self.n_messages} read"
            self.first_undecodable = f"first at {where}: {error}"

    def describe(self) -> str:
        """A one-line summary naming the file, the messages read and the break."""
        if not self.truncated:
            return f"{self.path}: {self.n_messages} messages read"
        parts = []
        if self.broken_at is not None:
            skipped = (f", {self.n_skipped_chunks} unreadable chunk(s) skipped"
                       if self.n_skipped_chunks else "")
            which = " of the selected topics" if self.filtered else ""
            where = f" at byte {self.broken_at} of {self.size_bytes}" if self.broken_at >= 0 else ""
            parts.append(f"truncated or corrupt log: salvaged {self.n_messages} messages{which}; "
                         f"broke{where} ({self.reason}){skipped}")
        if self.undecodable:
            counts = ", ".join(f"{n} on {topic}" for topic, n in sorted(self.undecodable.items()))
            parts.append(f"skipped {sum(self.undecodable.values())} message(s) that do not decode "
                         f"({counts}; {self.first_undecodable})")
        return f"{self.path}: " + "; ".join(parts)


@dataclass
class _Block:
    """A byte range of the data section read as one unit in the merge."""

    offset: int
    end: int
    min_time: int
    is_chunk: bool
    max_time: int = 0


@dataclass
class _Layout:
    """What the scan found: header fields, blocks in file order, schemas, channels."""

    profile: str = ""
    library: str = ""
    blocks: list[_Block] = field(default_factory=list)
    schemas: dict[int, SchemaInfo] = field(default_factory=dict)
    channels: dict[int, ChannelInfo] = field(default_factory=dict)
    raw_channels: dict[int, tuple] = field(default_factory=dict)
    extras: list[tuple[int, int, int]] = field(default_factory=list)  # metadata, attachments


@dataclass(frozen=True)
class AttachmentInfo:
    """An attachment record: times, name, media type and its bytes."""

    log_time_ns: int
    create_time_ns: int
    name: str
    media_type: str
    data: bytes


class _OpenLog:
    """A log reader holding its file open: a context manager that closes it."""

    _file: BinaryIO

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Close the file."""
        self._file.close()


class McapLog(_OpenLog):
    """An MCAP file opened for streaming; use as a context manager.

    Opening scans the record headers (see the module docstring); ``profile``,
    ``library`` and the channels defined outside chunks are then known. Channels defined
    inside chunks appear in ``channels`` as the chunks are read. ``max_chunk_bytes``
    bounds the decompressed chunk data held at once (default: :func:`max_chunk_bytes_setting`).
    """

    def __init__(self, path: str | os.PathLike, max_chunk_bytes: int | None = None) -> None:
        self.path = os.fspath(path)
        self.max_chunk_bytes = max_chunk_bytes or max_chunk_bytes_setting()
        try:
            if not stat.S_ISREG(os.stat(self.path).st_mode):  # a FIFO would block open()
                raise InputError(f"{self.path}: not a regular file: give an MCAP log file")
            self._file: BinaryIO = open(self.path, "rb")
        except OSError as err:
            raise InputError(f"{self.path}: cannot open: {err.strerror or err}") from err
        self.report = ReadReport(self.path, size_bytes=os.fstat(self._file.fileno()).st_size)
        try:
            self._layout = _scan(self._file, self.report)
        except BaseException:
            self._file.close()
            raise

    @property
    def profile(self) -> str:
        """The header's profile (``ros1``, ``ros2``, ``""``, ...)."""
        return self._layout.profile

    @property
    def library(self) -> str:
        """The header's writer library."""
        return self._layout.library

    @property
    def channels(self) -> dict[int, ChannelInfo]:
        """Channels known so far, by id."""
        return self._layout.channels

    def time_range(self) -> tuple[int, int] | None:
        """``(first, last)`` log time (ns) of the readable blocks, ``None`` without messages."""
        blocks = self._layout.blocks
        if not blocks:
            return None
        return min(b.min_time for b in blocks), max(max(b.max_time, b.min_time) for b in blocks)

    def iter_metadata(self) -> Iterator[tuple[str, dict[str, str]]]:
        """``(name, {key: value})`` of each metadata record, in file order.

        A record that cannot be parsed, or is larger than ``max_chunk_bytes``, is skipped
        and noted in ``report``, like a damaged chunk.
        """
        return self._iter_records(_OP_METADATA, _parse_metadata)

    def iter_attachments(self) -> Iterator[AttachmentInfo]:
        """Each attachment record, in file order (one in memory at a time); damaged or
        oversized ones are skipped as in :meth:`iter_metadata`."""
        return self._iter_records(_OP_ATTACHMENT, _parse_attachment)

    def _iter_records(self, op: int, parse: Callable[[bytes], Any]) -> Iterator[Any]:
        for kind, pos, end in self._layout.extras:
            if kind != op:
                continue
            size = end - pos - 9
            if size > self.max_chunk_bytes:
                self.report.note_break(pos, f"record (opcode 0x{op:02x}) of {size:,} bytes skipped: "
                                            f"over the {self.max_chunk_bytes / 2**20:g} MiB limit; "
                                            f"raise {MAX_CHUNK_ENV} to read it")
                continue
            self._file.seek(pos + 9)
            try:
                record = parse(self._file.read(size))
            except struct.error as err:
                self.report.note_break(pos, f"unreadable record (opcode 0x{op:02x}): {err}")
                continue
            yield record

    def iter_messages(self, topics: Iterable[str] | None = None,
                      on_progress: Callable[[int, int], None] | None = None) -> Iterator[RawMessage]:
        """Yield raw messages in log-time order, ties in file order.

        Args:
            topics: only these topics (``None``: all).
            on_progress: called with ``(bytes_read, file_size)`` as blocks are opened.

        ``self.report`` counts what was yielded and records where the file broke.
        """
        for message in self._merge(topics, on_progress):
            self.report.n_messages += 1
            yield message

    def iter_batches(self, topics: Iterable[str] | None = None,
                     on_progress: Callable[[int, int], None] | None = None) -> Iterator[MessageBatch]:
        """The messages of :meth:`iter_messages` as :class:`MessageBatch` es (a chunk at a
        time when chunks do not overlap in time), without a Python object per message."""
        for batch in self._merge(topics, on_progress).batches():
            self.report.n_messages += len(batch)
            yield batch

    def _merge(self, topics: Iterable[str] | None, on_progress) -> "_Merge":
        wanted = None if topics is None else frozenset(topics)
        self.report.filtered = wanted is not None
        return _Merge(self._file, self._layout, self.report, wanted, on_progress, self.max_chunk_bytes)


def max_chunk_bytes_setting() -> int:
    """The most decompressed chunk data held at once: ``SLEARN_MAX_CHUNK_MB`` MiB (default 256).

    A chunk that declares more, or that would take the chunks open at once (chunks
    overlapping in log time are merged together) over it, is skipped and reported like a
    damaged chunk.

    Raises:
        InputError: the variable is not a whole number of MiB from 1 to 2^20.
    """
    text = os.environ.get(MAX_CHUNK_ENV)
    if text is None:
        return DEFAULT_MAX_CHUNK_MB << 20
    try:
        mib = int(text)
    except ValueError:
        mib = 0
    if not 1 <= mib <= _MAX_CHUNK_MB_LIMIT:
        raise InputError(f"{MAX_CHUNK_ENV}={text[:40]!r}: give a whole number of MiB from 1 to "
                         f"{_MAX_CHUNK_MB_LIMIT:,} (default {DEFAULT_MAX_CHUNK_MB})")
    return mib << 20


def iter_messages(path: str | os.PathLike, *, topics: Iterable[str] | None = None,
                  report: ReadReport | None = None, warn: bool = True,
                  on_progress: Callable[[int, int], None] | None = None) -> Iterator[RawMessage]:
    """Yield the raw messages of one MCAP file in log-time order, ties in file order.

    Args:
        path: the MCAP file.
        topics: only these topics (``None``: all).
        report: filled in at the end of the pass (messages read, where the file broke).
        warn: at the end of a pass over a truncated or corrupt file, warn with a
            :class:`~slearn.errors.TruncatedLogWarning` naming the file, the number of
            messages read and the byte offset of the break.
        on_progress: called with ``(bytes_read, file_size)``.

    Raises:
        InputError: the file cannot be opened or is not MCAP at all.
    """
    with McapLog(path) as log:
        yield from log.iter_messages(topics, on_progress)
        if report is not None:
            vars(report).update(vars(log.report))
        if warn and log.report.truncated:
            warnings.warn(TruncatedLogWarning(log.report.describe()), stacklevel=2)


# --- pass 1: scan ---------------------------------------------------------------------

class _BlockBuilder:
    """Groups consecutive messages written outside chunks into blocks."""

    def __init__(self, blocks: list[_Block]) -> None:
        self.blocks = blocks
        self.start = self.end = self.count = 0
        self.min_time = self.max_time = 0

    def add(self, offset: int, end: int, log_time: int) -> None:
        if self.count and (self.count >= _BLOCK_MESSAGES or end - self.start > _BLOCK_BYTES):
            self.close()
        if not self.count:
            self.start, self.min_time, self.max_time = offset, log_time, log_time
        self.min_time = min(self.min_time, log_time)
        self.max_time = max(self.max_time, log_time)
        self.end, self.count = end, self.count + 1

    def close(self) -> None:
        if self.count:
            self.blocks.append(_Block(self.start, self.end, self.min_time, False, self.max_time))
        self.count = 0


def _scan(f: BinaryIO, report: ReadReport) -> _Layout:
    """Pass 1: walk record headers, build blocks, register schemas and channels."""
    size = report.size_bytes
    if f.read(8) != MAGIC:
        raise InputError(f"{report.path}: not an MCAP file (no MCAP magic at the start)")
    layout = _Layout()
    builder = _BlockBuilder(layout.blocks)
    pos = 8
    while True:
        head = f.read(9)
        if len(head) < 9:
            report.note_break(pos, "file ends before the footer" if not head
                              else "file ends inside a record header")
            break
        op, length = _RECORD_HEAD.unpack(head)
        if op == _OP_INVALID:
            builder.close()  # a block never spans the zeros
            after = _skip_zeros(f, pos, size, report)
            if after is None:
                break
            pos = after
            continue
        end = pos + 9 + length
        if end > size:
            report.note_break(pos, f"record (opcode 0x{op:02x}) of {length} bytes runs past the end")
            break
        if op == _OP_MESSAGE:
            builder.add(pos, end, _read_message_time(f, length))
        else:
            if op == _OP_CHUNK:
                builder.close()
            if op == _OP_FOOTER:
                break
            _scan_other(f, op, length, pos, end, layout, report)
        pos = end
        f.seek(pos)
    builder.close()
    _check_trailing_magic(f, pos, report)
    _resolve_channels(layout)
    return layout


def _skip_zeros(f: BinaryIO, pos: int, size: int, report: ReadReport) -> int | None:
    """Skip a run of zero bytes at ``pos`` (a zeroed region, never walked record by record).

    Returns where the records go on, or ``None`` to stop: the run reaches the end of the
    file, or the bytes at ``pos`` are an invalid record that is not zeros.
    """
    f.seek(pos)
    start = pos
    while pos < size:
        block = f.read(min(_ZERO_SCAN, size - pos))
        rest = block.lstrip(b"\0")
        pos += len(block) - len(rest)
        if rest:
            break
    if pos - start < 9:
        report.note_break(start, "invalid record (opcode 0x00)")
        return None
    report.note_break(start, f"{pos - start} zero bytes instead of records")
    f.seek(pos)
    return pos if pos < size else None


def _read_message_time(f: BinaryIO, length: int) -> int:
    if length < _MESSAGE_HEAD.size:
        return 0
    return _MESSAGE_HEAD.unpack(f.read(_MESSAGE_HEAD.size))[2]


def _scan_other(f: BinaryIO, op: int, length: int, pos: int, end: int, layout: _Layout,
                report: ReadReport) -> None:
    """Handle a non-message record of the scan (only its start has been read)."""
    if op == _OP_CHUNK:
        start_time, end_time = struct.unpack("<QQ", f.read(16)) if length >= 16 else (0, 0)
        layout.blocks.append(_Block(pos, end, start_time, True, end_time))
    elif op in (_OP_METADATA, _OP_ATTACHMENT):
        layout.extras.append((op, pos, end))
    elif op in (_OP_SCHEMA, _OP_CHANNEL, _OP_HEADER) and length < _SMALL_RECORD:
        try:
            _register_record(op, f.read(length), 0, length, layout)
        except struct.error:
            report.note_break(pos, f"unreadable record (opcode 0x{op:02x})")


def _check_trailing_magic(f: BinaryIO, pos: int, report: ReadReport) -> None:
    if report.truncated:
        return
    f.seek(pos + 9 + 20)  # footer: summary_start, summary_offset_start, crc
    if f.read(8) != MAGIC:
        report.note_break(pos, "footer or trailing magic missing")


def _read_str(buf: bytes, pos: int) -> tuple[str, int]:
    (n,) = _U32.unpack_from(buf, pos)
    pos += 4
    return bytes(buf[pos:pos + n]).decode("utf-8", "replace"), pos + n


def _register_record(op: int, buf: bytes, pos: int, end: int, layout: _Layout) -> None:
    """Parse a schema, channel or header record from ``buf[pos:end]`` into ``layout``."""
    if op == _OP_HEADER:
        layout.profile, pos = _read_str(buf, pos)
        layout.library, _ = _read_str(buf, pos)
    elif op == _OP_SCHEMA:
        (sid,) = _U16.unpack_from(buf, pos)
        name, pos = _read_str(buf, pos + 2)
        encoding, pos = _read_str(buf, pos)
        (n,) = _U32.unpack_from(buf, pos)
        layout.schemas.setdefault(sid, SchemaInfo(sid, name, encoding, bytes(buf[pos + 4:pos + 4 + n])))
    elif op == _OP_CHANNEL:
        cid, sid = struct.unpack_from("<HH", buf, pos)
        topic, pos = _read_str(buf, pos + 4)
        encoding, pos = _read_str(buf, pos)
        layout.raw_channels.setdefault(cid, (sid, topic, encoding, _read_map(buf, pos)))


def _read_map(buf: bytes, pos: int) -> dict[str, str]:
    (n,) = _U32.unpack_from(buf, pos)
    pos, end, out = pos + 4, pos + 4 + n, {}
    while pos < end:
        key, pos = _read_str(buf, pos)
        out[key], pos = _read_str(buf, pos)
    return out


def _parse_metadata(buf: bytes) -> tuple[str, dict[str, str]]:
    name, at = _read_str(buf, 0)
    return name, _read_map(buf, at)


def _parse_attachment(buf: bytes) -> AttachmentInfo:
    log_time, create_time = struct.unpack_from("<QQ", buf, 0)
    name, at = _read_str(buf, 16)
    media_type, at = _read_str(buf, at)
    (n,) = _U64.unpack_from(buf, at)
    return AttachmentInfo(log_time, create_time, name, media_type, bytes(buf[at + 8:at + 8 + n]))


def _resolve_channels(layout: _Layout) -> None:
    """Turn raw channel records into :class:`ChannelInfo` once their schema is known."""
    for cid, (sid, topic, encoding, metadata) in list(layout.raw_channels.items()):
        if cid in layout.channels or (sid != 0 and sid not in layout.schemas):
            continue
        layout.channels[cid] = ChannelInfo(cid, topic, encoding, layout.schemas.get(sid), metadata)


# --- pass 2: blocks and merge ---------------------------------------------------------

class CorruptData(Exception):
    """A block's bytes are damaged. Internal to the log readers (this module and
    :mod:`slearn.io.ros1_salvage`), which skip the block and say why; never raised to
    callers, and distinct from ``ValueError`` so that a bug is not mistaken for damage."""


class _TooLarge(CorruptData):
    """A block would not fit in the memory limit (see :func:`max_chunk_bytes_setting`)."""


def decompress_exactly(compression: str, data: bytes, size: int) -> bytes:
    """Decompress a chunk's records into exactly ``size`` bytes, never more.

    ``compression`` is MCAP's (``""``, ``zstd``, ``lz4``), or ``bz2`` (ROS 1 bag chunks).

    Raises:
        CorruptData: the data holds more or fewer bytes than declared, or does not decompress.
    """
    if compression == "":
        out = data
    elif compression == "zstd":
        out = _zstd(data, size)
    elif compression == "lz4":
        out = _lz4(data, size)
    elif compression == "bz2":
        import bz2

        out = _at_most(bz2.BZ2Decompressor(), data, size, "bz2")
    else:
        raise CorruptData(f"unsupported chunk compression {compression!r}")
    if len(out) != size:
        raise CorruptData(f"chunk records are {len(out)} bytes, the chunk declares {size}")
    return out


def _zstd(data: bytes, size: int) -> bytes:
    import zstandard

    declared = zstandard.frame_content_size(data)
    if declared not in (-1, size):  # -1: the frame does not say
        raise CorruptData(f"zstd frame holds {declared} bytes, the chunk declares {size}")
    # With a content size in the frame, zstandard allocates exactly that; without one, at
    # most max_output_size, and more output is an error: either way never above ``size``.
    return zstandard.ZstdDecompressor().decompress(data, max_output_size=max(size, 1))


def _lz4(data: bytes, size: int) -> bytes:
    import lz4.frame

    declared = lz4.frame.get_frame_info(data)["content_size"]
    if declared not in (0, size):  # 0: the frame does not say
        raise CorruptData(f"lz4 frame holds {declared} bytes, the chunk declares {size}")
    return _at_most(lz4.frame.LZ4FrameDecompressor(), data, size, "lz4")


def _at_most(decompressor, data: bytes, size: int, what: str) -> bytes:
    """Run a streaming ``decompressor`` on ``data`` for at most ``size`` bytes of output."""
    out = decompressor.decompress(data, max_length=size + 1)  # one byte more tells "too much"
    if len(out) == size and not decompressor.eof:
        raise CorruptData(f"{what} data holds more than the {size} bytes the chunk declares")
    return out


def _chunk_records(f: BinaryIO, block: _Block, room: int) -> bytes:
    """Read, decompress and check one chunk; raise ``CorruptData`` when it is unreadable.

    ``room`` is the memory still free under the limit: a chunk that declares more is not
    decompressed (:class:`_TooLarge`).
    """
    f.seek(block.offset + 9)
    buf = f.read(block.end - block.offset - 9)
    try:
        _, _, uncompressed_size, crc = _CHUNK_TIMES.unpack_from(buf, 0)
        compression, pos = _read_str(buf, _CHUNK_TIMES.size)
        (n,) = _U64.unpack_from(buf, pos)
    except struct.error as err:
        raise CorruptData(f"chunk header unreadable: {err}") from err
    if pos + 8 + n > len(buf):
        raise CorruptData("chunk records run past the chunk")
    if uncompressed_size > room:
        raise _TooLarge(f"chunk declares {uncompressed_size:,} bytes uncompressed")
    try:
        data = decompress_exactly(compression, buf[pos + 8:pos + 8 + n], uncompressed_size)
    except CorruptData:
        raise  # a size mismatch, said as it is
    except Exception as err:  # zstd/lz4 raise their own error types
        raise CorruptData(f"chunk cannot be decompressed: {err}") from err
    if crc and zlib.crc32(data) != crc:
        raise CorruptData("chunk CRC mismatch")
    return data


def _parse_messages(buf: bytes, layout: _Layout, wanted: frozenset[str] | None,
                    room: int) -> np.ndarray:
    """Messages of a run of records as rows ``(log_time, publish_time, sequence,
    channel_id, start, end)`` (``uint64``, sorted by log time, ties in file order),
    ``buf[start:end]`` being the payload; schemas and channels are registered.

    Raises:
        CorruptData: a record is cut or made of zero bytes (a damaged block).
        _TooLarge: holding the messages would take more than ``room`` bytes.
    """
    if len(buf) >= _SCAN_BYTES:
        rows = _scanned_messages(buf, layout, wanted, room)
        if rows is not None:
            return rows
    out = array("Q")
    pos, end, n_records = 0, len(buf), 0
    channels = layout.channels
    head, message = _RECORD_HEAD.unpack_from, _MESSAGE_HEAD.unpack_from
    while pos + 9 <= end:
        op, length = head(buf, pos)
        body, nxt = pos + 9, pos + 9 + length
        if nxt > end:
            raise CorruptData(f"record at +{pos} runs past the end of its block")
        n_records += 1
        if n_records % _BLOCK_MESSAGES == 0:  # every record counts: floods of tiny ones stop early
            check_room(end, n_records, room)
        if op == _OP_MESSAGE:
            cid, seq, log_time, publish_time = message(buf, body)
            if log_time > _LAST_TIME_NS:  # times are int64 downstream; no clock reads 2262 or later
                raise CorruptData(f"message at +{pos} has a log time of {log_time} ns, past the year 2262")
            channel = channels.get(cid)
            if wanted is None or channel is None or channel.topic in wanted:
                out.extend((log_time, publish_time, seq, cid, min(body + 22, nxt), nxt))
        elif op in (_OP_SCHEMA, _OP_CHANNEL):
            _register_record(op, buf, body, nxt, layout)
            _resolve_channels(layout)
        elif op == _OP_INVALID:  # zero bytes are never walked record by record
            raise CorruptData(f"zero bytes instead of a record at +{pos}")
        pos = nxt
    check_room(end, len(out) // _COLUMNS, room)
    rows = np.frombuffer(out, np.uint64).reshape(-1, _COLUMNS)
    return _in_time_order(rows)


def _scanned_messages(buf: bytes, layout: _Layout, wanted: frozenset[str] | None,
                      room: int) -> np.ndarray | None:
    """:func:`_parse_messages` by the compiled walk (:mod:`slearn.io.mcap_scan`); ``None``
    when it stopped (a damaged or too large block: the Python walk says why)."""
    from slearn.io import mcap_scan

    status, rows, others = mcap_scan.scan(np.frombuffer(buf, np.uint8), room, _BLOCK_MESSAGES,
                                          _MESSAGE_BYTES)
    if status != mcap_scan.OK:
        return None
    before = dict(layout.channels)
    defined_at: dict[int, int] = {}  # channel id -> where this block defines it
    for op, body, nxt in others.tolist():
        if op == _OP_CHANNEL and nxt - body >= 2:
            defined_at.setdefault(struct.unpack_from("<H", buf, body)[0], body)
        _register_record(op, buf, body, nxt, layout)
        _resolve_channels(layout)
    if wanted is not None and len(rows):
        keep = np.ones(len(rows), bool)
        cids = rows[:, 3]
        for cid in np.unique(cids).tolist():
            known = before.get(cid) or layout.channels.get(cid)
            if known is None or known.topic in wanted:
                continue
            drop = cids == cid  # unwanted once its channel is known (as the walk decides)
            if cid not in before and cid in defined_at:
                drop &= rows[:, 4] > defined_at[cid]
            keep &= ~drop
        rows = rows[keep]
    check_room(len(buf), len(rows), room)
    return _in_time_order(rows)


def _in_time_order(rows: np.ndarray) -> np.ndarray:
    """Rows sorted by log time, ties in file order (no copy when they already are)."""
    times = rows[:, 0]
    if np.all(times[1:] >= times[:-1]):
        return rows
    return rows[np.argsort(times, kind="stable")]


def block_cost(n_bytes: int, n_records: int) -> int:
    """Memory an opened block of ``n_bytes`` with ``n_records`` records is counted for."""
    return n_bytes + _MESSAGE_BYTES * n_records


def check_room(n_bytes: int, n_records: int, room: int) -> None:
    """Refuse a block of ``n_bytes`` holding ``n_records`` records that would not fit in ``room``
    bytes of memory (its bytes plus an index entry per record).

    Raises:
        _TooLarge: it would not fit (the block is skipped, like a damaged one).
    """
    if block_cost(n_bytes, n_records) > room:
        raise _TooLarge(f"{n_bytes:,} bytes of records with at least {n_records:,} records")


_NO_ROWS = np.zeros((0, _COLUMNS), np.uint64)


class _Opened(NamedTuple):
    """An opened block: its messages as rows (see :func:`_parse_messages`), their log times
    (contiguous, for searching), the bytes they point into, its memory."""

    rows: np.ndarray
    times: np.ndarray
    buf: bytes
    cost: int


class MessageBatch(NamedTuple):
    """Consecutive messages of a log (in log-time order) as arrays over one buffer.

    ``buf[starts[k]:ends[k]]`` is the payload of message ``k``, on channel
    ``channels[channel_ids[k]]``, logged at ``log_times[k]`` (``uint64``); ``offsets`` are
    their byte offsets as :attr:`RawMessage.offset` gives them.
    """

    buf: bytes
    channel_ids: np.ndarray
    log_times: np.ndarray
    starts: np.ndarray
    ends: np.ndarray
    offsets: np.ndarray
    channels: dict[int, ChannelInfo]

    def __len__(self) -> int:
        return len(self.log_times)


def batch_of(messages: list[RawMessage]) -> MessageBatch:
    """A batch of raw messages (payloads copied into one buffer)."""
    sizes = np.fromiter((len(m.data) for m in messages), np.int64, len(messages))
    ends = np.cumsum(sizes)
    channels = {m.channel.id: m.channel for m in messages}
    return MessageBatch(b"".join(m.data for m in messages),
                        np.fromiter((m.channel.id for m in messages), np.int64, len(messages)),
                        np.fromiter((m.log_time_ns for m in messages), np.uint64, len(messages)),
                        ends - sizes, ends,
                        np.fromiter((m.offset for m in messages), np.int64, len(messages)), channels)


def iter_batches_of(messages: Iterator[RawMessage], size: int = 4096) -> Iterator[MessageBatch]:
    """Group a message stream into batches of at most ``size`` messages."""
    pending: list[RawMessage] = []
    for message in messages:
        pending.append(message)
        if len(pending) >= size:
            yield batch_of(pending)
            pending = []
    if pending:
        yield batch_of(pending)


class _Merge:
    """Pass 2: k-way merge of blocks by ``(log_time, block index, index in block)``.

    It yields runs: consecutive messages of one block that come before every message of
    the other blocks (a whole chunk, when chunks do not overlap in time). Opened blocks
    stay in memory until their last message is yielded; together they take at most
    ``limit`` bytes (decompressed records plus the message index). Above ``soft`` bytes
    (or to make room for a block), a block whose next message comes after the last
    message of another open block is closed, and opened again when its turn comes:
    chunks that all start at log time 0 are read one at a time, each twice. A block that
    would still exceed ``limit`` is skipped and reported (raise the limit to read it).
    """

    def __init__(self, f: BinaryIO, layout: _Layout, report: ReadReport,
                 wanted: frozenset[str] | None, on_progress, limit: int) -> None:
        self.f, self.layout, self.report, self.wanted = f, layout, report, wanted
        self.on_progress, self.limit = on_progress, limit
        self.soft = min(limit, _SOFT_BYTES)
        self.order = sorted(range(len(layout.blocks)), key=lambda i: (layout.blocks[i].min_time, i))
        self.opened = [False] * len(layout.blocks)
        self.harvested_upto = 0  # blocks before this index are opened or harvested
        self.bytes_read = 0
        self.open_bytes = 0
        self.heap: list[list] = []  # [next log time, block index, position, _Opened or None]

    def _parse(self, i: int, count: bool = True) -> _Opened:
        block = self.layout.blocks[i]
        try:
            rows, buf = self._read(block)
        except _TooLarge as err:
            held = f" with {self.open_bytes / 2**20:.1f} MiB held by chunks overlapping in time" \
                if self.open_bytes else ""
            self._skip(block, f"{err}: over the {self.limit / 2**20:g} MiB of chunk data read at "
                              f"once{held}; raise {MAX_CHUNK_ENV} to read it")
            rows, buf = _NO_ROWS, b""
        except (CorruptData, struct.error) as err:  # struct.error: a record cut short
            self._skip(block, str(err))
            rows, buf = _NO_ROWS, b""
        if count:
            self.bytes_read += block.end - block.offset
            if self.on_progress is not None:
                self.on_progress(self.bytes_read, self.report.size_bytes)
        return _Opened(rows, np.ascontiguousarray(rows[:, 0]), buf, block_cost(len(buf), len(rows)))

    def _read(self, block: _Block) -> tuple[np.ndarray, bytes]:
        """Rows and buffer of a block; closes other blocks when it would not fit beside them."""
        while True:
            room = self.limit - self.open_bytes
            try:
                if block.is_chunk:
                    buf = _chunk_records(self.f, block, room)
                else:
                    self.f.seek(block.offset)
                    buf = self.f.read(block.end - block.offset)
                return _parse_messages(buf, self.layout, self.wanted, room), buf
            except _TooLarge:
                if not self._close_one():
                    raise

    def _skip(self, block: _Block, reason: str) -> None:
        where = "chunk" if block.is_chunk else "records"
        self.report.note_break(block.offset, f"{where} skipped: {reason}")
        self.report.n_skipped_chunks += block.is_chunk

    def _open(self, i: int) -> _Opened:
        self.opened[i] = True
        opened = self._parse(i)
        channels = self.layout.channels
        if any(int(c) not in channels for c in np.unique(opened.rows[:, 3])):
            self._harvest_before(i)
        return opened

    def _harvest_before(self, i: int) -> None:
        """Read unopened blocks before ``i`` in file order for the channels they define.

        Their messages are not kept (the blocks are read again when their turn comes),
        so harvesting never holds more than one extra block.
        """
        for j in range(self.harvested_upto, i):
            if not self.opened[j]:
                self._parse(j, count=False)
        self.harvested_upto = max(self.harvested_upto, i)

    def _push(self, i: int, j: int, opened: _Opened) -> None:
        if j < len(opened.times):
            self.open_bytes += opened.cost
            heapq.heappush(self.heap, [int(opened.times[j]), i, j, opened])
            while self.open_bytes > self.soft and self._close_one():
                pass

    def _close_one(self) -> bool:
        """Close the open block whose next message comes last, if it waits for another open
        block to finish (so it is opened again at most once per block finished: no
        thrashing); whether one was closed."""
        open_entries = [e for e in self.heap if e[3] is not None]
        if len(open_entries) < 2:
            return False
        victim = max(open_entries, key=lambda e: (e[0], e[1]))
        if victim[0] <= min(int(e[3].times[-1]) for e in open_entries if e is not victim):
            return False
        self.open_bytes -= victim[3].cost
        victim[3] = None
        return True

    def _reopen(self, entry: list) -> None:
        """Open a closed block again (the same rows: parsing is deterministic)."""
        opened = self._parse(entry[1], count=False)
        entry[3] = opened
        self.open_bytes += opened.cost

    def runs(self) -> Iterator[tuple[int, _Opened, int, int]]:
        """``(block index, opened block, first, stop)``: rows ``first:stop`` come next."""
        blocks, heap, order = self.layout.blocks, self.heap, self.order
        k = 0
        while True:
            while k < len(order) and (not heap or blocks[order[k]].min_time <= heap[0][0]):
                self._push(order[k], 0, self._open(order[k]))
                k += 1
            if not heap:
                return
            entry = heap[0]
            if entry[3] is None:
                self._reopen(entry)
            _, i, j, opened = heapq.heappop(heap)
            times = opened.times
            stop = len(times)
            if heap:
                stop = int(np.searchsorted(times, heap[0][0], "right" if i < heap[0][1] else "left"))
            if k < len(order):
                stop = min(stop, int(np.searchsorted(times, blocks[order[k]].min_time, "left")))
            stop = max(stop, j + 1)
            self.open_bytes -= opened.cost
            yield i, opened, j, stop
            self._push(i, stop, opened)

    def _selected(self, i: int, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The rows of a run on known channels of the wanted topics, and their channel ids;
        messages on undefined channels are reported."""
        channels = self.layout.channels
        cids = rows[:, 3].astype(np.int64)
        unique = np.unique(cids).tolist()
        defined = [c for c in unique if c in channels]
        keep = np.isin(cids, defined) if len(defined) < len(unique) else np.ones(len(cids), bool)
        if not keep.all():
            bad = int(cids[~keep][0])
            self.report.note_break(self.layout.blocks[i].offset, f"message on undefined channel id {bad}")
        if self.wanted is not None:
            wanted = [c for c in defined if channels[c].topic in self.wanted]
            if len(wanted) < len(defined):
                keep &= np.isin(cids, wanted)
        return (rows, cids) if keep.all() else (rows[keep], cids[keep])

    def batches(self) -> Iterator[MessageBatch]:
        """The runs as :class:`MessageBatch` es."""
        for i, opened, j, stop in self.runs():
            rows, cids = self._selected(i, opened.rows[j:stop])
            if len(rows):
                block = self.layout.blocks[i]
                starts, ends = rows[:, 4].astype(np.int64), rows[:, 5].astype(np.int64)
                offsets = np.full(len(rows), block.offset, np.int64) if block.is_chunk \
                    else block.offset + starts - 31
                yield MessageBatch(opened.buf, cids, rows[:, 0], starts, ends, offsets,
                                   self.layout.channels)

    def __iter__(self) -> Iterator[RawMessage]:
        channels = self.layout.channels
        for i, opened, j, stop in self.runs():
            rows, _ = self._selected(i, opened.rows[j:stop])
            block, buf = self.layout.blocks[i], opened.buf
            for log_time, publish, seq, cid, start, end in rows.tolist():
                offset = block.offset if block.is_chunk else block.offset + start - 31
                yield RawMessage(channels[cid], log_time, publish, seq, buf[start:end], offset)
