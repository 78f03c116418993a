"""slearn: S-learning of categorical event streams from MCAP logs."""

from slearn import _jit_cache

__version__ = "0.1.0"

_jit_cache.configure()
