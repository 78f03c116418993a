"""Online predict-then-learn speed against its anchor: a C VOM of the same order.

On one pointer stream (``--trials`` trials, condition ``--condition``), steps per second of:

- ``C VOM(k)``: ``bench/c/vom.c`` (compiled now with the system C compiler; skipped without
  one), the anchor of issue 12 ("online predict-then-learn >= 1/4 of a C VOM of the same
  order");
- ``numba VOM(k)``: :class:`peers.CountModel` of order ``k`` (VOM only, no PPM);
- ``slearn``: :func:`slearn_adapter.slearn_correct` (the current predictor, from empty),
  shown as a ratio to each C VOM. slearn's default library holds patterns of 5 steps, so
  its contexts reach 4 steps back: compare with ``k = 4``.

Every figure is the best of ``--repeat`` runs after one warm-up (compilation excluded).

Run: ``python bench/bench_vom_speed.py [--trials 1000000] [--condition simple] [--json]``.
"""

from __future__ import annotations

import argparse
import json
from typing import Callable

from peers import CountModel, load_c_vom, step_tokens
from slearn_adapter import slearn_correct
from timing import best_seconds

from slearn.core.tokens import TokenTable
from slearn.recorders.pointer import PointerConfig, simulate

ORDERS = range(1, 7)


def best_rate(work: Callable[[], object], steps: int, repeat: int) -> float:
    """Steps per second of the fastest of ``repeat`` runs, after one warm-up."""
    return steps / best_seconds(work, repeat)


def measure(trials: int, condition: str, repeat: int) -> dict:
    """Every rate on one stream."""
    episode = simulate(PointerConfig(condition, trials=trials)).to_episode()
    tokens = TokenTable().tokenize(episode)
    obs, act = step_tokens(episode)
    steps = len(obs) - 1
    c_vom = load_c_vom()
    out = {"trials": trials, "condition": condition, "steps": steps,
           "slearn": best_rate(lambda: slearn_correct(episode), steps, repeat),
           "numba_vom": {}, "c_vom": {} if c_vom else None}
    for k in ORDERS:
        out["numba_vom"][k] = best_rate(lambda k=k: CountModel(k).run(obs, act, ppm=None), steps,
                                        repeat)
        if c_vom:
            out["c_vom"][k] = best_rate(lambda k=k: c_vom(tokens, k), steps, repeat)
    return out


def render(result: dict) -> str:
    """One row per order."""
    lines = [f"pointer {result['condition']}, {result['steps']:,} steps; steps/s "
             f"(slearn: {result['slearn']:,.0f})",
             f"{'k':>2} {'C VOM(k)':>13} {'numba VOM(k)':>13} {'slearn / C':>11}"]
    for k in ORDERS:
        c = result["c_vom"][k] if result["c_vom"] else None
        ratio = f"{result['slearn'] / c:11.3f}" if c else f"{'-':>11}"
        c_text = f"{c:13,.0f}" if c else f"{'no compiler':>13}"
        lines.append(f"{k:>2} {c_text} {result['numba_vom'][k]:13,.0f} {ratio}")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=1_000_000)
    parser.add_argument("--condition", default="simple")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--json", action="store_true", help="print one JSON document")
    args = parser.parse_args()
    result = measure(args.trials, args.condition, args.repeat)
    print(json.dumps(result) if args.json else render(result))


if __name__ == "__main__":
    main()
