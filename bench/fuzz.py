"""Fuzz benchmark: hostile inputs through slearn's readers, 10^4 cases per class, one process.

Classes:
  mcap     small valid logs (zstd, lz4, uncompressed chunks, unchunked) with 1-4 mutations:
           bit flips, byte overwrites, truncations, records duplicated, removed or swapped,
           record lengths and opcodes replaced, zero runs inserted; read by ``slearn info``'s
           profiler and learned through the ``slearn learn`` path.
  bomb     decompression bombs and lying chunks: zstd and lz4 payloads whose real size (up to
           200 MiB of zeros, message or tiny-record floods) differs from or matches the declared
           one, huge declared sizes, missing content sizes, wrong labels and CRCs, chunks
           overlapping in time; read and learned as above.
  parquet  a small library with its JSON header mutated (fields replaced by random JSON or
           removed, bytes of the text replaced) or one bit of its Parquet footer flipped; read by
           load_library and describe (``slearn info LIB``).
  spec     random spec documents (every key, random JSON values) and random readings through
           the symbolizers; random ``--channel`` shorthands.

Prints, per class: cases, tracebacks (exceptions other than SlearnError; must be 0), hangs
(cases over --timeout seconds; must be 0), the slowest case, the largest input and the
process's peak RSS so far (must stay under 500 MB; every input is under 10 MB).

    python bench/fuzz.py [--cases 10000] [--seed 0] [--classes mcap,bomb,parquet,spec]
"""

from __future__ import annotations

import argparse
import json
import random
import resource
import signal
import sys
import tempfile
import time
import traceback
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # the MCAP record writer

import lz4.frame  # noqa: E402
import mcap_bytes as mb  # noqa: E402
import pyarrow.parquet as pq  # noqa: E402
import zstandard  # noqa: E402
from fuzz_cases import SPEC, base_logs, json_paths, mutated  # noqa: E402

from slearn.core.library import PatternLibrary  # noqa: E402
from slearn.core.vocabulary import Vocabulary  # noqa: E402
from slearn.errors import SlearnError  # noqa: E402
from slearn.io.library_file import METADATA_KEY, load_library, save_library  # noqa: E402
from slearn.io.library_info import describe  # noqa: E402
from slearn.io.serialize import read_episodes  # noqa: E402
from slearn.io.spec import Spec, parse_channel_option  # noqa: E402
from slearn.jobs.info import describe_log  # noqa: E402

MAX_INPUT = 10 << 20
MIB = 1 << 20


class Hang(BaseException):
    """A case ran past the timeout (BaseException: slearn's handlers must not catch it)."""


def _alarm(signum, frame):
    raise Hang()


# --- mcap -----------------------------------------------------------------------------------

class RandomPicks:
    """A mutation's choices from ``random.Random``."""

    def __init__(self, rng: random.Random) -> None:
        self.rng = rng

    def integer(self, lo: int, hi: int) -> int:
        return self.rng.randint(lo, hi)

    def choice(self, options):
        return self.rng.choice(options)

    def binary(self, most: int) -> bytes:
        return self.rng.randbytes(self.rng.randint(1, most))


def mutate(rng: random.Random, data: bytes) -> bytes:
    return mutated(data, RandomPicks(rng), 100_000)


def read_log(path: Path) -> None:
    guarded(describe_log, path)
    guarded(learn_log, path)


def learn_log(path: Path) -> None:
    library = PatternLibrary(3)
    for _, episode, _ in read_episodes([path], SPEC, Vocabulary()):
        library.learn(episode)


# --- bombs ------------------------------------------------------------------------------------

def _zstd_stream(piece: bytes, total: int, content_size: bool) -> bytes:
    compressor = zstandard.ZstdCompressor().compressobj(size=total if content_size else -1)
    out, left = [], total
    while left:
        part = piece[:left] if left < len(piece) else piece
        out.append(compressor.compress(part))
        left -= len(part)
    return b"".join(out) + compressor.flush()


def _lz4_stream(piece: bytes, total: int) -> bytes:
    compressor = lz4.frame.LZ4FrameCompressor()
    out, left = [compressor.begin(source_size=total)], total
    while left:
        part = piece[:left] if left < len(piece) else piece
        out.append(compressor.compress(part))
        left -= len(part)
    return b"".join(out) + compressor.flush()


def bomb_payloads() -> list[tuple[str, str, bytes, int]]:
    """``(name, compression, data, real size)``; made in 1 MiB pieces, never whole in memory."""
    pieces = {"zeros": (bytes(MIB), 1),
              "tiny": (b"".join(mb.message(i % 1000, b"") for i in range(MIB // 31)), 31),
              "flood": (mb.record(0x80, b"") * (MIB // 9), 9),
              "messages": (b"".join(mb.message(i, b'{"v": 1.5}') for i in range(MIB // 41)), 41)}
    out = []
    for name, (piece, record) in pieces.items():
        for kib, lz4_too in ((16, True), (64, True), (48 << 10, True), (64 << 10, False), (200 << 10, False)):
            size = (kib << 10) - (kib << 10) % record
            data = piece[:size] if size <= len(piece) else piece
            for content_size in (True, False):
                out.append((f"zstd-{name}-{kib}K{'' if content_size else '-nosize'}", "zstd",
                            _zstd_stream(data, size, content_size), size))
            if lz4_too:
                out.append((f"lz4-{name}-{kib}K", "lz4", _lz4_stream(data, size), size))
    return [p for p in out if len(p[2]) < MAX_INPUT // 4]


def bomb_file(rng: random.Random, payloads: list) -> bytes:
    """A log with one to three bomb chunks beside a normal one: mostly small bombs and lies
    that must be refused cheaply, and 1 % of chunks of 48-200 MiB (these take a second or
    two each: what they hold is walked and decoded until the memory limit stops it)."""
    small = [p for p in payloads if p[3] <= MIB]
    large = [p for p in payloads if p[3] > MIB]
    parts = [mb.chunk(b"".join(mb.message(t, b'{"v": 2.5}') for t in range(10)))]
    for _ in range(rng.choice([1, 1, 1, 2, 3])):
        name, compression, data, size = rng.choice(large if rng.random() < 0.01 else small)
        declared = rng.choice([size, size, size, size - 1, size + 1, size + 1, 1 << 40, 1 << 40,
                               rng.randrange(1 << 30), 0])
        label = compression if rng.random() < 0.9 else rng.choice(["zstd", "lz4", "", "bz2"])
        start = 0 if rng.random() < 0.5 else rng.randrange(10 ** 9)
        parts.append(mb.chunk(data=data, compression=label, declared=max(declared, 0), start=start,
                              crc=rng.choice([0, 0, rng.randrange(1 << 32)])))
    if rng.random() < 0.2:
        parts.append(bytes(rng.randrange(1, 2 * MIB)))
    data = mb.log(*parts)
    return data[:rng.randrange(len(data))] if rng.random() < 0.1 else data


# --- parquet ------------------------------------------------------------------------------------

def base_library(folder: Path) -> Path:
    import numpy as np

    from slearn.core.stream import Episode

    rng = np.random.default_rng(0)
    vocabulary = Vocabulary()
    for channel, role in (("/b", "action"), ("/a", "observation")):
        vocabulary.add_channel(channel, role)
    for value in ("L", "R"):
        vocabulary.symbol("/b", value)
    for value in range(6):
        vocabulary.symbol("/a", value)
    library = PatternLibrary(3)
    steps = [((), (2,))] + [((int(rng.integers(0, 2)),), (int(rng.integers(2, 8)),)) for _ in range(300)]
    library.learn(Episode.from_steps(steps))
    path = folder / "good.parquet"
    provenance = {"slearn_version": "bench",
                  "inputs": [{"path": "a.mcap", "size_bytes": 1, "sha256": "0" * 64}],
                  "time": "2020-01-01T00:00:00Z", "time_unix": 1577836800, "time_source": "bench"}
    spec = Spec.from_dict({"mode": "message", "channel": [
        {"topic": "/b", "field": "c", "role": "action", "values": ["L", "R"]},
        {"topic": "/a", "field": "v", "role": "observation", "range": [0, 6], "count": 6}]})
    save_library(path, library, vocabulary, spec=spec, params={"scoring": "adaptive"},
                 provenance=provenance)
    return path


def random_json(rng: random.Random, depth: int = 0):
    kind = rng.randrange(9 if depth < 3 else 6)
    if kind == 6:
        return [random_json(rng, depth + 1) for _ in range(rng.randrange(4))]
    if kind == 7:
        keys = [rng.choice(["a", "path", "rule", "x"]) for _ in range(rng.randrange(3))]
        return {key: random_json(rng, depth + 1) for key in keys}
    scalars = [None, True, rng.randrange(-2 ** 70, 2 ** 70),
               rng.choice([0.5, -1e308, 1e-320, 10.0 ** rng.randint(-5, 20)]),
               rng.choice(["", "x", "adaptive", "observation", "\u00e9" * rng.randint(0, 5)]),
               rng.randrange(-3, 100), None, None, [[[[]]]]]
    return scalars[kind]


def mutated_header(rng: random.Random, doc: dict) -> bytes:
    if rng.random() < 0.3:
        text = bytearray(json.dumps(doc).encode())
        for _ in range(rng.randint(1, 3)):
            text[rng.randrange(len(text))] = rng.randrange(256)
        return bytes(text)
    doc = json.loads(json.dumps(doc))
    for _ in range(rng.randint(1, 3)):
        path = rng.choice([p for p in json_paths(doc) if p])
        target = doc
        for key in path[:-1]:
            target = target[key]
        if isinstance(target, dict) and rng.random() < 0.2:
            del target[path[-1]]
        else:
            target[path[-1]] = random_json(rng)
    return json.dumps(doc).encode()


def read_library(path: Path) -> None:
    guarded(load_library, path)
    guarded(describe, path)


# --- spec ---------------------------------------------------------------------------------------

KEYS = ["field", "name", "values", "max_symbols", "width", "origin", "range", "count", "edges",
        "quantiles", "wrap", "bogus"]


def random_value(rng: random.Random):
    return rng.choice([None, True, False, rng.randrange(-2 ** 70, 2 ** 70), rng.randrange(-3, 10 ** 7),
                       rng.choice([0.0, -0.0, 5e-324, 1e308, float("inf"), float("nan"), 0.25, 1e-9]),
                       "x", [rng.uniform(-5, 5) for _ in range(rng.randrange(4))],
                       [rng.choice([1, 1.0, "a", [1, 2], float("nan")]) for _ in range(rng.randrange(4))],
                       list(range(rng.randrange(4)))[::-1]])


def random_spec(rng: random.Random) -> dict:
    entries = []
    for _ in range(rng.randint(1, 3)):
        entry = {"topic": rng.choice(["/a", "/a", "", 5, [1]]), "role": rng.choice(["action", "observation", "x"])}
        entry.update({key: random_value(rng) for key in rng.sample(KEYS, rng.randint(0, 4))})
        entries.append(entry)
    data = {"channel": entries}
    for key in rng.sample(["mode", "tick_ms", "tick_ns"], rng.randint(0, 2)):
        data[key] = rng.choice(["tick", "change", "x"]) if key == "mode" else random_value(rng)
    return data


def check_spec(rng: random.Random) -> None:
    spec = guarded(Spec.from_dict, random_spec(rng))
    readings = [rng.choice([10 ** 400, -(10 ** 400), float("nan"), 1e308, -1e308, 3.5, "7", True, None, [1]])
                for _ in range(8)]
    if spec is not None:
        for entry in spec.channels:
            for x in readings:
                entry.symbolizer.symbol_value(x)
    text = "".join(rng.choice("/ab:=;,.0123456789-enaifvlusrgcotwq_[]") for _ in range(rng.randrange(60)))
    entry = guarded(parse_channel_option, text)
    if entry is not None:
        guarded(Spec.from_dict, {"channel": [entry]})


# --- running ------------------------------------------------------------------------------------

def guarded(function, *args):
    """``function(*args)``; ``None`` when it refused the input with a SlearnError."""
    try:
        return function(*args)
    except SlearnError:
        return None


class Tally:
    def __init__(self, name: str) -> None:
        self.name, self.cases, self.tracebacks, self.hangs = name, 0, 0, 0
        self.slowest, self.largest = 0.0, 0
        self.examples: dict[str, str] = {}

    def run(self, case, timeout: float, size: int = 0) -> None:
        self.cases += 1
        self.largest = max(self.largest, size)
        start = time.perf_counter()
        signal.setitimer(signal.ITIMER_REAL, timeout)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                case()
        except Hang:
            self.hangs += 1
        except Exception as err:  # noqa: BLE001 - what the benchmark counts
            self.tracebacks += 1
            frame = traceback.extract_tb(err.__traceback__)[-1]
            key = f"{type(err).__name__} at {Path(frame.filename).name}:{frame.lineno}"
            self.examples.setdefault(key, str(err)[:160])
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
        self.slowest = max(self.slowest, time.perf_counter() - start)

    def line(self, seconds: float) -> str:
        rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        return (f"{self.name:<8} {self.cases:>7,} {self.tracebacks:>10} {self.hangs:>6} "
                f"{self.slowest:>10.2f} {self.largest / MIB:>9.2f} {rss:>10.0f} {seconds:>8.0f}")


def fuzz_logs(tally: Tally, files: list[bytes], n: int, rng: random.Random, folder: Path, timeout: float,
              make) -> None:
    path = folder / "case.mcap"
    for _ in range(n):
        data = make(rng, files)
        assert len(data) < MAX_INPUT
        path.write_bytes(data)
        tally.run(lambda: read_log(path), timeout, len(data))


def fuzz_parquet(tally: Tally, n: int, rng: random.Random, folder: Path, timeout: float) -> None:
    good = base_library(folder)
    table, data = pq.read_table(good), good.read_bytes()
    doc = json.loads(table.schema.metadata[METADATA_KEY])
    footer = len(data) - 8 - int.from_bytes(data[-8:-4], "little")
    path = folder / "case.parquet"
    for i in range(n):
        if i % 2:
            pq.write_table(table.replace_schema_metadata({METADATA_KEY: mutated_header(rng, doc)}), path)
        else:
            flipped = bytearray(data)
            flipped[rng.randrange(footer, len(data))] ^= 1 << rng.randrange(8)
            path.write_bytes(bytes(flipped))
        tally.run(lambda: read_library(path), timeout, path.stat().st_size)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=10_000, help="cases per class")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--timeout", type=float, default=10.0, help="seconds before a case is a hang")
    parser.add_argument("--classes", default="mcap,bomb,parquet,spec")
    args = parser.parse_args()
    signal.signal(signal.SIGALRM, _alarm)
    print(f"{'class':<8} {'cases':>7} {'tracebacks':>10} {'hangs':>6} {'slowest s':>10} "
          f"{'input MB':>9} {'peak RSS MB':>10} {'time s':>8}")
    tallies = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for name in args.classes.split(","):
            rng, tally, start = random.Random(f"{args.seed}-{name}"), Tally(name), time.perf_counter()
            if name == "mcap":
                fuzz_logs(tally, base_logs(60, 12), args.cases, rng, folder, args.timeout,
                          lambda r, files: mutate(r, r.choice(files)))
            elif name == "bomb":
                fuzz_logs(tally, bomb_payloads(), args.cases, rng, folder, args.timeout, bomb_file)
            elif name == "parquet":
                fuzz_parquet(tally, args.cases, rng, folder, args.timeout)
            elif name == "spec":
                for _ in range(args.cases):
                    tally.run(lambda rng=rng: check_spec(rng), args.timeout)
            print(tally.line(time.perf_counter() - start), flush=True)
            tallies.append(tally)
    for tally in tallies:
        for key, message in tally.examples.items():
            print(f"  {tally.name}: {key}: {message}")


if __name__ == "__main__":
    main()
