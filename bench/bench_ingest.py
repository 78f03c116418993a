"""Ingest throughput against mcap's own decoder, and the memory of learning long logs.

Run: ``python bench/bench_ingest.py`` (add ``--rss`` for the memory figures; uses
``../shared`` logs when present).

Speed, per log, best of ``--runs`` runs, each figure also as a ratio to the anchor measured
in the same run: the anchor is the mcap library's ``iter_decoded_messages`` over the spec's
topics (JSON through ``json.loads``, ROS 2 through mcap-ros2-support); ``ingest`` is
:func:`slearn.io.serialize.read_episodes` (read, decode, extract the spec's fields, symbolize,
build the steps); ``learn`` is :func:`slearn.jobs.learn.learn_files` (fit, read, learn, save the
library; kernels warm). Logs: a JSON pointer log (``--trials`` trials, written in code) and
the PR2 ROS 2 log repeated ``--copies`` times (its JointState and Odometry channels).

The PR2 log is also learned with quantile bins (fitted and learned in one read of the log).

Memory (``--rss``): peak RSS of ``slearn learn`` in a fresh process on pointer logs of
``--rss-messages`` messages and a tenth of that (in chunks of 20,000 trials), on a tiny
log (what the process takes before any data), on a log whose chunks all start at log
time 0, and on one whose 3,000,000 messages are all in a single chunk (read with
``SLEARN_MAX_CHUNK_MB=2048``: the default limit skips a chunk that large).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from mcap.decoder import DecoderFactory
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

sys.path.insert(0, str(Path(__file__).resolve().parent))

from ingest_logs import write_pointer_log  # noqa: E402

from slearn.core.vocabulary import Vocabulary  # noqa: E402
from slearn.io.serialize import read_episodes  # noqa: E402
from slearn.io.spec import Spec, pointer_spec  # noqa: E402
from slearn.jobs.learn import learn_files  # noqa: E402

SHARED = next((p / "shared" / "data" / "mcap" for p in Path(__file__).resolve().parents[1:]
               if (p / "shared" / "data" / "mcap").is_dir()), Path("shared"))  # ../shared, or above
PR2 = SHARED / "robot" / "ros2_cdr" / "pr2_pr1012_sensors_ros2.mcap"
PR2_SPEC = {"mode": "message", "channel": [
    {"topic": "/joint_states", "field": "position[name=laser_tilt_mount_joint]",
     "role": "observation", "range": [-0.7, 1.1], "count": 12},
    {"topic": "/joint_states", "field": "velocity[name=laser_tilt_mount_joint]",
     "role": "action", "edges": [-0.5, 0.5]},
    {"topic": "/joint_states", "field": "position[name=bl_caster_rotation_joint]",
     "role": "observation", "width": 0.05},
    {"topic": "/base_odometry/odom", "field": "twist.twist.angular.z",
     "role": "observation", "width": 0.01}]}


class JsonDecoderFactory(DecoderFactory):
    """mcap has no JSON decoder of its own: ``json.loads`` for ``json`` channels."""

    def decoder_for(self, message_encoding, schema):
        return json.loads if message_encoding == "json" else None


def best_of(fn, runs: int) -> tuple[float, object]:
    best, result = float("inf"), None
    for _ in range(runs):
        start = time.perf_counter()
        result = fn()
        best = min(best, time.perf_counter() - start)
    return best, result


def mcap_decoded(path: Path, topics: list[str], factory) -> int:
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[factory])
        return sum(1 for _ in reader.iter_decoded_messages(topics=topics))


def slearn_ingest(path: Path, spec: Spec) -> tuple[int, int]:
    [(_, episode, report)] = list(read_episodes([path], spec, Vocabulary()))
    return report.n_messages, episode.n_events


def slearn_learn(path: Path, spec: Spec, out: Path) -> int:
    return learn_files([path], out, spec=spec, overwrite=True).n_events


def write_repeated(source: Path, path: Path, copies: int) -> None:
    """``source`` written ``copies`` times in a row (log times shifted past the previous copy)."""
    with open(source, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        messages = [(channel, m) for _, channel, m in reader.iter_messages()]
    span = summary.statistics.message_end_time - summary.statistics.message_start_time + 1
    with open(path, "wb") as f:
        writer = Writer(f, compression=CompressionType.ZSTD)
        writer.start(profile="ros2", library="slearn-bench")
        ids = {}
        for sid, schema in summary.schemas.items():
            ids[("s", sid)] = writer.register_schema(schema.name, schema.encoding, schema.data)
        for cid, channel in summary.channels.items():
            ids[cid] = writer.register_channel(channel.topic, channel.message_encoding,
                                               ids[("s", channel.schema_id)], channel.metadata)
        for k in range(copies):
            for channel, m in messages:
                writer.add_message(ids[channel.id], m.log_time + k * span, m.data,
                                   m.publish_time + k * span, m.sequence)
        writer.finish()


def bench(name: str, path: Path, spec: Spec, factory, runs: int, folder: Path,
          quantile_spec: Spec | None = None) -> None:
    topics = spec.topics()
    slearn_ingest(path, spec)  # compile the kernels first (the record walk of large chunks)
    t_anchor, n_anchor = best_of(lambda: mcap_decoded(path, topics, factory), runs)
    t_ingest, (n_read, n_events) = best_of(lambda: slearn_ingest(path, spec), runs)
    slearn_learn(path, spec, folder / "warm.parquet")  # compile the kernels first
    t_learn, _ = best_of(lambda: slearn_learn(path, spec, folder / "lib.parquet"), runs)
    figures = [("slearn ingest (read_episodes)", t_ingest), ("slearn learn (learn_files)", t_learn)]
    if quantile_spec is not None:
        t_fit, _ = best_of(lambda: slearn_learn(path, quantile_spec, folder / "q.parquet"), runs)
        figures.append(("slearn learn, quantile bins", t_fit))
        import slearn.jobs.learn

        one_read = slearn.jobs.learn.can_fit_in_one_pass
        slearn.jobs.learn.can_fit_in_one_pass = lambda spec: False  # fit_spec, then a second read
        try:
            t_two, _ = best_of(lambda: slearn_learn(path, quantile_spec, folder / "q2.parquet"), runs)
        finally:
            slearn.jobs.learn.can_fit_in_one_pass = one_read
        figures.append(("  same, fitted in a read of its own", t_two))
    anchor = n_anchor / t_anchor
    print(f"{name}: {path.stat().st_size / 1e6:.1f} MB, {n_read:,} messages of the spec's "
          f"topics, {n_events:,} events")
    print(f"  mcap iter_decoded_messages (anchor)  {anchor:>10,.0f} msg/s  1.00x")
    for label, seconds in figures:
        rate = n_read / seconds
        print(f"  {label:<36} {rate:>10,.0f} msg/s  {rate / anchor:.2f}x")
    sys.stdout.flush()


# The child reports its own high-water mark (VmHWM counts from its exec; ru_maxrss of a
# child also counts the parent's pages it was forked with, and this process is large).
_REPORT_PEAK = ("import atexit, sys\n"
                "def peak():\n"
                "    for line in open('/proc/self/status'):\n"
                "        if line.startswith('VmHWM:'):\n"
                "            sys.stderr.write('PEAK_KB ' + line.split()[1] + '\\n')\n"
                "atexit.register(peak)\n"
                "from slearn.cli import main\n"
                "sys.argv = ['slearn'] + sys.argv[1:]\n"
                "main()\n")


def peak_rss_mb(args: list[str], env: dict | None = None) -> tuple[float, float, int]:
    """Peak RSS (MB) and seconds of ``slearn ARGS`` in a fresh process, and its exit code."""
    start = time.perf_counter()
    child = subprocess.run([sys.executable, "-c", _REPORT_PEAK, *args], stdout=subprocess.DEVNULL,
                           stderr=subprocess.PIPE, text=True,
                           env=None if env is None else {**os.environ, **env})
    seconds = time.perf_counter() - start
    peaks = [int(line.split()[1]) for line in child.stderr.splitlines() if line.startswith("PEAK_KB ")]
    return (peaks[-1] / 1024 if peaks else float("nan")), seconds, child.returncode


def rss(folder: Path, messages: int) -> None:
    print("peak RSS of `slearn learn LOG -o lib.parquet` (fresh process):")
    cases = [(1_000, "chunked"), (messages // 10, "chunked"), (messages, "chunked"),
             (messages // 10, "time0"), (3_000_000, "one_chunk")]
    for n, layout in cases:
        log = folder / f"pointer_{layout}_{n}.mcap"
        written = write_pointer_log(log, n // 2, layout)
        env = {"SLEARN_MAX_CHUNK_MB": "2048"} if layout == "one_chunk" else None
        mb, seconds, code = peak_rss_mb(["learn", str(log), "-o", str(folder / "rss.parquet"),
                                         "--force"], env)
        print(f"  {written:>12,} messages, {layout:<9} ({log.stat().st_size / 1e6:6.1f} MB): "
              f"{mb:7.0f} MB peak RSS, {seconds:6.1f} s, exit {code}")
        sys.stdout.flush()
        log.unlink()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=100_000)
    parser.add_argument("--copies", type=int, default=50)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--rss", action="store_true", help="measure peak RSS too")
    parser.add_argument("--rss-messages", type=int, default=10_000_000)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        log = folder / "pointer.mcap"
        write_pointer_log(log, args.trials)
        bench("JSON pointer log", log, pointer_spec(), JsonDecoderFactory(), args.runs, folder)
        if PR2.exists():
            from mcap_ros2.decoder import DecoderFactory as Ros2DecoderFactory

            log = folder / "pr2_x.mcap"
            write_repeated(PR2, log, args.copies)
            quantiles = {**PR2_SPEC, "channel": [
                {k: v for k, v in c.items() if k not in ("range", "count", "width", "edges")}
                | {"quantiles": 8} for c in PR2_SPEC["channel"]]}
            bench(f"ROS 2 PR2 log x{args.copies}", log, Spec.from_dict(PR2_SPEC),
                  Ros2DecoderFactory(), args.runs, folder, Spec.from_dict(quantiles))
        else:
            print(f"ROS 2 PR2 log: {PR2} not available, skipped")
        if args.rss:
            rss(folder, args.rss_messages)


if __name__ == "__main__":
    main()
