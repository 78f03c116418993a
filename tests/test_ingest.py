"""Streaming ingest: the same episodes, vocabulary, warnings and library as the per-message path."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from fixtures import SHARED_MCAP, write_log
from hypothesis import example, given, settings
from hypothesis import strategies as st
from mcap.writer import CompressionType

import slearn.io.ingest as ingest
import slearn.jobs.learn as learn_module
from slearn.core.vocabulary import Vocabulary
from slearn.io.mcap_read import ReadReport
from slearn.io.serialize import RangeCounts, _log_episodes, prepare_vocabulary, read_episodes
from slearn.io.slicing import TimeBound, TimeSlice
from slearn.io.spec import Spec, pointer_spec
from slearn.jobs.learn import learn_files


def write_raw(path, messages, chunk_size=600):
    """``(topic, log_time, payload bytes)`` as JSON channels in small zstd chunks."""
    return write_log(path, messages, chunk_size=chunk_size, compression=CompressionType.ZSTD)


def busy_messages(n, seed, markers=False):
    """Several topics at shared and distinct times, odd values, bad payloads, markers."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        t = int(i // 3) * 1000 + int(rng.integers(0, 2)) * 500
        out.append(("/a", t, json.dumps({"c": "LR"[int(rng.integers(0, 2))], "k": [1, 2]}).encode()))
        x = float(rng.normal(0, 2))
        value = [x, None, "text", True, float("nan"), 10 ** 30, int(x)][int(rng.integers(0, 7))] \
            if rng.random() < 0.3 else x
        out.append(("/s", t + int(rng.integers(0, 2)) * 500, json.dumps({"v": value, "w": [x, -x]}).encode()))
        if rng.random() < 0.05:
            out.append(("/s", t + 500, b'{"v": 1,'))  # does not decode
        out.append(("/c", t, json.dumps({"m": int(rng.integers(0, 3))}).encode()))
        if markers and rng.random() < 0.02:
            out.append(("/slearn/episode", t, b'{"name": "x"}'))
    return out


SPEC = {"mode": "message", "channel": [
    {"topic": "/a", "field": "c", "role": "action"},
    {"topic": "/s", "field": "v", "role": "observation", "width": 0.5},
    {"topic": "/s", "field": "w[1]", "role": "observation", "range": [-2, 2], "count": 7},
    {"topic": "/s", "field": "w[0]", "role": "observation", "range": [-3, 3], "count": 5, "wrap": True},
    {"topic": "/a", "field": "k[5]", "role": "action"},
    {"topic": "/c", "field": "m", "role": "observation", "mode": "change"},
    {"topic": "/s", "field": "v", "role": "observation", "name": "vcat"}]}


def old_read(paths, spec, window=None):
    """The per-message path: whole episodes, the vocabulary and the warnings."""
    vocabulary = prepare_vocabulary(spec, Vocabulary())
    ranges, out = RangeCounts(), []
    for path in paths:
        for name, episode, _, _ in _log_episodes(str(path), spec, vocabulary, ReadReport(str(path)),
                                                 False, window, ranges):
            out.append((name, episode))
    return out, vocabulary, ranges.messages(spec)


def new_read(paths, spec, window=None):
    vocabulary = Vocabulary()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = [(name, episode) for name, episode, _ in read_episodes(paths, spec, vocabulary,
                                                                      window=window)]
    return out, vocabulary, [str(w.message) for w in caught if "outside range" in str(w.message)]


def assert_same(old, new):
    (old_eps, old_vocab, old_warn), (new_eps, new_vocab, new_warn) = old, new
    assert [n for n, _ in old_eps] == [n for n, _ in new_eps]
    for (_, a), (_, b) in zip(old_eps, new_eps):
        assert np.array_equal(a.symbols, b.symbols)
        assert np.array_equal(a.step_offsets, b.step_offsets)
        assert np.array_equal(a.n_actions, b.n_actions)
    assert list(old_vocab.items()) == list(new_vocab.items())
    assert old_warn == new_warn


@pytest.mark.parametrize("mode", ["message", "change", "tick"])
@pytest.mark.parametrize("piece", [3, 1 << 18])
def test_streaming_gives_the_per_message_episodes(tmp_path, monkeypatch, mode, piece):
    monkeypatch.setattr(ingest, "PIECE_EVENTS", piece)
    paths = [write_raw(tmp_path / "a.mcap", busy_messages(400, 1)),
             write_raw(tmp_path / "b.mcap", busy_messages(300, 2, markers=True), chunk_size=300)]
    data = dict(SPEC, mode=mode, **({"tick_ms": 0.0007} if mode == "tick" else {}))
    if mode == "tick":  # every entry is sampled
        data["channel"] = [{k: v for k, v in e.items() if k != "mode"} for e in SPEC["channel"]]
    spec = Spec.from_dict(data)
    old = old_read(paths, spec)
    assert sum(e.n_events for _, e in old[0]) > 500 and len(old[0]) > 3
    assert_same(old, new_read(paths, spec))


def test_streaming_keeps_the_window(tmp_path):
    path = write_raw(tmp_path / "a.mcap", busy_messages(400, 3))
    window = TimeSlice(TimeBound(seconds=1.0e-4), TimeBound(seconds=3.0e-4))
    spec = Spec.from_dict(SPEC)
    assert_same(old_read([path], spec, window), new_read([path], spec, window))


def test_learning_pieces_writes_the_library_of_whole_episodes(tmp_path, monkeypatch):
    paths = [write_raw(tmp_path / "a.mcap", busy_messages(500, 4, markers=True))]
    spec = Spec.from_dict(SPEC)
    out = {}
    for label, piece in (("pieces", 5), ("whole", None)):
        if piece is None:
            def whole(paths, spec, vocabulary, progress=False, window=None):
                prepare_vocabulary(spec, vocabulary)
                for path in paths:
                    report = ReadReport(str(path))
                    for name, episode, _, _ in _log_episodes(str(path), spec, vocabulary, report,
                                                             False, window, None):
                        yield name, episode, report, True, True
            monkeypatch.setattr(learn_module, "read_pieces", whole)
        else:
            monkeypatch.setattr(ingest, "PIECE_EVENTS", piece)
        for scoring in ("adaptive", "literal"):
            target = tmp_path / f"{label}-{scoring}.parquet"
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                learn_files(paths, target, spec=spec, scoring=scoring, max_patterns=300)
            out[label, scoring] = target.read_bytes()
    assert out["pieces", "adaptive"] == out["whole", "adaptive"]
    assert out["pieces", "literal"] == out["whole", "literal"]


def test_pointer_pieces_are_complete_steps(tmp_path, monkeypatch):
    monkeypatch.setattr(ingest, "PIECE_EVENTS", 10)
    messages = [("/pointer/position", 0, b'{"position": 3}')]
    for i in range(100):
        messages += [("/pointer/command", i * 100, json.dumps({"command": "LR"[i % 2]}).encode()),
                     ("/pointer/position", i * 100 + 50, json.dumps({"position": i % 36 + 1}).encode())]
    path = write_raw(tmp_path / "p.mcap", messages)
    from slearn.io.serialize import read_pieces

    pieces = list(read_pieces([path], pointer_spec(), Vocabulary()))
    assert len(pieces) > 5 and pieces[0][3] and pieces[-1][4]
    assert sum(len(p[1]) for p in pieces) == 101
    assert all(len(p[1]) and p[1].n_actions[0] == 1 for p in pieces[1:])


ROBOT_SPECS = [
    ("robot/ros2_cdr/pr2_pr1012_sensors_ros2.mcap", {"mode": "message", "channel": [
        {"topic": "/joint_states", "field": "position[name=laser_tilt_mount_joint]",
         "role": "observation", "range": [-0.7, 1.1], "count": 12},
        {"topic": "/joint_states", "field": "velocity[name=laser_tilt_mount_joint]",
         "role": "action", "edges": [-0.5, 0.5]},
        {"topic": "/joint_states", "field": "position[3]", "role": "observation", "width": 0.05},
        {"topic": "/base_odometry/odom", "field": "twist.twist.angular.z",
         "role": "observation", "width": 0.01},
        {"topic": "/base_odometry/odom", "field": "header.frame_id", "role": "observation"}]}),
    ("robot/ros1/pr2_pr1012_sensors_ros1.mcap", {"mode": "message", "channel": [
        {"topic": "/joint_states", "field": "position[name=laser_tilt_mount_joint]",
         "role": "observation", "width": 0.05},
        {"topic": "/joint_states", "field": "velocity[name=laser_tilt_mount_joint]",
         "role": "action", "edges": [-0.5, 0.5]}]}),
]


@pytest.mark.shared
@pytest.mark.parametrize("rel, spec", ROBOT_SPECS, ids=["ros2", "ros1"])
def test_robot_logs_stream_as_they_read(rel, spec):
    path = SHARED_MCAP / rel
    spec = Spec.from_dict(spec)
    old = old_read([path], spec)
    assert old[0][0][1].n_events > 100
    assert_same(old, new_read([path], spec))


def test_json_batches_never_merge_bad_payloads(tmp_path):
    """Payloads that are not JSON alone but would make a valid array together stay undecodable."""
    bad = [b'{"v": [{}', b'{}]}', b'{"v": 1},{"v": 2}', b'{"v": "a\\"],["}', b'{"v": 3} ',
           b'\xef\xbb\xbf{"v": 4}', b'{"v": "\xc3\xa9"}', b'{"v": 5}']
    messages = [("/s", i * 10, data) for i, data in enumerate(bad * 3)]
    path = write_raw(tmp_path / "bad.mcap", messages)
    spec = Spec.from_dict({"channel": [{"topic": "/s", "field": "v", "role": "observation"}]})
    old_report = ReadReport(str(path))
    vocabulary = prepare_vocabulary(spec, Vocabulary())
    [(_, old, _, _)] = list(_log_episodes(str(path), spec, vocabulary, old_report, False, None, None))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        [(_, new, report)] = list(read_episodes([path], spec, Vocabulary()))
    assert np.array_equal(old.symbols, new.symbols) and len(new.symbols) == 15
    assert report.undecodable == old_report.undecodable == {"/s": 9}
    assert report.first_undecodable == old_report.first_undecodable


def _batch_of_payloads(payloads, gather_bytes, monkeypatch):
    from slearn.io.mcap_read import MessageBatch

    monkeypatch.setattr(ingest, "_GATHER_BYTES", gather_bytes)
    pad = b"#"  # bytes between payloads in the batch's buffer, not theirs
    buf, starts = b"", []
    for data in payloads:
        starts.append(len(buf) + 1)
        buf += pad + data
    starts_a = np.array(starts, np.int64)
    ends = starts_a + np.array([len(p) for p in payloads], np.int64)
    n = len(payloads)
    return MessageBatch(buf, np.zeros(n, np.int64), np.zeros(n, np.uint64), starts_a, ends,
                        np.arange(n, dtype=np.int64), {})


@settings(max_examples=300, deadline=None)
@given(st.lists(st.one_of(st.text('[]{}",:1 a\\', min_size=1, max_size=6),
                          st.recursive(st.none() | st.integers(-9, 9) | st.text("a,\"[", max_size=3),
                                       lambda inner: st.lists(inner, max_size=3)
                                       | st.dictionaries(st.text("ab,", max_size=2), inner, max_size=2),
                                       max_leaves=5).map(json.dumps)),
                max_size=8),
       st.sampled_from([0, 1 << 20]))
@example(["[1", "2],3"], 0)  # an array of the two has two elements, neither payload is JSON
@example(['{"v": [{}', '{}]}', '{"v": 1},{"v": 2}'], 1 << 20)  # one merge, one split: three
@example(['"a', 'b"', '1'], 0)
def test_a_batch_of_json_payloads_parses_as_each_payload_alone_or_not_at_all(texts, gather_bytes):
    """The payloads of a channel's batch are parsed as one JSON array (gathered with numpy
    or joined by slices): the values are those of ``json.loads`` of each payload alone,
    or ``None`` (then each is decoded alone), never values that only the array has."""
    payloads = [t.encode() for t in texts]
    with pytest.MonkeyPatch.context() as monkeypatch:
        batch = _batch_of_payloads(payloads, gather_bytes, monkeypatch)
        joined, sizes = ingest._joined(batch, np.arange(len(payloads)))
        assert joined == b",".join(payloads) and sizes.tolist() == [len(p) for p in payloads]
        got = ingest._json_joined(joined, sizes)
    alone = []
    for data in payloads:
        try:
            alone.append(json.loads(data))
        except ValueError:
            alone.append(ValueError)
    if got is not None:
        assert ValueError not in alone and json.dumps(got) == json.dumps(alone)
    if all(t.startswith(("[", "{", '"', "n", "-")) or t[0].isdigit() for t in texts) \
            and ValueError not in alone and all(t.isascii() for t in texts):
        assert got is not None or any(t != t.strip() for t in texts)  # plain payloads take the fast path


@pytest.mark.parametrize("sample", [50, 1 << 20])
def test_one_read_fits_and_learns_as_two_reads(tmp_path, monkeypatch, sample):
    """Quantile edges, vocabulary and library match fit_spec then read_pieces."""
    import slearn.io.onepass as onepass
    import slearn.io.serialize as serialize

    monkeypatch.setattr(serialize, "_QUANTILE_SAMPLE", sample)
    monkeypatch.setattr(ingest, "BATCH_MESSAGES", 97)
    paths = [write_raw(tmp_path / "a.mcap", busy_messages(400, 5, markers=True)),
             write_raw(tmp_path / "b.mcap", busy_messages(300, 6))]
    data = dict(SPEC, channel=SPEC["channel"] + [
        {"topic": "/s", "field": "v", "role": "observation", "quantiles": 5, "name": "vq"},
        {"topic": "/s", "field": "w[0]", "role": "observation", "quantiles": 3, "name": "wq"}])
    spec = Spec.from_dict(data)
    assert onepass.can_fit_in_one_pass(spec)
    out = {}
    for label in ("one", "two"):
        if label == "two":
            monkeypatch.setattr(learn_module, "can_fit_in_one_pass", lambda spec: False)
        target = tmp_path / f"{label}.parquet"
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            result = learn_files(paths, target, spec=spec)
        out[label] = (target.read_bytes(), sorted(str(w.message) for w in caught), result.n_episodes)
    assert out["one"] == out["two"]
    assert out["one"][2] > 3 and any("outside range" in w for w in out["one"][1])
    assert not list(tmp_path.glob("slearn-fit-*"))


@pytest.mark.parametrize("topics", [None, ["/s", "/c"]])
def test_compiled_record_walk_finds_what_the_python_walk_finds(tmp_path, monkeypatch, topics):
    import slearn.io.mcap_read as mcap_read

    path = write_raw(tmp_path / "a.mcap", busy_messages(300, 7, markers=True), chunk_size=4000)
    runs = []
    for scan_bytes in (1 << 60, 0):
        monkeypatch.setattr(mcap_read, "_SCAN_BYTES", scan_bytes)
        with mcap_read.McapLog(path) as log:
            runs.append([(m.topic, m.log_time_ns, m.data, m.offset) for m in log.iter_messages(topics)])
    assert runs[0] == runs[1] and len(runs[0]) > 500


def test_compiled_record_walk_leaves_damaged_blocks_to_the_python_walk(tmp_path, monkeypatch):
    import slearn.io.mcap_read as mcap_read

    messages = [("/s", i, b'{"v": 1}') for i in range(50)] + [("/s", 2**63, b'{"v": 2}')]
    path = write_raw(tmp_path / "late.mcap", messages, chunk_size=1 << 20)
    monkeypatch.setattr(mcap_read, "_SCAN_BYTES", 0)
    with mcap_read.McapLog(path) as log:
        assert list(log.iter_messages()) == []
        assert "past the year 2262" in log.report.describe()


def test_ros2_payloads_laid_out_alike_or_not_stream_as_they_read(tmp_path, monkeypatch):
    """A ROS 2 channel whose payloads change layout now and then (joint names, array
    lengths, byte order, a payload that does not decode) reads the same episodes,
    vocabulary and undecodable count through the column path as message by message."""
    from mcap.writer import Writer
    from test_cdr import JOINTS_SCHEMA, _payload

    rng = np.random.default_rng(3)
    monkeypatch.setattr(ingest, "BATCH_MESSAGES", 50)
    path = tmp_path / "joints.mcap"
    with open(path, "wb") as f:
        writer = Writer(f, chunk_size=2000)
        writer.start(profile="ros2", library="slearn-tests")
        schema = writer.register_schema("my_msgs/Joints", "ros2msg", JOINTS_SCHEMA)
        channel = writer.register_channel("/joints", "cdr", schema)
        for i in range(400):
            names = ["a", "b"] if rng.random() < 0.8 else ["b", "a", "c"]
            data = _payload(names, rng.normal(0, 1, len(names)).round(2).tolist(),
                            rng.normal(0, 1, int(rng.integers(1, 3))).tolist(), "<" if rng.random() < 0.9 else ">")
            if rng.random() < 0.03:
                data = data[:-5]  # does not decode
            writer.add_message(channel, log_time=i * 1000, publish_time=i * 1000, data=data)
        writer.finish()
    spec = Spec.from_dict({"mode": "message", "channel": [
        {"topic": "/joints", "field": "position[name=a]", "role": "observation", "width": 0.25},
        {"topic": "/joints", "field": "velocity[1]", "role": "action", "edges": [0.0]},
        {"topic": "/joints", "field": "header.frame_id", "role": "observation"}]})
    old = old_read([path], spec)
    assert old[0][0][1].n_events > 600
    assert_same(old, new_read([path], spec))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        [(_, _, report)] = list(read_episodes([path], spec, Vocabulary()))
    assert 0 < report.undecodable["/joints"] < 30
