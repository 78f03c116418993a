"""Library storage figures: save and load time and file bytes per pattern.

1. A library of about 10^6 patterns, learned from one long random stream over 10^4
   observation symbols (a noisy random walk on a ring of 10^4 positions, actions L/R).
2. The six pointer conditions (10,000 trials, seed 0), each recorded to MCAP and learned
   with ``slearn.jobs.learn.learn_files``, next to the paper's figure for the simple system
   (2155 patterns in 599 kB).

Load times are warm (compiled kernels already loaded in the process: the pointer runs go
first); the first load in a process also pays for loading numba's cached machine code.
Wall and process CPU times are both shown: CPU time is steadier on a shared machine.

Run: ``python bench/bench_storage.py [--steps N]``.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from slearn.core.library import PatternLibrary
from slearn.core.stream import Episode
from slearn.core.vocabulary import Vocabulary
from slearn.io.library_file import load_library, save_library
from slearn.jobs.learn import learn_files
from slearn.recorders.pointer import CONDITIONS, PointerConfig
from slearn.recorders.record_pointer import record_pointer

PAPER_PATTERNS = 2155
PAPER_BYTES = 599_000
RING = 10_000


def random_walk(steps: int, seed: int = 0, noise: int = 2) -> Episode:
    """Actions L/R (symbols 0, 1) move +-1 plus uniform noise on a ring of RING positions."""
    rng = np.random.default_rng(seed)
    actions = rng.integers(0, 2, steps)
    moves = np.where(actions == 1, 1, -1) + rng.integers(-noise, noise + 1, steps)
    positions = (np.cumsum(moves) + RING // 2) % RING
    return Episode.from_pairs([2 + RING // 2], actions.astype(np.int32),
                              (positions + 2).astype(np.int32))


def walk_vocabulary() -> Vocabulary:
    vocabulary = Vocabulary()
    vocabulary.add_channel("command", "action")
    vocabulary.add_channel("position", "observation")
    for value in ("L", "R"):
        vocabulary.symbol("command", value)
    for k in range(RING):
        vocabulary.symbol("position", k)
    return vocabulary


def timed(fn, *args, **kwargs):
    start = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - start


def cpu_timed(fn, *args, **kwargs):
    """``(result, wall seconds, process CPU seconds)``: CPU time is steadier on a busy machine."""
    cpu = time.process_time()
    out, wall = timed(fn, *args, **kwargs)
    return out, wall, time.process_time() - cpu


def same_library(a: PatternLibrary, b: PatternLibrary) -> bool:
    ea, eb = a.export(), b.export()
    return a.clock == b.clock and all(np.array_equal(ea[k], eb[k]) for k in ea)


def bench_big(folder: Path, steps: int) -> None:
    library = PatternLibrary()
    _, learn_s = timed(library.learn, random_walk(steps))
    vocabulary = walk_vocabulary()
    path = folder / "big.parquet"
    summary, save_s, save_cpu = cpu_timed(save_library, path, library, vocabulary, spec=None,
                                          params={"scoring": "adaptive"}, provenance={}, overwrite=True)
    loads = [cpu_timed(load_library, path) for _ in range(3)]
    loaded = loads[0][0]
    print(f"random walk, {steps:,} steps over {len(vocabulary):,} symbols (learned in {learn_s:.2f} s)")
    print(f"  patterns {summary.n_patterns:,}  file {summary.size_bytes:,} B  "
          f"{summary.bytes_per_pattern:.2f} B/pattern")
    print(f"  save {save_s:.3f} s wall, {save_cpu:.3f} s CPU")
    print(f"  load {min(x[1] for x in loads):.3f} s wall, {min(x[2] for x in loads):.3f} s CPU "
          f"(best of 3)  identical after load: {same_library(library, loaded.library)}")
    print(f"  in memory: library arrays {library.nbytes() / len(library):.1f} B/pattern")


def bench_pointer(folder: Path, trials: int) -> None:
    print(f"\npointer conditions, {trials:,} trials, seed 0 "
          f"(paper, simple: {PAPER_PATTERNS} patterns in {PAPER_BYTES / 1000:.0f} kB = "
          f"{PAPER_BYTES / PAPER_PATTERNS:.0f} B/pattern)")
    print(f"  {'condition':<10} {'patterns':>9} {'bytes':>9} {'B/pattern':>10} {'vs paper':>9} "
          f"{'learn+save s':>13} {'load s':>8} {'RAM B/pat':>10}")
    for condition in CONDITIONS:
        log = folder / f"{condition}.mcap"
        record_pointer(PointerConfig(condition, trials, 0, switch_trial=trials // 2), log, overwrite=True)
        result, learn_s = timed(learn_files, [log], folder / f"{condition}.parquet", overwrite=True)
        loaded, load_s = timed(load_library, folder / f"{condition}.parquet")
        assert len(loaded.library) == result.n_patterns
        ratio = (PAPER_BYTES / PAPER_PATTERNS) / result.bytes_per_pattern
        memory = loaded.library.nbytes() / result.n_patterns
        print(f"  {condition:<10} {result.n_patterns:>9,} {result.size_bytes:>9,} "
              f"{result.bytes_per_pattern:>10.1f} {ratio:>8.0f}x {learn_s:>13.3f} {load_s:>8.3f} "
              f"{memory:>10.0f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=128_000,
                        help="random-walk steps (about 10^6 patterns at the default)")
    parser.add_argument("--trials", type=int, default=10_000, help="pointer trials")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        bench_pointer(folder, args.trials)  # also compiles and loads the kernels
        print()
        bench_big(folder, args.steps)


if __name__ == "__main__":
    main()
