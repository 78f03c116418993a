"""Salvage of ROS 1 bags whose index is missing or damaged: a linear read of their records.

``rosbags`` reads a bag through its index, which is written last: a recorder that was
killed, or a copy cut short, leaves a bag without one. This reader walks the records from
the start instead. Pass 1 registers the connection records and notes each chunk's time
range (uncompressed, ``bz2`` or ``lz4`` chunks); pass 2 merges the chunks' messages in
log-time order (ties in file order), opening a chunk only when the merge reaches its
first time, so memory holds the chunks whose times overlap. Where the file broke is
recorded in the report, as for MCAP files.

Memory and time are bounded as for MCAP files (:mod:`slearn.io.mcap_read`): a chunk is
decompressed into exactly the size its header declares, a chunk declaring more than
``SLEARN_MAX_CHUNK_MB`` or holding more records than fit in it is skipped, and the chunks
open at once stay under that limit; a record header too short to hold its ``op`` field
(zero bytes) ends the chunk as damaged instead of being walked.
"""

from __future__ import annotations

import heapq
import os
import struct
from dataclasses import dataclass, replace
from functools import partial
from typing import BinaryIO, Callable, Iterable, Iterator

from slearn.errors import InputError
from slearn.io.files import regular_file
from slearn.io.mcap_read import (
    MAX_CHUNK_ENV,
    AttachmentInfo,
    ChannelInfo,
    CorruptData,
    RawMessage,
    ReadReport,
    SchemaInfo,
    _OpenLog,
    block_cost,
    check_room,
    decompress_exactly,
    max_chunk_bytes_setting,
)

MAGIC = b"#ROSBAG V2.0\n"
_OP_MESSAGE, _OP_CHUNK, _OP_CONNECTION = 0x02, 0x05, 0x07
_U32 = struct.Struct("<I")
_TIME = struct.Struct("<II")
_MAX_RECORD = 1 << 31  # a longer header or data length is corruption, not data
_MIN_HEADER = 8  # the shortest header field, op=X, takes 4 + 4 bytes
_COMPRESSION = {"none": "", "bz2": "bz2", "lz4": "lz4"}  # ROS 1 names -> decompress_exactly's


@dataclass
class _Chunk:
    """A chunk's place in the file, its declared size and the log times of its messages."""

    offset: int
    data_pos: int
    data_len: int
    compression: str
    size: int
    min_time: int
    max_time: int


def _fields(buf: bytes) -> dict[str, bytes]:
    """The ``name=value`` fields of a record header."""
    out, pos = {}, 0
    while pos + 4 <= len(buf):
        (n,) = _U32.unpack_from(buf, pos)
        name, _, value = buf[pos + 4:pos + 4 + n].partition(b"=")
        out[name.decode("ascii", "replace")] = value
        pos += 4 + n
    return out


def _records(buf: bytes, limit: int) -> Iterator[tuple[dict[str, bytes], bytes]]:
    """``(header fields, data)`` of the records in a decompressed chunk.

    Raises:
        CorruptData: a record is cut or has no header, or the records would not fit in
            ``limit`` bytes of memory (:func:`~slearn.io.mcap_read.check_room`).
    """
    pos, n_records = 0, 0
    while pos + 4 <= len(buf):
        n_records += 1
        if n_records % 4096 == 0:
            check_room(len(buf), n_records, limit)
        (n,) = _U32.unpack_from(buf, pos)
        if n < _MIN_HEADER:
            raise CorruptData(f"a record header of {n} bytes at +{pos} (zero bytes?)")
        header = _fields(buf[pos + 4:pos + 4 + n])
        (m,) = _U32.unpack_from(buf, pos + 4 + n)
        start = pos + 8 + n
        if start + m > len(buf):
            raise CorruptData("a record runs past the end of its chunk")
        yield header, buf[start:start + m]
        pos = start + m


def _decompress(chunk: _Chunk, data: bytes, limit: int) -> bytes:
    """The chunk's records: exactly the bytes its header declares, refused above ``limit``.

    Raises:
        CorruptData: over the limit, another size than declared, or not decompressible.
    """
    if chunk.size > limit:
        raise CorruptData(f"chunk declares {chunk.size:,} bytes uncompressed, over the "
                         f"{limit / 2**20:.1f} MiB it may use; raise {MAX_CHUNK_ENV} to read it")
    if chunk.compression not in _COMPRESSION:
        raise CorruptData(f"unknown chunk compression {chunk.compression!r}")
    try:
        return decompress_exactly(_COMPRESSION[chunk.compression], data, chunk.size)
    except CorruptData:
        raise
    except Exception as err:  # bz2 and lz4 raise their own error types
        raise CorruptData(f"chunk cannot be decompressed: {err}") from err


def chunk_decompressor(f: BinaryIO, offset: int, limit: int) -> Callable[[bytes], bytes]:
    """A function decompressing the data of the chunk record at byte ``offset`` of ``f`` as
    this module does: into exactly the size its header declares, at most ``limit`` bytes.

    Its ``ValueError`` names the damage (a header without ``size`` included).
    """
    try:
        f.seek(offset)
        (n,) = _U32.unpack(f.read(4))
        header = _fields(f.read(n) if n < _MAX_RECORD else b"")
        chunk = _Chunk(offset, 0, 0, header.get("compression", b"none").decode("ascii", "replace"),
                       _U32.unpack(header["size"][:4])[0], 0, 0)
    except (struct.error, KeyError) as err:
        return partial(_refuse, f"the header of the chunk at byte {offset} is unreadable ({err!r})")
    return partial(_decompress, chunk, limit=limit)


def _refuse(reason: str, data: bytes) -> bytes:
    raise CorruptData(reason)


def _time_ns(field: bytes) -> int:
    sec, nsec = _TIME.unpack(field[:8])
    return sec * 1_000_000_000 + nsec


class Ros1Salvage(_OpenLog):
    """A ROS 1 bag read linearly (see the module docstring); the interface of an MCAP log."""

    profile = "ros1"
    library = ""

    def __init__(self, path: str | os.PathLike, max_chunk_bytes: int | None = None) -> None:
        self.path = os.fspath(regular_file(path, "ROS 1 bag file"))  # a FIFO would block open()
        self.limit = max_chunk_bytes or max_chunk_bytes_setting()
        try:
            self._file = open(self.path, "rb")
        except OSError as err:
            raise InputError(f"{self.path}: cannot open: {err.strerror or err}") from err
        self.report = ReadReport(self.path, size_bytes=os.fstat(self._file.fileno()).st_size)
        self._channels: dict[int, ChannelInfo] = {}
        self._chunks: list[_Chunk] = []
        try:
            self._scan()
        except BaseException:
            self._file.close()
            raise

    @property
    def channels(self) -> dict[int, ChannelInfo]:
        """The connections found, as channels, by id."""
        return self._channels

    def _scan(self) -> None:
        if self._file.read(len(MAGIC)) != MAGIC:
            raise InputError(f"{self.path}: not a ROS 1 bag (no #ROSBAG V2.0 at the start)")
        pos, size, indexed = len(MAGIC), self.report.size_bytes, False
        while True:
            start = pos
            record = self._read_record(pos, size)
            if record is None:
                break
            header, data_pos, data_len, pos = record
            op = header.get("op", b"\0")[0]
            if op == _OP_CHUNK:
                self._scan_chunk(start, header, data_pos, data_len)
            elif op == _OP_CONNECTION:
                self._file.seek(data_pos)
                self._connection(header, self._file.read(data_len))
            indexed = indexed or op == 0x06  # chunk info records follow the last chunk
        if not indexed:
            self.report.note_break(pos, "the bag ends without its index (was the recorder stopped?)")

    def _read_record(self, pos: int, size: int) -> tuple | None:
        """``(header, data position, data length, next position)``; ``None`` at the end or a break."""
        self._file.seek(pos)
        head = self._file.read(4)
        if len(head) < 4:
            if head:
                self.report.note_break(pos, "the file ends inside a record")
            return None
        (n,) = _U32.unpack(head)
        header = self._file.read(n) if n < _MAX_RECORD else b""
        tail = self._file.read(4)
        if len(header) < n or len(tail) < 4:
            self.report.note_break(pos, "the file ends inside a record header")
            return None
        (m,) = _U32.unpack(tail)
        data_pos = pos + 8 + n
        if data_pos + m > size:
            self.report.note_break(pos, f"a record of {m} bytes runs past the end of the file")
            return None
        return _fields(header), data_pos, m, data_pos + m

    def _scan_chunk(self, offset: int, header: dict[str, bytes], data_pos: int, data_len: int) -> None:
        try:
            chunk = _Chunk(offset, data_pos, data_len,
                           header.get("compression", b"none").decode("ascii", "replace"),
                           _U32.unpack(header["size"][:4])[0], 0, 0)
            times = [_time_ns(h["time"]) for h, _ in self._chunk_records(chunk, self.limit)
                     if h.get("op", b"\0")[0] == _OP_MESSAGE]
        except (CorruptData, OSError, struct.error, KeyError) as err:
            self._skip(offset, f"unreadable chunk: {err}")
            return
        if times:
            self._chunks.append(replace(chunk, min_time=min(times), max_time=max(times)))

    def _skip(self, offset: int, reason: str) -> None:
        self.report.note_break(offset, reason)
        self.report.n_skipped_chunks += 1

    def _chunk_records(self, chunk: _Chunk, room: int):
        self._file.seek(chunk.data_pos)
        records = _decompress(chunk, self._file.read(chunk.data_len), room)
        for record_header, data in _records(records, room):
            if record_header.get("op", b"\0")[0] == _OP_CONNECTION:
                self._connection(record_header, data)
            yield record_header, data

    def _connection(self, header: dict[str, bytes], data: bytes) -> None:
        conn = _U32.unpack(header["conn"][:4])[0]
        if conn in self._channels:
            return
        info = _fields(data)
        text = {k: v.decode("utf-8", "replace") for k, v in info.items()}
        topic = text.get("topic") or header.get("topic", b"").decode("utf-8", "replace")
        schema = SchemaInfo(conn, text.get("type", ""), "ros1msg", info.get("message_definition", b""))
        self._channels[conn] = ChannelInfo(conn, topic, "ros1", schema, {"md5sum": text.get("md5sum", "")})

    def time_range(self) -> tuple[int, int] | None:
        """``(first, last)`` log time of the readable chunks."""
        if not self._chunks:
            return None
        return min(c.min_time for c in self._chunks), max(c.max_time for c in self._chunks)

    def iter_messages(self, topics: Iterable[str] | None = None,
                      on_progress: Callable[[int, int], None] | None = None) -> Iterator[RawMessage]:
        """Raw messages in log-time order (ties in file order); ``offset`` is their chunk's."""
        wanted = None if topics is None else frozenset(topics)
        self.report.filtered = wanted is not None
        order = sorted(range(len(self._chunks)), key=lambda i: (self._chunks[i].min_time, i))
        heap: list[tuple] = []
        k = held = 0
        while True:
            while k < len(order) and (not heap or self._chunks[order[k]].min_time <= heap[0][0]):
                messages, cost = self._messages(order[k], wanted, self.limit - held)
                if messages:
                    held += cost
                    heapq.heappush(heap, (messages[0][0], order[k], 0, messages, cost))
                if on_progress is not None:
                    on_progress(self._chunks[order[k]].data_pos, self.report.size_bytes)
                k += 1
            if not heap:
                return
            log_time, i, j, messages, cost = heap[0]
            if j + 1 < len(messages):
                heapq.heapreplace(heap, (messages[j + 1][0], i, j + 1, messages, cost))
            else:
                heapq.heappop(heap)
                held -= cost
            self.report.n_messages += 1
            yield RawMessage(self._channels[messages[j][1]], log_time, log_time, 0, messages[j][2],
                             self._chunks[i].offset)

    def _messages(self, i: int, wanted: frozenset[str] | None,
                  room: int) -> tuple[list[tuple[int, int, bytes]], int]:
        """A chunk's messages sorted by time, and the memory they are counted for; a chunk
        that does not fit in ``room`` (with the chunks open before it) is skipped."""
        chunk = self._chunks[i]
        out = []
        try:
            for header, data in self._chunk_records(chunk, room):
                if header.get("op", b"\0")[0] != _OP_MESSAGE:
                    continue
                conn = _U32.unpack(header["conn"][:4])[0]
                channel = self._channels.get(conn)
                if channel is not None and (wanted is None or channel.topic in wanted):
                    out.append((_time_ns(header["time"]), conn, data))
        except CorruptData as err:
            self._skip(chunk.offset, f"chunk skipped: {err} (with {(self.limit - room) / 2**20:.1f} "
                                     f"MiB held by chunks overlapping in time)")
            return [], 0
        out.sort(key=lambda m: m[0])  # stable: ties keep file order
        return out, block_cost(sum(len(m[2]) for m in out), len(out))

    def iter_metadata(self) -> Iterator[tuple[str, dict[str, str]]]:
        """ROS 1 bags have no metadata records."""
        return iter(())

    def iter_attachments(self) -> Iterator[AttachmentInfo]:
        """ROS 1 bags have no attachments."""
        return iter(())
