"""Bags get the limits of MCAP logs: bounded chunk decompression, FIFOs refused, offsets in
warnings, outputs that are inputs refused. Every bag is written here with rosbags."""

from __future__ import annotations

import os
import struct
import threading
from pathlib import Path

import pytest
from click.testing import CliRunner
from rosbags.rosbag1 import Writer as Ros1Writer  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402
from test_bags import pointer_messages, split_folder, write_ros1_bag  # noqa: E402

from slearn.cli import EXIT_TRUNCATED, main
from slearn.io.bags import open_log

T0 = 1_700_000_000_000_000_000
SPEC_TOML = ('[[channel]]\ntopic = "/cmd"\nfield = "data"\nrole = "action"\n'
             '[[channel]]\ntopic = "/pos"\nfield = "data"\nrole = "observation"\n')


def run(*args, env=None):
    return CliRunner().invoke(main, [str(a) for a in args], env=env)


def text_bag(path: Path, n: int, size: int, compression=Ros1Writer.CompressionFormat.BZ2) -> Path:
    """A ROS 1 bag of ``n`` strings of ``size`` bytes each on /s, 10 ms apart, one chunk per
    four messages (text compresses to almost nothing: a small file, large chunks)."""
    store = get_typestore(Stores.ROS1_NOETIC)
    writer = Ros1Writer(path)
    writer.set_compression(compression)
    writer.chunk_threshold = 4 * size
    with writer:
        connection = writer.add_connection("/s", "std_msgs/msg/String", typestore=store)
        for i in range(n):
            message = store.types["std_msgs/msg/String"](data=chr(97 + i % 26) * size)
            writer.write(connection, T0 + i * 10_000_000, store.serialize_ros1(message, "std_msgs/msg/String"))
    return path


def chunk_offsets(data: bytes) -> list[int]:
    """Byte offsets of the chunk records of a ROS 1 bag (op 0x05)."""
    out, pos = [], len(b"#ROSBAG V2.0\n")
    while pos + 8 <= len(data):
        (n,) = struct.unpack_from("<I", data, pos)
        (m,) = struct.unpack_from("<I", data, pos + 4 + n)
        if b"op=\x05" in data[pos + 4:pos + 4 + n]:
            out.append(pos)
        pos += 8 + n + m
    return out


def set_declared_size(data: bytearray, chunk: int, size: int) -> None:
    at = data.index(b"size=", chunk) + len(b"size=")
    data[at:at + 4] = struct.pack("<I", size)


def read_all(path):
    with open_log(path) as log:
        messages = list(log.iter_messages())
        return messages, log.report


def cut_after_chunks(bag: Path, keep_last: bool = True) -> None:
    """Drop a ROS 1 bag's index (a killed recorder): it is then read by ros1_salvage."""
    data = bag.read_bytes()
    last = chunk_offsets(data)[-1]
    (n,) = struct.unpack_from("<I", data, last)
    (m,) = struct.unpack_from("<I", data, last + 4 + n)
    bag.write_bytes(data[:last + 8 + n + m] if keep_last else data[:last])


def rewrite(bag: Path, edit) -> None:
    data = bytearray(bag.read_bytes())
    edit(data, chunk_offsets(bytes(data)))
    bag.write_bytes(bytes(data))


@pytest.mark.parametrize("cut", [False, True], ids=["indexed", "salvaged"])
def test_ros1_chunks_over_the_memory_limit_are_not_decompressed(tmp_path, monkeypatch, cut):
    bag = text_bag(tmp_path / "big.bag", 40, 200_000)  # chunks of 800 kB, the file a few kB
    assert bag.stat().st_size < 100_000
    if cut:
        cut_after_chunks(bag)
    monkeypatch.setenv("SLEARN_MAX_CHUNK_MB", "2")
    messages, report = read_all(bag)
    assert len(messages) == 40 and report.truncated == cut
    rewrite(bag, lambda data, chunks: set_declared_size(data, chunks[1], 1 << 30))
    messages, report = read_all(bag)
    assert report.truncated and "chunk declares 1,073,741,824 bytes uncompressed" in report.describe()
    assert "SLEARN_MAX_CHUNK_MB" in report.describe() and "byte -1" not in report.describe()
    assert [m.data[4:5] for m in messages[:4]] == [b"a", b"b", b"c", b"d"]  # the first chunk is kept
    assert len(messages) == (36 if cut else 4)  # the index reader stops; the linear one skips


@pytest.mark.parametrize("cut", [False, True], ids=["indexed", "salvaged"])
def test_a_ros1_chunk_holding_more_than_it_declares_is_refused(tmp_path, cut):
    bag = text_bag(tmp_path / "lie.bag", 12, 10_000, Ros1Writer.CompressionFormat.LZ4)
    rewrite(bag, lambda data, chunks: set_declared_size(data, chunks[-1], 100))
    if cut:
        cut_after_chunks(bag)
    messages, report = read_all(bag)
    assert 0 < len(messages) < 12 and report.truncated
    assert "the chunk declares 100" in report.describe()


def test_a_zeroed_ros1_chunk_is_skipped_not_walked(tmp_path):
    bag = write_ros1_bag(tmp_path / "z.bag", pointer_messages(300))

    def zero_second_chunk(data, chunks):
        (n,) = struct.unpack_from("<I", data, chunks[1])
        (m,) = struct.unpack_from("<I", data, chunks[1] + 4 + n)
        data[chunks[1] + 8 + n:chunks[1] + 8 + n + m] = bytes(m)

    rewrite(bag, zero_second_chunk)
    cut_after_chunks(bag, keep_last=False)
    messages, report = read_all(bag)
    assert messages and report.n_skipped_chunks == 1
    assert "record header of 0 bytes" in report.describe()
    assert {m.offset for m in messages} <= set(chunk_offsets(bag.read_bytes()))  # each its chunk's


def write_bag(kind: str, path: Path, messages, short: set[int]) -> Path:
    """A pointer log as a ``bag``, a ``db3`` or a two-file rosbag2 ``folder``; the messages
    whose index is in ``short`` get a one-byte payload (it does not decode)."""
    ros1 = kind == "bag"
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.LATEST)
    types = {"/cmd": "std_msgs/msg/Int8", "/pos": "std_msgs/msg/Int32"}
    serialize = store.serialize_ros1 if ros1 else store.serialize_cdr
    payloads = [(topic, time_ns, serialize(store.types[types[topic]](data=value), types[topic]))
                for topic, time_ns, value in messages]
    payloads = [(t, ns, data[:1] if i in short else data) for i, (t, ns, data) in enumerate(payloads)]
    if ros1:
        from rosbags.rosbag1 import Writer
        with Writer(path) as writer:
            ids = {t: writer.add_connection(t, m, typestore=store) for t, m in types.items()}
            for topic, time_ns, data in payloads:
                writer.write(ids[topic], time_ns, data)
        return path
    from rosbags.rosbag2 import StoragePlugin, Writer
    parts = [payloads] if kind == "db3" else [payloads[:len(payloads) // 2], payloads[len(payloads) // 2:]]
    plugin = StoragePlugin.SQLITE3 if kind == "db3" else StoragePlugin.MCAP
    for i, part in enumerate(parts):
        with Writer(path / f"part{i}", version=9, storage_plugin=plugin) as writer:
            ids = {t: writer.add_connection(t, m, typestore=store) for t, m in types.items()}
            for topic, time_ns, data in part:
                writer.write(ids[topic], time_ns, data)
    if kind == "db3":
        return path / "part0" / "part0.db3"
    for i in range(2):
        (path / f"part{i}" / f"part{i}.mcap").rename(path / f"split_{i}.mcap")
    (path / "metadata.yaml").write_text(
        "rosbag2_bagfile_information:\n  version: 9\n  storage_identifier: mcap\n"
        "  relative_file_paths:\n  - split_0.mcap\n  - split_1.mcap\n")
    return path


@pytest.mark.parametrize("kind", ["db3", "bag", "folder"])
def test_undecodable_bag_messages_are_named_by_number_not_byte_minus_one(tmp_path, kind):
    messages = pointer_messages(100)
    short = {i for i, (topic, _, _) in enumerate(messages) if topic == "/pos"}
    short = set(sorted(short)[10:12])
    spec = tmp_path / "spec.toml"
    spec.write_text(SPEC_TOML)
    path = write_bag(kind, tmp_path / ("p.bag" if kind == "bag" else "p"), messages, short)
    result = run("learn", path, "--spec", spec, "-o", tmp_path / "lib.parquet", "-q")
    assert result.exit_code == EXIT_TRUNCATED, result.output
    assert f"do not decode (2 on /pos; first at message {min(short) + 1} read:" in result.stderr
    assert "byte -1" not in result.stderr


@pytest.mark.parametrize("make", ["x.bag", "x.db3", "metadata", "storage"])
def test_fifos_among_bag_inputs_are_refused_without_blocking(tmp_path, make):
    if make in ("x.bag", "x.db3"):
        target = tmp_path / make
        os.mkfifo(target)
    else:
        target = split_folder(tmp_path, pointer_messages(20))
        fifo = target / ("metadata.yaml" if make == "metadata" else "split_1.mcap")
        fifo.unlink()
        os.mkfifo(fifo)
    results = []
    thread = threading.Thread(target=lambda: results.append(run("info", target)), daemon=True)
    thread.start()
    thread.join(20)
    assert results, f"slearn info blocked on a FIFO ({make})"
    assert results[0].exit_code == 1 and "not a regular file" in results[0].stderr


def test_an_output_inside_an_input_bag_folder_is_refused_even_with_force(tmp_path):
    folder = split_folder(tmp_path, pointer_messages(200))
    spec = tmp_path / "spec.toml"
    spec.write_text(SPEC_TOML)
    for target in (folder / "split_1.mcap", folder / "metadata.yaml"):
        before = target.read_bytes()
        for source in (folder, folder / "metadata.yaml"):
            result = run("learn", source, "--spec", spec, "-o", target, "--force")
            assert result.exit_code == 1 and "even with --force" in result.stderr, result.output
            suggested = run("info", source, "--suggest-spec", target, "--force")
            assert suggested.exit_code == 1 and "input" in suggested.stderr
        assert target.read_bytes() == before
    assert run("learn", folder, "--spec", spec, "-o", folder / "lib.parquet").exit_code == 0


def test_annotated_copies_and_layouts_of_bags_never_replace_an_input(tmp_path):
    folder = split_folder(tmp_path, pointer_messages(200))
    spec = tmp_path / "out.layout.json"  # the layout written beside out.mcap would be this
    spec.write_text(SPEC_TOML)
    lib = tmp_path / "lib.parquet"
    assert run("learn", folder, "--spec", spec, "-o", lib, "-q").exit_code == 0
    before = (folder / "split_0.mcap").read_bytes()
    out = run("replay", lib, folder, "--write-mcap", folder / "split_0.mcap", "--force", "-q")
    assert out.exit_code == 1 and "is in an input folder" in out.stderr, out.output
    out = run("replay", "--spec", spec, folder, "--write-mcap", tmp_path / "out.mcap", "--force", "-q")
    assert out.exit_code == 1 and "is also an input" in out.stderr, out.output
    assert spec.read_text() == SPEC_TOML and not (tmp_path / "out.mcap").exists()
    written = run("replay", lib, folder, "--write-mcap", tmp_path / "copy.mcap", "-q")
    assert written.exit_code == 0, written.output
    assert (tmp_path / "copy.layout.json").exists() and (folder / "split_0.mcap").read_bytes() == before
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]
