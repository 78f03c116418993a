"""slearn: S-learning of categorical event streams from MCAP logs.

The names a Python user needs; everything else is reachable by its module but not
promised. Importing slearn imports no compiled code (nor numba): ``SequenceModel`` is
imported on first use, so that commands which compile nothing start at once.
"""

from slearn.errors import SlearnError

__version__ = "0.1.0"

__all__ = ["SequenceModel", "SlearnError", "__version__"]


def __getattr__(name: str):
    if name == "SequenceModel":
        from slearn.model import SequenceModel

        return SequenceModel
    raise AttributeError(f"module 'slearn' has no attribute {name!r}")
