"""Many episodes in one log: the episode-boundary convention slearn's recorders write.

A log is one episode unless it has messages on the topic ``/slearn/episode`` (JSON,
schema ``slearn.EpisodeStart``: ``{"episode": k, "name": "..."}``, both optional). Each
such message starts a new episode at its log time: the messages after it (in log-time
order, ties in file order) belong to that episode, up to the next marker. Messages before
the first marker, if any, form an episode of their own, named as the log; the episode
started by the ``k``-th marker (from 0) is named ``LOG#k``. ``learn`` and ``replay`` parse
each episode on its own: patterns never run across a boundary.

A writer puts the marker before the episode's first message (at the same log time or
earlier, and first in the file at equal times) and starts each episode after the
previous one's last message. :mod:`slearn.recorders.record_stream` writes whole sequence
databases into one file this way.
"""

from __future__ import annotations

import os

EPISODE_TOPIC = "/slearn/episode"
EPISODE_SCHEMA_NAME = "slearn.EpisodeStart"
EPISODE_SCHEMA = {
    "title": EPISODE_SCHEMA_NAME,
    "description": "Starts a new episode at this log time (slearn's episode-boundary convention).",
    "type": "object",
    "properties": {"episode": {"type": "integer", "description": "episode number, from 0"},
                   "name": {"type": "string", "description": "where the episode came from"}},
}


def episode_name(log: str | os.PathLike, index: int | None) -> str:
    """The name of episode ``index`` of ``log`` (``None``: the part before any marker)."""
    return os.fspath(log) if index is None else f"{os.fspath(log)}#{index}"


def split_episode_name(name: str) -> tuple[str, int | None]:
    """``(log, index)`` of an episode name (``index`` ``None`` for a whole log)."""
    log, hash_, index = name.rpartition("#")
    if hash_ and index.isdigit() and not os.path.exists(name):
        return log, int(index)
    return name, None
