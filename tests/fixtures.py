"""Small fixtures shared by several test modules (built in code, no ../shared needed)."""

import json
from pathlib import Path

from mcap.writer import CompressionType, Writer

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


def write_log(path, messages, encodings=None, chunk_size=1 << 20):
    """Write ``(topic, log_time_ns, payload dict)`` as JSON (or another declared encoding)."""
    encodings = encodings or {}
    with open(path, "wb") as f:
        writer = Writer(f, chunk_size=chunk_size, compression=CompressionType.NONE)
        writer.start(profile="", library="slearn-tests")
        schema = writer.register_schema("Thing", "jsonschema", b"{}")
        channels = {}
        for topic, log_time, payload in messages:
            if topic not in channels:
                channels[topic] = writer.register_channel(topic, encodings.get(topic, "json"), schema)
            writer.add_message(channels[topic], log_time=log_time, publish_time=log_time,
                               data=json.dumps(payload).encode())
        writer.finish()
    return Path(path)
