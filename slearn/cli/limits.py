"""Option types and bounds shared by the commands; click states each range in ``--help``
and in the usage error (exit 2)."""

from __future__ import annotations

import math

import click

from slearn.io.library_header import MAX_LENGTH, MAX_PATTERNS
from slearn.recorders.pointer import MAX_TRIALS as MAX_TRIALS  # re-exported with the other limits

MAX_TOP_K = 100
MAX_GOALS = 1_000_000
MAX_STEPS = 1_000_000

LENGTH = click.IntRange(1, MAX_LENGTH)
PATTERNS = click.IntRange(16, MAX_PATTERNS)


class FiniteFloat(click.FloatRange):
    """A :class:`click.FloatRange` that also refuses NaN and infinities."""

    def convert(self, value, param, ctx):
        number = super().convert(value, param, ctx)
        if not math.isfinite(number):
            self.fail(f"{value!r} is not a finite number.", param, ctx)
        return number
