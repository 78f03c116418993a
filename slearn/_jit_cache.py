"""Where numba keeps slearn's compiled kernels.

Numba checks a cached kernel against its own source file only, so a kernel that calls a
kernel from another module would keep running stale code after that module changed
(an editable install after ``git pull``). Keying the cache folder on a fingerprint of
all of slearn's sources makes any change recompile everything once. A user's own
``NUMBA_CACHE_DIR`` is respected (the fingerprint becomes a subfolder of it).
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path


def source_fingerprint(package_dir: Path) -> str:
    """A short hash of the sources of the package's modules that hold compiled kernels."""
    digest = hashlib.sha1()
    for path in sorted(package_dir.glob("*.py")):
        source = path.read_bytes()
        if b"numba.njit" in source:
            digest.update(path.name.encode() + b"\0" + source)
    return digest.hexdigest()[:16]


def configure() -> None:
    """Point numba's cache at a folder named after slearn's source fingerprint."""
    import numba

    base = os.environ.get("NUMBA_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(Path.home(), ".cache"), "slearn", "numba")
    numba.config.CACHE_DIR = os.path.join(base, source_fingerprint(Path(__file__).parent))
