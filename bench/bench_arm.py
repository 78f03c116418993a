"""Curse-of-dimensionality benchmark: the pointer arm with 1 to 4 joints.

The paper's discussion expects that more degrees of freedom only need their commands and
sensors serialized into one stream, and that storage will not feel the curse of
dimensionality "full force". Per joint count and sensor layout (see
:mod:`slearn.recorders.arm`) this prints, averaged over seeds:

- patterns: library size after all trials (every context of every joint's view);
  ``mem``: ``PatternLibrary.nbytes()``;
  ``file``: the saved Parquet library (``slearn.io.library_file``), and file bytes per pattern;
- ``conceivable``: log10 of the number of patterns a dense table up to the same length
  would need (``|O| * (|A| |O|)^m`` summed over ``m = 1..max_length``);
- ``learn``: seconds for ``PatternLibrary.learn`` on the whole episode (compiled kernels
  warmed up first);
- accuracy per thousand trials: prequential (a fresh library predicts each step, then
  learns it; a step is right when every joint reporting in it is), the paper's Fig. 2 measure.

Run: ``python bench/bench_arm.py [--trials 10000] [--seeds 3] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from slearn_adapter import step_correct

from slearn.core.library import PatternLibrary
from slearn.recorders.arm import MAX_JOINTS, SENSORS, ArmConfig, arm_spec, arm_vocabulary, simulate_arm
from slearn.recorders.pointer import N_BINS

try:
    from slearn.io.library_file import save_library
except ImportError:  # storage not built: report in-memory bytes only
    save_library = None

WINDOW = 1000  # trials per accuracy column


def conceivable_log10(joints: int, sensors: str, max_length: int) -> float:
    """log10 of the patterns a dense table of all sequences up to ``max_length`` steps holds."""
    actions = 2 * joints
    observations = N_BINS * joints if sensors == "moved" else N_BINS ** joints
    total = sum(observations * (actions * observations) ** m for m in range(1, max_length + 1))
    return math.log10(total)


def file_bytes(library: PatternLibrary, joints: int) -> int | None:
    """Bytes of the library saved as Parquet, or ``None`` without ``slearn.io.library_file``."""
    if save_library is None:
        return None
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "arm.parquet"
        save_library(path, library, arm_vocabulary(joints), spec=arm_spec(joints), params={},
                     provenance={})
        return path.stat().st_size


def measure(joints: int, sensors: str, trials: int, seed: int, max_length: int,
            window: int = WINDOW) -> dict:
    """One episode: prequential accuracy per window, library size, bytes, learning time."""
    episode = simulate_arm(ArmConfig(joints, trials, seed, sensors)).to_episode()
    library = PatternLibrary(max_length=max_length, vocabulary=arm_vocabulary(joints))
    correct = step_correct(library, episode)
    learner = PatternLibrary(max_length=max_length, vocabulary=arm_vocabulary(joints))
    start = time.perf_counter()
    learner.learn(episode)
    seconds = time.perf_counter() - start
    windows = len(correct) // window
    accuracy = correct[:windows * window].reshape(windows, window).mean(axis=1)
    return {"patterns": len(library), "mem_bytes": library.nbytes(),
            "file_bytes": file_bytes(library, joints), "learn_s": seconds,
            "obs_tokens": len({tuple(o) for _, o in episode.steps()}),
            "accuracy": accuracy.tolist()}


def average(rows: list[dict]) -> dict:
    """Mean of every number over seeds (accuracy per window, too)."""
    out = {}
    for key, value in rows[0].items():
        if isinstance(value, list):
            out[key] = np.mean([r[key] for r in rows], axis=0).tolist()
        elif value is None:
            out[key] = None
        else:
            out[key] = float(np.mean([r[key] for r in rows]))
    return out


def run(trials: int, seeds: int, max_length: int, layouts: list[str],
        window: int = WINDOW) -> list[dict]:
    """Every joint count and layout, averaged over ``seeds`` seeds."""
    step_correct(PatternLibrary(vocabulary=arm_vocabulary(1)), simulate_arm(ArmConfig(1, 50)).to_episode())
    results = []
    for sensors in layouts:
        for joints in range(1, MAX_JOINTS + 1):
            print(f"arm: {joints} joint(s), sensors {sensors} ...", file=sys.stderr)
            rows = [measure(joints, sensors, trials, seed, max_length, window)
                    for seed in range(seeds)]
            results.append({"joints": joints, "sensors": sensors, "trials": trials,
                            "seeds": seeds, "max_length": max_length, "window": window,
                            "conceivable_log10": conceivable_log10(joints, sensors, max_length),
                            **average(rows)})
    return results


def render(results: list[dict]) -> str:
    """A plain-text table: one row per joint count and layout."""
    n_windows, window = len(results[0]["accuracy"]), results[0]["window"]
    head = (f"{'joints':>6} {'sensors':>7} {'patterns':>8} {'mem KiB':>8} {'file KiB':>8} "
            f"{'B/pat':>6} {'concv':>6} {'obs tok':>7} {'learn ms':>8}  "
            + " ".join(f"{(k + 1) * window // 1000:>4}k" for k in range(n_windows)))
    lines = [head, "-" * len(head)]
    for r in results:
        file_kib = f"{r['file_bytes'] / 1024:8.1f}" if r["file_bytes"] else f"{'-':>8}"
        per = f"{r['file_bytes'] / r['patterns']:6.1f}" if r["file_bytes"] else f"{'-':>6}"
        lines.append(f"{r['joints']:>6} {r['sensors']:>7} {r['patterns']:8.0f} "
                     f"{r['mem_bytes'] / 1024:8.0f} {file_kib} {per} "
                     f"{r['conceivable_log10']:6.1f} {r['obs_tokens']:7.0f} "
                     f"{r['learn_s'] * 1000:8.1f}  "
                     + " ".join(f"{100 * a:4.0f}%" for a in r["accuracy"]))
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=10_000)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--max-length", type=int, default=5)
    parser.add_argument("--window", type=int, default=WINDOW, help="trials per accuracy column")
    parser.add_argument("--sensors", default=",".join(SENSORS),
                        help="comma-separated layouts: moved, all")
    parser.add_argument("--json", action="store_true", help="print one JSON document")
    args = parser.parse_args()
    results = run(args.trials, args.seeds, args.max_length, args.sensors.split(","), args.window)
    print(json.dumps(results) if args.json else render(results))


if __name__ == "__main__":
    main()
