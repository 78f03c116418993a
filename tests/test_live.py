"""recorders.live: episodes per file, valid files when the loop raises, spec round trip."""

import itertools

import pytest
from mcap.reader import make_reader

from slearn.core.vocabulary import Vocabulary
from slearn.errors import InputError, SlearnError
from slearn.io.serialize import read_episodes
from slearn.io.spec import Bins, ChannelSpec, Spec, load_spec
from slearn.recorders.live import LiveRecorder, events_spec, spec_toml


def _clock():
    ticks = itertools.count(0, 10)
    return lambda: next(ticks)


def _steps(paths, spec):
    vocabulary = Vocabulary()
    return [[([vocabulary.name(a)[1] for a in acts], [vocabulary.name(o)[1] for o in obs])
             for acts, obs in episode.steps()]
            for _, episode, _ in read_episodes(paths, spec, vocabulary)]


def _run(rec, n):
    command = rec.channel("/cmd", "action")
    position = rec.channel("/pos", "observation")
    position.write(0)
    for i in range(n):
        command.write("R")
        position.write(i + 1)


def test_episodes_become_files_and_the_spec_reads_them(tmp_path):
    with LiveRecorder(tmp_path / "runs", prefix="arm", clock=_clock()) as rec:
        _run(rec, 2)
        first = rec.end_episode()
        _run(rec, 1)
        rec.write_spec(tmp_path / "spec.toml")
    assert first == tmp_path / "runs" / "arm-00000.mcap"
    assert rec.paths == [first, tmp_path / "runs" / "arm-00001.mcap"]
    assert _steps(rec.paths, load_spec(tmp_path / "spec.toml")) == [
        [([], [0]), (["R"], [1]), (["R"], [2])], [([], [0]), (["R"], [1])]]
    with open(first, "rb") as f:
        reader = make_reader(f)
        channels = reader.get_summary().channels.values()
        assert {c.topic: c.metadata["role"] for c in channels} == {"/cmd": "action", "/pos": "observation"}
        [meta] = list(reader.iter_metadata())
        assert meta.name == "slearn.live" and meta.metadata["episode"] == "0"


def test_a_raising_loop_still_leaves_a_valid_file(tmp_path):
    with pytest.raises(RuntimeError, match="motor fault"):
        with LiveRecorder(tmp_path, clock=_clock()) as rec:
            _run(rec, 3)
            rec.flush()
            raise RuntimeError("motor fault")
    [path] = rec.paths
    assert _steps([path], rec.spec()) == [[([], [0]), (["R"], [1]), (["R"], [2]), (["R"], [3])]]
    assert [p.name for p in tmp_path.iterdir()] == [path.name]  # no temporary file left


def test_write_all_groups_readings_into_one_step(tmp_path):
    with LiveRecorder(tmp_path, clock=_clock()) as rec:
        rec.channel("/a", "observation")
        rec.channel("/b", "observation")
        rec.write_all({"/a": 1, "/b": "x"})
        rec.write_all({"/a": 2, "/b": "y"}, time_ns=1000)
    assert _steps(rec.paths, rec.spec()) == [[([], [1, "x"]), ([], [2, "y"])]]


def test_empty_episodes_leave_no_file(tmp_path):
    with LiveRecorder(tmp_path) as rec:
        rec.channel("/a", "observation")
        assert rec.end_episode() is None
    assert rec.paths == [] and list(tmp_path.iterdir()) == []


def test_misuse_is_reported(tmp_path):
    rec = LiveRecorder(tmp_path)
    rec.channel("/a", "observation")
    with pytest.raises(SlearnError, match="not open"):
        rec.write("/a", 1)
    with rec:
        with pytest.raises(InputError, match="not registered"):
            rec.write("/b", 1)
        with pytest.raises(InputError, match="already registered as observation"):
            rec.channel("/a", "action")
        with pytest.raises(InputError, match="role must be"):
            rec.channel("/c", "sensor")
        with pytest.raises(InputError, match="dict"):
            rec.write("/a", {"x": 1})
        with pytest.raises(InputError, match="finite"):
            rec.write("/a", float("nan"))


def test_existing_episode_is_refused_without_overwrite(tmp_path):
    (tmp_path / "episode-00000.mcap").write_bytes(b"old")
    with pytest.raises(InputError, match="already exists"):
        with LiveRecorder(tmp_path) as rec:
            rec.channel("/a", "observation").write(1)
    assert (tmp_path / "episode-00000.mcap").read_bytes() == b"old"


def test_spec_toml_round_trips(tmp_path):
    spec = Spec((ChannelSpec("/j", "position[name=a b]", "observation", "a \"b\"",
                             Bins(range=(-1.5, 2.0), count=7, wrap=True)),
                 events_spec({"/c": "action"}).channels[0]), mode="tick", tick_ns=10_000_000)
    path = tmp_path / "s.toml"
    path.write_text(spec_toml(spec, "two lines\nof comment"), encoding="utf-8")
    assert load_spec(path).to_dict() == spec.to_dict()
