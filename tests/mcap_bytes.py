"""MCAP files made record by record, for damaged and hostile inputs (bombs, bad sizes).

Also used by ``bench/fuzz.py``. Messages are JSON on channel 1 (``/a``, schema 1).
"""

from __future__ import annotations

import struct
import zlib

import lz4.frame
import zstandard

MAGIC = b"\x89MCAP0\r\n"


def record(op: int, body: bytes) -> bytes:
    """One record: opcode, length, body."""
    return struct.pack("<BQ", op, len(body)) + body


def string(text: str) -> bytes:
    data = text.encode()
    return struct.pack("<I", len(data)) + data


def header() -> bytes:
    return record(0x01, string("") + string("slearn-tests"))


def schema(schema_id: int = 1) -> bytes:
    return record(0x03, struct.pack("<H", schema_id) + string("Thing") + string("jsonschema")
                  + struct.pack("<I", 2) + b"{}")


def channel(channel_id: int = 1, topic: str = "/a", schema_id: int = 1) -> bytes:
    return record(0x04, struct.pack("<HH", channel_id, schema_id) + string(topic) + string("json")
                  + struct.pack("<I", 0))


def message(log_time: int, data: bytes = b'{"v":1}', channel_id: int = 1) -> bytes:
    return record(0x05, struct.pack("<HIQQ", channel_id, 0, log_time, log_time) + data)


def compress(records: bytes, compression: str) -> bytes:
    if compression == "zstd":
        return zstandard.ZstdCompressor().compress(records)
    if compression == "lz4":
        return lz4.frame.compress(records)
    return records


def chunk(records: bytes = b"", compression: str = "zstd", *, declared: int | None = None,
          start: int = 0, end: int = 10 ** 9, data: bytes | None = None, crc: int | None = None) -> bytes:
    """A chunk of ``records`` (or of already ``data`` compressed), declaring ``declared``
    uncompressed bytes (default: the truth) and the CRC of ``records`` (0 when ``data``)."""
    if data is None:
        data = compress(records, compression)
        crc = zlib.crc32(records) if crc is None else crc
    size = len(records) if declared is None else declared
    body = (struct.pack("<QQQI", start, end, size, crc or 0) + string(compression)
            + struct.pack("<Q", len(data)) + data)
    return record(0x06, body)


def footer() -> bytes:
    return record(0x02, struct.pack("<QQI", 0, 0, 0))


def log(*parts: bytes) -> bytes:
    """A whole file: magic, header, schema 1 and channel 1, ``parts``, footer, magic."""
    return MAGIC + header() + schema() + channel() + b"".join(parts) + footer() + MAGIC
