"""Small file helpers shared by every writer: atomic outputs get ordinary permissions."""

from __future__ import annotations

import os


def default_mode() -> int:
    """The mode a plain ``open()`` would give a new file under the current umask."""
    umask = os.umask(0o022)
    os.umask(umask)
    return 0o666 & ~umask


def give_default_mode(fd: int) -> None:
    """``mkstemp`` creates files readable by their owner only; give them the usual mode."""
    os.fchmod(fd, default_mode())
