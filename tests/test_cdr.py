"""The field-only CDR reader gives what the full decoder gives, on every ROS 2 log at hand."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from fixtures import ROS2_HEADER_TYPES, SHARED_MCAP

from slearn.io import cdr
from slearn.io.decode import MISSING, DecoderCache, iter_scalar_fields, parse_field_path
from slearn.io.mcap_read import ChannelInfo, McapLog, SchemaInfo

LOGS = sorted(str(p.relative_to(SHARED_MCAP)) for p in SHARED_MCAP.rglob("*.mcap")
              if p.parts[-2] != "derived" or "truncated_500" in p.name)
PER_CHANNEL = 40  # messages compared per channel (the derived logs are copies of the PR2 log)


def _paths(obj) -> list[str]:
    """Scalar fields, whole primitive arrays, and name lookups, as a spec would name them."""
    paths = [path for path, _ in iter_scalar_fields(obj, max_items=3)]
    extra = []
    for path in paths:
        head, bracket, _ = path.rpartition("[")
        if bracket:
            extra += [head, f"{head}[-1]", f"{head}[99]", f"{head}[name=nothing]"]
    return paths + extra


def _same(a, b) -> bool:
    if isinstance(a, float) and isinstance(b, float) and np.isnan(a) and np.isnan(b):
        return True
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    return type(a) is type(b) and a == b


def _compare_log(path: Path) -> tuple[int, int]:
    """Messages compared (plans and full decoding agree on each, or the test fails), and
    of those, how many ``FieldPlan.many`` read as columns (it must agree too)."""
    compared = 0
    with McapLog(path) as log:
        counts: dict[int, int] = {}
        plans: dict[int, tuple] = {}
        read: dict[int, list] = {}  # the payloads each plan read, and what it read
        cache = DecoderCache()
        for message in log.iter_messages():
            channel = message.channel
            if channel.message_encoding != "cdr" or counts.get(channel.id, 0) >= PER_CHANNEL:
                continue
            decoder = cache.get(channel)
            if decoder is None:
                continue
            counts[channel.id] = counts.get(channel.id, 0) + 1
            try:
                obj = decoder(message.data)
            except Exception:  # noqa: BLE001 - the plan must then fail too
                obj = MISSING
            if channel.id not in plans:
                if obj is MISSING:
                    continue
                fields = [f for f in _paths(obj) if cdr.field_plan(channel, [f]) is not None]
                plans[channel.id] = (fields, cdr.field_plan(channel, fields) if fields else None)
            fields, plan = plans[channel.id]
            if plan is None:
                continue
            try:
                got = plan(message.data)
            except cdr.CdrError:
                got = MISSING
            if obj is MISSING:
                assert got is MISSING, f"{path}: {channel.topic}: the plan read a payload rosbags refuses"
                continue
            assert got is not MISSING, f"{path}: {channel.topic}: the plan refused a payload"
            want = [parse_field_path(f).get(obj) for f in fields]
            for field, a, b in zip(fields, got, want):
                assert (a is MISSING and b is MISSING) or _same(a, b), (path, channel.topic, field, a, b)
            read.setdefault(channel.id, [channel]).append((message.data, got))
            compared += 1
    columns = 0
    for cid, (channel, *pairs) in read.items():
        fields = [f for f, value in zip(plans[cid][0], pairs[0][1]) if not isinstance(value, list)]
        if fields:
            columns += _compare_columns(cdr.field_plan(channel, fields), fields, plans[cid][0], pairs,
                                        f"{path}: {channel.topic}")
    return compared, columns


def _compare_columns(plan, fields, all_fields, pairs, where) -> int:
    """``plan.many`` over the payloads of ``pairs`` against what the plan of ``all_fields``
    read from each: payloads it reads, it reads alike; how many it read."""
    buf = b"".join(data for data, _ in pairs)
    ends = np.cumsum([len(data) for data, _ in pairs])
    columns, alike = plan.many(buf, ends - [len(data) for data, _ in pairs], ends)
    for j, i in enumerate(np.flatnonzero(alike).tolist()):
        got = dict(zip(all_fields, pairs[i][1]))
        for field, column in zip(fields, columns):
            a, b = column[j], got[field]
            assert (a is MISSING and b is MISSING) or _same(a, b), (where, i, field, a, b)
    return int(alike.sum())


@pytest.mark.shared
def test_plans_read_what_rosbags_decodes_on_every_shared_log():
    compared = {rel: _compare_log(SHARED_MCAP / rel) for rel in LOGS}
    assert compared["robot/ros2_cdr/pr2_pr1012_sensors_ros2.mcap"][0] >= 160
    assert compared["robot/ros2_cdr/pr2_pr1012_sensors_ros2.mcap"][1] >= 120  # most read as columns
    assert sum(n for n, _ in compared.values()) > 1000


JOINTS_SCHEMA = ("""std_msgs/Header header
string[] name
float64[] position
float64[] velocity
bool ok
uint8[3] raw
""" + ROS2_HEADER_TYPES).encode()


def _channel() -> ChannelInfo:
    schema = SchemaInfo(1, "my_msgs/Joints", "ros2msg", JOINTS_SCHEMA)
    return ChannelInfo(1, "/joints", "cdr", schema)


def _payload(names, position, velocity, endian="<", frame="base", bad_utf8=False) -> bytes:
    out = bytearray(b"\x00\x01\x00\x00" if endian == "<" else b"\x00\x00\x00\x00")

    def align(n):
        while (len(out) - 4) % n:
            out.append(0)

    def string(text):
        data = text.encode() if not bad_utf8 else b"\xff"
        align(4)
        out.extend(struct.pack(endian + "I", len(data) + 1) + data + b"\x00")

    align(4)
    out.extend(struct.pack(endian + "iI", 12, 34))
    string(frame)
    align(4)
    out.extend(struct.pack(endian + "I", len(names)))
    for name in names:
        string(name)
    for values in (position, velocity):
        align(4)
        out.extend(struct.pack(endian + "I", len(values)))
        if values:
            align(8)
            out.extend(struct.pack(endian + f"{len(values)}d", *values))
    out.extend(b"\x01\x07\x08\x09")
    return bytes(out)


@pytest.mark.parametrize("endian", ["<", ">"])
def test_plan_reads_names_lookups_and_skips_the_rest(endian):
    fields = ["position[name=b]", "velocity[0]", "header.stamp.sec", "ok", "raw", "raw[2]",
              "position[name=zz]", "name"]
    plan = cdr.field_plan(_channel(), fields)
    decoder = DecoderCache().require(_channel())
    for names, position, velocity in ((["a", "b"], [1.5, 2.5], [0.25]), (["a", "b"], [3.0, 4.0], []),
                                      (["b"], [], [1.0])):
        data = _payload(names, position, velocity, endian)
        want = [parse_field_path(f).get(decoder(data)) for f in fields]
        assert plan(data) == want
    assert plan(_payload(["a", "b"], [1.5, 2.5], [0.25], endian))[:2] == [2.5, 0.25]


def test_plan_refuses_what_rosbags_refuses():
    plan = cdr.field_plan(_channel(), ["velocity[0]"])
    with pytest.raises(cdr.CdrError):
        plan(_payload(["a"], [1.0], [2.0], bad_utf8=True))  # a skipped string that is not UTF-8
    with pytest.raises(cdr.CdrError):
        plan(_payload(["a"], [1.0], [2.0])[:-6])  # cut short
    with pytest.raises(cdr.CdrError):
        plan(_payload(["a"], [1.0], [2.0]) + bytes(8))  # longer than its message


def test_no_plan_for_paths_it_cannot_read():
    assert cdr.field_plan(_channel(), ["header"]) is None  # a whole message
    assert cdr.field_plan(_channel(), ["nope"]) is None  # the full decoder says why
    assert cdr.field_plan(_channel(), ["position[0].x"]) is None


@pytest.mark.parametrize("endian", ["<", ">"])
def test_many_reads_payloads_laid_out_alike_as_columns_and_leaves_the_rest(endian):
    """``FieldPlan.many``: payloads of the first one's size whose lengths, strings and
    padding equal its own are read as columns, the same values as one by one; payloads
    laid out otherwise (other names, lengths, byte order, a string that is not UTF-8) are
    left to the one-by-one path, which decides whether they decode."""
    fields = ["position[name=b]", "velocity[0]", "header.stamp.sec", "ok", "raw[2]", "position[name=zz]",
              "header.frame_id", "velocity[5]"]
    plan = cdr.field_plan(_channel(), fields)
    other = ">" if endian == "<" else "<"
    payloads = [_payload(["a", "b"], [1.5, 2.5], [0.25], endian),
                _payload(["a", "b"], [3.0, -4.0], [7.0], endian),          # alike: values only differ
                _payload(["a", "c"], [1.5, 2.5], [0.25], endian),          # other names
                _payload(["a", "b"], [1.5, 2.5], [0.25, 1.0], endian),     # another length
                _payload(["a", "b"], [1.5, 2.5], [0.25], other),           # other byte order
                _payload(["a", "b"], [9.5, 8.5], [0.5], endian, frame="bask"),  # another string, as long
                _payload(["a", "b"], [1.5, 2.5], [0.25], endian).replace(b"base", b"\xff\xfe\xfd\xfc"),  # no UTF-8
                _payload(["a", "b"], [5.5, 6.5], [2.25], endian)]          # alike
    sizes = np.array([len(p) for p in payloads])
    ends = np.cumsum(sizes) + 3 * np.arange(1, len(payloads) + 1)  # (bytes between payloads)
    buf = b"".join(b"\x07\x07\x07" + p for p in payloads)
    columns, alike = plan.many(buf, ends - sizes, ends)
    assert alike.tolist() == [True, True, False, False, False, False, False, True]
    for j, i in enumerate(np.flatnonzero(alike).tolist()):
        assert [column[j] for column in columns] == plan(payloads[i])
    assert [column[1] for column in columns][:3] == [-4.0, 7.0, 12]
    with pytest.raises(cdr.CdrError):
        plan(payloads[6])
    keyed = cdr.field_plan(_channel(), ["position[raw=8]"])  # the key's values pick the element
    assert keyed(payloads[0]) == [2.5] and not keyed.many(buf, ends - sizes, ends)[1].any()
    assert plan.many(b"", np.zeros(0, np.int64), np.zeros(0, np.int64))[1].size == 0
