"""slearn: S-learning of categorical event streams from MCAP logs.

The names a Python user needs; everything else is reachable by its module but not
promised. Importing slearn imports no compiled code: kernels load when first used.
"""

from slearn.errors import SlearnError
from slearn.model import SequenceModel

__version__ = "0.1.0"

__all__ = ["SequenceModel", "SlearnError", "__version__"]
