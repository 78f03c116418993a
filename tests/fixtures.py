"""Small fixtures shared by several test modules (built in code, no ../shared needed)."""

import json
from pathlib import Path

from mcap.writer import CompressionType, Writer

SHARED_MCAP = Path(__file__).resolve().parents[2] / "shared" / "data" / "mcap"
"""The real files of ``../shared/data/mcap`` (tests that read them are marked ``shared``)."""

ROS2_HEADER_TYPES = """================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""
"""The embedded definitions a ROS 2 schema with a ``std_msgs/Header`` carries."""

POINTER_TOML = """mode = "message"
[[channel]]
topic = "/pointer/command"
field = "command"
role = "action"
values = ["L", "R"]
[[channel]]
topic = "/pointer/position"
field = "position"
role = "observation"
"""


def write_log(path, messages, encodings=None, chunk_size=1 << 20, compression=CompressionType.NONE):
    """Write ``(topic, log_time_ns, payload)`` as JSON (or another declared encoding): a
    payload dict is serialized, bytes are written as they are."""
    encodings = encodings or {}
    with open(path, "wb") as f:
        writer = Writer(f, chunk_size=chunk_size, compression=compression)
        writer.start(profile="", library="slearn-tests")
        schema = writer.register_schema("Thing", "jsonschema", b"{}")
        channels = {}
        for topic, log_time, payload in messages:
            if topic not in channels:
                channels[topic] = writer.register_channel(topic, encodings.get(topic, "json"), schema)
            writer.add_message(channels[topic], log_time=log_time, publish_time=log_time,
                               data=payload if isinstance(payload, bytes) else json.dumps(payload).encode())
        writer.finish()
    return Path(path)


def online_correct(library, episode):
    """Predict then learn every step of ``episode``; per step after the first, whether all
    its observations were predicted right (abstentions count as wrong)."""
    import numpy as np

    codes = library.encode(episode)
    reports = library.run(codes, learn=True, record=True)
    wrong = reports.context & (reports.predicted != codes.token)
    bad = np.zeros(len(codes), bool)
    np.logical_or.at(bad, np.repeat(np.arange(len(codes)), np.diff(codes.offsets)), wrong)
    return ~bad[1:]
