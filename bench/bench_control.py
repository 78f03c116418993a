"""Goal-seeking control: planning time per step and the acceptance table of issue 7.

For each condition and seed, a library is learned offline from 10,000 random trials (the
unchanged pointer for ``reversal``/``scramble``), then the pointer is steered in closed
loop to random goals while the library keeps learning; the Q-learning baseline (trained
for one goal on the same trials) gets the same goals. Targets:

- ``simple``, ``hardstop``: >= 99 % of goals reached, mean steps <= 1.1 x shortest;
- ``error``: >= 95 % reached within 2 x shortest; ``delay``: >= 90 % within 3 x shortest;
- ``reversal``: control recovers (last block after the switch: >= 99 % reached, steps
  ratio <= 1.2); ``scramble`` is shown without a target.

Run: ``python bench/bench_control.py [--goals 300] [--seeds 3]`` (numba compiles once; the
timings exclude it).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from slearn.control import ControlConfig, offline_library, run_control
from slearn.planner import Planner
from slearn.recorders.pointer import PointerConfig, simulate

CONDITIONS = ("simple", "hardstop", "error", "delay", "reversal", "scramble")


def _passes(condition: str, result) -> str:
    s = result.slearn
    if condition in ("simple", "hardstop"):
        ok = s.success >= 0.99 and s.steps_ratio <= 1.1
    elif condition == "error":
        ok = s.within_2x >= 0.95
    elif condition == "delay":
        ok = s.within_3x >= 0.90
    elif condition == "reversal":
        last = result.blocks[-1].summary
        ok = last.success >= 0.99 and last.steps_ratio <= 1.2
    else:
        return "  -"
    return "yes" if ok else " NO"


def bench_planning(condition: str, calls: int = 2_000) -> None:
    """Planning time per call from random histories toward random goals (library frozen)."""
    library, _ = offline_library(ControlConfig(condition, seed=0))
    planner = Planner(library, [(0,), (1,)])
    run = simulate(PointerConfig(condition if condition not in ("reversal", "scramble") else "simple",
                                 calls + 1, 99))
    steps = run.to_episode().steps()
    rng = np.random.default_rng(0)
    times = np.empty(calls)
    for i in range(calls):
        goal = int(rng.integers(1, 37)) + 1
        started = time.perf_counter()
        planner.plan(steps[i: i + 2], goal)
        times[i] = time.perf_counter() - started
    print(f"plan   {condition:<9} {1000 * times.mean():6.2f} ms mean  {1000 * np.percentile(times, 99):6.2f} ms p99"
          f"  ({len(library):,} patterns)")


def bench_acceptance(goals: int, seeds: int) -> None:
    print(f"\nacceptance: {goals} random goals x {seeds} seeds per condition, budget 100 steps per goal")
    print(f"{'condition':<9} {'seed':>4}  reached  <=1.1x    <=2x    <=3x  steps/shortest  "
          f"Q trained  Q new goals  ms/step  pass")
    for condition in CONDITIONS:
        for seed in range(seeds):
            result = run_control(ControlConfig(condition, goals=goals, seed=seed, blocks=10))
            s, q = result.slearn, result.qlearning
            print(f"{condition:<9} {seed:>4}  {100 * s.success:5.1f} %  {100 * s.within_1_1x:5.1f} %  "
                  f"{100 * s.within_2x:5.1f} %  {100 * s.within_3x:5.1f} %  {s.steps_ratio:10.2f}      "
                  f"{100 * q.trained_goal_success:5.1f} %     {100 * q.new_goals.success:5.1f} %   "
                  f"{result.plan_ms_per_step:6.2f}   {_passes(condition, result)}")
            if condition in ("reversal", "scramble") and seed == 0:
                _curve(result)


def _curve(result) -> None:
    cells = [f"{'*' if b.after_switch else ' '}{100 * b.summary.success:.0f}%/{b.summary.steps_ratio:.2f}"
             for b in result.blocks]
    print(f"  curve (reached/steps ratio per block of {result.config.n_goals // len(result.blocks)} goals,"
          f" * after the switch): {' '.join(cells)}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--goals", type=int, default=300)
    parser.add_argument("--seeds", type=int, default=3)
    args = parser.parse_args()
    run_control(ControlConfig("simple", goals=2, trials=500))  # compile
    for condition in ("simple", "hardstop", "error", "delay"):
        bench_planning(condition)
    bench_acceptance(args.goals, args.seeds)


if __name__ == "__main__":
    main()
