"""Learning-curve windows sized to the data."""

from __future__ import annotations

import math

POINTS = 50
MIN_EVENTS = 100


def round_up(x: float) -> int:
    """The smallest 1, 2 or 5 times a power of ten that is at least ``x`` (and at least 1)."""
    x = max(x, 1.0)
    exponent = 10 ** math.floor(math.log10(x))
    for m in (1, 2, 5, 10):
        if m * exponent >= x - 1e-9:
            return int(m * exponent)
    return int(10 * exponent)


def data_window(n_steps: int, n_events: int, points: int = POINTS, min_events: int = MIN_EVENTS) -> int:
    """Steps per window: about ``points`` windows, each with at least ``min_events``
    predicted events on average (fewer windows when the log is small), never more steps
    than the log has (one window then holds it all)."""
    if n_steps <= 0:
        return 1
    per_event = n_steps / max(n_events, 1)
    window = round_up(max(n_steps / points, min_events * per_event))
    return min(window, round_up(n_steps))
