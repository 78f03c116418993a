"""The channel spec: TOML and shorthand, symbolizers, errors naming file/entry/field."""

from __future__ import annotations

import json
import math

import pytest
from hypothesis import given, strategies as st

from slearn.errors import SpecError
from slearn.spec import (Bins, Categorical, Spec, load_spec, parse_channel_option, pointer_spec,
                         spec_from_options)
from slearn.vocabulary import Vocabulary

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
    from slearn.serialize import prepare_vocabulary
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


def test_resolve_spec(tmp_path):
    from slearn.spec import resolve_spec
    assert resolve_spec() is None
    path = _write(tmp_path, GOOD)
    assert resolve_spec(path).mode == "tick"
    overridden = resolve_spec(path, mode="message")
    assert overridden.mode == "message" and overridden.channels == load_spec(path).channels
    assert resolve_spec(path, tick_ms=10).tick_ns == 10_000_000
    assert resolve_spec(None, ["/t:x:action"]).channels[0].role == "action"
    with pytest.raises(SpecError, match="not both"):
        resolve_spec(path, ["/t:x:action"])
