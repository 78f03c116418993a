"""Symbols and their names: one vocabulary maps each integer symbol to (channel, value)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Hashable, Iterable

import numpy as np

from slearn.errors import InputError

ACTION = "action"
OBSERVATION = "observation"
ROLES = (ACTION, OBSERVATION)
STORABLE = "text, numbers, booleans, None and tuples of them"
"""What a library file can store as a value (:func:`storable`)."""


def storable(value: Hashable) -> bool:
    """Whether a library file can store ``value``: ``None``, a bool, a number (NumPy's
    too), text that is valid Unicode, or a tuple of these."""
    if value is None or isinstance(value, (bool, int, float, np.bool_, np.integer, np.floating)):
        return True
    if isinstance(value, str):
        try:
            value.encode("utf-8")
        except UnicodeEncodeError:  # (a lone surrogate)
            return False
        return True
    if isinstance(value, tuple):
        return all(storable(v) for v in value)
    return False


@dataclass
class Vocabulary:
    """Bidirectional map between symbols (``int``) and ``(channel, value)`` pairs.

    Symbols are handed out densely from 0 in order of first registration, so the
    same registration order always gives the same symbols. Each channel has a role,
    ``"action"`` or ``"observation"``; values are kept as first given (str, int, bool,
    ...). Values equal in Python are one value, as in a ``dict``: ``1``, ``1.0`` and
    ``True`` of one channel share a symbol.
    """

    _names: list[tuple[str, Hashable]] = field(default_factory=list)
    _symbols: dict[tuple[str, Hashable], int] = field(default_factory=dict)
    roles: dict[str, str] = field(default_factory=dict)
    value_labels: dict[str, Callable[[Hashable], str]] = field(default_factory=dict, compare=False,
                                                               repr=False)
    """Per channel, how its values read (bins as value ranges); set from the spec."""
    _rank: dict[str, int] = field(default_factory=dict, compare=False, repr=False)  # channel -> its place

    def add_channel(self, channel: str, role: str) -> None:
        """Declare ``channel`` with its role; re-declaring with another role is an error."""
        if role not in ROLES:
            raise InputError(f"channel {channel!r}: role must be one of {ROLES}, not {role!r}")
        known = self.roles.setdefault(channel, role)
        self._rank.setdefault(channel, len(self._rank))
        if known != role:
            raise InputError(f"channel {channel!r} is declared both {known} and {role}")

    def symbol(self, channel: str, value: Hashable) -> int:
        """The symbol of ``(channel, value)``, registering it on first sight."""
        key = (channel, value)
        found = self._symbols.get(key)
        if found is not None:
            return found
        if channel not in self.roles:
            raise InputError(f"channel {channel!r} has no role: declare it with add_channel first")
        found = len(self._names)
        self._names.append(key)
        self._symbols[key] = found
        return found

    def truncate(self, symbols: int, channels: int) -> None:
        """Forget every symbol from ``symbols`` on and every channel declared after the
        first ``channels`` (undoing a registration that failed part-way)."""
        for key in self._names[symbols:]:
            del self._symbols[key]
        del self._names[symbols:]
        for channel in list(self.roles)[channels:]:
            del self.roles[channel], self._rank[channel]
            self.value_labels.pop(channel, None)

    def get_symbol(self, channel: str, value: Hashable) -> int | None:
        """The symbol of ``(channel, value)`` or ``None`` when it was never registered."""
        return self._symbols.get((channel, value))

    def known_symbols(self, mapping: dict, role: str) -> tuple[int, ...] | None:
        """The symbols of a ``{channel: value}`` mapping, in :meth:`in_channel_order`, or
        ``None`` when a channel is not one of ``role`` or a value was never registered (or
        is not hashable)."""
        get, roles = self._symbols.get, self.roles
        out = []
        try:
            for channel, value in self.in_channel_order(mapping.items()):
                found = get((channel, value))
                if found is None or roles[channel] != role:
                    return None
                out.append(found)
        except (KeyError, TypeError):
            return None
        return tuple(out)

    def in_channel_order(self, pairs: Iterable[tuple[str, Hashable]]) -> list[tuple[str, Hashable]]:
        """One step's ``(channel, value)`` pairs in the order the channels were declared (as a
        spec orders the channels of a log's steps; channels never declared last), whatever
        the order they come in: a step's actions are one token, so equal sets of pairs must
        give equal tuples."""
        pairs = list(pairs)
        if len(pairs) > 1:
            rank, last = self._rank, len(self._rank)
            pairs.sort(key=lambda pair: rank.get(pair[0], last))
        return pairs

    def get_symbols(self, channel: str, values: Iterable[Hashable]) -> list[int | None]:
        """:meth:`get_symbol` of each value (raises ``TypeError`` for one not hashable)."""
        get = self._symbols.get
        return [get((channel, value)) for value in values]

    def name(self, symbol: int) -> tuple[str, Hashable]:
        """``(channel, value)`` of a symbol."""
        return self._names[symbol]

    def role(self, symbol: int) -> str:
        """The role of the channel a symbol belongs to."""
        return self.roles[self._names[symbol][0]]

    def label(self, symbol: int) -> str:
        """A short human-readable label, ``channel=value``."""
        return f"{self._names[symbol][0]}={self.value_text(symbol)}"

    def value_text(self, symbol: int) -> str:
        """The value of a symbol as text (a bin as its value range when the spec says)."""
        channel, value = self._names[symbol]
        show = self.value_labels.get(channel)
        return show(value) if show is not None else str(value)

    def channels(self) -> list[str]:
        """Channels in declaration order."""
        return list(self.roles)

    def symbols_of(self, channel: str) -> list[int]:
        """All symbols of one channel, in symbol order."""
        return [s for s, (c, _) in enumerate(self._names) if c == channel]

    def __len__(self) -> int:
        return len(self._names)

    def names(self, start: int = 0) -> list[tuple[str, Hashable]]:
        """``(channel, value)`` of symbols ``start, start + 1, ...``, in symbol order."""
        return self._names[start:]

    def items(self) -> Iterable[tuple[int, str, Hashable]]:
        """``(symbol, channel, value)`` for every symbol, in symbol order."""
        for symbol, (channel, value) in enumerate(self._names):
            yield symbol, channel, value
