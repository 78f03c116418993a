"""Serialization: episodes per file, modes, event order, vocabulary, fitting, spec errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
from fixtures import SHARED_MCAP, write_log

from slearn.core.vocabulary import Vocabulary
from slearn.errors import SpecError, TruncatedLogWarning
from slearn.io.serialize import fit_spec, read_episodes
from slearn.io.spec import Spec, load_spec, pointer_spec

SHARED = SHARED_MCAP
ROBOT = SHARED / "robot"


def pointer_messages(commands, positions):
    """The pointer recorder's layout: position 0 and commands at i*100 ms, results 50 ms later."""
    out = [("/pointer/position", 0, {"position": positions[0]}), ("/pointer/angle", 0, {"angle_deg": 1.0})]
    for i, (command, position) in enumerate(zip(commands, positions[1:])):
        out += [("/pointer/command", i * 100_000_000, {"command": command}),
                ("/pointer/position", i * 100_000_000 + 50_000_000, {"position": position}),
                ("/pointer/angle", i * 100_000_000 + 50_000_000, {"angle_deg": 2.0})]
    return out


def episodes(paths, spec, vocabulary=None):
    vocabulary = vocabulary if vocabulary is not None else Vocabulary()
    return [episode for _, episode, _ in read_episodes(paths, spec, vocabulary)], vocabulary


def test_pointer_log_gives_the_pointer_episode(tmp_path):
    path = write_log(tmp_path / "p.mcap", pointer_messages("RRL", [17, 18, 19, 18]))
    [episode], vocabulary = episodes([path], pointer_spec())
    assert episode.steps() == [((), (18,)), ((1,), (19,)), ((1,), (20,)), ((0,), (19,))]
    assert len(vocabulary) == 38 and vocabulary.name(1) == ("/pointer/command", "R")


def test_pointer_recorder_round_trip(tmp_path):
    from slearn.recorders import pointer
    from slearn.recorders import record_pointer as record
    config = pointer.PointerConfig("noise" if "noise" in pointer.CONDITIONS else "simple",
                                   trials=500, seed=3)
    record.record_pointer(config, tmp_path / "p.mcap")
    [episode], _ = episodes([tmp_path / "p.mcap"], pointer_spec())
    expected = pointer.simulate(config).to_episode()
    assert np.array_equal(episode.symbols, expected.symbols)
    assert np.array_equal(episode.step_offsets, expected.step_offsets)
    assert np.array_equal(episode.n_actions, expected.n_actions)


MODES_LOG = [("/s", 0, {"v": 1}), ("/a", 10, {"c": "x"}), ("/s", 20, {"v": 1}),
             ("/a", 30, {"c": "x"}), ("/s", 40, {"v": 2}), ("/s", 50, {"v": 2})]


def _two_channel_spec(mode, **extra):
    return Spec.from_dict({"mode": mode, **extra, "channel": [
        {"topic": "/a", "field": "c", "role": "action"},
        {"topic": "/s", "field": "v", "role": "observation", "values": [1, 2]}]})


@pytest.mark.parametrize("mode, extra, expected", [
    ("message", {}, [((), ("s1",)), (("x",), ("s1",)), (("x",), ("s2",)), ((), ("s2",))]),
    ("change", {}, [((), ("s1",)), (("x",), ("s2",))]),
    ("tick", {"tick_ns": 20}, [((), ("s1",)), ((), ("s1",)), (("x",), ("s2",)), (("x",), ("s2",))]),
])
def test_modes(tmp_path, mode, extra, expected):
    path = write_log(tmp_path / "m.mcap", MODES_LOG)
    [episode], vocabulary = episodes([path], _two_channel_spec(mode, **extra))
    names = {vocabulary.get_symbol("/a", "x"): "x", vocabulary.get_symbol("/s", 1): "s1",
             vocabulary.get_symbol("/s", 2): "s2"}
    assert [(tuple(names[s] for s in a), tuple(names[s] for s in o)) for a, o in episode.steps()] == expected
    assert vocabulary.get_symbol("/s", 1) == 0 and vocabulary.get_symbol("/a", "x") == 2


def test_order_at_equal_log_time(tmp_path):
    # file order: action, then /o2, then /o1, all at t=5; spec order: /o1 before /o2
    path = write_log(tmp_path / "t.mcap", [("/o1", 0, {"v": 0}), ("/a", 5, {"c": "go"}),
                                           ("/o2", 5, {"v": 2}), ("/o1", 5, {"v": 1}),
                                           ("/o1", 9, {"v": 3})])
    spec = Spec.from_dict({"mode": "message", "channel": [
        {"topic": "/a", "field": "c", "role": "action"},
        {"topic": "/o1", "field": "v", "role": "observation"},
        {"topic": "/o2", "field": "v", "role": "observation"}]})
    [episode], vocabulary = episodes([path], spec)
    labels = [(tuple(vocabulary.label(s) for s in a), tuple(vocabulary.label(s) for s in o))
              for a, o in episode.steps()]
    assert labels == [((), ("/o1=0",)), ((), ("/o1=1", "/o2=2")), (("/a=go",), ("/o1=3",))]


def test_files_are_separate_episodes_with_one_vocabulary(tmp_path):
    a = write_log(tmp_path / "a.mcap", pointer_messages("RR", [1, 2, 3]))
    b = write_log(tmp_path / "b.mcap", pointer_messages("L", [1, 36]))
    spec = Spec.from_dict({"mode": "message", "channel": [
        {"topic": "/pointer/command", "field": "command", "role": "action"},
        {"topic": "/pointer/position", "field": "position", "role": "observation"}]})
    (ea, eb), vocabulary = episodes([a, b], spec)
    assert len(ea) == 3 and len(eb) == 2
    assert [vocabulary.name(s) for s in range(len(vocabulary))] == [
        ("/pointer/position", 1), ("/pointer/command", "R"), ("/pointer/position", 2),
        ("/pointer/position", 3), ("/pointer/command", "L"), ("/pointer/position", 36)]


def test_quantile_fit_saved_and_reloaded_bins_identically(tmp_path):
    train = write_log(tmp_path / "train.mcap", [("/x", i, {"v": float(i % 100)}) for i in range(1000)])
    held = write_log(tmp_path / "held.mcap", [("/x", i, {"v": float((i * 37) % 120)}) for i in range(300)])
    spec = Spec.from_dict({"mode": "message", "channel": [
        {"topic": "/x", "field": "v", "role": "observation", "quantiles": 4}]})
    with pytest.raises(SpecError, match="not fitted"):
        episodes([train], spec)
    fitted = fit_spec(spec, [train])
    assert fitted.channels[0].symbolizer.edges == (24.75, 49.5, 74.25)
    restored = Spec.from_dict(json.loads(json.dumps(fitted.to_dict())))
    [first], v1 = episodes([held], fitted)
    [second], v2 = episodes([held], restored)
    assert np.array_equal(first.symbols, second.symbols) and list(v1.items()) == list(v2.items())
    assert sorted(set(first.symbols.tolist())) == [0, 1, 2, 3]


@pytest.mark.parametrize("channel, message", [
    ({"topic": "/nope", "field": "v"}, "topic '/nope' is not in this log"),
    ({"topic": "/x", "field": "w"}, "entry 1 .*no field 'w'"),
    ({"topic": "/x", "field": "arr[name=zz]"}, "matched none of the 3 messages"),
    ({"topic": "/x", "field": ""}, "is a message, not a value"),
    ({"topic": "/bad", "field": "v"}, "selects topic '/bad'.*'wrong_format'"),
])
def test_spec_errors_name_file_and_entry(tmp_path, channel, message):
    path = write_log(tmp_path / "e.mcap", [("/x", i, {"v": i, "arr": [1], "name": ["a"]}) for i in range(3)]
                     + [("/bad", 5, {"v": 1})], encodings={"/bad": "wrong_format"})
    spec = Spec.from_dict({"channel": [dict(channel, role="observation")]})
    with pytest.raises(SpecError, match=message) as caught:
        episodes([path], spec)
    assert str(path) in str(caught.value)


def test_undecodable_channel_not_in_spec_is_ignored(tmp_path):
    path = write_log(tmp_path / "e.mcap", [("/x", 1, {"v": 1}), ("/bad", 2, {"v": 1})],
                     encodings={"/bad": "wrong_format"})
    [episode], _ = episodes([path], Spec.from_dict({"channel": [{"topic": "/x", "field": "v", "role": "observation"}]}))
    assert episode.n_events == 1


def test_truncated_log_salvages_and_warns(tmp_path, capsys):
    full = write_log(tmp_path / "f.mcap", pointer_messages("R" * 300, list(range(1, 37)) * 9)[:901],
                     chunk_size=2000).read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(full[:len(full) // 2])
    with pytest.warns(TruncatedLogWarning, match="cut.mcap: truncated"):
        [(path, episode, report)] = list(read_episodes([cut], pointer_spec(), Vocabulary(), progress=True))
    assert report.truncated and 50 < len(episode) < 300
    out, err = capsys.readouterr()
    assert out == "" and "cut.mcap" in err


def _shared(*parts):
    path = ROBOT.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"{path} is not available")
    return path


PR2_SPEC = """
mode = "change"
[[channel]]
topic = "/joint_states"
field = "position[name=laser_tilt_mount_joint]"
role = "observation"
range = [-0.7, 1.1]
count = 12
[[channel]]
topic = "/joint_states"
field = "position[name=bl_caster_rotation_joint]"
role = "observation"
quantiles = 4
[[channel]]
topic = "/joint_states"
field = "velocity[name=laser_tilt_mount_joint]"
role = "action"
edges = [-0.5, 0.5]
[[channel]]
topic = "/base_odometry/odom"
field = "twist.twist.angular.z"
role = "observation"
width = 0.01
"""


@pytest.mark.shared
def test_pr2_ros2_and_ros1_give_the_identical_event_stream(tmp_path):
    ros2 = _shared("ros2_cdr", "pr2_pr1012_sensors_ros2.mcap")
    ros1 = _shared("ros1", "pr2_pr1012_sensors_ros1.mcap")
    (tmp_path / "pr2.toml").write_text(PR2_SPEC)
    spec = fit_spec(load_spec(tmp_path / "pr2.toml"), [ros2])
    [e2], v2 = episodes([ros2], spec)
    [e1], v1 = episodes([ros1], spec)
    assert np.array_equal(e1.symbols, e2.symbols) and np.array_equal(e1.step_offsets, e2.step_offsets)
    assert np.array_equal(e1.n_actions, e2.n_actions) and list(v1.items()) == list(v2.items())
    assert e2.n_events > 100 and e2.n_actions.sum() > 10
    assert {channel for _, channel, _ in v2.items()} == {c.name for c in spec.channels}


@pytest.mark.shared
def test_rosbag2_service_events_and_wrong_format_are_clear_errors():
    bags = ("rosbag2_tests", "rosbag2_tests", "resources", "mcap")
    services = _shared(*bags, "bag_with_topics_and_service_events", "bag_with_topics_and_service_events.mcap")
    wrong = _shared(*bags, "wrong_rmw_test", "wrong_rmw_test_0.mcap")
    service_spec = Spec.from_dict({"channel": [
        {"topic": "/test_service1/_service_event", "field": "info.event_type", "role": "observation"}]})
    with pytest.raises(SpecError, match="_service_event.*service"):
        episodes([services], service_spec)
    topic_spec = Spec.from_dict({"channel": [
        {"topic": "/test_topic1", "field": "string_value_default1", "role": "observation"}]})
    [episode], vocabulary = episodes([services], topic_spec)
    assert episode.n_events == 1 and vocabulary.name(0) == ("/test_topic1", "Hello world!")
    wrong_spec = Spec.from_dict({"channel": [{"topic": "/test_topic", "field": "int8_value", "role": "observation"}]})
    with pytest.raises(SpecError, match="'/test_topic'.*wrong_format"):
        episodes([wrong], wrong_spec)


def test_default_spec_is_the_pointer_spec_for_pointer_logs(tmp_path):
    from slearn.jobs.learn import default_spec
    pointer = write_log(tmp_path / "p.mcap", pointer_messages("R", [1, 2]))
    assert default_spec(str(pointer)) == pointer_spec()
    other = write_log(tmp_path / "o.mcap", MODES_LOG)
    with pytest.raises(SpecError, match="o.mcap: not a pointer log.*--suggest-spec"):
        default_spec(str(other))


def test_tick_mode_refuses_absurd_tick_counts(tmp_path):
    from slearn.errors import InputError
    path = write_log(tmp_path / "static.mcap", [("/s", 0, {"v": 1}), ("/s", 10**18, {"v": 2})])
    spec = Spec.from_dict({"mode": "tick", "tick_ns": 1000, "channel": [
        {"topic": "/s", "field": "v", "role": "observation"}]})
    with pytest.raises(InputError, match="more than .* ticks.*log time 0"):
        episodes([path], spec)


def _warnings_of(call):
    import warnings

    from slearn.errors import DataWarning
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = call()
    return result, [str(w.message) for w in caught if issubclass(w.category, DataWarning)]


def test_change_detection_is_per_entry(tmp_path):
    path = write_log(tmp_path / "m.mcap", MODES_LOG)
    spec = Spec.from_dict({"channel": [
        {"topic": "/a", "field": "c", "role": "action"},
        {"topic": "/s", "field": "v", "role": "observation", "values": [1, 2], "mode": "change"}]})
    [episode], vocabulary = episodes([path], spec)
    x, s1, s2 = (vocabulary.get_symbol(*k) for k in (("/a", "x"), ("/s", 1), ("/s", 2)))
    # every command stays an event; the repeated readings (t=20, t=50) are dropped
    assert episode.steps() == [((), (s1,)), ((x,), ()), ((x,), (s2,))]


TICK_B = [m for i in range(20) for m in (("/s", i * 100, {"v": i % 3}), ("/a", i * 100 + 50, {"c": "LR"[i % 2]}))]


def test_tick_phase_samples_after_the_command_and_a_bad_phase_is_warned_about(tmp_path):
    # a controller that reads at k*100 and commands at k*100+50: the reading after
    # command k is the one at (k+1)*100
    path = write_log(tmp_path / "b.mcap", TICK_B)
    base = {"mode": "tick", "tick_ns": 100, "channel": [
        {"topic": "/a", "field": "c", "role": "action"},
        {"topic": "/s", "field": "v", "role": "observation", "values": [0, 1, 2]}]}
    (late, _), late_warnings = _warnings_of(lambda: episodes([path], Spec.from_dict(base)))
    [warning] = late_warnings
    assert "tick mode: 18 of 19 commands are paired with a reading logged before them or after " \
           "the next command" in warning and "phase_ms" in warning
    ([good], vocabulary), none = _warnings_of(lambda: episodes([path], Spec.from_dict({**base, "phase_ns": 50})))
    assert none == []
    names = {vocabulary.get_symbol("/a", "L"): "L", vocabulary.get_symbol("/a", "R"): "R"}
    steps = [(tuple(names[a] for a in acts), tuple(vocabulary.name(o)[1] for o in obs))
             for acts, obs in good.steps()]
    # step k pairs command k-2 (issued at (k-2)*100+50) with the reading at (k-1)*100
    assert steps[:4] == [((), (0,)), ((), (0,)), (("L",), (1,)), (("R",), (2,))]


def test_values_outside_the_range_are_counted_and_clip_accepts_them(tmp_path):
    path = write_log(tmp_path / "r.mcap", [("/s", i, {"v": i * 0.5}) for i in range(10)])
    entry = {"topic": "/s", "field": "v", "role": "observation", "range": [0, 3.14], "count": 4}
    _, [range_warning, *_] = _warnings_of(lambda: episodes([path], Spec.from_dict({"channel": [entry]})))
    assert range_warning.startswith("channel '/s': 3 of 10 values (30.0 %) in 1 log(s) fell outside "
                                    "range [0, 3.14]") and "clip = true" in range_warning
    _, warned = _warnings_of(lambda: episodes([path], Spec.from_dict({"channel": [{**entry, "clip": True}]})))
    assert not any("outside" in w for w in warned)


def test_episode_markers_split_one_file_into_episodes(tmp_path):
    from slearn.io.episodes import EPISODE_TOPIC, split_episode_name

    messages = [("/s", 0, {"v": 9})]
    for k in range(3):
        messages += [(EPISODE_TOPIC, 1000 * (k + 1), {"episode": k}),
                     ("/s", 1000 * (k + 1), {"v": k}), ("/s", 1000 * (k + 1) + 10, {"v": k + 1})]
    path = write_log(tmp_path / "many.mcap", messages)
    spec = Spec.from_dict({"channel": [{"topic": "/s", "field": "v", "role": "observation"}]})
    vocabulary = Vocabulary()
    read = list(read_episodes([path], spec, vocabulary))
    assert [name for name, _, _ in read] == [str(path), f"{path}#0", f"{path}#1", f"{path}#2"]
    assert [[vocabulary.name(o)[1] for _, obs in e.steps() for o in obs] for _, e, _ in read] == \
        [[9], [0, 1], [1, 2], [2, 3]]
    assert split_episode_name(f"{path}#2") == (str(path), 2)
    assert split_episode_name(str(path)) == (str(path), None)


def test_a_time_window_reads_part_of_each_log(tmp_path):
    from slearn.errors import InputError
    from slearn.io.slicing import HELDOUT, time_slice

    path = write_log(tmp_path / "w.mcap", [("/s", 1_000_000_000 + i * 100_000_000, {"v": i}) for i in range(10)])
    spec = Spec.from_dict({"channel": [{"topic": "/s", "field": "v", "role": "observation"}]})

    def values(window):
        vocabulary = Vocabulary()
        [(_, episode, _)] = list(read_episodes([path], spec, vocabulary, window=window))
        return [vocabulary.name(o)[1] for _, obs in episode.steps() for o in obs]

    assert values(time_slice("0.2", "0.5")) == [2, 3, 4]
    assert values(time_slice(split=0.7)) == list(range(7))
    assert values(time_slice(split=0.7, part=HELDOUT)) == [7, 8, 9]
    assert values(time_slice(start="1970-01-01T00:00:01.8Z")) == [8, 9]
    with pytest.raises(InputError, match="leaves no time of this log"):
        values(time_slice(start="5"))
