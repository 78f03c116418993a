"""Startup and compilation costs, each against its anchor in the same run.

- ``slearn --help``: wall time (median of ``--repeat`` runs) against ``python -c "import
  click"`` (issue 12: at most 2.5x);
- ``slearn info small.mcap`` and ``slearn datasets list``: their time, and whether they import
  numba (they must not: they compile nothing);
- a cold ``slearn demo`` (empty kernel cache): CPU seconds spent compiling (the sum of numba's
  compile events, callees counted once; issue 12: at most 3 s), every kernel's own compile
  cost, and the cold and warm demo's total CPU time; ``--seeds``/``--trials`` are the demo's
  (its defaults: 5 seeds of 10,000 trials). The anchor: the same cold demo without the
  kernels compiled at install (``SLEARN_AOT=0``: numba compiles everything at first use).

Every command runs in a fresh interpreter (``sys.executable -m slearn``); the cold demo gets a
new, empty ``SLEARN_CACHE_DIR`` and ``NUMBA_CACHE_DIR``.

Run: ``python bench/bench_startup.py [--repeat 7] [--seeds 5] [--trials 10000] [--json]``.
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

# Runs inside the measured interpreter: records numba's compile events in CPU seconds (a
# caller's time excludes its callees') and the modules imported, then runs the CLI.
_CHILD = r"""
import json, sys, time
events, stack = {}, []
try_numba = sys.argv[1] == "demo"
if try_numba:
    import numba.core.event as ev

    class Compiles(ev.Listener):
        def on_start(self, event):
            stack.append([time.process_time(), 0.0])

        def on_end(self, event):
            started, inner = stack.pop()
            spent = time.process_time() - started
            if stack:
                stack[-1][1] += spent
            d = event.data["dispatcher"]
            name = f"{d.py_func.__module__}.{d.py_func.__qualname__}"
            events.setdefault(name, []).append(spent - inner)

    ev.register("numba:compile", Compiles())
from slearn.cli import main
code = 0
try:
    main(sys.argv[1:], standalone_mode=False)
except SystemExit as exit:
    code = exit.code or 0
report = {"numba": "numba" in sys.modules, "cpu_s": time.process_time(), "code": code,
          "compiles": events}
sys.stderr.write("\nBENCH " + json.dumps(report) + "\n")
"""


def _run(args: list[str], env: dict | None = None) -> tuple[float, str]:
    """Wall seconds of one run and its stderr."""
    started = time.perf_counter()
    done = subprocess.run(args, capture_output=True, text=True, env=env)
    elapsed = time.perf_counter() - started
    if done.returncode not in (0, 3):
        raise RuntimeError(f"{' '.join(args)} failed: {done.stderr[-2000:]}")
    return elapsed, done.stderr


def median_wall(args: list[str], repeat: int) -> float:
    """Median wall seconds of ``repeat`` runs after one warm-up (file cache warm)."""
    _run(args)
    return statistics.median(_run(args)[0] for _ in range(repeat))


def child_report(cli_args: list[str], env: dict | None = None) -> dict:
    """Run the CLI in a fresh interpreter with the compile recorder; its report."""
    _, err = _run([sys.executable, "-c", _CHILD, *cli_args], env)
    line = next(x for x in reversed(err.splitlines()) if x.startswith("BENCH "))
    return json.loads(line[len("BENCH "):])


def small_log(folder: Path) -> Path:
    """A small pointer log (100 trials)."""
    path = folder / "small.mcap"
    subprocess.run([sys.executable, "-m", "slearn", "record", "pointer", "--condition", "simple",
                    "--trials", "100",
                    "-o", str(path)], check=True, capture_output=True)
    return path


def demo(folder: Path, name: str, env: dict, seeds: int, trials: int) -> dict:
    """One demo run's report (total CPU, compile events)."""
    args = ["demo", "--out", str(folder / name), "--seeds", str(seeds), "--trials", str(trials),
            "--quiet", "--json"]
    return child_report(args, env)


def measure(repeat: int, seeds: int, trials: int) -> dict:
    """Every figure, in one run."""
    python = sys.executable
    out = {"repeat": repeat,
           "import_click_s": median_wall([python, "-c", "import click"], repeat),
           "help_s": median_wall([python, "-m", "slearn", "--help"], repeat)}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        log = small_log(folder)
        out["info_s"] = median_wall([python, "-m", "slearn", "info", str(log)], repeat)
        out["info_imports_numba"] = child_report(["info", str(log)])["numba"]
        out["datasets_list_imports_numba"] = child_report(["datasets", "list"])["numba"]
        out["help_imports_numba"] = child_report(["--help"])["numba"]
        cache, jit_cache = folder / "cache", folder / "jit-cache"
        env = dict(os.environ, SLEARN_CACHE_DIR=str(cache / "slearn"), NUMBA_CACHE_DIR=str(cache))
        cold = demo(folder, "cold", env, seeds, trials)
        warm = demo(folder, "warm", env, seeds, trials)
        jit_env = dict(os.environ, SLEARN_AOT="0", SLEARN_CACHE_DIR=str(jit_cache / "slearn"),
                       NUMBA_CACHE_DIR=str(jit_cache))
        jit = demo(folder, "jit", jit_env, seeds, trials)
    from slearn.core import _aot
    kernels = {name: sum(times) for name, times in cold["compiles"].items()}
    jit_kernels = {name: sum(times) for name, times in jit["compiles"].items()}
    out.update(demo_seeds=seeds, demo_trials=trials, cold_demo_cpu_s=cold["cpu_s"],
               shipped_kernels=_aot._extension() is not None,
               jit_compile_cpu_s=sum(jit_kernels.values()),
               jit_kernels=dict(sorted(jit_kernels.items(), key=lambda kv: -kv[1])),
               jit_cold_demo_cpu_s=jit["cpu_s"],
               warm_demo_cpu_s=warm["cpu_s"], compile_cpu_s=sum(kernels.values()),
               warm_compiles=len(warm["compiles"]),
               kernels=dict(sorted(kernels.items(), key=lambda kv: -kv[1])),
               specializations={name: len(times) for name, times in cold["compiles"].items()})
    return out


def render(r: dict) -> str:
    """The figures as text, each next to its anchor."""
    lines = [f"slearn --help          {r['help_s'] * 1000:7.0f} ms   import click "
             f"{r['import_click_s'] * 1000:5.0f} ms   ratio {r['help_s'] / r['import_click_s']:.2f} "
             f"(target <= 2.5)",
             f"slearn info small.mcap {r['info_s'] * 1000:7.0f} ms   imports numba: "
             f"{r['info_imports_numba']}",
             f"slearn datasets list   imports numba: {r['datasets_list_imports_numba']}; "
             f"slearn --help imports numba: {r['help_imports_numba']}",
             f"slearn demo --seeds {r['demo_seeds']} --trials {r['demo_trials']}: cold {r['cold_demo_cpu_s']:.2f} "
             f"s CPU, warm {r['warm_demo_cpu_s']:.2f} s CPU; compiling {r['compile_cpu_s']:.2f} s CPU "
             f"(target <= 3), warm run compiled {r['warm_compiles']} kernels",
             f"  kernels compiled at install in use: {r['shipped_kernels']}; without them (SLEARN_AOT=0, "
             f"numba compiling at first use): compiling {r['jit_compile_cpu_s']:.2f} s CPU, cold demo "
             f"{r['jit_cold_demo_cpu_s']:.2f} s CPU",
             "", f"{'kernel (own compile CPU, callees excluded)':<58} {'ms':>7} {'sigs':>4}"]
    for name, seconds in r["kernels"].items():
        lines.append(f"{name:<58} {seconds * 1000:7.0f} {r['specializations'][name]:>4}")
    lines += ["", f"{'without them, the ten largest':<58} {'ms':>7}"]
    for name, seconds in list(r["jit_kernels"].items())[:10]:
        lines.append(f"{name:<58} {seconds * 1000:7.0f}")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=7)
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--trials", type=int, default=10_000)
    parser.add_argument("--json", action="store_true", help="print one JSON document")
    args = parser.parse_args()
    result = measure(args.repeat, args.seeds, args.trials)
    print(json.dumps(result, indent=2) if args.json else render(result))


if __name__ == "__main__":
    main()
