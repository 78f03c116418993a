"""Learning speed against its anchor: the same rule in C, and the same library byte for byte.

Issue 12 asks learning to run at >= 1/3 of a C implementation of the same rule. The rule
is what ``slearn learn`` does to an encoded episode (slearn/core/online.py with learning on):
count every occurrence of every context of every view and train the mixer's weights and
change detectors. ``bench/c/learn.c`` is that rule in plain C (compiled now with the system
compiler; skipped without one), twice: the plain loop, and with the prefetches slearn's
kernel makes (``-DPREFETCH``: the lookups of a step's contexts ask for their memory at
once), the anchor for slearn as it runs. Both run on the same encoded steps; the library the C code
builds is exported with slearn's own export and compared array by array (patterns, counts,
recency, fresh counts, weights, detectors, epochs).

Streams: the pointer (``--trials`` trials of ``--condition``) and, with ``--arm``, the
4-joint arm with every joint observed (4 views). Encoding (symbols to tokens) is timed on
its own: it is part of ingest, not of the rule. Every figure is the best of ``--repeat``
runs after one warm-up.

Run: ``python bench/bench_learn.py [--trials 1000000] [--condition delay] [--arm] [--json]``.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
from timing import best_seconds

from slearn.core import context_tree, mixer
from slearn.core.library import PatternLibrary
from slearn.recorders.arm import ArmConfig, arm_vocabulary, simulate_arm
from slearn.recorders.pointer import PointerConfig, pointer_vocabulary, simulate

_SOURCE = Path(__file__).parent / "c" / "learn.c"
_TREE_FIELDS = ("parent", "token", "first", "best", "newest", "fresh_best", "epoch", "node_slots",
                "owner", "outcome", "next", "entry_slots", "count", "last_seen", "fresh", "size")


class _Tree(ctypes.Structure):
    _fields_ = [(name, ctypes.c_void_p) for name in _TREE_FIELDS] + [
        ("node_slot_count", ctypes.c_int64), ("entry_slot_count", ctypes.c_int64)]


class _Params(ctypes.Structure):
    _fields_ = [("n_views", ctypes.c_int32), ("K", ctypes.c_int32), ("has_actions", ctypes.c_int32),
                ("empty_action", ctypes.c_int32), ("empty_observation", ctypes.c_int32),
                ("beta", ctypes.c_double), ("floor_", ctypes.c_double), ("threshold", ctypes.c_double),
                ("below", ctypes.c_double), ("prior", ctypes.c_double), ("octaves", ctypes.c_int32),
                ("same", ctypes.c_double)]


def load_c_learn(folder: Path, prefetch: bool = False):
    """The compiled ``slearn_learn`` of ``bench/c/learn.c`` (with ``-DPREFETCH``), or
    ``None`` without a compiler."""
    compiler = next((c for c in ("cc", "gcc", "clang") if shutil.which(c)), None)
    if compiler is None:
        return None
    library = folder / f"liblearn{'-prefetch' if prefetch else ''}.so"
    subprocess.run([compiler, "-O2", "-ffp-contract=off", *(["-DPREFETCH"] if prefetch else []),
                    "-shared", "-fPIC", "-o", str(library), str(_SOURCE), "-lm"],
                   check=True, capture_output=True)
    lib = ctypes.CDLL(str(library))
    lib.slearn_learn.restype = ctypes.c_int64
    lib.slearn_learn.argtypes = [ctypes.c_void_p] * 15 + [ctypes.c_int64, ctypes.c_int64, ctypes.c_void_p]
    return lib.slearn_learn


def c_library(c_learn, template: PatternLibrary, codes, nodes: int, entries: int):
    """Run the C rule on ``codes``; return a library holding what it built (for export)."""
    out = PatternLibrary(template.max_length, vocabulary=template.vocabulary,
                         has_actions=template.has_actions)
    out.tokens = template.tokens
    out.view_names = list(template.view_names)
    out.tree = context_tree.new_tree(nodes, entries)
    out.mixer = mixer.new_mixer(len(out.view_names), out.max_context)
    out.streams = None
    out._ensure_state()
    tree, streams, mix = out.tree, out.streams, out.mixer
    arrays = [np.ascontiguousarray(a) for a in (codes.action, codes.offsets, codes.view, codes.token)]
    struct = _Tree(*[getattr(tree, name).ctypes.data for name in _TREE_FIELDS],
                   len(tree.node_slots), len(tree.entry_slots))
    params = _Params(len(out.view_names), out.max_context, int(out.has_actions), out.empty_action,
                     out.empty_observation, float(np.exp(-mixer.ETA)), float(np.exp(-mixer.SPREAD)),
                     float(np.log(1.0 / mixer.FALSE_ALARM)),
                     mixer._BELOW, mixer.PRIOR, mixer.OCTAVES,
                     mixer.SAME)
    out.clock_array[0] = c_learn(
        ctypes.byref(struct), mix.weight.ctypes.data, mix.detector.ctypes.data, mix.epoch.ctypes.data,
        mix.calibration.ctypes.data, mix.rounds.ctypes.data, mix.persist.ctypes.data,
        streams.recent.ctypes.data, streams.filled.ctypes.data, streams.held.ctypes.data,
        streams.root.ctypes.data, *(a.ctypes.data for a in arrays), ctypes.c_int64(len(codes)),
        ctypes.c_int64(0), ctypes.byref(params))
    return out


def same_library(a: PatternLibrary, b: PatternLibrary) -> list[str]:
    """The names of the arrays where two libraries differ (empty: byte-identical)."""
    ea, eb = a.export(), b.export()
    diff = [k for k in ea if ea[k].tobytes() != eb[k].tobytes()]
    for name, x, y in zip(a.mixer._fields, a.mixer, b.mixer):
        if np.asarray(x).tobytes() != np.asarray(y).tobytes():
            diff.append(name)
    return diff + (["clock"] if a.clock != b.clock else [])


def measure(name: str, episode, vocabulary, c_learns: dict, repeat: int) -> dict:
    """Encode once; learn with slearn and with C; compare the libraries."""
    template = PatternLibrary(vocabulary=vocabulary)
    started = time.perf_counter()
    codes = template.encode(episode)
    encode_s = time.perf_counter() - started
    result = {}

    def learn_slearn():
        library = PatternLibrary(vocabulary=vocabulary)
        library.tokens = template.tokens
        library.run(codes, learn=True, record=False)
        result["slearn"] = library

    slearn_s = best_seconds(learn_slearn, repeat)
    row = {"stream": name, "steps": len(codes), "events": int(episode.n_events),
           "encode_s": encode_s, "slearn_s": slearn_s, "patterns": len(result["slearn"])}
    size = result["slearn"].tree.size
    nodes, entries = int(size[0]) + 64, int(size[1]) + 64
    for variant, c_learn in c_learns.items():  # "c": the plain loop, "cp": with prefetches

        def learn_c(variant=variant, c_learn=c_learn):
            result[variant] = c_library(c_learn, template, codes, nodes, entries)

        row[f"{variant}_s"] = best_seconds(learn_c, repeat)
        row[f"{variant}_ratio"] = row[f"{variant}_s"] / slearn_s
        row["differences"] = sorted(set(row.get("differences", [])) |
                                    set(same_library(result["slearn"], result[variant])))
    return row


def render(rows: list[dict]) -> str:
    lines = [f"{'stream':<22} {'steps':>10} {'slearn M ev/s':>14} {'C M ev/s':>10} {'slearn/C':>9} "
             f"{'C+prefetch':>11} {'slearn/C+p':>11} {'encode M ev/s':>14}  library"]
    for r in rows:
        c = " ".join(f"{r['events'] / r[f'{v}_s'] / 1e6:{w}.2f} {r[f'{v}_ratio']:{w2}.2f}" if f"{v}_s" in r
                     else f"{'-':>{w}} {'-':>{w2}}" for v, w, w2 in (("c", 10, 9), ("cp", 11, 11)))
        same = ("byte-identical" if not r.get("differences") else "DIFFERS: " + ", ".join(r["differences"])) \
            if "c_s" in r else "-"
        lines.append(f"{r['stream']:<22} {r['steps']:>10,} {r['events'] / r['slearn_s'] / 1e6:14.2f} {c} "
                     f"{r['events'] / r['encode_s'] / 1e6:14.2f}  {same}")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=1_000_000)
    parser.add_argument("--condition", default="delay")
    parser.add_argument("--arm", action="store_true", help="also the 4-joint arm (4 views)")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="slearn-clearn-") as folder:
        c_learns = {v: f for v, f in (("c", load_c_learn(Path(folder))),
                                      ("cp", load_c_learn(Path(folder), prefetch=True))) if f is not None}
        streams = [(f"pointer {args.condition}",
                    simulate(PointerConfig(args.condition, trials=args.trials)).to_episode(),
                    pointer_vocabulary())]
        if args.arm:
            streams.append(("arm 4 joints, all", simulate_arm(ArmConfig(4, args.trials // 4, 0, "all"))
                            .to_episode(), arm_vocabulary(4)))
        rows = [measure(name, episode, vocabulary, c_learns, args.repeat)
                for name, episode, vocabulary in streams]
    print(json.dumps(rows, default=str) if args.json else render(rows))


if __name__ == "__main__":
    main()
