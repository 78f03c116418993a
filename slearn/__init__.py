"""slearn: S-learning of categorical event streams from MCAP logs."""

__version__ = "0.1.0"
