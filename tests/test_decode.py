"""Decoders per channel, failures with reasons and no chatter, field paths into messages."""

from __future__ import annotations

import pytest
from fixtures import ROS2_HEADER_TYPES, SHARED_MCAP
from mcap_ros2.writer import Writer as Ros2Writer

from slearn.errors import DecodeError, FieldPathError
from slearn.io.decode import MISSING, DecoderCache, decode_payload, iter_scalar_fields, make_decoder, parse_field_path
from slearn.io.mcap_read import ChannelInfo, SchemaInfo, iter_messages

SHARED = SHARED_MCAP
ROSBAG2 = SHARED / "robot" / "rosbag2_tests" / "rosbag2_tests" / "resources" / "mcap"

JOINT_STATE = """std_msgs/Header header
string[] name
float64[] position
float64[] velocity
float64[] effort
""" + ROS2_HEADER_TYPES

JOINTS = {"header": {"stamp": {"sec": 1, "nanosec": 2}, "frame_id": "base"},
          "name": ["a_joint", "b_joint", "c_joint"], "position": [0.5, -1.25, 3.0],
          "velocity": [], "effort": []}


def _channel(encoding="json", schema=None):
    return ChannelInfo(1, "/t", encoding, schema)


def write_joint_states(path, positions):
    with open(path, "wb") as f:
        writer = Ros2Writer(f)
        schema = writer.register_msgdef("sensor_msgs/msg/JointState", JOINT_STATE)
        for i, position in enumerate(positions):
            writer.write_message("/joint_states", schema, dict(JOINTS, position=position),
                                 log_time=i * 10)
        writer.finish()
    return path


def test_json_and_schemaless_json_decode():
    assert make_decoder(_channel())(b'{"command": "R"}') == {"command": "R"}
    schemaless = ChannelInfo(0, "/t", "json", None)
    assert make_decoder(schemaless)(b"[1, 2]") == [1, 2]


def test_ros2_cdr_round_trip_and_parallel_lookup(tmp_path):
    path = write_joint_states(tmp_path / "j.mcap", [[0.5, -1.25, 3.0], [0.0, 2.0, 1.0]])
    cache = DecoderCache()
    values = []
    for message in iter_messages(path):
        obj = decode_payload(cache.require(message.channel), message.channel, message.data)
        values.append(parse_field_path("position[name=b_joint]").get(obj))
        assert parse_field_path('position["c_joint"]').get(obj) == obj.position[2]
        assert parse_field_path("header.frame_id").get(obj) == "base"
    assert values == [-1.25, 2.0]


def test_unknown_encoding_is_reported_with_reason():
    with pytest.raises(DecodeError, match="no decoder for message encoding 'wrong_format'"):
        make_decoder(_channel("wrong_format", SchemaInfo(1, "x/msg/Y", "ros2msg", b"int32 a")))
    cache = DecoderCache()
    channel = _channel("wrong_format")
    assert cache.get(channel) is None and cache.get(channel) is None
    assert "wrong_format" in cache.failures[1]
    with pytest.raises(DecodeError, match="channel '/t' .*cannot be decoded"):
        cache.require(channel)


def test_broken_schema_fails_without_chatter(capfd):
    schema = SchemaInfo(1, "pkg/srv/Thing_Event", "ros2msg", b"int32 a\n---\nint32 b\n")
    with pytest.raises(DecodeError, match="service"):
        make_decoder(_channel("cdr", schema))
    out, err = capfd.readouterr()
    assert out == "" and err == ""


def test_corrupt_payload_names_the_channel():
    with pytest.raises(DecodeError, match="channel '/t': a message does not decode"):
        decode_payload(make_decoder(_channel()), _channel(), b"{not json")


MESSAGE = {"pose": {"pose": {"position": {"x": 1.5, "y": 2}}},
           "name": ["j1", "j2"], "position": [10, 20],
           "transforms": [{"child_frame_id": "arm", "z": 1}, {"child_frame_id": "base", "z": 2}]}


@pytest.mark.parametrize("path, value", [
    ("pose.pose.position.x", 1.5),
    ("position[1]", 20),
    ("position[-1]", 20),
    ("position[name=j1]", 10),
    ("position['j2']", 20),
    ("transforms[child_frame_id=base].z", 2),
    ("position[name=nope]", MISSING),
    ("position[5]", MISSING),
    ("transforms[child_frame_id=nope].z", MISSING),
])
def test_field_paths(path, value):
    assert parse_field_path(path).get(MESSAGE) == value


def test_missing_field_is_a_spec_error_listing_fields():
    with pytest.raises(FieldPathError, match="no field 'posi' here .*pose, name, position"):
        parse_field_path("posi").get(MESSAGE)


@pytest.mark.parametrize("bad", ["a..b", "a[b]]", "a[=3]", "1abc"])
def test_malformed_paths(bad):
    with pytest.raises(FieldPathError):
        parse_field_path(bad)


def test_scalar_fields_name_parallel_arrays():
    fields = dict(iter_scalar_fields(MESSAGE))
    assert fields["pose.pose.position.x"] == 1.5
    assert fields["position[name=j2]"] == 20
    assert fields["name[0]"] == "j1"
    assert fields["transforms[0].child_frame_id"] == "arm"
    for path, value in fields.items():
        assert parse_field_path(path).get(MESSAGE) == value


def _first_failure(path):
    cache = DecoderCache()
    for message in iter_messages(path):
        cache.get(message.channel)
    return cache


@pytest.mark.shared
def test_rosbag2_service_events_and_wrong_format(capfd):
    bag = ROSBAG2 / "bag_with_topics_and_service_events" / "bag_with_topics_and_service_events.mcap"
    wrong = ROSBAG2 / "wrong_rmw_test" / "wrong_rmw_test_0.mcap"
    if not bag.exists() or not wrong.exists():
        pytest.skip("rosbag2 test bags are not available")
    cache = _first_failure(bag)
    assert len(cache.failures) == 2 and len(cache.decoders) == 2
    assert all("service" in reason and "BasicTypes_Event" in reason for reason in cache.failures.values())
    assert capfd.readouterr() == ("", "")
    cache = _first_failure(wrong)
    assert not cache.decoders
    assert all("wrong_format" in reason for reason in cache.failures.values())


@pytest.mark.shared
def test_protobuf_and_ros1_decode():
    proto = SHARED / "robot" / "protobuf" / "rerun_foxglove_log.mcap"
    ros1 = SHARED / "robot" / "ros1" / "pr2_pr1012_sensors_ros1.mcap"
    if not proto.exists() or not ros1.exists():
        pytest.skip("robot logs are not available")
    cache = DecoderCache()
    levels = [parse_field_path("level").get(decode_payload(cache.require(m.channel), m.channel, m.data))
              for m in iter_messages(proto)]
    assert levels == [0, 1, 2, 3, 4, 5]
    message = next(m for m in iter_messages(ros1, topics=["/joint_states"]))
    obj = decode_payload(DecoderCache().require(message.channel), message.channel, message.data)
    assert isinstance(parse_field_path("position[name=r_shoulder_pan_joint]").get(obj), float)


def _both_ros2_decoders(channel):
    from mcap.records import Schema
    from mcap_ros2.decoder import DecoderFactory

    from slearn.io.decode import _rosbags_cdr_decoder
    s = channel.schema
    slow = DecoderFactory().decoder_for("cdr", Schema(id=s.id, name=s.name, encoding=s.encoding, data=s.data))
    return _rosbags_cdr_decoder(channel), slow


def test_rosbags_and_mcap_ros2_agree(tmp_path):
    logs = [write_joint_states(tmp_path / "j.mcap", [[0.5, -1.25, 3.0], [0.0, 2.0, 1.0]])]
    pr2 = SHARED / "robot" / "ros2_cdr" / "pr2_pr1012_sensors_ros2.mcap"
    logs += [pr2] if pr2.exists() else []
    compared = 0
    for path in logs:
        decoders = {}
        for message in iter_messages(path):
            if message.channel.id not in decoders:
                decoders[message.channel.id] = _both_ros2_decoders(message.channel)
            fast, slow = decoders[message.channel.id]
            if compared % 7 == 0:  # a sample keeps this quick
                assert dict(iter_scalar_fields(fast(message.data), max_items=100)) == dict(
                    iter_scalar_fields(slow(message.data), max_items=100))
            compared += 1
    assert compared >= 2
