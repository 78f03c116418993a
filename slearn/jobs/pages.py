"""Memory pages of a process that runs slearn's jobs: small ones.

On Linux, NumPy advises transparent huge pages for every array of 4 MiB or more, and
Arrow's allocator (mimalloc) for its whole arena. Where the kernel honours that advice
(``/sys/kernel/mm/transparent_hugepage/enabled`` set to ``madvise`` or ``always``), the
first touch of a fresh page clears 2 MiB, however little of it is used. A job allocates
and frees such memory all the time (a chunk's decoded columns, a library's table for
Parquet): on this project's test machine, clearing pages was 73 % of the first save of a
learned library (1.0 s against 0.26 s with small pages) and 9 % of a whole ``slearn
learn`` of 16 pointer logs. Learning itself gains nothing from huge pages (the context
tree's arrays are anonymous maps touched at random; advising them huge was no faster).

So the command line and slearn's Ray tasks turn transparent huge pages off for their own
process (``prctl(PR_SET_THP_DISABLE)``; inherited by the processes it starts, such as a
local Ray instance). Results do not depend on it; a process that imports slearn as a
library keeps its own setting.
"""

from __future__ import annotations

import ctypes
import sys

PR_SET_THP_DISABLE = 41
PR_GET_THP_DISABLE = 42


def small_pages() -> bool:
    """Turn transparent huge pages off for this process; whether they are off now.

    Does nothing (and says ``False``) where the system has no such setting (not Linux, or a
    kernel older than 3.15).
    """
    prctl = _prctl()
    return prctl is not None and prctl(PR_SET_THP_DISABLE, 1, 0, 0, 0) == 0 \
        and prctl(PR_GET_THP_DISABLE, 0, 0, 0, 0) == 1


def _prctl():
    if not sys.platform.startswith("linux"):
        return None
    try:
        return ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None
