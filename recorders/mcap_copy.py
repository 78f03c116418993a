"""Faithful MCAP copies of logs: the same profile, channels, schemas, messages, metadata
records and attachments, written atomically.

:class:`CopyWriter` is an :class:`~slearn.recorders.mcap_episode.EpisodeWriter` that
also copies raw messages (schemas, encodings, times and sequence numbers as they were),
the source's metadata records and its attachments; its header keeps the source's profile
(``ros1``, ``ros2``, ...). :func:`copy_log` copies a time window of any log slearn reads
(an MCAP file, a rosbag2 folder, a ``.db3`` or a ``.bag``) into one MCAP file; the
annotated logs of :mod:`slearn.replay.annotate` and the train/held-out splits of
``slearn datasets build pr2-sample --source`` are made this way.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from slearn.io.bags import open_log
from slearn.io.mcap_read import ChannelInfo, RawMessage
from slearn.recorders.mcap_episode import EpisodeWriter

SOURCE_RECORD = "slearn.source"
"""Metadata record a copy adds: the source's path, profile and writer library."""


class CopyWriter(EpisodeWriter):
    """An :class:`EpisodeWriter` that also copies messages, metadata and attachments of a log."""

    def __enter__(self) -> "CopyWriter":
        super().__enter__()
        self._copied: dict[int, int] = {}
        return self

    def copy_message(self, message: RawMessage) -> None:
        """Write ``message`` on a copy of its channel (registered on first use)."""
        channel_id = self._copied.get(message.channel.id)
        if channel_id is None:
            channel_id = self._copied[message.channel.id] = self._copy_channel(message.channel)
        with self._writing():
            self._active().add_message(channel_id, log_time=message.log_time_ns, data=message.data,
                                       publish_time=message.publish_time_ns, sequence=message.sequence)

    def copy_extras(self, log) -> None:
        """Copy every metadata record and attachment of ``log`` (one attachment in memory at a time),
        then add a :data:`SOURCE_RECORD` record naming it."""
        for name, data in log.iter_metadata():
            self.add_metadata(name, dict(data))
        writer = self._active()
        for a in log.iter_attachments():
            with self._writing():
                writer.add_attachment(create_time=a.create_time_ns, log_time=a.log_time_ns,
                                      name=a.name, media_type=a.media_type, data=a.data)
        self.add_metadata(SOURCE_RECORD, {"path": str(log.path), "profile": log.profile,
                                          "library": log.library})

    def _copy_channel(self, channel: ChannelInfo) -> int:
        writer = self._active()
        schema_id = 0
        with self._writing():
            if channel.schema is not None:
                s = channel.schema
                key = ("copied", s.name, s.encoding, s.data)
                schema_id = self._schemas.get(key) or writer.register_schema(s.name, s.encoding, s.data)
                self._schemas[key] = schema_id
            return writer.register_channel(channel.topic, channel.message_encoding, schema_id,
                                           dict(channel.metadata))


@dataclass(frozen=True)
class CopySummary:
    """What :func:`copy_log` wrote."""

    path: str
    source: str
    messages: int
    start_ns: int | None
    end_ns: int | None
    damage: str | None = None  # how the source broke, when it was truncated or corrupt


def copy_log(source: str | os.PathLike, target: str | os.PathLike, *, start_ns: int = 0,
             end_ns: int = 1 << 64, overwrite: bool = False) -> CopySummary:
    """Copy the messages of ``source`` with ``start_ns <= log time < end_ns`` into an MCAP file.

    Everything else (profile, metadata records, attachments) is copied whole.

    Raises:
        InputError: the source cannot be read, ``target`` is the source (always) or exists
            without ``overwrite``.
    """
    count, first, last = 0, None, None
    with open_log(source) as log, CopyWriter(Path(target), overwrite=overwrite, inputs=[source],
                                             profile=log.profile) as out:
        out.copy_extras(log)
        for message in log.iter_messages():
            if start_ns <= message.log_time_ns < end_ns:
                out.copy_message(message)
                count += 1
                first = message.log_time_ns if first is None else first
                last = message.log_time_ns
        damage = log.report.describe() if log.report.truncated else None
    return CopySummary(str(target), str(source), count, first, last, damage)
