"""Small memory pages against the system's huge ones: ``slearn learn`` and ``replay``, same run.

The command line turns transparent huge pages off for its process
(:mod:`slearn.jobs.pages`). This bench runs each command in a fresh interpreter both
ways, alternated ``--repeat`` times on the same logs (this machine's speed drifts within
minutes: each pair runs back to back), and prints the medians of wall and CPU seconds
and of the pairs' ratios. The "system pages" runs are the same command line with
:func:`slearn.jobs.pages.small_pages` replaced by a function that does nothing. Both ways
write the same library, byte for byte (checked).

The logs: ``--logs`` pointer logs of ``--trials`` trials (``--condition``, seeds 0..).

Run: ``python bench/bench_pages.py [--logs 8] [--trials 100000] [--repeat 5] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from slearn.recorders.pointer import PointerConfig
from slearn.recorders.record_pointer import record_pointer

# The setting is inherited: each child starts with the system's, whatever ran this bench.
_CHILD = r"""
import ctypes, sys
import slearn.jobs.pages as pages
ctypes.CDLL(None).prctl(pages.PR_SET_THP_DISABLE, 0, 0, 0, 0)
if sys.argv[1] == "system":
    pages.small_pages = lambda: False
from slearn.cli import main
main(sys.argv[2:])
"""


def _run(pages: str, args: list[str]) -> tuple[float, float]:
    """Wall and CPU seconds of one command line in a fresh interpreter."""
    with tempfile.TemporaryFile() as err:
        started = time.perf_counter()
        process = subprocess.Popen([sys.executable, "-c", _CHILD, pages, *args],
                                   stdout=subprocess.DEVNULL, stderr=err)
        _, status, usage = os.wait4(process.pid, 0)
        wall = time.perf_counter() - started
        process.returncode = os.waitstatus_to_exitcode(status)
        if process.returncode != 0:
            err.seek(0)
            raise SystemExit(f"slearn {args[0]} failed: {err.read().decode().strip()}")
    return wall, usage.ru_utime + usage.ru_stime


def _available() -> bool:
    """Whether this system can turn huge pages off (asked in a child: the setting is
    inherited, and this process must not pass it to the "system pages" runs)."""
    code = "from slearn.jobs.pages import small_pages; print(small_pages())"
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True).stdout.strip() == "True"


def measure(args) -> dict:
    with tempfile.TemporaryDirectory(prefix="slearn-bench-pages-") as folder:
        return _measure(args, Path(folder))


def _measure(args, folder: Path) -> dict:
    logs = [str(record_pointer(PointerConfig(condition=args.condition, trials=args.trials, seed=i),
                               folder / f"log{i:03d}.mcap").path) for i in range(args.logs)]
    held = str(record_pointer(PointerConfig(condition=args.condition, trials=args.trials, seed=1000),
                              folder / "held.mcap").path)
    commands = {
        "learn": lambda pages: ["learn", *logs, "-o", str(folder / f"{pages}.parquet"), "--force"],
        "replay": lambda pages: ["replay", str(folder / "small.parquet"), held,
                                 "--json", "-q"],
    }
    _run("small", commands["learn"]("small"))  # kernels compiled (or loaded) once before timing
    out: dict = {"logs": args.logs, "trials_per_log": args.trials, "condition": args.condition,
                 "small_pages_here": _available()}
    for name, command in commands.items():
        runs: dict[str, list[tuple[float, float]]] = {"small": [], "system": []}
        for i in range(args.repeat):
            for pages in ("small", "system") if i % 2 == 0 else ("system", "small"):
                runs[pages].append(_run(pages, command(pages)))
        ratios = [s[0] / m[0] for s, m in zip(runs["system"], runs["small"])]
        out[name] = {pages: {"wall_s": statistics.median(w for w, _ in r),
                             "cpu_s": statistics.median(c for _, c in r)} for pages, r in runs.items()}
        out[name]["speedup_median_pair"] = statistics.median(ratios)
        out[name]["speedup_per_pair"] = ratios
    out["identical"] = (folder / "small.parquet").read_bytes() == (folder / "system.parquet").read_bytes()
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--logs", type=int, default=8)
    parser.add_argument("--trials", type=int, default=100_000)
    parser.add_argument("--condition", default="error")
    parser.add_argument("--repeat", type=int, default=5, help="pairs of runs (alternated)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    os.environ.setdefault("SOURCE_DATE_EPOCH", "0")
    m = measure(args)
    if args.json:
        print(json.dumps(m, indent=2))
        return
    print(f"{m['logs']} pointer logs x {m['trials_per_log']:,} trials ({m['condition']}); "
          f"small pages available here: {m['small_pages_here']}")
    for name in ("learn", "replay"):
        r = m[name]
        print(f"slearn {name:7s} small pages {r['small']['wall_s']:6.2f} s wall "
              f"{r['small']['cpu_s']:6.2f} s CPU; system pages {r['system']['wall_s']:6.2f} s wall "
              f"{r['system']['cpu_s']:6.2f} s CPU; median pair {r['speedup_median_pair']:.2f}x "
              f"(pairs {', '.join(f'{x:.2f}' for x in r['speedup_per_pair'])})")
    print(f"same library both ways: {m['identical']}")


if __name__ == "__main__":
    main()
