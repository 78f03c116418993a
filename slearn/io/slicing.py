"""Time slices of logs: ``--start``/``--end`` and ``--split`` for learn, replay and info.

A bound is a number of seconds from the log's start (its earliest log time) or an ISO 8601
time (``2024-05-01T12:00:03.5Z``; without a zone it is UTC), compared with log times as
Unix time. A :class:`TimeSlice` is resolved against each log's own time range into a
half-open window ``[low_ns, high_ns)``: the bounds first, then ``split``: with
``split = 0.7`` the ``train`` part is the first 70 % of that window's time and the
``heldout`` part the rest, so ``learn --split 0.7`` and ``replay --split 0.7`` on the same
logs never share a message.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from typing import Iterable

from slearn.errors import InputError

TRAIN, HELDOUT = "train", "heldout"
_EPOCH = datetime(1970, 1, 1, tzinfo=timezone.utc)
_LAST_NS = 2**63 - 1  # the largest log time MCAP can hold


@dataclass(frozen=True)
class TimeBound:
    """Seconds from the log start (``seconds``) or an absolute Unix time (``unix_ns``)."""

    seconds: float | None = None
    unix_ns: int | None = None
    text: str = ""

    def at(self, first_ns: int) -> int:
        """The log time (ns) of this bound in a log that starts at ``first_ns``."""
        if self.unix_ns is not None:
            return min(max(self.unix_ns, -_LAST_NS), _LAST_NS)
        # (a bound has seconds or unix_ns; one past any log's time is the last log time there is)
        return min(first_ns + round(min(self.seconds or 0.0, _LAST_NS / 1e9) * 1e9), _LAST_NS)


def parse_time_bound(text: str, option: str = "--start") -> TimeBound:
    """``"12.5"`` (seconds from the log start) or an ISO 8601 time.

    Raises:
        InputError: neither a non-negative number nor an ISO time.
    """
    try:
        seconds = float(text)
    except ValueError:
        seconds = None
    if seconds is not None:
        if not math.isfinite(seconds) or seconds < 0:
            raise InputError(f"{option} {text}: seconds from the log start must be >= 0")
        return TimeBound(seconds=seconds, text=text)
    try:
        moment = datetime.fromisoformat(text)
    except ValueError:
        raise InputError(f"{option} {text!r}: give seconds from the log start (12.5) or an ISO "
                         f"8601 time (2024-05-01T12:00:03Z)") from None
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=timezone.utc)
    return TimeBound(unix_ns=(moment - _EPOCH) // timedelta(microseconds=1) * 1000, text=text)


@dataclass(frozen=True)
class TimeSlice:
    """Which time of each log to read: bounds, then a train/held-out split of what is left."""

    start: TimeBound | None = None
    end: TimeBound | None = None
    split: float | None = None
    part: str = TRAIN

    def window(self, first_ns: int, last_ns: int) -> tuple[int, int]:
        """``[low_ns, high_ns)`` of a log whose messages span ``first_ns .. last_ns``."""
        low, high = first_ns, last_ns + 1
        if self.start is not None:
            low = max(low, self.start.at(first_ns))
        if self.end is not None:
            high = min(high, self.end.at(first_ns))
        if self.split is not None and high > low:
            cut = low + int((high - low) * self.split)
            low, high = (low, cut) if self.part == TRAIN else (cut, high)
        return low, high

    def for_part(self, part: str) -> "TimeSlice":
        """The same slice for the other side of the split."""
        return TimeSlice(self.start, self.end, self.split, part)

    def describe(self) -> str:
        """One phrase, e.g. ``the first 70 % of seconds 10-end of each log``."""
        bounds = ""
        if self.start is not None or self.end is not None:
            start, end = self.start.text if self.start else "start", self.end.text if self.end else "end"
            bounds = f"{start} to {end}"
        if self.split is None:
            return f"{bounds} of each log"
        share = self.split if self.part == TRAIN else 1 - self.split
        side = "first" if self.part == TRAIN else "last"
        where = f" ({bounds})" if bounds else ""
        return f"the {side} {100 * share:.0f} % of the time of each log{where}"

    def to_dict(self) -> dict:
        """Plain JSON-able data (:func:`slice_from_dict` reads it back)."""
        return {"start": self.start.text if self.start else None,
                "end": self.end.text if self.end else None, "split": self.split, "part": self.part}


def slice_from_dict(data: dict | None) -> TimeSlice | None:
    """The :class:`TimeSlice` of :meth:`TimeSlice.to_dict` (``None`` for ``None``)."""
    if not data:
        return None
    return time_slice(data.get("start"), data.get("end"), data.get("split"), data.get("part", TRAIN))


def time_slice(start: str | None = None, end: str | None = None, split: float | None = None,
               part: str = TRAIN) -> TimeSlice | None:
    """The slice of command-line options; ``None`` when they ask for the whole logs.

    Raises:
        InputError: a bound cannot be read, ``split`` is not in (0, 1), or ``end`` is not
            after ``start``.
    """
    if start is None and end is None and split is None:
        return None
    if split is not None and not 0 < split < 1:
        raise InputError(f"--split {split}: give the training share of each log's time, "
                         f"between 0 and 1 (0.7: the first 70 % trains)")
    lo = parse_time_bound(str(start), "--start") if start is not None else None
    hi = parse_time_bound(str(end), "--end") if end is not None else None
    if lo is not None and hi is not None and _comparable(lo, hi) and _key(hi) <= _key(lo):
        raise InputError(f"--end {hi.text} is not after --start {lo.text}")
    return TimeSlice(lo, hi, split, part)


def _comparable(a: TimeBound, b: TimeBound) -> bool:
    return (a.seconds is None) == (b.seconds is None)


def _key(bound: TimeBound) -> float:
    if bound.seconds is not None:
        return bound.seconds
    return bound.unix_ns or 0


def overlap(a: TimeSlice | None, b: TimeSlice | None) -> bool | None:
    """Whether slices ``a`` and ``b`` of the same log share time: ``True``, ``False``, or
    ``None`` when that depends on the log's own time range (different bounds and a split,
    or a bound in seconds against one in Unix time). ``None`` is the whole log."""
    if a is None or b is None:
        return True
    if _bounds(a) == _bounds(b):
        (lo_a, hi_a), (lo_b, hi_b) = _shares(a), _shares(b)  # of the same bounded window
        return max(lo_a, lo_b) < min(hi_a, hi_b)
    if a.split is not None or b.split is not None:
        return None
    bounds = [x for x in (a.start, a.end, b.start, b.end) if x is not None]
    if bounds and any(not _comparable(bounds[0], x) for x in bounds):
        return None
    low = max((_key(x) for x in (a.start, b.start) if x is not None), default=-math.inf)
    high = min((_key(x) for x in (a.end, b.end) if x is not None), default=math.inf)
    return low < high


def shares_time(learned: Iterable[TimeSlice | None], window: TimeSlice | None) -> bool | None:
    """Whether ``window`` shares time with any of the ``learned`` slices of the same log:
    ``True``, ``None`` (it may: see :func:`overlap`) or ``False``."""
    verdicts = [overlap(part, window) for part in learned]
    return True if any(verdicts) else None if None in verdicts else False


def _bounds(s: TimeSlice) -> tuple:
    return tuple(None if b is None else (b.seconds, b.unix_ns) for b in (s.start, s.end))


def _shares(s: TimeSlice) -> tuple[float, float]:
    """``[low, high)`` of a slice as shares of its bounded window."""
    if s.split is None:
        return 0.0, 1.0
    return (0.0, s.split) if s.part == TRAIN else (s.split, 1.0)
