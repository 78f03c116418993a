"""Bags: a rosbag2 folder split into files is one episode; ROS 2 .db3 and ROS 1 .bag files
are read like MCAP logs. Every bag is written here with rosbags."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from fixtures import SHARED_MCAP
from rosbags.typesys import Stores, get_typestore  # noqa: E402

from slearn.cli import EXIT_TRUNCATED, main
from slearn.core.vocabulary import Vocabulary
from slearn.errors import InputError
from slearn.io.bags import log_record, open_log
from slearn.io.serialize import read_episodes
from slearn.io.spec import Spec
from slearn.recorders.pointer import PointerConfig, simulate

SHARED = SHARED_MCAP / "robot" / "rosbag2_tests"
SPEC = {"channel": [{"topic": "/cmd", "field": "data", "role": "action", "values": [-1, 1]},
                    {"topic": "/pos", "field": "data", "role": "observation"}]}
T0 = 1_700_000_000_000_000_000


def pointer_messages(trials: int, seed: int = 0) -> list[tuple[str, int, int]]:
    """``(topic, log time, value)`` of a pointer: command at k*100 ms, position 50 ms later."""
    run = simulate(PointerConfig("simple", trials, seed))
    out = [("/pos", T0, int(run.positions[0]))]
    for k, (c, p) in enumerate(zip(run.commands.tolist(), run.positions[1:].tolist())):
        out += [("/cmd", T0 + (k + 1) * 100_000_000, 1 if c else -1),
                ("/pos", T0 + (k + 1) * 100_000_000 + 50_000_000, int(p))]
    return out


def write_rosbag2(folder: Path, messages, storage: str) -> Path:
    from rosbags.rosbag2 import StoragePlugin, Writer

    store = get_typestore(Stores.LATEST)
    types = {"/cmd": "std_msgs/msg/Int8", "/pos": "std_msgs/msg/Int32"}
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(folder, version=9, storage_plugin=plugin) as writer:
        # channels numbered in the order the messages first show their topics, as a recorder does
        connections = {t: writer.add_connection(t, types[t], typestore=store)
                       for t in dict.fromkeys(topic for topic, _, _ in messages)}
        for topic, time_ns, value in messages:
            message = store.types[types[topic]](data=value)
            writer.write(connections[topic], time_ns, store.serialize_cdr(message, types[topic]))
    return folder


def write_ros1_bag(path: Path, messages) -> Path:
    from rosbags.rosbag1 import Writer

    store = get_typestore(Stores.ROS1_NOETIC)
    types = {"/cmd": "std_msgs/msg/Int8", "/pos": "std_msgs/msg/Int32"}
    writer = Writer(path)
    writer.chunk_threshold = 4096  # several chunks, so a cut file keeps whole ones
    with writer:
        connections = {t: writer.add_connection(t, msgtype, typestore=store) for t, msgtype in types.items()}
        for topic, time_ns, value in messages:
            message = store.types[types[topic]](data=value)
            writer.write(connections[topic], time_ns, store.serialize_ros1(message, types[topic]))
    return path


def split_folder(tmp_path: Path, messages, half: int | None = None) -> Path:
    """A rosbag2 MCAP bag split into two files, as `ros2 bag record --max-bag-size` leaves it
    (the second file starts at message ``half``, by default the middle one)."""
    half = len(messages) // 2 if half is None else half
    parts = [write_rosbag2(tmp_path / f"part{i}", chunk, "mcap")
             for i, chunk in enumerate((messages[:half], messages[half:]))]
    folder = tmp_path / "split"
    folder.mkdir()
    for i, part in enumerate(parts):
        (part / f"part{i}.mcap").rename(folder / f"split_{i}.mcap")
    (folder / "metadata.yaml").write_text(
        "rosbag2_bagfile_information:\n  version: 9\n  storage_identifier: mcap\n"
        "  compression_format: ''\n  compression_mode: ''\n"
        "  relative_file_paths:\n  - split_0.mcap\n  - split_1.mcap\n")
    return folder


def steps_of(paths, spec=SPEC):
    vocabulary = Vocabulary()
    read = list(read_episodes(paths, Spec.from_dict(spec), vocabulary))
    return [(name, [([vocabulary.name(a)[1] for a in acts], [vocabulary.name(o)[1] for o in obs])
                    for acts, obs in episode.steps()]) for name, episode, _ in read]


def test_a_split_rosbag2_folder_is_one_episode(tmp_path):
    messages = pointer_messages(300)
    folder = split_folder(tmp_path, messages)
    whole = write_rosbag2(tmp_path / "whole", messages, "mcap")
    [(name, steps)] = steps_of([folder])
    assert name == str(folder) and len(steps) == 301
    assert steps == steps_of([whole])[0][1]
    assert steps_of([folder / "metadata.yaml"])[0][1] == steps  # the metadata file names the bag
    with open_log(folder) as log:
        assert log.profile == "ros2" and {c.topic for c in log.channels.values()} == {"/cmd", "/pos"}
        assert len(log.channels) == 2  # one channel per topic across the files
        assert log.time_range() == (T0, messages[-1][1])
        [(name, record)] = [(n, r) for n, r in log.iter_metadata() if n == "rosbag2.metadata_yaml"]
        assert "split_1.mcap" in record["metadata.yaml"]
    assert log_record(folder)["size_bytes"] == sum(f.stat().st_size for f in folder.iterdir())


def test_a_split_bag_whose_files_number_channels_differently_keeps_each_message_s_topic(tmp_path):
    """Each file of a split bag numbers its channels in the order it first saw them (rosbag2's
    own test bag `wbag` does): the second file here starts with a command, so /cmd is
    channel 1 there and /pos channel 1 in the first. Messages must keep their own topic."""
    from slearn.io.mcap_read import McapLog

    messages = pointer_messages(300)
    assert messages[301][0] == "/cmd" and messages[0][0] == "/pos"
    folder = split_folder(tmp_path, messages, half=301)
    numbering = [{c.topic: c.id for c in McapLog(folder / f"split_{i}.mcap").channels.values()}
                 for i in range(2)]
    assert numbering[0] != numbering[1]
    whole = write_rosbag2(tmp_path / "whole", messages, "mcap")
    assert steps_of([folder])[0][1] == steps_of([whole])[0][1]
    with open_log(folder) as log:
        got = [(m.channel.topic, m.log_time_ns) for m in log.iter_messages(["/pos"])]
    assert got == [(t, time) for t, time, _ in messages if t == "/pos"]


@pytest.mark.parametrize("kind", ["db3", "db3 folder", "ros1"])
def test_db3_and_ros1_bags_read_like_mcap(tmp_path, kind):
    messages = pointer_messages(200)
    if kind == "ros1":
        path = write_ros1_bag(tmp_path / "p.bag", messages)
    else:
        folder = write_rosbag2(tmp_path / "p", messages, "sqlite3")
        path = folder if kind == "db3 folder" else folder / "p.db3"
    [(name, steps)] = steps_of([path])
    assert name == str(path)
    assert steps[:2] == [([], [messages[0][2]]), ([messages[1][2]], [messages[2][2]])]
    assert len(steps) == 201


def test_the_cli_learns_replays_and_describes_bags(tmp_path):
    train = write_ros1_bag(tmp_path / "train.bag", pointer_messages(2000, seed=0))
    test = split_folder(tmp_path, pointer_messages(500, seed=1))
    spec = tmp_path / "spec.toml"
    spec.write_text('[[channel]]\ntopic = "/cmd"\nfield = "data"\nrole = "action"\n'
                    '[[channel]]\ntopic = "/pos"\nfield = "data"\nrole = "observation"\n')
    library = tmp_path / "lib.parquet"
    learned = CliRunner().invoke(main, ["learn", str(train), "--spec", str(spec), "-o", str(library), "--json"])
    assert learned.exit_code == 0, learned.output
    assert json.loads(learned.stdout)["episodes"] == 1
    replayed = CliRunner().invoke(main, ["replay", str(library), str(test), "--json", "-q"])
    assert replayed.exit_code == 0, replayed.output
    doc = json.loads(replayed.stdout)
    assert doc["totals"]["accuracy"] == 1.0 and doc["baselines"]["fit"] == "training"
    info = CliRunner().invoke(main, ["info", str(train), str(test), "--json"])
    assert info.exit_code == 0, info.output
    ros1, folder = json.loads(info.stdout)["files"]
    assert ros1["profile"] == "ros1" and folder["profile"] == "ros2"
    pos = next(c for c in folder["channels"] if c["topic"] == "/pos")
    assert pos["count"] == 501 and pos["schema"] == "std_msgs/msg/Int32"


def test_a_damaged_db3_keeps_what_was_read_or_is_refused_in_one_line(tmp_path):
    folder = write_rosbag2(tmp_path / "p", pointer_messages(300), "sqlite3")
    db3 = folder / "p.db3"
    data = db3.read_bytes()
    db3.write_bytes(data[: len(data) // 2])
    result = CliRunner().invoke(main, ["info", str(db3)])
    assert result.exit_code in (1, EXIT_TRUNCATED)
    assert "Traceback" not in result.output and str(db3) in result.stderr


def test_a_folder_without_metadata_is_refused(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="not a rosbag2 bag"):
        open_log(tmp_path / "empty")


@pytest.mark.shared
def test_rosbag2_own_split_bags_are_one_log():
    folder = SHARED / "rosbag2_py" / "test" / "resources" / "mcap" / "wbag"
    with open_log(folder) as log:
        n = sum(1 for _ in log.iter_messages())
        assert n == 6074 and len({c.topic for c in log.channels.values()}) == 8
        times = [m.log_time_ns for m in log.iter_messages()]
    assert times == sorted(times) and np.unique(times).size > 1


def test_a_ros1_bag_cut_short_is_salvaged_in_log_time_order(tmp_path):
    messages = pointer_messages(1500)
    whole = write_ros1_bag(tmp_path / "whole.bag", messages)
    cut = tmp_path / "cut.bag"
    cut.write_bytes(whole.read_bytes()[: whole.stat().st_size * 2 // 3])
    with open_log(cut) as log:
        salvaged = [(m.topic, m.log_time_ns) for m in log.iter_messages()]
        assert log.report.truncated and "runs past the end of the file" in log.report.describe()
    assert 0 < len(salvaged) < len(messages)
    assert salvaged == [(t, time_ns) for t, time_ns, _ in messages[:len(salvaged)]]
    spec = tmp_path / "spec.toml"
    spec.write_text('[[channel]]\ntopic = "/cmd"\nfield = "data"\nrole = "action"\n'
                    '[[channel]]\ntopic = "/pos"\nfield = "data"\nrole = "observation"\n')
    learned = CliRunner().invoke(main, ["learn", str(cut), "--spec", str(spec), "-o",
                                        str(tmp_path / "lib.parquet"), "--json"])
    assert learned.exit_code == EXIT_TRUNCATED and "truncated or corrupt log" in learned.stderr
    assert json.loads(learned.stdout)["steps"] > 500
    not_a_bag = tmp_path / "x.bag"
    not_a_bag.write_bytes(b"hello")
    with pytest.raises(InputError, match="cannot be read as a ROS 1 bag"):
        open_log(not_a_bag)


def test_a_log_is_hashed_once_while_it_is_unchanged(tmp_path, monkeypatch):
    """Provenance hashes whole logs; a replay of a library's own training log (``--split``)
    asks for it as a training log and as a held-out log: one read. A log rewritten (new
    bytes, new time) is read again and gets its new digest."""
    import hashlib
    import os

    import slearn.io.bags as bags

    reads = []
    real_open = open
    monkeypatch.setattr(bags, "open", lambda path, *a, **k: reads.append(path) or real_open(path, *a, **k),
                        raising=False)
    log = tmp_path / "a.mcap"
    log.write_bytes(b"first bytes")
    first = log_record(log)
    assert log_record(log) == first and reads == [str(log)]
    log.write_bytes(b"other bytes, longer")
    os.utime(log, ns=(log.stat().st_atime_ns, log.stat().st_mtime_ns + 10**9))
    assert log_record(log)["sha256"] == hashlib.sha256(b"other bytes, longer").hexdigest() != first["sha256"]
    assert len(reads) == 2
    with pytest.raises(InputError, match="cannot read"):
        log_record(tmp_path / "gone.mcap")
