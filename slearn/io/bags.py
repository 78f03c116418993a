"""Logs that are not one MCAP file: rosbag2 folders, ROS 2 ``.db3`` and ROS 1 ``.bag`` files.

:func:`open_log` opens any log slearn reads and gives the interface of
:class:`~slearn.io.mcap_read.McapLog`: ``profile``, ``library``, ``channels``, ``report``,
``iter_messages(topics, on_progress)`` in log-time order, ``time_range()``,
``iter_metadata()``, ``iter_attachments()``. Messages come raw, with channels whose schema
is the message definition (``ros2msg`` or ``ros1msg``), so decoding, specs and field paths
are those of MCAP logs.

- A **rosbag2 folder** (or its ``metadata.yaml``) is one log, whatever the number of files
  it was split into. MCAP storage is read file by file with slearn's own reader (the same
  salvage of truncated files) and merged in log-time order; channels of the same topic and
  type in several files are one channel. ``sqlite3`` storage is read with ``rosbags``.
- A **ROS 2 ``.db3``** file is read with ``rosbags``; when the file carries no message
  definitions (before ROS 2 Iron), those of ``rosbags``' newest type store are used.
- A **ROS 1 ``.bag``** is read with ``rosbags``; a bag whose index is missing or damaged
  (a recorder that was killed) is read linearly instead (:mod:`slearn.io.ros1_salvage`).

A file that breaks while being read (``rosbags`` raises) keeps what was read before: the
report notes where it broke, and a :class:`~slearn.errors.TruncatedLogWarning` follows as
for MCAP files.

The limits of MCAP files hold for bags too: a FIFO or device is refused before it is
opened, and ROS 1 chunks are decompressed into exactly the size they declare, at most
``SLEARN_MAX_CHUNK_MB`` (:func:`~slearn.io.ros1_salvage.chunk_decompressor`, also for the
chunks ``rosbags`` reads). Messages read through ``rosbags``, and those of a folder of
several files, carry no byte offset (:data:`~slearn.io.mcap_read.UNKNOWN_OFFSET`): warnings
name them by their number instead.
"""

from __future__ import annotations

import heapq
import os
from functools import lru_cache
from pathlib import Path
from typing import Callable, Iterable, Iterator

from slearn.errors import InputError
from slearn.io.files import regular_file
from slearn.io.mcap_read import (
    UNKNOWN_OFFSET,
    AttachmentInfo,
    ChannelInfo,
    McapLog,
    RawMessage,
    ReadReport,
    SchemaInfo,
    max_chunk_bytes_setting,
)

METADATA_FILE = "metadata.yaml"
BAG_SUFFIXES = (".db3", ".bag")
_MAX_METADATA_BYTES = 64 << 20  # a rosbag2 metadata.yaml larger than this is not one


def is_log_path(path: str | os.PathLike) -> bool:
    """Whether ``path`` names something :func:`open_log` reads as a bag (folder, .db3, .bag)."""
    path = Path(path)
    return (path.is_dir() and (path / METADATA_FILE).is_file()) or path.name == METADATA_FILE \
        or path.suffix.lower() in BAG_SUFFIXES


def check_log_path(path: str | os.PathLike) -> None:
    """Refuse ``path`` unless it is a regular file or a rosbag2 folder (one with its
    ``metadata.yaml``), in one line naming it: missing, a plain folder, a pipe or a device.
    Opens nothing."""
    if not (os.path.isdir(path) and is_log_path(path)):
        regular_file(path, "log file (or rosbag2 folder with metadata.yaml)")


def open_log(path: str | os.PathLike):
    """Open a log: MCAP file, rosbag2 folder (or its ``metadata.yaml``), ``.db3`` or ``.bag``.

    Raises:
        InputError: the path does not exist or cannot be read as a log.
    """
    path = Path(path)
    if path.name == METADATA_FILE:
        path = path.parent
    if path.is_dir():
        if not os.path.lexists(path / METADATA_FILE):
            raise InputError(f"{path}: a folder, but not a rosbag2 bag (no {METADATA_FILE} in it)")
        return _open_rosbag2_folder(path)
    if path.suffix.lower() == ".db3":
        return RosbagsLog(regular_file(path, "ROS 2 .db3 bag"), "ros2")
    if path.suffix.lower() == ".bag":
        return _open_ros1(regular_file(path, "ROS 1 .bag file"))
    return McapLog(path)


def _open_ros1(path: Path):
    """A ROS 1 bag through its index (``rosbags``), else read linearly to salvage it."""
    from slearn.io.ros1_salvage import Ros1Salvage

    try:
        return RosbagsLog(path, "ros1")
    except InputError as indexed_failure:
        try:
            return Ros1Salvage(path)
        except InputError:
            raise indexed_failure from None


def log_files(path: str | os.PathLike) -> list[Path]:
    """The files that make up a log (a folder's storage files and its ``metadata.yaml``)."""
    path = Path(path)
    if path.name == METADATA_FILE:
        path = path.parent
    if not path.is_dir():
        return [path]
    files = [path / METADATA_FILE]
    return files + [path / name for name in _bag_metadata(path)["files"]]


def _bag_metadata(folder: Path) -> dict:
    """``{"storage": ..., "files": [...], "compression": ..., "text": ...}`` of ``metadata.yaml``."""
    from ruamel.yaml import YAML
    from ruamel.yaml.error import YAMLError

    where = regular_file(folder / METADATA_FILE, "rosbag2 metadata file")  # never a FIFO
    try:
        if where.stat().st_size > _MAX_METADATA_BYTES:
            raise ValueError(f"over {_MAX_METADATA_BYTES >> 20} MiB")
        text = where.read_text(encoding="utf-8")
        info = YAML(typ="safe").load(text)["rosbag2_bagfile_information"]
        return {"storage": str(info.get("storage_identifier", "")), "text": text,
                "files": [Path(p).name for p in info["relative_file_paths"]],
                "compression": str(info.get("compression_mode") or "").lower()}
    except (OSError, UnicodeDecodeError, YAMLError, KeyError, TypeError, ValueError,
            AttributeError, RecursionError) as err:
        raise InputError(f"{where}: not a readable rosbag2 metadata file ({type(err).__name__}: "
                         f"{str(err)[:200]})") from None


def _open_rosbag2_folder(folder: Path):
    meta = _bag_metadata(folder)
    for name in meta["files"]:
        regular_file(folder / name, f"storage file of the bag (listed in {METADATA_FILE})")
    if meta["storage"] == "mcap" and meta["compression"] in ("", "none"):
        return Rosbag2McapFolder(folder, meta)
    return RosbagsLog(folder, "ros2", meta["text"])


class _LogBase:
    """Context manager and shared accessors of the bag readers."""

    path: str
    profile: str = ""
    library: str = ""

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:  # pragma: no cover - overridden
        """Close the files."""


class Rosbag2McapFolder(_LogBase):
    """A rosbag2 folder with MCAP storage: its files merged into one log."""

    def __init__(self, folder: Path, meta: dict) -> None:
        self.path, self._meta = str(folder), meta
        self._logs: list[McapLog] = []
        try:
            for name in meta["files"]:
                self._logs.append(McapLog(folder / name))
        except BaseException:
            self.close()
            raise
        first = self._logs[0] if self._logs else None
        self.profile = first.profile if first else "ros2"
        self.library = first.library if first else ""
        self.report = ReadReport(self.path, size_bytes=sum(log.report.size_bytes for log in self._logs))
        self._channels: dict[tuple, ChannelInfo] = {}
        self._by_file: dict[tuple[int, int], ChannelInfo] = {}
        for i, log in enumerate(self._logs):
            for channel in log.channels.values():
                self._unified(i, channel)

    def close(self) -> None:
        for log in self._logs:
            log.close()

    @property
    def channels(self) -> dict[int, ChannelInfo]:
        """Channels of all files, one per (topic, encoding, schema), by id."""
        return {c.id: c for c in self._channels.values()}

    def _unified(self, i: int, channel: ChannelInfo) -> ChannelInfo:
        found = self._by_file.get((i, channel.id))
        if found is None:
            s = channel.schema
            key = (channel.topic, channel.message_encoding) + ((s.name, s.encoding, s.data) if s else ())
            found = self._channels.get(key)
            if found is None:
                found = self._channels[key] = ChannelInfo(len(self._channels) + 1, channel.topic,
                                                          channel.message_encoding, s,
                                                          dict(channel.metadata))
            self._by_file[(i, channel.id)] = found
        return found

    def time_range(self) -> tuple[int, int] | None:
        """``(first, last)`` log time over the files."""
        spans = [r for r in (log.time_range() for log in self._logs) if r is not None]
        return (min(a for a, _ in spans), max(b for _, b in spans)) if spans else None

    def iter_messages(self, topics: Iterable[str] | None = None,
                      on_progress: Callable[[int, int], None] | None = None) -> Iterator[RawMessage]:
        """Raw messages of all files in log-time order (ties: file order)."""
        topics = None if topics is None else list(topics)
        total, done = self.report.size_bytes, [0] * len(self._logs)

        def progress(i: int) -> Callable[[int, int], None]:
            def show(read: int, _: int) -> None:
                done[i] = read
                if on_progress is not None:
                    on_progress(sum(done), total)
            return show

        streams = [_stamped(i, log.iter_messages(topics, progress(i))) for i, log in enumerate(self._logs)]
        for _, i, message in heapq.merge(*streams, key=lambda item: item[:2]):
            self.report.n_messages += 1  # offsets are the files': named by number instead
            yield message._replace(channel=self._unified(i, message.channel), offset=UNKNOWN_OFFSET)
        self._collect_reports()

    def _collect_reports(self) -> None:
        self.report.filtered = any(log.report.filtered for log in self._logs)
        for log in self._logs:
            self.report.n_skipped_chunks += log.report.n_skipped_chunks
            if log.report.broken_at is not None:
                self.report.note_break(UNKNOWN_OFFSET, f"in {os.path.basename(log.path)} at byte "
                                       f"{log.report.broken_at} of {log.report.size_bytes}: "
                                       f"{log.report.reason}")

    def iter_metadata(self) -> Iterator[tuple[str, dict[str, str]]]:
        """The bag's ``metadata.yaml`` (as record ``rosbag2.metadata_yaml``), then every file's records."""
        yield "rosbag2.metadata_yaml", {"metadata.yaml": self._meta["text"]}
        for log in self._logs:
            yield from log.iter_metadata()

    def iter_attachments(self) -> Iterator[AttachmentInfo]:
        """Every file's attachments."""
        for log in self._logs:
            yield from log.iter_attachments()


def _stamped(i: int, messages: Iterator[RawMessage]) -> Iterator[tuple[int, int, RawMessage]]:
    """``(log time, file index, message)`` of file ``i``'s messages. (A generator expression
    in a comprehension would read ``i`` when consumed, after the comprehension ended: every
    file's messages would carry the last file's index, and their channel ids would be read
    in the last file's numbering.)"""
    for m in messages:
        yield m.log_time_ns, i, m


class RosbagsLog(_LogBase):
    """A ROS 2 ``.db3`` file or sqlite3 rosbag2 folder, or a ROS 1 ``.bag``, read by ``rosbags``."""

    def __init__(self, path: Path, profile: str, metadata_yaml: str | None = None) -> None:
        self.path, self.profile, self._yaml = str(path), profile, metadata_yaml
        self.library = ""
        size = sum(f.stat().st_size for f in log_files(path) if f.is_file())
        self.report = ReadReport(self.path, size_bytes=size)
        self._reader = self._open(path)
        try:
            self._channels = {c.id: _channel_of(c, profile) for c in self._reader.connections}
        except BaseException:
            self.close()
            raise

    def _open(self, path: Path):
        if self.profile == "ros1":
            from rosbags.rosbag1 import Reader as Ros1Reader
            reader_type: type = Ros1Reader
        else:
            from rosbags.rosbag2 import Reader as Ros2Reader
            reader_type = Ros2Reader
        try:
            reader = reader_type(path)
            reader.open()
        except Exception as err:  # rosbags, sqlite and the OS raise many types
            kind = "a ROS 1 bag" if self.profile == "ros1" else "a ROS 2 bag"
            raise InputError(f"{path}: cannot be read as {kind}: {type(err).__name__}: {err}") from err
        if self.profile == "ros1":
            _bound_chunks(reader, path)
        return reader

    def close(self) -> None:
        if getattr(self, "_reader", None) is not None:
            reader, self._reader = self._reader, None
            reader.close()

    @property
    def channels(self) -> dict[int, ChannelInfo]:
        """The bag's connections as channels, by id."""
        return self._channels

    def time_range(self) -> tuple[int, int] | None:
        """``(first, last)`` log time from the bag's index."""
        if not self._reader.message_count:
            return None
        return self._reader.start_time, self._reader.end_time - 1

    def iter_messages(self, topics: Iterable[str] | None = None,
                      on_progress: Callable[[int, int], None] | None = None) -> Iterator[RawMessage]:
        """Raw messages in log-time order; a read error ends the pass and is reported."""
        wanted = None if topics is None else set(topics)
        self.report.filtered = wanted is not None
        connections = [c for c in self._reader.connections if wanted is None or c.topic in wanted]
        if not connections:
            return
        total = max(sum(c.msgcount for c in connections), 1)
        messages = self._reader.messages(connections)
        while True:
            try:
                connection, log_time, data = next(messages)
            except StopIteration:
                return
            except Exception as err:  # a damaged bag: keep what was read, say where it broke
                self.report.note_break(UNKNOWN_OFFSET, f"message {self.report.n_messages + 1} "
                                       f"cannot be read: {type(err).__name__}: {err}")
                return
            self.report.n_messages += 1
            if on_progress is not None and self.report.n_messages % 4096 == 0:
                size = self.report.size_bytes
                on_progress(self.report.n_messages * size // total, size)
            yield RawMessage(self._channels[connection.id], log_time, log_time, 0, bytes(data))

    def iter_metadata(self) -> Iterator[tuple[str, dict[str, str]]]:
        """A rosbag2 folder's ``metadata.yaml`` as record ``rosbag2.metadata_yaml``."""
        if self._yaml is not None:
            yield "rosbag2.metadata_yaml", {"metadata.yaml": self._yaml}

    def iter_attachments(self) -> Iterator[AttachmentInfo]:
        """Bags have no attachments."""
        return iter(())


def _bound_chunks(reader, path: Path) -> None:
    """``rosbags`` decompresses a ROS 1 chunk whole, however large: give every chunk in its
    table the bounded decompression of :mod:`slearn.io.ros1_salvage` instead.

    Raises:
        InputError: this ``rosbags`` keeps no chunk table (the bag is then read linearly,
            by :class:`~slearn.io.ros1_salvage.Ros1Salvage`, which is bounded).
    """
    from slearn.io.ros1_salvage import chunk_decompressor

    chunks = getattr(reader, "chunks", None)  # {chunk record offset: Chunk(..., decompressor)}
    if not isinstance(chunks, dict):
        reader.close()
        raise InputError(f"{path}: this rosbags version cannot be read with bounded memory")
    limit = max_chunk_bytes_setting()
    with open(path, "rb") as f:
        for offset, chunk in chunks.items():
            chunks[offset] = chunk._replace(decompressor=chunk_decompressor(f, offset, limit))


def _channel_of(connection, profile: str) -> ChannelInfo:
    """A rosbags connection as a channel whose schema is the message definition."""
    msgtype = connection.msgtype
    definition = connection.msgdef.data if connection.msgdef is not None else ""
    if profile == "ros1":
        name = msgtype.replace("/msg/", "/")
        schema = SchemaInfo(connection.id, name, "ros1msg", definition.encode())
        return ChannelInfo(connection.id, connection.topic, "ros1", schema, {"md5sum": connection.digest})
    if not definition:
        definition = _known_definition(msgtype)
    encoding = "ros2idl" if _is_idl(connection) else "ros2msg"
    schema = SchemaInfo(connection.id, msgtype, encoding, definition.encode())
    return ChannelInfo(connection.id, connection.topic, "cdr", schema, {})


def _is_idl(connection) -> bool:
    from rosbags.interfaces import MessageDefinitionFormat

    return connection.msgdef is not None and connection.msgdef.format == MessageDefinitionFormat.IDL


def _known_definition(msgtype: str) -> str:
    """The definition of a standard type from ``rosbags``' newest type store ("" if unknown)."""
    from rosbags.typesys import Stores, get_typestore

    try:
        return get_typestore(Stores.LATEST).generate_msgdef(msgtype, ros_version=2)[0]
    except Exception:  # noqa: BLE001 - an unknown type: decoding then says so for its channel
        return ""


def log_record(path: str | os.PathLike) -> dict:
    """``{"path", "size_bytes", "sha256"}`` of a log, for provenance.

    A folder's digest is the sha256 of its files' ``NAME SHA256`` lines (metadata.yaml
    first, then the storage files in bag order).

    Raises:
        InputError: a file cannot be read.
    """
    files = log_files(path)
    records = [_file_digest(f) for f in files]
    if len(files) == 1 and not Path(path).is_dir():
        return {"path": os.fspath(path), "size_bytes": records[0][0], "sha256": records[0][1]}
    import hashlib

    lines = "".join(f"{f.name} {digest}\n" for f, (_, digest) in zip(files, records))
    return {"path": os.fspath(path), "size_bytes": sum(size for size, _ in records),
            "sha256": hashlib.sha256(lines.encode()).hexdigest()}


def _file_digest(path: Path) -> tuple[int, str]:
    """``(size, sha256)`` of a file, read once per process while it is unchanged (same size,
    modification time and inode): a replay of the log a library was learned from with
    ``--split`` checks it as a training log and as a held-out log."""
    try:
        stat = os.stat(path)
    except OSError as err:
        raise InputError(f"{path}: cannot read: {err.strerror or err}") from err
    return _digest(os.fspath(path), stat.st_size, stat.st_mtime_ns, stat.st_ino)


@lru_cache(maxsize=4096)
def _digest(path: str, size: int, mtime_ns: int, inode: int) -> tuple[int, str]:
    import hashlib

    digest = hashlib.sha256()
    try:
        with open(path, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                digest.update(block)
        return os.stat(path).st_size, digest.hexdigest()
    except OSError as err:
        raise InputError(f"{path}: cannot read: {err.strerror or err}") from err
