"""Write one episode of JSON events to an MCAP file, atomically.

:class:`EpisodeWriter` is a context manager around ``mcap.writer.Writer``. It writes to a
temporary file next to the target (:func:`slearn.io.files.atomic_write`) and always calls
``Writer.finish()``, so the summary and footer are written. On a clean exit it fsyncs the
file and renames it onto the target, so a reader never sees a half-written episode. A full
disk or an unwritable folder is a one-line :class:`~slearn.errors.InputError`, and the
temporary file is removed.

When the block raises, what happens depends on ``keep_partial``:

- ``False`` (default, for batch recording): the temporary file is removed and the target is
  left as it was.
- ``True`` (for live loops): the episode recorded so far is finished into a valid MCAP file
  and moved onto the target anyway; the exception still propagates.

If the process is killed outright, only the temporary file (``.NAME.*.tmp`` in the same
folder) remains; chunks written before the last :meth:`EpisodeWriter.flush` can be salvaged
from it with a linear reader (with ``keep_partial``, such files are never swept; without
it they are swept by a later write of the same target once an hour old).

Channels carry JSON objects (``message_encoding="json"``) with named ``jsonschema``
schemas, which Foxglove shows as they are. Time fields inside messages use
``{"sec", "nsec"}`` (see :func:`stamp`).
"""

from __future__ import annotations

import json
import os
from contextlib import contextmanager
from pathlib import Path
from types import TracebackType
from typing import Any, Iterable, Iterator

from mcap.writer import CompressionType, Writer

from slearn import __version__
from slearn.errors import InputError, SlearnError
from slearn.io.files import AtomicFile, atomic_write, write_error

_NS_PER_S = 1_000_000_000


def stamp(time_ns: int) -> dict[str, int]:
    """A time as the ``{"sec", "nsec"}`` object Foxglove reads."""
    sec, nsec = divmod(int(time_ns), _NS_PER_S)
    return {"sec": sec, "nsec": nsec}


class EpisodeWriter:
    """Context manager writing one MCAP episode of JSON messages to ``path``.

    Args:
        path: the target file.
        overwrite: replace an existing target; without it an existing target is an
            :class:`~slearn.errors.InputError`.
        keep_partial: when the block raises, keep what was written as a valid file.
        chunk_size: bytes per zstd-compressed chunk.
        inputs: files the episode is made from; a target that is one of them is refused.
        profile: the header's profile (``""``; copies of ROS logs keep ``ros1``/``ros2``).

    Example::

        with EpisodeWriter("run.mcap") as out:
            channel = out.register_channel("/pointer/command", "slearn.pointer.Command",
                                           {"type": "object"})
            out.write(channel, 0, {"command": "R"})
    """

    def __init__(self, path: str | os.PathLike, *, overwrite: bool = False,
                 keep_partial: bool = False, chunk_size: int = 1 << 20,
                 inputs: Iterable[str | os.PathLike] = (), profile: str = "") -> None:
        self.path = Path(path)
        self.profile = profile
        self.overwrite = overwrite
        self.keep_partial = keep_partial
        self._chunk_size = chunk_size
        self._inputs = list(inputs)
        self._out: AtomicFile | None = None
        self._writer: Writer | None = None
        self._schemas: dict[tuple[str, str], int] = {}
        self._sequences: dict[int, int] = {}

    def __enter__(self) -> "EpisodeWriter":
        self._check_target()
        self._out = atomic_write(self.path, overwrite=self.overwrite, inputs=self._inputs,
                                 sweep=not self.keep_partial)
        try:
            with self._writing():
                self._writer = Writer(self._out.file, chunk_size=self._chunk_size,
                                      compression=CompressionType.ZSTD)
                self._writer.start(profile=self.profile, library=f"slearn {__version__}")
        except BaseException:
            self._out.discard()
            raise
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 traceback: TracebackType | None) -> None:
        writer, self._writer = self._writer, None
        if exc_type is not None and not self.keep_partial:
            self._out.discard()
            return
        try:
            with self._writing():
                writer.finish()
        except BaseException:
            self._out.discard()
            raise
        self._out.commit()

    def register_channel(self, topic: str, schema_name: str, json_schema: dict[str, Any],
                         metadata: dict[str, str] | None = None) -> int:
        """Declare a JSON channel; returns its id. Equal schemas are stored once."""
        schema_data = json.dumps(json_schema, sort_keys=True).encode()
        key = (schema_name, schema_data.decode())
        schema_id = self._schemas.get(key)
        if schema_id is None:
            with self._writing():
                schema_id = self._active().register_schema(schema_name, "jsonschema", schema_data)
            self._schemas[key] = schema_id
        with self._writing():
            channel_id = self._active().register_channel(topic, "json", schema_id, metadata or {})
        self._sequences[channel_id] = 0
        return channel_id

    def write(self, channel_id: int, log_time_ns: int, message: dict[str, Any]) -> None:
        """Write one JSON object on a channel at ``log_time_ns`` (also its publish time)."""
        self.write_encoded(channel_id, log_time_ns,
                           json.dumps(message, separators=(",", ":")).encode())

    def write_encoded(self, channel_id: int, log_time_ns: int, data: bytes) -> None:
        """Write an already JSON-encoded message (for hot loops that cache payloads)."""
        writer = self._active()
        sequence = self._sequences.get(channel_id)
        if sequence is None:
            raise InputError(f"{self.path}: channel id {channel_id} was not registered "
                             "(use register_channel's return value)")
        self._sequences[channel_id] = sequence + 1
        with self._writing():
            writer.add_message(channel_id, log_time=log_time_ns, data=data,
                               publish_time=log_time_ns, sequence=sequence)

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """Add an MCAP metadata record (per-episode facts: seed, condition, version)."""
        with self._writing():
            self._active().add_metadata(name, {str(k): str(v) for k, v in data.items()})

    def flush(self) -> None:
        """Push buffered messages to the temporary file (call at episode ends in live loops).

        Closes the current chunk, so what was written survives a killed process in the
        temporary file.
        """
        with self._writing():
            self._active().flush()
            self._out.file.flush()

    def _check_target(self) -> None:
        if self.path.exists() and not self.overwrite:
            raise InputError(f"{self.path} already exists: choose another name or allow "
                             "overwriting it")
        if not self.path.parent.is_dir():
            raise InputError(f"cannot write {self.path}: folder {self.path.parent} does not exist")

    def _active(self) -> Writer:
        if self._writer is None:
            raise SlearnError(f"EpisodeWriter for {self.path} is not open: use it in a with block")
        return self._writer

    @contextmanager
    def _writing(self) -> Iterator[None]:
        """A failed write (a full disk) is a one-line error naming the target."""
        try:
            yield
        except OSError as err:
            raise write_error(self.path, err) from err
