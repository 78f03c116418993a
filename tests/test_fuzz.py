"""Fuzzing (hypothesis, bounded to about a minute): mutated MCAP logs, mutated library
headers and footers, random spec values. Nothing may escape but a ``SlearnError``.

``bench/fuzz.py`` runs the same classes at 10^4 cases each and measures hangs and memory.
"""

from __future__ import annotations

import json
import warnings

import pyarrow.parquet as pq
import pytest
from fuzz_cases import SPEC, base_logs, json_paths, mutated
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_storage import learned, save

from slearn.core.library import PatternLibrary
from slearn.core.vocabulary import Vocabulary
from slearn.errors import SlearnError
from slearn.io.library_file import METADATA_KEY, load_library
from slearn.io.library_info import describe
from slearn.io.serialize import read_episodes
from slearn.io.spec import Spec, parse_channel_option
from slearn.jobs.info import describe_log


def fuzz(examples: int):
    """Fixed examples (CI is reproducible), no deadline; the four tests take about 40 s."""
    return settings(max_examples=examples, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])



BASES = base_logs()


class DrawnPicks:
    """A mutation's choices drawn by hypothesis (so failures shrink)."""

    def __init__(self, draw) -> None:
        self.draw = draw

    def integer(self, lo: int, hi: int) -> int:
        return self.draw(st.integers(lo, hi))

    def choice(self, options):
        return self.draw(st.sampled_from(list(options)))

    def binary(self, most: int) -> bytes:
        return self.draw(st.binary(min_size=1, max_size=most))


@st.composite
def mutated_log(draw) -> bytes:
    return mutated(draw(st.sampled_from(BASES)), DrawnPicks(draw), 5000)


def only_slearn_errors(function, *args):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            return function(*args)
        except SlearnError:
            return None


def learn_log(path):
    library = PatternLibrary(3)
    for _, episode, _ in read_episodes([path], SPEC, Vocabulary()):
        library.learn(episode)
    return library


@fuzz(3000)
@given(data=mutated_log())
def test_mutated_logs_raise_nothing_but_slearn_errors(tmp_path, data):
    path = tmp_path / "fuzz.mcap"
    path.write_bytes(data)
    only_slearn_errors(describe_log, path)
    only_slearn_errors(learn_log, path)


# --- library headers and footers ------------------------------------------------------------

@pytest.fixture(scope="module")
def library_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("lib") / "good.parquet"
    save(path, learned(episodes=2, steps=60))
    return path


JSON = st.recursive(st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=8),
                    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=6), inner, max_size=3),
                    max_leaves=8)


@st.composite
def mutated_header(draw, doc: dict) -> bytes:
    doc = json.loads(json.dumps(doc))
    if draw(st.booleans()):
        text = bytearray(json.dumps(doc).encode())
        for _ in range(draw(st.integers(1, 3))):
            text[draw(st.integers(0, len(text) - 1))] = draw(st.integers(0, 255))
        return bytes(text)
    for _ in range(draw(st.integers(1, 3))):
        paths = [p for p in json_paths(doc) if p]
        path = draw(st.sampled_from(paths))
        target = doc
        for key in path[:-1]:
            target = target[key]
        if draw(st.integers(0, 4)) == 0 and isinstance(target, dict):
            del target[path[-1]]
        else:
            target[path[-1]] = draw(JSON)
    return json.dumps(doc).encode()


def test_mutated_headers_and_footers_raise_nothing_but_slearn_errors(library_file, tmp_path):
    table = pq.read_table(library_file)
    doc = json.loads(table.schema.metadata[METADATA_KEY])
    data = library_file.read_bytes()
    footer = len(data) - 8 - int.from_bytes(data[-8:-4], "little")

    @fuzz(1500)
    @given(raw=mutated_header(doc), flip=st.integers(footer, len(data) - 1), bit=st.integers(0, 7))
    def check(raw, flip, bit):
        edited = tmp_path / "edited.parquet"
        pq.write_table(table.replace_schema_metadata({METADATA_KEY: raw}), edited)
        flipped = bytearray(data)
        flipped[flip] ^= 1 << bit
        (tmp_path / "flipped.parquet").write_bytes(bytes(flipped))
        for path in (edited, tmp_path / "flipped.parquet"):
            only_slearn_errors(load_library, path)
            only_slearn_errors(describe, path)

    check()


# --- spec values ------------------------------------------------------------------------------

KEYS = ["field", "name", "values", "max_symbols", "width", "origin", "range", "count",
        "edges", "quantiles", "wrap"]
VALUE = (st.none() | st.booleans() | st.integers(-2 ** 70, 2 ** 70) | st.floats() | st.text(max_size=6)
         | st.lists(st.integers(-5, 5) | st.floats() | st.text(max_size=3), max_size=5)
         | st.lists(st.lists(st.integers(), max_size=2), max_size=2))
ENTRY = st.fixed_dictionaries({"topic": st.just("/a") | VALUE,
                               "role": st.sampled_from(["action", "observation", "x"])},
                              optional={k: VALUE for k in KEYS})
SPECS = st.fixed_dictionaries({"channel": st.lists(ENTRY, min_size=1, max_size=3)},
                              optional={"mode": st.sampled_from(["message", "change", "tick", "x"]),
                                        "tick_ms": VALUE, "tick_ns": VALUE})


@fuzz(2000)
@given(data=SPECS, readings=st.lists(st.integers(-2 ** 1100, 2 ** 1100) | st.floats() | st.text(max_size=4)
                                      | st.booleans(), max_size=10))
def test_spec_values_raise_nothing_but_spec_errors(data, readings):
    spec = only_slearn_errors(Spec.from_dict, data)
    if spec is None:
        return
    assert Spec.from_dict(spec.to_dict()) == Spec.from_dict(spec.to_dict())
    for entry in spec.channels:
        declared = entry.symbolizer.declared_values()
        assert declared is None or len(declared) <= entry.symbol_limit
        for x in readings:
            value = entry.symbolizer.symbol_value(x)
            assert value is None or hash(value) is not None


@fuzz(1000)
@given(text=st.text(alphabet="/ab:=;,.0123456789-enaifvlusrgcotwq_[]", max_size=60))
def test_channel_shorthands_raise_nothing_but_spec_errors(text):
    entry = only_slearn_errors(parse_channel_option, text)
    if entry is not None:
        only_slearn_errors(Spec.from_dict, {"channel": [entry]})
