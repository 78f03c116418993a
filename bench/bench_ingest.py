"""Ingest throughput: messages/s and events/s, next to the mcap library's raw rate.

Run: ``python bench/bench_ingest.py`` (uses ``../shared`` logs when present).

For each log: the mcap library's ``make_reader(f).iter_messages()`` (raw, undecoded),
slearn's raw reader (:func:`slearn.mcap_read.iter_messages`), and the whole ingest path
(:func:`slearn.serialize.read_episodes`: read, decode the spec's topics, extract fields,
symbolize, build the episode). Best of three runs.
"""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from slearn.mcap_read import iter_messages
from slearn.serialize import read_episodes
from slearn.spec import Spec, pointer_spec
from slearn.vocabulary import Vocabulary

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data" / "mcap" / "robot"
PR2_SPEC = {"mode": "message", "channel": [
    {"topic": "/joint_states", "field": "position[name=laser_tilt_mount_joint]",
     "role": "observation", "range": [-0.7, 1.1], "count": 12},
    {"topic": "/joint_states", "field": "velocity[name=laser_tilt_mount_joint]",
     "role": "action", "edges": [-0.5, 0.5]},
    {"topic": "/joint_states", "field": "position[name=bl_caster_rotation_joint]",
     "role": "observation", "width": 0.05},
    {"topic": "/base_odometry/odom", "field": "twist.twist.angular.z",
     "role": "observation", "width": 0.01}]}


def best_of(fn, runs: int = 3) -> tuple[float, object]:
    best, result = float("inf"), None
    for _ in range(runs):
        start = time.perf_counter()
        result = fn()
        best = min(best, time.perf_counter() - start)
    return best, result


def write_json_log(path: Path, trials: int) -> None:
    """A pointer-like JSON log: command, position and angle channels, 3 messages per trial."""
    with open(path, "wb") as f:
        writer = Writer(f, compression=CompressionType.ZSTD)
        writer.start()
        schema = writer.register_schema("Thing", "jsonschema", b"{}")
        ids = [writer.register_channel(t, "json", schema)
               for t in ("/pointer/command", "/pointer/position", "/pointer/angle")]
        writer.add_message(ids[1], log_time=0, publish_time=0, data=b'{"position": 1}')
        for i in range(trials):
            t = i * 100_000_000
            writer.add_message(ids[0], log_time=t, publish_time=t,
                               data=json.dumps({"command": "LR"[i % 3 % 2]}).encode())
            writer.add_message(ids[1], log_time=t + 50_000_000, publish_time=t,
                               data=json.dumps({"position": i % 36 + 1}).encode())
            writer.add_message(ids[2], log_time=t + 50_000_000, publish_time=t,
                               data=json.dumps({"angle_deg": i * 0.37 % 360}).encode())
        writer.finish()


def mcap_raw(path: Path) -> int:
    with open(path, "rb") as f:
        return sum(1 for _ in make_reader(f).iter_messages())


def slearn_raw(path: Path) -> int:
    return sum(1 for _ in iter_messages(path))


def slearn_ingest(path: Path, spec: Spec) -> tuple[int, int]:
    [(_, episode, report)] = list(read_episodes([path], spec, Vocabulary()))
    return report.n_messages, episode.n_events


def bench(name: str, path: Path, spec: Spec) -> None:
    t_mcap, n_mcap = best_of(lambda: mcap_raw(path))
    t_raw, n_raw = best_of(lambda: slearn_raw(path))
    t_ingest, (n_read, n_events) = best_of(lambda: slearn_ingest(path, spec))
    print(f"{name}  ({path.stat().st_size / 1e6:.1f} MB, {n_mcap} messages)")
    print(f"  mcap make_reader().iter_messages   {n_mcap / t_mcap:>12,.0f} msg/s")
    print(f"  slearn iter_messages (raw)         {n_raw / t_raw:>12,.0f} msg/s")
    print(f"  slearn read_episodes (decode+spec) {n_read / t_ingest:>12,.0f} msg/s  "
          f"{n_events / t_ingest:>12,.0f} events/s  ({n_read} messages of the spec's topics, "
          f"{n_events} events)")


def main() -> None:
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "pointer_like.mcap"
        write_json_log(path, 100_000)
        bench("JSON log (pointer-like, built in code)", path, pointer_spec())
    pr2_spec = Spec.from_dict(PR2_SPEC)
    for name, rel in (("ROS 2 CDR PR2 log", "ros2_cdr/pr2_pr1012_sensors_ros2.mcap"),
                      ("ROS 1 PR2 log", "ros1/pr2_pr1012_sensors_ros1.mcap")):
        if (SHARED / rel).exists():
            bench(name, SHARED / rel, pr2_spec)
        else:
            print(f"{name}: {SHARED / rel} not available, skipped")


if __name__ == "__main__":
    main()
