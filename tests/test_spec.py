"""The channel spec: TOML and shorthand, symbolizers, errors naming file/entry/field."""

from __future__ import annotations

import json
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from slearn.core.vocabulary import Vocabulary
from slearn.errors import SpecError
from slearn.io.spec import Bins, Categorical, Spec, load_spec, parse_channel_option, pointer_spec, spec_from_options

GOOD = """
mode = "tick"
tick_ms = 50

[[channel]]
topic = "/joint_states"
field = "position[name=r_shoulder_pan_joint]"
role = "observation"
range = [-2.0, 2.0]
count = 4

[[channel]]
topic = "/joint_states"
field = "position[name=l_shoulder_pan_joint]"
role = "observation"
quantiles = 3

[[channel]]
topic = "/cmd"
field = "mode"
role = "action"
values = ["stop", "go"]

[[channel]]
topic = "/yaw"
field = "angle"
role = "observation"
range = [-180, 180]
count = 4
wrap = true
name = "yaw"

[[channel]]
topic = "/odom"
field = "x"
role = "observation"
width = 0.5
origin = 0.25

[[channel]]
topic = "/grip"
field = "force"
role = "observation"
edges = [0, 10, 100]
"""


def _write(tmp_path, text, name="spec.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_load_good_spec(tmp_path):
    spec = load_spec(_write(tmp_path, GOOD))
    assert spec.mode == "tick" and spec.tick_ns == 50_000_000
    names = [c.name for c in spec.channels]
    assert names == ["/joint_states:position[name=r_shoulder_pan_joint]",
                     "/joint_states:position[name=l_shoulder_pan_joint]", "/cmd", "yaw", "/odom", "/grip"]
    assert spec.topics() == ["/joint_states", "/cmd", "/yaw", "/odom"] + ["/grip"]
    assert [c.role for c in spec.channels].count("action") == 1
    assert not spec.fitted  # the quantile entry needs fitting
    assert spec.channels[2].symbolizer == Categorical(("stop", "go"))


def test_bins_behave():
    four = Bins(range=(-2.0, 2.0), count=4)
    assert [four.symbol_value(x) for x in (-9, -1.5, -0.5, 0.0, 1.99, 2.0, 50)] == [0, 0, 1, 2, 3, 3, 3]
    assert four.declared_values() == [0, 1, 2, 3]
    width = Bins(width=0.5, origin=0.25)
    assert [width.symbol_value(x) for x in (0.25, 0.74, 0.75, -0.3)] == [0, 0, 1, -2]
    assert width.declared_values() is None
    edges = Bins(edges=(0.0, 10.0, 100.0))
    assert [edges.symbol_value(x) for x in (-1, 0, 9.9, 10, 1e9)] == [0, 1, 1, 2, 3]
    assert edges.label(1) == "[0, 10)"
    assert Bins(range=(-2.0, 2.0), count=4).symbol_value(math.nan) is None
    assert Bins(range=(-2.0, 2.0), count=4).symbol_value("text") is None


def test_wrap_puts_equivalent_angles_in_one_bin():
    yaw = Bins(range=(-180.0, 180.0), count=4, wrap=True)
    assert yaw.symbol_value(190) == yaw.symbol_value(-170) == 0
    assert yaw.symbol_value(-190) == yaw.symbol_value(170) == 3
    assert yaw.symbol_value(540) == yaw.symbol_value(180) == yaw.symbol_value(-180)


@given(st.floats(allow_nan=False, allow_infinity=False, min_value=-1e12, max_value=1e12),
       st.integers(1, 40))
def test_range_bins_always_in_range(x, count):
    assert 0 <= Bins(range=(-3.0, 5.0), count=count).symbol_value(x) < count
    assert 0 <= Bins(range=(-3.0, 5.0), count=count, wrap=True).symbol_value(x) < count


def test_to_dict_round_trip_through_json(tmp_path):
    spec = load_spec(_write(tmp_path, GOOD))
    fitted = spec.with_channels([c if c.symbolizer.fitted else
                                 type(c)(c.topic, c.field, c.role, c.name,
                                         Bins(quantiles=3, edges=(-0.1, 0.4)))
                                 for c in spec.channels])
    again = Spec.from_dict(json.loads(json.dumps(fitted.to_dict())))
    assert again.channels == fitted.channels
    assert (again.mode, again.tick_ns) == (fitted.mode, fitted.tick_ns)
    assert again.fitted


def test_shorthand():
    entry = parse_channel_option("/joint_states:position[name=r_wrist_roll_joint]:observation:range=-3;3,count=6")
    assert entry == {"topic": "/joint_states", "field": "position[name=r_wrist_roll_joint]",
                     "role": "observation", "range": [-3, 3], "count": 6}
    spec = spec_from_options(["/pointer/command:command:action:values=L;R",
                              "/pointer/position:position:observation:values=1;2;3"], mode="message")
    assert spec.channels[0].symbolizer == Categorical(("L", "R"))
    assert spec.channels[1].symbolizer == Categorical((1, 2, 3))
    with pytest.raises(SpecError, match="TOPIC:FIELD:ROLE"):
        parse_channel_option("/topic:field")


def test_pointer_spec_symbols():
    spec = pointer_spec()
    assert spec.mode == "message" and spec.topics() == ["/pointer/command", "/pointer/position"]
    from slearn.io.serialize import prepare_vocabulary
    vocabulary = prepare_vocabulary(spec, Vocabulary())
    assert vocabulary.get_symbol("/pointer/command", "L") == 0
    assert vocabulary.get_symbol("/pointer/command", "R") == 1
    assert [vocabulary.get_symbol("/pointer/position", k) for k in (1, 17, 36)] == [2, 18, 37]
    assert len(vocabulary) == 38


ENTRY = '[[channel]]\ntopic = "/t"\nfield = "x"\nrole = "observation"\n'


@pytest.mark.parametrize("text, message", [
    ("mode = 'sometimes'\n" + ENTRY, "mode must be one of"),
    ("mode = 'tick'\n" + ENTRY, "needs tick_ms"),
    ("colour = 1\n" + ENTRY, "unknown key"),
    ("mode = 'change'\n", "no \\[\\[channel\\]\\] entries"),
    (ENTRY + "rnage = [0, 1]\n", "entry 1 \\(/t:x\\): unknown key\\(s\\) rnage"),
    (ENTRY.replace('role = "observation"', 'role = "sensor"'), "entry 1 .*role must be"),
    (ENTRY.replace('role = "observation"\n', ""), "`role` is required"),
    (ENTRY + "range = [0, 1]\n", "`range` needs `count`"),
    (ENTRY + "range = [1, 0]\ncount = 2\n", "low < high"),
    (ENTRY + "width = 1\nrange = [0, 1]\ncount = 2\n", "choose one binning"),
    (ENTRY + "width = 0\n", "`width` must be a number from 1e-300 to 1e\\+300, not 0"),
    (ENTRY + "width = 1\nwrap = true\n", "`wrap` needs `range`"),
    (ENTRY + "edges = [3, 1]\n", "increasing"),
    (ENTRY + "values = ['a']\ncount = 3\n", "cannot be combined|needs one of"),
    (ENTRY + "count = 3\n", "needs one of width"),
    (ENTRY.replace('"x"', '"x[=1]"'), "entry 1 .*selector"),
    (ENTRY + ENTRY, "two entries are named"),
    ("[[channel]\n", "not valid TOML"),
])
def test_errors_name_file_and_entry(tmp_path, text, message):
    path = _write(tmp_path, text, "bad.toml")
    with pytest.raises(SpecError, match=message) as caught:
        load_spec(path)
    assert str(path) in str(caught.value)


def test_missing_file(tmp_path):
    with pytest.raises(SpecError, match="cannot read spec"):
        load_spec(tmp_path / "none.toml")


def test_every_message_is_an_event_unless_the_spec_asks_for_change():
    spec = Spec.from_dict({"channel": [{"topic": "/c", "field": "data", "role": "action"},
                                       {"topic": "/s", "field": "v", "role": "observation",
                                        "mode": "change"}]})
    assert spec.mode == "message"
    assert [spec.channel_mode(i) for i in range(2)] == ["message", "change"]
    assert spec.to_dict()["channel"][1]["mode"] == "change" and "mode" not in spec.to_dict()["channel"][0]
    assert Spec.from_dict(spec.to_dict()) == spec
    with pytest.raises(SpecError, match="an entry's mode must be"):
        Spec.from_dict({"channel": [{"topic": "/c", "role": "action", "mode": "tick"}]})
    with pytest.raises(SpecError, match="drop the entries' own `mode`"):
        Spec.from_dict({"mode": "tick", "tick_ms": 10,
                        "channel": [{"topic": "/c", "role": "action", "mode": "change"}]})


@pytest.mark.parametrize("extra, message", [
    ({"phase_ms": 10}, "phase_ms is for mode"),
    ({"tick_ms": 10}, "tick_ms is for mode \"tick\""),  # (mode message ignored it silently)
    ({"mode": "tick", "tick_ms": 100, "phase_ms": 150}, "at most one tick"),
    ({"mode": "tick", "tick_ms": 100, "phase_ms": 0}, "above 0"),
])
def test_the_tick_phase_lies_within_a_tick(extra, message):
    with pytest.raises(SpecError, match=message):
        Spec.from_dict({**extra, "channel": [{"topic": "/c", "role": "action"}]})
    ok = Spec.from_dict({"mode": "tick", "tick_ms": 100, "phase_ms": 50,
                         "channel": [{"topic": "/c", "role": "action"}]})
    assert ok.phase_ns == 50_000_000 and Spec.from_dict(ok.to_dict()) == ok


def test_bins_read_as_value_ranges_and_know_what_falls_outside():
    angle = Bins(range=(0.0, 2 * math.pi), count=36, wrap=True, unit="rad")
    assert [angle.label(k) for k in (0, 5, 35)] == ["[0°, 10°)", "[50°, 60°)", "[350°, 360°)"]
    small = Bins(range=(-math.pi / 18 * 9, math.pi / 18 * 9), count=9)
    assert small.label(4) == "[-0.17, 0.17)"
    assert Bins(edges=(-0.5, 0.5)).label(0) == "[-inf, -0.5)"
    assert Bins(range=(0.0, 2.0), count=4, unit="m").label(1) == "[0.5, 1) m"
    bounded = Bins(range=(0.0, 3.14), count=4)
    assert bounded.outside(6.0) and bounded.outside(-0.1) and not bounded.outside(3.14)
    assert not Bins(range=(0.0, 3.14), count=4, clip=True).outside(6.0)
    assert not angle.outside(20.0) and not Bins(edges=(1.0,)).outside(99.0)
    spec = Spec.from_dict({"channel": [{"topic": "/j", "field": "p", "role": "observation",
                                        "range": [0, 6.283185307179586], "count": 36, "unit": "rad"}]})
    assert spec.value_label("/j", 5) == "[50°, 60°)" and spec.value_label("/other", 5) == "5"
    with pytest.raises(SpecError, match="`clip` goes with `range`"):
        Spec.from_dict({"channel": [{"topic": "/j", "role": "observation", "width": 1, "clip": True}]})


def test_the_vocabulary_labels_bins_as_value_ranges():
    from slearn.io.serialize import prepare_vocabulary

    spec = spec_from_options(["/j:p:observation:range=[0,360],count=36,unit=deg", "/c:d:action"])
    vocabulary = prepare_vocabulary(spec, Vocabulary())
    assert vocabulary.label(vocabulary.get_symbol("/j", 5)) == "/j=[50°, 60°)"
    assert vocabulary.label(vocabulary.symbol("/c", 1)) == "/c=1"


def test_shorthand_takes_lists_in_brackets_and_every_key():
    entry = parse_channel_option("/j:position[name=a]:observation:range=[0,6.28],count=36,wrap=true,"
                                 "unit=rad,mode=change")
    assert entry == {"topic": "/j", "field": "position[name=a]", "role": "observation",
                     "range": [0, 6.28], "count": 36, "wrap": True, "unit": "rad", "mode": "change"}
    assert parse_channel_option("/c:data:action:values=[-1,1]")["values"] == [-1, 1]
    assert parse_channel_option("/c:data:action:values=[L, R]")["values"] == ["L", "R"]
    with pytest.raises(SpecError, match="key=value"):
        parse_channel_option("/c:data:action:count")


def test_a_spec_without_actions_is_warned_about_and_topics_can_be_selected():
    spec = spec_from_options(["/a:x:observation", "/b:y:observation"])
    [warning] = spec.warnings()
    assert "no action channel" in warning
    assert spec_from_options(["/a:x:action"]).warnings() == []
    assert spec.only_topics(["/b"]).topics() == ["/b"]
    with pytest.raises(SpecError, match="--topics '/c' is not a topic"):
        spec.only_topics(["/c"])
