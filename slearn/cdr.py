"""ROS 2 CDR: read only the fields a spec names (placeholder)."""

from __future__ import annotations


class CdrError(ValueError):
    """A payload does not decode."""


def field_plan(channel, fields):
    return None
