"""Record categorical events from a live loop into MCAP episodes, one file per episode.

Every channel carries JSON objects ``{"value": V}`` (schema ``slearn.Event``) where ``V``
is a string, integer, number or boolean; the channel's role (``action`` or
``observation``) is stored in its MCAP channel metadata. :func:`events_spec` gives the
spec that learns such files, :func:`spec_toml` its TOML text.

Example::

    with LiveRecorder("runs/", prefix="arm") as rec:
        command = rec.channel("/arm/command", "action")
        position = rec.channel("/arm/position", "observation")
        for episode in range(3):
            for _ in range(100):
                command.write(policy())
                position.write(read_sensor())
            rec.end_episode()          # runs/arm-00000.mcap is complete and published
        rec.write_spec("runs/spec.toml")

Each episode file is written by an :class:`~slearn.recorders.mcap_episode.EpisodeWriter`
with ``keep_partial=True``: when the loop raises, the episode recorded so far is finished
into a valid MCAP file and the exception propagates. :meth:`LiveRecorder.flush` closes the
current chunk so that a killed process loses nothing written before it.
"""

from __future__ import annotations

import json
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, Callable, Iterable

from slearn import __version__
from slearn.core.vocabulary import ROLES
from slearn.errors import InputError, SlearnError
from slearn.io.episodes import EPISODE_SCHEMA, EPISODE_SCHEMA_NAME, EPISODE_TOPIC
from slearn.io.files import write_atomic
from slearn.io.spec import Categorical, ChannelSpec, Spec
from slearn.recorders.mcap_episode import EpisodeWriter

EVENT_SCHEMA_NAME = "slearn.Event"
EVENT_SCHEMA = {
    "title": EVENT_SCHEMA_NAME,
    "description": "One categorical event: the value a channel took at this log time.",
    "type": "object",
    "properties": {"value": {"type": ["string", "integer", "number", "boolean"]}},
    "required": ["value"],
}
EVENT_FIELD = "value"


def check_role(channel: str, role: str) -> str:
    """``role`` if it is ``"action"`` or ``"observation"``, else an :class:`InputError`."""
    if role not in ROLES:
        raise InputError(f"channel {channel!r}: role must be \"action\" or \"observation\", "
                         f"not {role!r}")
    return role


def event_value(value: Any, where: str) -> str | int | float | bool:
    """``value`` as a JSON scalar (numpy scalars unwrapped); anything else is an error."""
    if hasattr(value, "item") and not isinstance(value, (str, bytes)):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        raise InputError(f"{where}: value {value!r} is not a finite number: leave a missing "
                         "reading out (no event), or give it a label such as \"missing\"")
    if not isinstance(value, (str, int, float, bool)):
        raise InputError(f"{where}: value {value!r} is a {type(value).__name__}; events take "
                         "a string, integer, number or boolean")
    return value


class EventFile:
    """One episode of events in one MCAP file (channels registered on first use).

    Args:
        path: the MCAP file to write.
        overwrite: replace an existing file.
        keep_partial: publish what was written when the block raises.
        metadata: ``{record name: {key: value}}`` MCAP metadata records.
    """

    def __init__(self, path: str | os.PathLike, *, overwrite: bool = False,
                 keep_partial: bool = False,
                 metadata: dict[str, dict[str, str]] | None = None) -> None:
        self._writer = EpisodeWriter(path, overwrite=overwrite, keep_partial=keep_partial)
        self._metadata = metadata or {}
        self._ids: dict[str, int] = {}
        self.counts: dict[str, int] = {}

    @property
    def path(self) -> Path:
        """The target file."""
        return self._writer.path

    def __enter__(self) -> "EventFile":
        self._writer.__enter__()
        try:
            for name, data in self._metadata.items():
                self._writer.add_metadata(name, data)
        except BaseException as err:  # __exit__ is not called when __enter__ raises
            self._writer.__exit__(type(err), err, err.__traceback__)
            raise
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 traceback: TracebackType | None) -> None:
        self._writer.__exit__(exc_type, exc, traceback)

    def register(self, channel: str, role: str) -> None:
        """Declare ``channel`` (its MCAP topic) with its role; repeating it is harmless."""
        if channel not in self._ids:
            self._ids[channel] = self._writer.register_channel(
                channel, EVENT_SCHEMA_NAME, EVENT_SCHEMA, {"role": check_role(channel, role)})
            self.counts[channel] = 0

    def write(self, channel: str, time_ns: int, value: Any) -> None:
        """Write ``{"value": value}`` on a registered channel at log time ``time_ns``."""
        channel_id = self._ids.get(channel)
        if channel_id is None:
            raise InputError(f"{self.path}: channel {channel!r} is not registered")
        payload = {EVENT_FIELD: event_value(value, f"{self.path}: channel {channel!r}")}
        self._writer.write_encoded(channel_id, int(time_ns),
                                   json.dumps(payload, separators=(",", ":")).encode())
        self.counts[channel] += 1

    def mark_episode(self, time_ns: int, episode: int, name: str = "") -> None:
        """Start episode ``episode`` at ``time_ns`` (:mod:`slearn.io.episodes`): write the marker
        before the episode's first event."""
        if EPISODE_TOPIC not in self._ids:
            self._ids[EPISODE_TOPIC] = self._writer.register_channel(EPISODE_TOPIC, EPISODE_SCHEMA_NAME,
                                                                     EPISODE_SCHEMA)
        self._writer.write(self._ids[EPISODE_TOPIC], int(time_ns), {"episode": episode, "name": name})

    def flush(self) -> None:
        """Close the current chunk (it then survives a killed process)."""
        self._writer.flush()


@dataclass(frozen=True)
class LiveChannel:
    """A handle on one registered channel of a :class:`LiveRecorder`."""

    recorder: "LiveRecorder"
    name: str
    role: str

    def write(self, value: Any, time_ns: int | None = None) -> None:
        """Record ``value`` now (or at ``time_ns``) in the current episode."""
        self.recorder.write(self.name, value, time_ns)


class LiveRecorder:
    """Context manager recording a live loop's events, one MCAP file per episode.

    Args:
        folder: where the episodes go (created if missing); episode ``k`` is
            ``FOLDER/PREFIX-kkkkk.mcap``.
        prefix: file name prefix.
        overwrite: replace existing episode files (refused otherwise).
        clock: returns the log time in integer nanoseconds (default ``time.time_ns``).
        metadata: extra ``key: value`` facts stored in each file's ``slearn.live`` record.

    An episode file is opened at the first write after the start or after
    :meth:`end_episode`; episodes with no event leave no file.
    """

    def __init__(self, folder: str | os.PathLike, prefix: str = "episode", *,
                 overwrite: bool = False, clock: Callable[[], int] = time.time_ns,
                 metadata: dict[str, str] | None = None) -> None:
        self.folder = Path(folder)
        self.prefix = prefix
        self.overwrite = overwrite
        self.clock = clock
        self.metadata = dict(metadata or {})
        self.roles: dict[str, str] = {}
        self.paths: list[Path] = []
        self._file: EventFile | None = None
        self._open = False

    def __enter__(self) -> "LiveRecorder":
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise InputError(f"cannot create {self.folder}: {err.strerror or err}") from err
        self._open = True
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 traceback: TracebackType | None) -> None:
        self._open = False
        self._finish(exc_type, exc, traceback)

    def channel(self, name: str, role: str) -> LiveChannel:
        """Register a channel (its MCAP topic) with its role; returns a handle to write with."""
        known = self.roles.setdefault(name, check_role(name, role))
        if known != role:
            raise InputError(f"channel {name!r} is already registered as {known}, not {role}")
        if self._file is not None:
            self._file.register(name, role)
        return LiveChannel(self, name, role)

    def write(self, channel: str, value: Any, time_ns: int | None = None) -> None:
        """Record one event of ``channel`` at ``time_ns`` (default: the clock, now)."""
        if channel not in self.roles:
            raise InputError(f"channel {channel!r} is not registered: call channel() first")
        self._current().write(channel, self.clock() if time_ns is None else time_ns, value)

    def write_all(self, values: dict[str, Any], time_ns: int | None = None) -> None:
        """Record several channels' events at one log time (readings taken together).

        Events of one step share a log time: give readings taken at the same instant
        one time, or the learner sees them as separate steps.
        """
        now = self.clock() if time_ns is None else time_ns
        for channel, value in values.items():
            self.write(channel, value, now)

    def flush(self) -> None:
        """Push what was written to disk (survives a killed process in the temporary file)."""
        if self._file is not None:
            self._file.flush()

    def end_episode(self) -> Path | None:
        """Finish the current episode into a valid, published file; return its path."""
        path = self._file.path if self._file is not None else None
        self._finish(None, None, None)
        return path

    def spec(self) -> Spec:
        """The spec that learns the recorded files (every message an event)."""
        return events_spec(self.roles)

    def write_spec(self, path: str | os.PathLike) -> None:
        """Write :meth:`spec` as TOML to ``path``."""
        write_text(path, spec_toml(self.spec(), f"spec for the {self.prefix}-*.mcap episodes"))

    def _current(self) -> EventFile:
        if not self._open:
            raise SlearnError(f"LiveRecorder for {self.folder} is not open: use it in a with block")
        if self._file is None:
            path = self.folder / f"{self.prefix}-{len(self.paths):05d}.mcap"
            metadata = {"slearn.live": {**self.metadata, "episode": str(len(self.paths)),
                                        "slearn_version": __version__}}
            self._file = EventFile(path, overwrite=self.overwrite, keep_partial=True,
                                   metadata=metadata).__enter__()
            for name, role in self.roles.items():
                self._file.register(name, role)
        return self._file

    def _finish(self, exc_type, exc, traceback) -> None:
        current, self._file = self._file, None
        if current is not None:
            current.__exit__(exc_type, exc, traceback)
            self.paths.append(current.path)


def events_spec(roles: dict[str, str], mode: str = "message", source: str = "<events>") -> Spec:
    """The spec reading event channels ``{name: role}`` (categorical ``value`` fields)."""
    channels = tuple(ChannelSpec(name, EVENT_FIELD, check_role(name, role), name, Categorical())
                     for name, role in roles.items())
    if not channels:
        raise InputError(f"{source}: no channel was recorded, so there is nothing to learn")
    return Spec(channels, mode=mode, source=source)


def spec_toml(spec: Spec, comment: str = "") -> str:
    """A spec as TOML text that :func:`slearn.io.spec.load_spec` reads back to the same spec."""
    data = spec.to_dict()
    lines = [f"# {line}".rstrip() for line in comment.splitlines()]
    lines += [f"{key} = {_toml_value(value)}" for key, value in data.items() if key != "channel"]
    for entry in data["channel"]:
        lines += ["", "[[channel]]"]
        lines += [f"{key} = {_toml_value(value)}" for key, value in entry.items()]
    return "\n".join(lines) + "\n"


def write_text(path: str | os.PathLike, text: str, *, overwrite: bool = True,
               inputs: Iterable[str | os.PathLike] = ()) -> None:
    """Write a text file atomically; an unwritable path is a one-line :class:`InputError`."""
    write_atomic(path, text, overwrite=overwrite, inputs=inputs)


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise InputError(f"cannot write {value!r} in a TOML spec")
