"""Memory with ``--max-patterns``: RSS stays flat over a 10^8-event stream.

Issue 11 asks that a library bounded by ``max_patterns`` keeps this process's resident
memory flat however long the stream. The stream here never stops producing new contexts
(observations drawn from a Zipf law over ``--vocabulary`` values, four actions), so the
bound is reached early and forgetting runs all along; it is learned in pieces of
``--piece`` steps, as ``slearn learn`` streams a long log. RSS is read from
``/proc/self/statm`` after each tenth of the stream.

Prints, per tenth: events so far, patterns held, RSS (MB); then the growth of RSS from the
first tenth at which the bound was reached to the end (flat: within a few MB, the
allocator's slack), and the library's allocated bytes per pattern.

Run: ``python bench/bench_forgetting.py [--events 100000000] [--max-patterns 1000000]``.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
from bench_core import resident_bytes

from slearn.core.library import PatternLibrary
from slearn.core.stream import Episode


def rss_mb() -> float:
    return resident_bytes() / 2**20


def pieces(events: int, piece: int, vocabulary: int, seed: int = 0):
    """Episodes of ``piece`` steps (two events each) until ``events`` events."""
    rng = np.random.default_rng(seed)
    made = 0
    while made < events:
        n = min(piece, (events - made) // 2)
        obs = rng.zipf(1.3, n + 1) % vocabulary
        actions = vocabulary + rng.integers(0, 4, n)
        yield Episode.from_pairs(obs[:1], actions, obs[1:])
        made += 2 * n + 1


def pointer_pieces(events: int, piece: int, condition: str, distinct: int = 20):
    """``distinct`` pointer episodes of ``piece`` trials (two events each), seeds 0..,
    simulated first (so the RSS of the first tenth holds them), then taken in turn until
    ``events`` events: more patterns than the bound, so the library keeps forgetting and
    learning them again."""
    from slearn.recorders.pointer import PointerConfig, simulate
    episodes = [simulate(PointerConfig(condition, trials=piece, seed=i)).to_episode() for i in range(distinct)]
    made, i = 0, 0
    while made < events:
        yield episodes[i % distinct]
        made += episodes[i % distinct].n_events
        i += 1


def measure(events: int, max_patterns: int, piece: int, vocabulary: int, source: str = "zipf") -> dict:
    library = PatternLibrary(max_patterns=max_patterns)
    rows, done, next_mark, started = [], 0, events // 10, time.perf_counter()
    stream = pieces(events, piece, vocabulary) if source == "zipf" else pointer_pieces(events, piece, source)
    for episode in stream:
        library.learn(episode)
        done += episode.n_events
        if done >= next_mark or done >= events:
            rows.append({"events": done, "patterns": len(library), "rss_mb": rss_mb(),
                         "seconds": time.perf_counter() - started})
            next_mark += events // 10
    full = next((i for i, r in enumerate(rows) if r["patterns"] >= 0.9 * max_patterns), len(rows) - 1)
    return {"events": done, "max_patterns": max_patterns, "rows": rows, "bound_reached_at": full,
            "growth_after_bound_mb": rows[-1]["rss_mb"] - rows[full]["rss_mb"],
            "bytes_per_pattern": library.nbytes() / max(len(library), 1)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--events", type=int, default=100_000_000)
    parser.add_argument("--max-patterns", type=int, default=1_000_000)
    parser.add_argument("--piece", type=int, default=500_000, help="steps per learned piece")
    parser.add_argument("--vocabulary", type=int, default=10_000)
    parser.add_argument("--source", default="zipf",
                        help="zipf, or a pointer condition (20 episodes of --piece trials, in turn)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    result = measure(args.events, args.max_patterns, args.piece, args.vocabulary, args.source)
    if args.json:
        print(json.dumps(result, indent=2))
        return
    print(f"max_patterns {result['max_patterns']:,}; {args.source} stream of {result['events']:,} events")
    print(f"{'events':>13} {'patterns':>11} {'RSS MB':>8} {'seconds':>8}")
    for r in result["rows"]:
        print(f"{r['events']:>13,} {r['patterns']:>11,} {r['rss_mb']:>8.0f} {r['seconds']:>8.0f}")
    at = result["rows"][result["bound_reached_at"]]
    print(f"RSS from {at['events']:,} events (bound reached) to the end: "
          f"{result['growth_after_bound_mb']:+.0f} MB; library {result['bytes_per_pattern']:.0f} "
          f"bytes/pattern as allocated")


if __name__ == "__main__":
    main()
