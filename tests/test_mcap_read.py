"""The MCAP reader: log-time order with stable ties, every layout, salvage of broken files."""

from __future__ import annotations

import json
import tracemalloc
import warnings
from pathlib import Path

import pytest
from fixtures import SHARED_MCAP
from mcap.writer import CompressionType, IndexType, Writer

from slearn.errors import InputError, TruncatedLogWarning
from slearn.io.mcap_read import McapLog, ReadReport, iter_messages

SHARED = SHARED_MCAP
DERIVED = SHARED / "derived"
PR2_FIRST = "pr2_pr1012_sensors_ros2_first1.0s__"


def write_log(path, messages, *, chunk_size=1 << 20, compression=CompressionType.ZSTD,
              use_chunking=True, index_types=IndexType.ALL, summary=True, repeat=True):
    """Write ``(topic, log_time_ns, payload dict)`` messages as a JSON MCAP file."""
    with open(path, "wb") as f:
        writer = Writer(f, chunk_size=chunk_size, compression=compression,
                        use_chunking=use_chunking, index_types=index_types,
                        repeat_channels=repeat, repeat_schemas=repeat,
                        use_statistics=summary, use_summary_offsets=summary)
        writer.start(profile="", library="slearn-tests")
        schema = writer.register_schema("Thing", "jsonschema", b'{"type": "object"}')
        channels = {}
        for i, (topic, log_time, payload) in enumerate(messages):
            if topic not in channels:
                channels[topic] = writer.register_channel(topic, "json", schema)
            writer.add_message(channels[topic], log_time=log_time, publish_time=log_time,
                               sequence=i, data=json.dumps(payload).encode())
        writer.finish()
    return Path(path)


def read_all(path, **kwargs):
    return [(m.topic, m.log_time_ns, json.loads(m.data)["i"]) for m in iter_messages(path, **kwargs)]


def _shuffled_messages(n=300):
    # log times jump back and forth across chunk boundaries, with many ties
    return [("/a" if i % 3 else "/b", (i * 7919) % 50, {"i": i}) for i in range(n)]


def _expected(messages):
    return sorted(((t, p["i"], topic) for topic, t, p in messages), key=lambda e: e[0])


@pytest.mark.parametrize("options", [
    dict(),
    dict(chunk_size=200),
    dict(chunk_size=200, compression=CompressionType.LZ4),
    dict(chunk_size=200, compression=CompressionType.NONE, index_types=IndexType.NONE),
    dict(chunk_size=200, index_types=IndexType.CHUNK, repeat=False),
    dict(use_chunking=False, index_types=IndexType.NONE, summary=False, repeat=False),
], ids=["one-chunk", "small-chunks", "lz4", "no-index", "chunk-index-only", "unchunked"])
def test_log_time_order_with_ties_in_file_order(tmp_path, options):
    messages = _shuffled_messages()
    path = write_log(tmp_path / "x.mcap", messages, **options)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = [(t, i, topic) for topic, t, i in read_all(path)]
    assert got == _expected(messages)


def test_unchunked_log_larger_than_a_block_is_merged(tmp_path):
    messages = [("/a", (i * 37) % 1000, {"i": i}) for i in range(10_000)]
    path = write_log(tmp_path / "x.mcap", messages, use_chunking=False, index_types=IndexType.NONE)
    assert [(t, i) for _, t, i in read_all(path)] == [(t, i) for t, i, _ in _expected(messages)]


def test_topic_filter_and_report(tmp_path):
    path = write_log(tmp_path / "x.mcap", _shuffled_messages(30))
    report = ReadReport("")
    got = read_all(path, topics=["/b"], report=report)
    assert {topic for topic, _, _ in got} == {"/b"}
    assert report.n_messages == len(got) == 10
    assert not report.truncated


def test_header_and_channels_known_after_open(tmp_path):
    path = write_log(tmp_path / "x.mcap", _shuffled_messages(6))
    with McapLog(path) as log:
        assert log.library == "slearn-tests"
        assert sorted(c.topic for c in log.channels.values()) == ["/a", "/b"]
        channel = next(iter(log.channels.values()))
        assert (channel.message_encoding, channel.schema_name, channel.schema_encoding) == (
            "json", "Thing", "jsonschema")


def test_channel_defined_in_a_later_opened_chunk(tmp_path):
    # the channel record lives in chunk 1 (late log times); chunk 2 is earlier in log time
    # and there are no channels in the summary: its messages must still resolve
    messages = [("/a", 1000 + i, {"i": i}) for i in range(20)] + [("/a", i, {"i": 100 + i}) for i in range(20)]
    path = write_log(tmp_path / "x.mcap", messages, chunk_size=300, repeat=False)
    got = read_all(path)
    assert [i for _, _, i in got] == list(range(100, 120)) + list(range(20))


def test_not_mcap_is_an_input_error(tmp_path):
    path = tmp_path / "x.mcap"
    path.write_bytes(b"hello world, not mcap")
    with pytest.raises(InputError, match="not an MCAP file"):
        list(iter_messages(path))
    with pytest.raises(InputError, match="cannot open"):
        list(iter_messages(tmp_path / "missing.mcap"))


@pytest.mark.parametrize("use_chunking", [True, False])
def test_every_truncation_salvages_a_prefix_and_warns(tmp_path, use_chunking):
    messages = [("/a", i, {"i": i}) for i in range(200)]
    full = write_log(tmp_path / "full.mcap", messages, chunk_size=400,
                     compression=CompressionType.NONE, use_chunking=use_chunking).read_bytes()
    previous = 0
    for cut in range(8, len(full), 211):
        path = tmp_path / "cut.mcap"
        path.write_bytes(full[:cut])
        report = ReadReport("")
        with pytest.warns(TruncatedLogWarning) as caught:
            got = [i for _, _, i in read_all(path, report=report)]
        assert got == list(range(len(got)))  # a prefix, in order
        assert len(got) >= previous
        previous = len(got)
        assert report.truncated and report.broken_at <= cut and report.n_messages == len(got)
        text = str(caught[0].message)
        assert str(path) in text and f"salvaged {len(got)} messages" in text and "byte" in text
    assert previous > 150


def test_corrupt_chunk_is_skipped_and_reported(tmp_path):
    messages = [("/a", i, {"i": i}) for i in range(100)]
    data = bytearray(write_log(tmp_path / "x.mcap", messages, chunk_size=300,
                               compression=CompressionType.ZSTD).read_bytes())
    data[400:420] = b"\xff" * 20  # inside the compressed records of an early chunk
    path = tmp_path / "bad.mcap"
    path.write_bytes(bytes(data))
    report = ReadReport("")
    with pytest.warns(TruncatedLogWarning):
        got = [i for _, _, i in read_all(path, report=report)]
    assert 50 < len(got) < 100 and got == sorted(got)
    assert report.n_skipped_chunks >= 1


def test_memory_does_not_grow_with_log_length(tmp_path):
    messages = [("/a", i, {"i": i, "pad": "x" * 100}) for i in range(30_000)]
    path = write_log(tmp_path / "big.mcap", messages, chunk_size=64 << 10)
    tracemalloc.start()
    count = sum(1 for _ in iter_messages(path))
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert count == 30_000
    assert peak < 2_000_000  # the payloads alone are ~3.5 MB


# --- shared real files ------------------------------------------------------------------

def _conformance_expected(json_path):
    records = json.loads(json_path.read_text())["records"]
    messages = []
    for record in records:
        if record["type"] == "Message":
            f = dict(record["fields"])
            messages.append((int(f["log_time"]), int(f["publish_time"]), int(f["sequence"]),
                             int(f["channel_id"]), bytes(int(b) for b in f["data"])))
    return sorted(messages, key=lambda m: m[0])


@pytest.mark.shared
def test_all_conformance_files_yield_exactly_their_messages():
    folder = SHARED / "conformance"
    if not folder.is_dir():
        pytest.skip("../shared/data/mcap/conformance is not available")
    files = sorted(folder.glob("*/*.json"))
    assert len(files) == 416
    for json_path in files:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            got = [(m.log_time_ns, m.publish_time_ns, m.sequence, m.channel_id, m.data)
                   for m in iter_messages(json_path.with_suffix(".mcap"))]
        assert got == _conformance_expected(json_path), json_path.name


def _derived(name):
    path = DERIVED / (PR2_FIRST + name)
    if not path.exists():
        pytest.skip(f"{path} is not available")
    return path


@pytest.mark.shared
@pytest.mark.parametrize("name", ["chunkindex_no_messageindex", "lz4_chunk64k", "unchunked_nosummary",
                                  "uncompressed_chunk64k", "zstd_chunk16k"])
def test_derived_layouts_give_the_same_453_messages(name):
    reference = [(m.log_time_ns, m.topic, m.data) for m in iter_messages(_derived("zstd_chunk16k.mcap"))]
    got = [(m.log_time_ns, m.topic, m.data) for m in iter_messages(_derived(name + ".mcap"))]
    assert len(got) == 453
    assert got == reference
    assert [t for t, _, _ in got] == sorted(t for t, _, _ in got)


@pytest.mark.shared
@pytest.mark.parametrize("permille, salvaged", [(500, 204), (999, 453)])
def test_derived_truncated_files_salvage_and_warn(permille, salvaged):
    path = _derived(f"uncompressed_chunk64k__truncated_{permille}permille.mcap")
    report = ReadReport("")
    with pytest.warns(TruncatedLogWarning, match=f"salvaged {salvaged} messages; broke at byte"):
        count = sum(1 for _ in iter_messages(path, report=report))
    assert count == report.n_messages == salvaged
    assert report.truncated and 0 < report.broken_at <= path.stat().st_size


def test_random_corruption_never_escapes_as_a_traceback(tmp_path):
    import random
    rng = random.Random(7)
    sources = [write_log(tmp_path / f"{name}.mcap", _shuffled_messages(120), **options).read_bytes()
               for name, options in (("chunked", dict(chunk_size=300)),
                                     ("unchunked", dict(use_chunking=False, index_types=IndexType.NONE)))]
    path = tmp_path / "fuzz.mcap"
    for _ in range(300):
        data = bytearray(rng.choice(sources))
        for _ in range(rng.randint(1, 6)):
            data[rng.randrange(len(data))] = rng.randrange(256)
        path.write_bytes(bytes(data[:rng.randrange(len(data))] if rng.random() < 0.3 else data))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", TruncatedLogWarning)
            try:
                times = [m.log_time_ns for m in iter_messages(path)]
            except InputError:
                continue
        assert len(times) <= 120


# --- hostile chunks: bombs, sizes that lie, zero runs, memory limits ----------------------

import mcap_bytes as mb  # noqa: E402

from slearn.io import mcap_read  # noqa: E402


def _read_bytes(tmp_path, data, name="x.mcap"):
    path = tmp_path / name
    path.write_bytes(data)
    report = ReadReport("")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", TruncatedLogWarning)
        got = [(m.log_time_ns, m.data) for m in iter_messages(path, report=report)]
    return got, report


def _messages(n, start=0, data=b'{"v":1}'):
    return b"".join(mb.message(start + i, data) for i in range(n))


def test_a_chunk_declaring_more_than_the_limit_is_skipped_without_decompressing(tmp_path, monkeypatch):
    real = mcap_read.decompress_exactly
    sizes = []

    def recorded(compression, data, size):
        sizes.append(size)
        return real(compression, data, size)

    monkeypatch.setattr(mcap_read, "decompress_exactly", recorded)
    bomb = mb.chunk(_messages(10), declared=1 << 40)
    got, report = _read_bytes(tmp_path, mb.log(bomb, mb.chunk(_messages(5, 100))))
    assert [t for t, _ in got] == [100, 101, 102, 103, 104]
    assert report.n_skipped_chunks == 1 and sizes == [5 * len(mb.message(0))]
    assert "declares 1,099,511,627,776 bytes uncompressed" in report.reason
    assert "raise SLEARN_MAX_CHUNK_MB" in report.describe()


@pytest.mark.parametrize("compression", ["zstd", "lz4", ""])
@pytest.mark.parametrize("lie", [-1, 1, 1000])
def test_records_that_differ_from_the_declared_size_are_a_damaged_chunk(tmp_path, compression, lie):
    records = _messages(20)
    bad = mb.chunk(records, compression, declared=len(records) + lie)
    got, report = _read_bytes(tmp_path, mb.log(bad, mb.chunk(_messages(3, 50), compression)))
    assert [t for t, _ in got] == [50, 51, 52]
    assert report.n_skipped_chunks == 1 and report.broken_at == len(mb.MAGIC + mb.header() + mb.schema()
                                                                     + mb.channel())


def test_a_zstd_stream_longer_than_declared_stops_at_the_declared_size(tmp_path):
    import zstandard
    compressor = zstandard.ZstdCompressor().compressobj()
    data = compressor.compress(b"\0" * (8 << 20)) + compressor.flush()  # no content size in the frame
    got, report = _read_bytes(tmp_path, mb.log(mb.chunk(data=data, declared=1000)))
    assert got == [] and report.n_skipped_chunks == 1 and "decompress" in report.reason


def test_a_chunk_of_zeros_is_refused_at_its_first_record(tmp_path):
    got, report = _read_bytes(tmp_path, mb.log(mb.chunk(b"\0" * (16 << 20)), mb.chunk(_messages(2, 7))))
    assert [t for t, _ in got] == [7, 8]
    assert "zero bytes instead of a record at +0" in report.reason


def test_a_zero_run_between_records_is_skipped_whole_and_reading_goes_on(tmp_path):
    zeros = b"\0" * (3 << 20)
    data = mb.log(_messages(5), zeros, _messages(5, 10))
    got, report = _read_bytes(tmp_path, data)
    assert [t for t, _ in got] == [0, 1, 2, 3, 4, 10, 11, 12, 13, 14]
    assert report.reason == f"{len(zeros)} zero bytes instead of records"
    assert report.broken_at == data.index(zeros)


def test_a_chunk_of_tiny_messages_over_the_limit_is_skipped(tmp_path, monkeypatch):
    data = mb.log(mb.chunk(_messages(100_000, data=b"")), mb.chunk(_messages(3, 10 ** 6)))
    got, report = _read_bytes(tmp_path, data)
    assert len(got) == 100_003 and not report.truncated
    monkeypatch.setenv("SLEARN_MAX_CHUNK_MB", "10")  # 3.1 MB of records, 25 MB of index
    got, report = _read_bytes(tmp_path, data)
    assert len(got) == 3 and report.n_skipped_chunks == 1
    assert "3,100,000 bytes of records with at least 32,768 records: over the 10 MiB of chunk data " \
           "read at once; raise SLEARN_MAX_CHUNK_MB to read it" in report.reason


def test_chunks_overlapping_in_time_share_the_memory_limit(tmp_path, monkeypatch):
    monkeypatch.setenv("SLEARN_MAX_CHUNK_MB", "1")
    payload = b'{"pad":"' + b"x" * 1000 + b'"}'
    overlapping = mb.log(*[mb.chunk(_messages(300, data=payload)) for _ in range(4)])
    got, report = _read_bytes(tmp_path, overlapping)
    assert len(got) == 600 and report.n_skipped_chunks == 2
    assert "over the 1 MiB of chunk data read at once with 0.7 MiB held by chunks overlapping in time" \
        in report.reason
    successive = mb.log(*[mb.chunk(_messages(300, 1000 * k, payload), start=1000 * k, end=1000 * k + 299)
                          for k in range(4)])
    got, report = _read_bytes(tmp_path, successive)
    assert len(got) == 1200 and not report.truncated


@pytest.mark.parametrize("value", ["0", "-3", "lots", "2000000"])
def test_a_bad_memory_limit_is_an_input_error(tmp_path, monkeypatch, value):
    path = tmp_path / "x.mcap"
    path.write_bytes(mb.log(_messages(2)))
    monkeypatch.setenv("SLEARN_MAX_CHUNK_MB", value)
    with pytest.raises(InputError, match="SLEARN_MAX_CHUNK_MB=.*whole number of MiB from 1 to 1,048,576"):
        McapLog(path)


def test_a_fifo_is_refused_without_opening_it(tmp_path):
    import os
    fifo = tmp_path / "pipe.mcap"
    os.mkfifo(fifo)
    with pytest.raises(InputError, match="not a regular file"):
        McapLog(fifo)  # opening a FIFO would block until a writer came


def test_metadata_and_attachments_over_the_limit_or_damaged_are_skipped_and_noted(tmp_path):
    path = tmp_path / "extras.mcap"
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start(profile="ros2", library="test")
        writer.add_metadata("small", {"k": "v"})
        writer.add_attachment(1, 2, "big.bin", "application/octet-stream", bytes(2 << 20))
        writer.add_attachment(3, 4, "small.txt", "text/plain", b"hello")
        writer.add_metadata("damaged", {"a": "b"})
        writer.finish()
    data = bytearray(path.read_bytes())
    at = data.index(b"damaged") + len(b"damaged")
    data[at:at + 4] = (1 << 31).to_bytes(4, "little")  # its map says 2 GiB of entries
    path.write_bytes(bytes(data))
    with McapLog(path, max_chunk_bytes=1 << 20) as log:
        assert [(a.name, a.data) for a in log.iter_attachments()] == [("small.txt", b"hello")]
        described = log.report.describe()  # the first break is the one described
        assert list(log.iter_metadata()) == [("small", {"k": "v"})]
    assert "(opcode 0x09) of 2,097,2" in described and "raise SLEARN_MAX_CHUNK_MB" in described
