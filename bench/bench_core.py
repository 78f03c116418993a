"""Core throughput and memory: prints the figures behind the issue's targets.

- learning events/s on a long pointer stream (target >= 1,000,000 on one core);
- online predict-then-learn steps/s (target >= 200,000);
- RAM per stored pattern (a context with one outcome) at 10^6 patterns over a vocabulary
  of 10^4 symbols, everything prediction needs included (target <= 100 bytes): as
  allocated, and as resident (the RSS growth of this process while learning it; a tree's
  room not yet used is reserved but never written, see ``context_tree.new_tree``).

Run: ``python bench/bench_core.py`` (numba compiles once; the first figures exclude it).
"""

from __future__ import annotations

import gc
import os
import time

import numpy as np

from slearn.core.library import PatternLibrary
from slearn.core.stream import Episode
from slearn.recorders.pointer import PointerConfig, simulate


def pointer_stream(trials: int, seed: int = 0) -> Episode:
    return simulate(PointerConfig("simple", trials=trials, seed=seed)).to_episode()


def warm_up() -> None:
    library = PatternLibrary()
    library.run(library.encode(pointer_stream(200)), learn=True, record=True, top_k=1)
    library.learn(pointer_stream(200))


def bench_learning(trials: int) -> None:
    for condition in ("simple", "error"):
        episode = simulate(PointerConfig(condition, trials=trials, seed=1)).to_episode()
        library = PatternLibrary()
        started = time.perf_counter()
        library.learn(episode)
        seconds = time.perf_counter() - started
        print(f"learn  {condition:<7} {episode.n_events:>11,} events  {seconds:6.2f} s  "
              f"{episode.n_events / seconds:>12,.0f} events/s  ({len(library):,} patterns)")


def bench_online(trials: int) -> None:
    for condition in ("simple", "error", "delay"):
        episode = simulate(PointerConfig(condition, trials=trials, seed=2)).to_episode()
        library = PatternLibrary()
        started = time.perf_counter()
        codes = library.encode(episode)
        reports = library.run(codes, learn=True, record=True, top_k=1)
        seconds = time.perf_counter() - started
        correct = reports.predicted[1:] == codes.token[1:]
        print(f"online {condition:<7} {len(episode) - 1:>11,} steps   {seconds:6.2f} s  "
              f"{(len(episode) - 1) / seconds:>12,.0f} steps/s   (accuracy {correct.mean():.1%})")


def resident_bytes() -> int:
    """This process's resident memory (``/proc/self/statm``; 0 where there is none)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except OSError:
        return 0


def bench_memory(target_patterns: int, vocabulary: int) -> None:
    rng = np.random.default_rng(3)
    gc.collect()
    before = resident_bytes()
    library = PatternLibrary()
    started = time.perf_counter()
    steps = 0
    while len(library) < target_patterns:
        n = 20_000
        obs = rng.zipf(1.3, n + 1) % vocabulary
        actions = vocabulary + rng.integers(0, 4, n)
        library.learn(Episode.from_pairs(obs[:1], actions, obs[1:]))
        steps += n
    learn_seconds = time.perf_counter() - started
    n = len(library)
    print(f"memory {n:,} patterns from {steps:,} steps over {vocabulary + 4:,} symbols "
          f"(learned in {learn_seconds:.1f} s)")
    gc.collect()
    resident = resident_bytes() - before
    print(f"       library {library.nbytes() / n:6.1f} bytes/pattern as allocated (capacity, of "
          f"which the room not yet used is reserved, not resident); prediction needs nothing else")
    print(f"       resident {resident / n:6.1f} bytes/pattern: this process's RSS growth while "
          f"learning it (target <= 100)")


if __name__ == "__main__":
    warm_up()
    bench_learning(2_000_000)
    bench_online(1_000_000)
    bench_memory(1_000_000, 10_000)
