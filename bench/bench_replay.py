"""Replay throughput: predictions per second, for the evaluation core and the whole command.

- ``core``: :func:`slearn.replay.evaluation.evaluate` on in-memory pointer episodes (the
  library's predictions, both baselines, per-channel, windowed and confusion scores), in
  frozen and online mode; compiled kernels warmed up first.
- ``command``: ``slearn replay LIB LOG --json`` in-process on a recorded pointer MCAP log
  (library loading, reading and binning the log, baselines counted on the library's
  training logs, evaluation, JSON), and the same with ``--write-mcap``.

The library is learned on pointer ``simple`` seeds 0-2 (``--train-trials`` each); the
held-out episode is seed 3 (``--trials``). Target: >= 200,000 predictions/s for the core.

Run: ``python bench/bench_replay.py [--trials 200000] [--train-trials 10000] [--json]``.
"""

from __future__ import annotations

import argparse
import io
import json
import sys
import tempfile
import time
from contextlib import redirect_stdout
from pathlib import Path

from slearn.core.library import PatternLibrary
from slearn.recorders.pointer import PointerConfig, pointer_vocabulary, simulate
from slearn.recorders.record_pointer import record_pointer
from slearn.replay.baselines import Baselines
from slearn.replay.evaluation import evaluate


def _train(train_trials: int) -> tuple[PatternLibrary, Baselines]:
    library = PatternLibrary(vocabulary=pointer_vocabulary())
    baselines = Baselines(library)
    for seed in range(3):
        episode = simulate(PointerConfig("simple", trials=train_trials, seed=seed)).to_episode()
        codes = library.encode(episode)
        library.run(codes, learn=True, record=False)
        baselines.learn(codes)
    return library, baselines


def bench_core(trials: int, train_trials: int, condition: str, online: bool) -> dict:
    """Predictions/s of :func:`evaluate` on one in-memory episode (best of 3)."""
    episode = simulate(PointerConfig(condition, trials=trials, seed=3,
                                     switch_trial=trials // 2)).to_episode()
    best = None
    for _ in range(3):
        library, baselines = _train(train_trials)
        result = evaluate(library, [("held-out", episode, None)], pointer_vocabulary(),
                          online=online, baselines=baselines)
        best = result if best is None or result.elapsed_s < best.elapsed_s else best
    return {"what": f"core {condition} {'online' if online else 'frozen'}",
            "predictions": best.predictions, "seconds": round(best.elapsed_s, 4),
            "predictions_per_s": round(best.predictions_per_s), "accuracy": round(best.accuracy, 4)}


def bench_predictor(trials: int, train_trials: int, online: bool) -> dict:
    """Predictions/s of the library's own run (the floor of the core; best of 3)."""
    episode = simulate(PointerConfig("simple", trials=trials, seed=3)).to_episode()
    best = None
    for _ in range(3):
        library, _ = _train(train_trials)
        started = time.perf_counter()
        codes = library.encode(episode)
        reports = library.run(codes, learn=online, record=True)
        seconds = time.perf_counter() - started
        best = (seconds, codes, reports) if best is None or seconds < best[0] else best
    seconds, codes, reports = best
    predicted = reports.context
    correct = reports.predicted[predicted] == codes.token[predicted]
    return {"what": f"library.run alone simple {'online' if online else 'frozen'}",
            "predictions": int(predicted.sum()), "seconds": round(seconds, 4),
            "predictions_per_s": round(int(predicted.sum()) / seconds),
            "accuracy": round(float(correct.mean()), 4)}


def bench_command(trials: int, train_trials: int, folder: Path, annotate: bool) -> dict:
    """Predictions/s of the whole ``slearn replay`` command on a recorded log (second run)."""
    from slearn.cli import main
    from slearn.jobs.learn import learn_files

    library_path, log = folder / "library.parquet", folder / "held_out.mcap"
    if not library_path.exists():
        training = [folder / f"train{seed}.mcap" for seed in range(3)]
        for seed, path in enumerate(training):
            record_pointer(PointerConfig("simple", trials=train_trials, seed=seed), path)
        record_pointer(PointerConfig("simple", trials=trials, seed=3), log)
        learn_files(training, library_path)
    args = ["replay", str(library_path), str(log), "--json", "--quiet"]
    if annotate:
        args += ["--write-mcap", str(folder / "annotated.mcap"), "--force"]
    for _ in range(2):  # the first run loads compiled kernels
        started = time.perf_counter()
        with redirect_stdout(io.StringIO()) as out:
            try:
                main.main(args, standalone_mode=False)
            except SystemExit:
                pass
        seconds = time.perf_counter() - started
    doc = json.loads(out.getvalue())
    what = "command --write-mcap" if annotate else "command"
    return {"what": what, "predictions": doc["speed"]["predictions"], "seconds": round(seconds, 4),
            "predictions_per_s": round(doc["speed"]["predictions"] / seconds),
            "accuracy": doc["totals"]["accuracy"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=200_000, help="held-out trials (core)")
    parser.add_argument("--command-trials", type=int, default=50_000, help="held-out trials (command)")
    parser.add_argument("--train-trials", type=int, default=10_000, help="trials per training seed")
    parser.add_argument("--json", action="store_true", help="print one JSON document")
    args = parser.parse_args()
    rows = [bench_predictor(args.trials, args.train_trials, False),
            bench_predictor(args.trials, args.train_trials, True),
            bench_core(args.trials, args.train_trials, "simple", False),
            bench_core(args.trials, args.train_trials, "simple", True),
            bench_core(args.trials, args.train_trials, "error", False),
            bench_core(args.trials, args.train_trials, "reversal", True)]
    with tempfile.TemporaryDirectory() as tmp:
        rows.append(bench_command(args.command_trials, args.train_trials, Path(tmp), False))
        rows.append(bench_command(args.command_trials, args.train_trials, Path(tmp), True))
    if args.json:
        print(json.dumps(rows, indent=2))
        return
    print(f"{'what':<34} {'predictions':>12} {'seconds':>9} {'predictions/s':>14} {'accuracy':>9}")
    for r in rows:
        print(f"{r['what']:<34} {r['predictions']:>12,} {r['seconds']:>9.3f} "
              f"{r['predictions_per_s']:>14,} {r['accuracy']:>9.4f}")
    sys.stdout.flush()


if __name__ == "__main__":
    main()
