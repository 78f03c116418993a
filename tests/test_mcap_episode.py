"""The MCAP episode writer and the pointer recording: content, atomicity, partial files."""

import json

import pytest
from mcap.reader import NonSeekingReader, make_reader

from slearn import __version__
from slearn.errors import InputError, SlearnError
from slearn.recorders.mcap_episode import EpisodeWriter, stamp
from slearn.recorders.pointer import PointerConfig, simulate
from slearn.recorders.record_pointer import TRIAL_NS, record_pointer, write_pointer_mcap

SCHEMA = {"type": "object", "properties": {"value": {"type": "integer"}}}


def _read(path):
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
        messages = [(channel.topic, message.log_time, json.loads(message.data))
                    for _, channel, message in reader.iter_messages(log_time_order=False)]
    return summary, metadata, messages


@pytest.fixture(scope="module")
def pointer_file(tmp_path_factory):
    run = simulate(PointerConfig("error", trials=500, seed=3))
    path = tmp_path_factory.mktemp("rec") / "pointer.mcap"
    return run, write_pointer_mcap(run, path), path


def test_pointer_file_has_the_channels_and_schemas(pointer_file):
    _, _, path = pointer_file
    summary, _, _ = _read(path)
    channels = {c.topic: c for c in summary.channels.values()}
    assert set(channels) == {"/pointer/command", "/pointer/position", "/pointer/angle"}
    assert all(c.message_encoding == "json" for c in channels.values())
    schemas = {summary.schemas[c.schema_id].name: summary.schemas[c.schema_id]
               for c in channels.values()}
    assert set(schemas) == {"slearn.pointer.Command", "slearn.pointer.Position",
                            "slearn.pointer.Angle"}
    assert all(s.encoding == "jsonschema" for s in schemas.values())
    position_schema = json.loads(schemas["slearn.pointer.Position"].data)
    assert position_schema["properties"]["position"]["maximum"] == 36
    assert channels["/pointer/command"].metadata["role"] == "action"


def test_pointer_file_messages_match_the_run(pointer_file):
    run, result, path = pointer_file
    summary, _, messages = _read(path)
    by_topic = {}
    for topic, log_time_ns, payload in messages:
        by_topic.setdefault(topic, []).append((log_time_ns, payload))
    commands, positions = by_topic["/pointer/command"], by_topic["/pointer/position"]
    angles = by_topic["/pointer/angle"]
    assert (len(commands), len(positions), len(angles)) == (500, 501, 501)
    assert result.messages == {"/pointer/command": 500, "/pointer/position": 501,
                               "/pointer/angle": 501}
    assert summary.statistics.message_count == 1502
    assert [p["command"] for _, p in commands] == ["LR"[c] for c in run.commands]
    assert [p["position"] for _, p in positions] == run.positions.tolist()
    assert [p["angle_deg"] for _, p in angles] == run.angles.tolist()
    assert [t for t, _ in commands] == [i * TRIAL_NS for i in range(500)]
    assert [t for t, _ in positions] == [0] + [i * TRIAL_NS + TRIAL_NS // 2 for i in range(500)]


def test_pointer_file_metadata(pointer_file):
    _, result, path = pointer_file
    _, metadata, _ = _read(path)
    record = metadata["slearn.pointer"]
    assert record["condition"] == "error" and record["seed"] == "3"
    assert record["trials"] == "500" and record["error_deg"] == "5.0"
    assert record["delay_prob"] == "0.5" and record["switch_trial"] == "5000"
    assert record["slearn_version"] == __version__
    assert result.size_bytes == path.stat().st_size


def test_scramble_metadata_records_the_permutation(tmp_path):
    config = PointerConfig("scramble", trials=100, switch_trial=50)
    record_pointer(config, tmp_path / "s.mcap")
    _, metadata, _ = _read(tmp_path / "s.mcap")
    labels = [int(x) for x in metadata["slearn.pointer"]["sensor_labels_after_switch"].split()]
    assert sorted(labels) == list(range(1, 37))


def test_existing_target_needs_overwrite(tmp_path):
    path = tmp_path / "p.mcap"
    path.write_bytes(b"keep me")
    run = simulate(PointerConfig("simple", trials=10))
    with pytest.raises(InputError, match="already exists"):
        write_pointer_mcap(run, path)
    assert path.read_bytes() == b"keep me"
    write_pointer_mcap(run, path, overwrite=True)
    assert _read(path)[0].statistics.message_count == 32


def test_missing_folder_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        with EpisodeWriter(tmp_path / "no" / "x.mcap"):
            pass


def _write_some(out, n):
    channel = out.register_channel("/counter", "test.Counter", SCHEMA)
    for i in range(n):
        out.write(channel, i * 1000, {"value": i})
    return channel


def test_exception_leaves_the_target_untouched_and_no_temp_file(tmp_path):
    path = tmp_path / "e.mcap"
    path.write_bytes(b"old")
    with pytest.raises(RuntimeError, match="loop failed"):
        with EpisodeWriter(path, overwrite=True) as out:
            _write_some(out, 10)
            raise RuntimeError("loop failed")
    assert path.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["e.mcap"]


def test_keep_partial_finishes_a_valid_file_when_the_loop_raises(tmp_path):
    path = tmp_path / "live.mcap"
    with pytest.raises(KeyboardInterrupt):
        with EpisodeWriter(path, keep_partial=True) as out:
            _write_some(out, 25)
            out.add_metadata("episode", {"reason": "interrupted"})
            raise KeyboardInterrupt
    summary, metadata, messages = _read(path)
    assert [m[2]["value"] for m in messages] == list(range(25))
    assert metadata == {"episode": {"reason": "interrupted"}}
    assert summary.statistics.message_count == 25
    assert sorted(p.name for p in tmp_path.iterdir()) == ["live.mcap"]


def test_flush_makes_messages_salvageable_from_the_temp_file(tmp_path):
    path = tmp_path / "f.mcap"
    with EpisodeWriter(path) as out:
        _write_some(out, 5)
        out.flush()
        (tmp,) = [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]
        salvaged = []
        with open(tmp, "rb") as f:
            try:
                for _, _, message in NonSeekingReader(f).iter_messages(log_time_order=False):
                    salvaged.append(json.loads(message.data)["value"])
            except Exception:  # no footer yet: reading stops after the complete chunks
                pass
        assert salvaged == list(range(5))
    assert not tmp.exists() and _read(path)[0].statistics.message_count == 5


def test_schemas_are_shared_and_sequences_count_per_channel(tmp_path):
    path = tmp_path / "s.mcap"
    with EpisodeWriter(path) as out:
        first = out.register_channel("/a", "test.Counter", SCHEMA)
        second = out.register_channel("/b", "test.Counter", SCHEMA)
        for i in range(3):
            out.write(first, i, {"value": i})
        out.write(second, 5, {"value": 9, "stamp": stamp(5)})
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        sequences = [(c.topic, m.sequence) for _, c, m in reader.iter_messages()]
    assert len(summary.schemas) == 1
    assert sequences == [("/a", 0), ("/a", 1), ("/a", 2), ("/b", 0)]
    assert summary.chunk_indexes[0].compression == "zstd"


def test_stamp_splits_nanoseconds():
    assert stamp(1_500_000_123) == {"sec": 1, "nsec": 500_000_123}


def test_misuse_is_a_clear_error(tmp_path):
    with pytest.raises(SlearnError, match="with block"):
        EpisodeWriter(tmp_path / "x.mcap").write(0, 0, {})
    with pytest.raises(InputError, match="channel id 7 was not registered"):
        with EpisodeWriter(tmp_path / "y.mcap") as out:
            out.write(7, 0, {})
    assert not list(tmp_path.iterdir())
