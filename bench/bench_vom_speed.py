"""Online predict-then-learn speed against its anchor: a C VOM of the same order.

On one pointer stream (``--trials`` trials, condition ``--condition``), steps per second of:

- ``C VOM(k)``: ``bench/c/vom.c`` (compiled now with the system C compiler; skipped without
  one), the anchor of issue 12 ("online predict-then-learn >= 1/4 of a C VOM of the same
  order, measured the same way"). It runs from tokens made before its clock starts;
- ``numba VOM(k)``: :class:`peers.CountModel` of order ``k`` (VOM only, no PPM);
- ``slearn``: a default library from empty, ``library.run(codes, learn=True, record=True)``
  over codes made before its clock starts, as the C VOM's tokens are (``slearn + encoding``:
  with ``library.encode`` timed too). slearn's default contexts span 12 tokens (6 steps of
  action and observation); VOM(k) reads ``2k + 1`` tokens, so VOM(6) is the same order
  and VOM(5) one token shorter.

Each round runs every model once, in turn, so a slow spell of the shared host slows all of
them alike; every figure is the best of ``--repeat`` rounds after one warm-up
(compilation excluded).

Run: ``python bench/bench_vom_speed.py [--trials 1000000] [--condition simple] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import time
from typing import Callable

from peers import CountModel, load_c_vom, step_tokens
from slearn_adapter import new_library

from slearn.core.tokens import TokenTable
from slearn.recorders.pointer import PointerConfig, simulate

ORDERS = range(1, 7)


def _seconds(work: Callable[[], object], setup: Callable[[], object] | None = None) -> float:
    prepared = setup() if setup else None
    started = time.perf_counter()
    work(prepared) if setup else work()
    return time.perf_counter() - started


def measure(trials: int, condition: str, repeat: int) -> dict:
    """Every rate on one stream: the best of ``repeat`` interleaved rounds."""
    episode = simulate(PointerConfig(condition, trials=trials)).to_episode()
    tokens = TokenTable().tokenize(episode)
    obs, act = step_tokens(episode)
    steps = len(obs) - 1
    c_vom = load_c_vom()

    def encoded():
        library = new_library({})
        return library, library.encode(episode)

    def slearn_run(prepared):
        library, codes = prepared
        library.run(codes, learn=True, record=True, top_k=1)

    def slearn_with_encoding():
        library = new_library({})
        library.run(library.encode(episode), learn=True, record=True, top_k=1)

    work: dict[str, tuple] = {"slearn": (slearn_run, encoded), "slearn_encoding": (slearn_with_encoding, None)}
    for k in ORDERS:
        work[f"numba_vom{k}"] = (lambda k=k: CountModel(k).run(obs, act, ppm=None), None)
        if c_vom:
            work[f"c_vom{k}"] = (lambda k=k: c_vom(tokens, k), None)
    best = {name: float("inf") for name in work}
    for round_ in range(repeat + 1):  # round 0 warms up
        for name, (function, setup) in work.items():
            seconds = _seconds(function, setup)
            if round_:
                best[name] = min(best[name], seconds)
    rate = {name: steps / seconds for name, seconds in best.items()}
    return {"trials": trials, "condition": condition, "steps": steps, "rounds": repeat,
            "slearn": rate["slearn"], "slearn_encoding": rate["slearn_encoding"],
            "numba_vom": {k: rate[f"numba_vom{k}"] for k in ORDERS},
            "c_vom": {k: rate[f"c_vom{k}"] for k in ORDERS} if c_vom else None}


def render(result: dict) -> str:
    """One row per order."""
    lines = [f"pointer {result['condition']}, {result['steps']:,} steps; steps/s, best of "
             f"{result['rounds']} interleaved rounds (slearn: {result['slearn']:,.0f} from codes, "
             f"{result['slearn_encoding']:,.0f} with encoding)",
             f"{'k':>2} {'C VOM(k)':>13} {'numba VOM(k)':>13} {'slearn / C':>11} {'+ encoding':>11}"]
    for k in ORDERS:
        c = result["c_vom"][k] if result["c_vom"] else None
        ratio = f"{result['slearn'] / c:11.3f} {result['slearn_encoding'] / c:11.3f}" if c else f"{'-':>23}"
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
