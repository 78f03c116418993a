"""The timing rule of the speed benchmarks: one warm-up run, then the fastest of ``repeat``."""

from __future__ import annotations

import time
from typing import Callable


def best_seconds(work: Callable[[], object], repeat: int) -> float:
    """Seconds of the fastest of ``repeat`` runs of ``work``, after one warm-up run."""
    work()
    times = []
    for _ in range(repeat):
        started = time.perf_counter()
        work()
        times.append(time.perf_counter() - started)
    return min(times)
