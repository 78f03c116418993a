"""Action scopes: an arm whose controller commands every joint at every step.

Each joint of ``J`` (2-7) on 12 positions moves by its own command (-1, 0 or +1 at random,
every joint every step), so the step's command tuple takes ``3^J`` values. Per joint count,
mean of ``--seeds`` seeds, frozen accuracy per joint on 2,000 held-out steps after
``--train`` training steps (one episode):

- ``scoped``: slearn with the scopes :func:`slearn.core.action_scopes.suggest_scopes`
  chooses from the training steps (what ``slearn info --suggest-spec`` writes); ``found``
  says whether it gave every joint exactly its own command;
- ``tuple``: slearn without scopes (every joint sees the whole command tuple);
- peers, dict models a user would write, each joint on its own: ``last+tuple`` counts the
  next reading after (last reading, command tuple), backing off to the last reading;
  ``last+own`` counts it after (last reading, the joint's own command), the structure
  known in advance (the ceiling here: the walk is deterministic).

With slip (``--slips``, default ``0,0.2``: one table each) a move is one position more or
less than commanded with that probability, so the ceiling is below 1 (``last+own``).

Run: ``python bench/bench_scopes.py [--train 9000] [--seeds 3] [--joints 2,3,5,7] [--slips 0,0.2] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import time
from collections import Counter, defaultdict

import numpy as np

from slearn import SequenceModel
from slearn.core.action_scopes import suggest_scopes
from slearn.core.stream import Episode

POSITIONS = 12
HELD_OUT = 2000
HISTORY = 6


def walk(joints: int, seed: int, steps: int, slip: float = 0.0) -> list:
    """Steps ``({c0..: command}, {p0..: position})`` of the busy arm; with ``slip``, each
    joint's move is one position more or less (at random) with that probability."""
    rng = np.random.default_rng(seed)
    position = [int(p) for p in rng.integers(POSITIONS, size=joints)]
    out = []
    for _ in range(steps):
        cmd = [int(c) for c in rng.integers(-1, 2, size=joints)]
        moves = [c + (int(rng.choice((-1, 1))) if slip and rng.random() < slip else 0) for c in cmd]
        position = [min(POSITIONS - 1, max(0, p + m)) for p, m in zip(position, moves)]
        out.append(({f"c{j}": cmd[j] for j in range(joints)}, {f"p{j}": position[j] for j in range(joints)}))
    return out


class DictPeer:
    """Per joint, the most frequent next reading after ``key(step, joint)``, backing off
    to the last reading alone."""

    def __init__(self, key) -> None:
        self.key = key
        self.counts: dict = defaultdict(Counter)
        self.backoff: dict = defaultdict(Counter)

    def learn(self, steps: list) -> None:
        for before, step in zip(steps, steps[1:]):
            for channel, value in step[1].items():
                self.counts[(channel, before[1][channel], self.key(step[0], channel))][value] += 1
                self.backoff[(channel, before[1][channel])][value] += 1

    def predict(self, before: tuple, actions: dict, channel: str):
        seen = self.counts.get((channel, before[1][channel], self.key(actions, channel))) \
            or self.backoff.get((channel, before[1][channel]))
        return seen.most_common(1)[0][0] if seen else before[1][channel]


def slearn_accuracy(model: SequenceModel, held: list) -> float:
    right = [model.predict_step(held[i - HISTORY:i], held[i][0]).get(c) == v
             for i in range(HISTORY, len(held)) for c, v in held[i][1].items()]
    return float(np.mean(right))


def peer_accuracy(peer: DictPeer, held: list) -> float:
    right = [peer.predict(held[i - 1], held[i][0], c) == v
             for i in range(HISTORY, len(held)) for c, v in held[i][1].items()]
    return float(np.mean(right))


def measure(joints: int, train: int, seed: int, slip: float = 0.0) -> dict:
    steps, held = walk(joints, seed, train, slip), walk(joints, seed + 1000, HELD_OUT, slip)
    probe = SequenceModel()
    probe.learn_steps(steps[:1])  # the channels, for the choice's vocabulary
    episode = Episode.from_steps([probe._step_symbols(s, learn=True) for s in steps])
    started = time.perf_counter()
    scopes = suggest_scopes([episode], probe.vocabulary)
    choose_s = time.perf_counter() - started
    row = {"joints": joints, "seed": seed, "slip": slip, "choose_s": choose_s,
           "found": scopes == {f"p{j}": (f"c{j}",) for j in range(joints)}}
    for name, chosen in (("scoped", {k: list(v) for k, v in scopes.items()}), ("tuple", None)):
        model = SequenceModel(action_scopes=chosen)
        started = time.perf_counter()
        model.learn_steps(steps)
        row[f"{name}_learn_s"] = time.perf_counter() - started
        row[f"{name}_patterns"] = len(model.library)
        row[name] = slearn_accuracy(model, held)
    for name, key in (("last+tuple", lambda acts, c: tuple(acts.values())),
                      ("last+own", lambda acts, c: acts["c" + c[1:]])):
        peer = DictPeer(key)
        peer.learn(steps)
        row[name] = peer_accuracy(peer, held)
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--train", type=int, default=9000)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--joints", default="2,3,5,7")
    parser.add_argument("--slips", default="0,0.2", help="slip probabilities, one table each")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    slips = [float(p) for p in args.slips.split(",")]
    rows = [measure(j, args.train, s, slip) for slip in slips for j in map(int, args.joints.split(","))
            for s in range(args.seeds)]
    if args.json:
        print(json.dumps(rows, indent=2))
        return
    for slip in slips:
        table([r for r in rows if r["slip"] == slip], args, slip)


def table(rows: list, args, slip: float) -> None:
    print(f"busy arm, {POSITIONS} positions, slip {slip:g}, {args.train:,} training steps, {HELD_OUT:,} "
          f"held out, mean of {args.seeds} seeds; accuracy per joint")
    print(f"{'joints':>6} {'found':>6} {'scoped':>7} {'tuple':>7} {'last+tuple':>10} {'last+own':>9} "
          f"{'scoped/peer':>11} {'patterns scoped/tuple':>22} {'learn s scoped/tuple':>21} {'choose s':>8}")
    for joints in sorted({r["joints"] for r in rows}):
        mine = [r for r in rows if r["joints"] == joints]

        def mean(key, mine=mine):
            return float(np.mean([r[key] for r in mine]))

        found = sum(r["found"] for r in mine)
        print(f"{joints:>6} {found:>3}/{len(mine):<2} {mean('scoped'):>7.3f} {mean('tuple'):>7.3f} "
              f"{mean('last+tuple'):>10.3f} {mean('last+own'):>9.3f} "
              f"{mean('scoped') / max(mean('last+tuple'), 1e-9):>11.2f} "
              f"{mean('scoped_patterns'):>10,.0f}/{mean('tuple_patterns'):<11,.0f} "
              f"{mean('scoped_learn_s'):>10.2f}/{mean('tuple_learn_s'):<10.2f} {mean('choose_s'):>8.2f}")


if __name__ == "__main__":
    main()
