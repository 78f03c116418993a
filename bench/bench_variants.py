"""slearn against its natural peers on pointer variants it was never tuned on.

Every variant (:data:`VARIANTS`: other bin counts, error amplitudes and delay
probabilities, switches early, late and back, two effects at once, a drifting error, a
50,000-trial run, and the paper's six conditions) is simulated per seed, and on the same
episode, online from empty (predict each trial, then learn it), run:

- ``slearn``: :func:`slearn_adapter.slearn_correct` (the current predictor);
- ``VOM(1..6)``, ``VOM(1.5..5.5)`` (contexts that begin at an action), ``AKOM(5)``,
  ``PPM-C(5)``: :mod:`peers`. The table shows VOM(1..6), the best of the half orders, and
  ``best VOM``: the fixed order (whole or half) with the highest mean over seeds in the
  window shown (its order in brackets); JSON has every order;
- ``ceiling``: the exact Bayes filter (:mod:`slearn.recorders.pointer_oracle`), hits.

Steady state is the last half of the run, minus the 2,000 trials after each switch
(``switch_trial`` and ``switch_back_trial``): ``scramble`` at 8000 is measured over trials
5000-7999, the paper's ``reversal`` over 7000-9999, a 50,000-trial run over 25,000-49,999.
``slearn - VOM`` is slearn's steady-state figure minus the best VOM's. For every switch the
second table compares the thousand trials after it with the first thousand of the run
(from an empty library) and with an empty library that starts learning at the switch
(``slearn new``: the same thousand trials, so what they cost by themselves is left out).
The last table is the paper's six conditions in the windows of the demo's acceptance
figures: thousands 6-10, or the thousand after the switch (6) for ``scramble`` and
``reversal``. Percent, mean over seeds; abstentions count as wrong.

With ``--arm``, a last table runs the pointer arm (:mod:`slearn.recorders.arm`: 1-4
joints, sensors ``moved`` and ``all``, conditions ``simple`` and ``error``) over thousands
6-10: slearn, the best whole-step VOM(1..6) on the step tokens (a step's readings as one
tuple), the per-channel VOM(1..3) of :func:`peers.per_channel_correct` (each joint from its
own readings and the commands) and the exact ceiling (:func:`arm_oracle_correct`).

Run: ``python bench/bench_variants.py [--seeds 0-4] [--variants NAME,...] [--arm] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass, field

import numpy as np
from peers import channel_map, per_channel_correct, prequential_correct
from slearn_adapter import slearn_correct

from slearn.recorders.arm import MAX_JOINTS, SENSORS, ArmConfig, arm_oracle_correct, arm_vocabulary, simulate_arm
from slearn.recorders.pointer import PointerConfig, simulate
from slearn.recorders.pointer_oracle import oracle_correct

SETTLE = 2000  # trials after a switch that are not steady state
MAX_ORDER = 6
PEER_ORDER = 5
WHOLE = [f"VOM{k}" for k in range(1, MAX_ORDER + 1)]
HALF = [f"VOM{k}.5" for k in range(1, MAX_ORDER)]
OTHERS = [f"AKOM{PEER_ORDER}", f"PPM-C{PEER_ORDER}", "ceiling"]
COLUMNS = ["slearn"] + WHOLE + HALF + OTHERS


@dataclass(frozen=True)
class Variant:
    """A named pointer configuration (seed left out)."""

    name: str
    condition: str
    options: dict = field(default_factory=dict)

    def config(self, seed: int) -> PointerConfig:
        return PointerConfig(self.condition, seed=seed, **self.options)


DEFAULTS = [Variant(c, c) for c in ("simple", "hardstop", "scramble", "reversal", "error", "delay")]
VARIANTS = [
    Variant("bins12 delay", "delay", {"bins": 12}),
    Variant("bins72 error2.5", "error", {"bins": 72, "error_deg": 2.5}),
    Variant("error 2.5", "error", {"error_deg": 2.5}),
    Variant("error 8", "error", {"error_deg": 8.0}),
    Variant("delay 0.3", "delay", {"delay_prob": 0.3}),
    Variant("delay 0.7", "delay", {"delay_prob": 0.7}),
    Variant("reversal @2000", "reversal", {"switch_trial": 2000}),
    Variant("scramble @8000", "scramble", {"switch_trial": 8000}),
    Variant("reversal @3000 back @6000", "reversal",
            {"switch_trial": 3000, "switch_back_trial": 6000}),
    Variant("error+delay", "error+delay"),
    Variant("reversal+error", "reversal+error"),
    Variant("error drift 0-10", "error", {"error_deg": 0.0, "error_end_deg": 10.0}),
    Variant("delay 50k", "delay", {"trials": 50_000}),
    Variant("bins24 delay", "delay", {"bins": 24}),
    Variant("delay 0.1", "delay", {"delay_prob": 0.1}),
    Variant("delay 0.9", "delay", {"delay_prob": 0.9}),
    Variant("error+delay 0.3", "error+delay", {"delay_prob": 0.3}),
    Variant("scramble @1000", "scramble", {"switch_trial": 1000}),
    Variant("scramble @3000 back @7000", "scramble",
            {"switch_trial": 3000, "switch_back_trial": 7000}),
    Variant("scramble+error", "scramble+error"),
    Variant("reversal+delay", "reversal+delay"),
] + DEFAULTS


def switches(config: PointerConfig) -> list[int]:
    """The trials where the dynamics switch (none without reversal or scramble)."""
    first, end = config.switched()
    return [t for t in (first, end) if t < config.trials]


def steady_mask(config: PointerConfig) -> np.ndarray:
    """The steady-state trials: the last half, minus ``SETTLE`` trials after each switch."""
    mask = np.zeros(config.trials, bool)
    mask[config.trials // 2:] = True
    for trial in switches(config):
        mask[trial:trial + SETTLE] = False
    return mask


def demo_mask(config: PointerConfig) -> np.ndarray:
    """The demo's acceptance window: thousand 6 after a switch at 5000, else thousands 6-10."""
    mask = np.zeros(config.trials, bool)
    mask[5000:6000 if switches(config) else 10_000] = True
    return mask


def measure(config: PointerConfig) -> dict[str, np.ndarray]:
    """Per column, whether each trial was predicted right (one seed)."""
    run = simulate(config)
    episode = run.to_episode()
    peers = prequential_correct(episode, MAX_ORDER, PEER_ORDER, "C", PEER_ORDER)
    out = {"slearn": np.asarray(slearn_correct(episode), bool)}
    out.update({f"VOM{k}": peers.vom[:, k - 1] for k in range(1, MAX_ORDER + 1)})
    out.update({f"VOM{k}.5": peers.half[:, k - 1] for k in range(1, MAX_ORDER)})
    out[f"AKOM{PEER_ORDER}"], out[f"PPM-C{PEER_ORDER}"] = peers.akom, peers.ppm
    out["ceiling"] = oracle_correct(run)
    for trial in switches(config):  # an empty library from the switch on, the same trials
        out[f"empty at {trial}"] = np.asarray(slearn_correct(episode.slice_steps(trial, len(episode))),
                                              bool)[:1000]
    return out


def _percent(runs: list[dict[str, np.ndarray]], window: np.ndarray) -> dict[str, float]:
    return {c: 100.0 * float(np.mean([r[c][window].mean() for r in runs])) for c in COLUMNS}


ARM_COLUMNS = ["slearn", "VOM", "VOM order", "channel VOM1", "channel VOM2", "channel VOM3",
               "ceiling"]


def measure_arm(config: ArmConfig) -> dict[str, np.ndarray]:
    """Per column, whether each arm trial was predicted right (one seed)."""
    run = simulate_arm(config)
    episode = run.to_episode()
    whole = prequential_correct(episode, MAX_ORDER, PEER_ORDER, "C", PEER_ORDER)
    out = {"slearn": np.asarray(slearn_correct(episode, vocabulary=arm_vocabulary(config.joints)), bool),
           "ceiling": arm_oracle_correct(run)}
    out.update({f"VOM{k}": whole.vom[:, k - 1] for k in range(1, MAX_ORDER + 1)})
    channels = channel_map(arm_vocabulary(config.joints))
    for k in (1, 2, 3):
        out[f"channel VOM{k}"] = per_channel_correct(episode, channels, order=k).step
    return out


def run_arm(seeds: list[int], trials: int = 10_000) -> list[dict]:
    """Every arm layout over ``seeds``, thousands 6-10 (the last half)."""
    results = []
    for condition in ("simple", "error"):
        for sensors in SENSORS:
            for joints in range(1, MAX_JOINTS + 1):
                runs = [measure_arm(ArmConfig(joints, trials, seed, sensors, condition))
                        for seed in seeds]
                window = slice(trials // 2, trials)
                figures = {c: 100.0 * float(np.mean([r[c][window].mean() for r in runs]))
                           for c in runs[0]}
                order = max(range(1, MAX_ORDER + 1), key=lambda k: figures[f"VOM{k}"])
                figures.update({"VOM": figures[f"VOM{order}"], "VOM order": order})
                results.append({"condition": condition, "sensors": sensors, "joints": joints,
                                **figures})
                print(f"arm {condition} {sensors} {joints}: done", file=sys.stderr)
    return results


def render_arm(rows: list[dict]) -> str:
    """The arm table."""
    head = f"{'condition':<10}{'sensors':<8}{'joints':>6} " + " ".join(f"{c:>12}" for c in ARM_COLUMNS)
    lines = ["", "pointer arm, thousands 6-10 (VOM: the best whole-step order 1-6)", head,
             "-" * len(head)]
    for r in rows:
        lines.append(f"{r['condition']:<10}{r['sensors']:<8}{r['joints']:>6} " + " ".join(
            f"{r[c]:12.0f}" if c == "VOM order" else f"{r[c]:12.1f}" for c in ARM_COLUMNS))
    return "\n".join(lines)


def _with_best(figures: dict[str, float]) -> dict:
    half = max(HALF, key=lambda c: figures[c])
    best = max(WHOLE + HALF, key=lambda c: figures[c])
    return {**figures, "best_half": figures[half], "best_half_order": half[3:],
            "best_vom": figures[best], "best_vom_order": best[3:],
            "slearn_minus_best_vom": figures["slearn"] - figures[best]}


def summarize(variant: Variant, runs: list[dict[str, np.ndarray]], config: PointerConfig) -> dict:
    """Steady-state figures, per-switch thousands and (for the six conditions) the demo window."""
    first = np.zeros(config.trials, bool)
    first[:1000] = True
    out = {"name": variant.name, "config": config.parameters(),
           "steady": _with_best(_percent(runs, steady_mask(config))), "switches": []}
    for trial in switches(config):
        after = np.zeros(config.trials, bool)
        after[trial:trial + 1000] = True
        restart = 100.0 * float(np.mean([r[f"empty at {trial}"].mean() for r in runs]))
        out["switches"].append({"trial": trial, "first_thousand": _percent(runs, first),
                                "after": _percent(runs, after), "empty_at_switch": restart})
    if variant in DEFAULTS:
        out["demo"] = _with_best(_percent(runs, demo_mask(config)))
    return out


def run(variants: list[Variant], seeds: list[int]) -> list[dict]:
    """Every variant over ``seeds``; progress on stderr."""
    results = []
    for variant in variants:
        started = time.perf_counter()
        runs = [measure(variant.config(seed)) for seed in seeds]
        results.append(summarize(variant, runs, variant.config(seeds[0])))
        print(f"{variant.name}: {time.perf_counter() - started:.1f} s", file=sys.stderr)
    return results


def _row(label: str, figures: dict, width: int = 27) -> str:
    whole = " ".join(f"{figures[c]:5.1f}" for c in ["slearn"] + WHOLE)
    half = f"{figures['best_half']:5.1f} ({figures['best_half_order']})"
    best = f"{figures['best_vom']:5.1f} ({figures['best_vom_order']})"
    rest = " ".join(f"{figures[c]:6.1f}" for c in OTHERS)
    return (f"{label:<{width}}{whole} {half:>11} {best:>11} {rest}"
            f" {figures['slearn_minus_best_vom']:+7.1f}")


def _head(title: str, width: int = 27) -> list[str]:
    head = (f"{title:<{width}}" + " ".join(f"{c:>5}" for c in ["slearn"] + WHOLE)
            + f" {'VOM k.5':>11} {'best VOM':>11} " + " ".join(f"{c:>6}" for c in OTHERS)
            + f" {'sl-VOM':>7}")
    return [head, "-" * len(head)]


def render(results: list[dict], seeds: list[int]) -> str:
    """The three plain-text tables."""
    lines = [f"steady state (last half, minus {SETTLE} trials after each switch), "
             f"% mean of seeds {_seed_text(seeds)}"]
    lines += _head("variant") + [_row(r["name"], r["steady"]) for r in results]
    lines += ["", "after each switch: the thousand after it / the first thousand of the run "
              "(slearn new: an empty library learning from the switch on, the same thousand)"]
    shown = ["slearn", "VOM1", "VOM2", "VOM3", "VOM1.5", "VOM2.5"] + OTHERS
    head = (f"{'variant':<27}{'switch':>7} {shown[0]:>11} {'slearn new':>10} "
            + " ".join(f"{c:>11}" for c in shown[1:]))
    lines += [head, "-" * len(head)]
    for r in results:
        for s in r["switches"]:
            cells = [f"{s['after'][c]:5.1f}/{s['first_thousand'][c]:<5.1f}" for c in shown]
            lines.append(f"{r['name']:<27}{s['trial']:>7} {cells[0]} {s['empty_at_switch']:10.1f} "
                         + " ".join(cells[1:]))
    demo = [r for r in results if "demo" in r]
    if demo:
        lines += ["", "the six conditions in the demo's windows (thousands 6-10; 6 after a switch)"]
        lines += _head("condition") + [_row(r["name"], r["demo"]) for r in demo]
    return "\n".join(lines)


def _seed_text(seeds: list[int]) -> str:
    return ",".join(map(str, seeds))


def parse_seeds(text: str) -> list[int]:
    """``"0-4"`` or ``"0,2,5"`` as a list of seeds."""
    if "-" in text:
        low, high = text.split("-")
        return list(range(int(low), int(high) + 1))
    return [int(s) for s in text.split(",")]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", default="0-4", help="seeds, e.g. 0-4 or 0,3")
    parser.add_argument("--variants", help="comma-separated variant names (default: all)")
    parser.add_argument("--arm", action="store_true", help="add the pointer arm table")
    parser.add_argument("--json", action="store_true", help="print one JSON document")
    args = parser.parse_args()
    chosen = VARIANTS
    if args.variants:
        wanted = args.variants.split(",")
        chosen = [v for v in VARIANTS if v.name in wanted]
        unknown = set(wanted) - {v.name for v in chosen}
        if unknown:
            parser.error(f"unknown variant(s): {', '.join(sorted(unknown))}; "
                         f"known: {', '.join(v.name for v in VARIANTS)}")
    seeds = parse_seeds(args.seeds)
    results = run(chosen, seeds)
    arm = run_arm(seeds) if args.arm else None
    if args.json:
        print(json.dumps({"seeds": seeds, "settle_trials": SETTLE, "columns": COLUMNS,
                          "variants": results, "arm": arm}))
    else:
        print(render(results, seeds) + ("\n" + render_arm(arm) if arm else ""))


if __name__ == "__main__":
    main()
