"""The library header schema: every damaged field is refused with one line naming it."""

from __future__ import annotations

import json
import re

import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner
from fixtures import write_log
from test_storage import learned, save

from slearn.cli import main
from slearn.errors import LibraryFormatError
from slearn.io.library_file import METADATA_KEY, load_library, read_info
from slearn.io.library_header import FORMAT_VERSION, HEADER, Field, validate_header
from slearn.io.library_info import describe
from slearn.jobs.merge import merge_files


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    path = tmp_path_factory.mktemp("lib") / "good.parquet"
    save(path, learned(episodes=2, steps=120))
    return path


def with_header(good, tmp_path, raw: bytes):
    table = pq.read_table(good)
    path = tmp_path / "edited.parquet"
    pq.write_table(table.replace_schema_metadata({METADATA_KEY: raw}), path)
    return path


def edited(good, tmp_path, change):
    doc = json.loads(pq.read_schema(good).metadata[METADATA_KEY])
    change(doc)
    return with_header(good, tmp_path, json.dumps(doc).encode())


def one_line_error(function, path) -> str:
    with pytest.raises(LibraryFormatError) as err:
        function(path)
    text = str(err.value)
    assert "\n" not in text and text.startswith(str(path))
    return text


def _set(path: str, value):
    def change(doc):
        *parents, last = path.split(".")
        target = doc
        for key in parents:
            target = target[int(key)] if isinstance(target, list) else target[key]
        if isinstance(target, list):
            target[int(last)] = value
        else:
            target[last] = value
    return change


def _drop(path: str):
    def change(doc):
        *parents, last = path.split(".")
        target = doc
        for key in parents:
            target = target[key]
        del target[last]
    return change


def _nest(depth):
    value = []
    for _ in range(depth):
        value = [value]
    return value


MUTATIONS = [
    (_set("params.max_length", 10 ** 9), "field params.max_length must be an integer from 1 to 64, not 1000000000"),
    (_set("params.max_length", "5"), "field params.max_length must be an integer, not '5'"),
    (_set("params.max_length", True), "field params.max_length must be an integer, not True"),
    (_set("params.max_length", 4.0), "field params.max_length must be an integer, not 4.0"),
    (_drop("params.max_length"), "field params.max_length is missing"),
    (_set("params", []), "field params must be an object, not list"),
    (_set("params.max_patterns", 3), "field params.max_patterns must be an integer from 16"),
    (_set("params.max_patterns", 10 ** 20), "field params.max_patterns must be an integer from 16 to 2,147,483,647"),
    (_set("params.scoring", "bogus"), "field params.scoring must be one of adaptive, literal or an object"),
    (_set("params.scoring", {"rule": "adaptive", "alpha": 5}), "field params.scoring.alpha must be a number from 1e-09 to 1"),
    (_set("params.scoring", {"alpha": 0.1}), "field params.scoring.rule is missing"),
    (_set("library.clock", -5), "field library.clock must be an integer from 0"),
    (_set("library.forgotten", None), "field library.forgotten must not be null"),
    (_set("library.channels", "cmd"), "field library.channels must be a list, not 'cmd'"),
    (_set("library.channels.0", ["cmd"]), 'field library.channels[0] must be [channel name, "action" | "observation"]'),
    (_set("library.channels.0", ["cmd", "sensor"]), "field library.channels[0] must be [channel name"),
    (_set("library.channels.1", ["cmd", "action"]), "field library.channels names a channel twice"),
    (_set("library.rows.token", "1"), "field library.rows.token must be an integer, not '1'"),
    (_drop("library.rows.vocabulary"), "field library.rows.vocabulary is missing"),
    (_set("library.patterns", 3), "field library.patterns (3) differs from library.rows.pattern"),
    (_set("spec", []), "field spec must be an object, not list"),
    (_set("spec.mode", "sometimes"), "field spec: mode must be one of message, change, tick"),
    (_set("spec.channel.2.count", 10 ** 9), "field spec: channel entry 3 (/pos:x): `count` must be an integer from 1 to 1,000,000"),
    (_set("spec.channel.2.range", [0, float("inf")]), "not valid JSON"),
    (_set("spec.channel.0.values", [[1, 2]]), "`values` may hold strings, integers, finite numbers and booleans"),
    (_set("spec.channel", []), "no [[channel]] entries"),
    (_set("provenance", None), "field provenance must not be null"),
    (_set("provenance.inputs", {}), "field provenance.inputs must be a list, not dict"),
    (_set("provenance.inputs.0.path", 1), "field provenance.inputs[0].path must be a string, not 1"),
    (_set("provenance.inputs.0.size_bytes", -1), "field provenance.inputs[0].size_bytes must be an integer from 0"),
    (_set("provenance.inputs.0.sha256", "zz"), "field provenance.inputs[0].sha256 must be 64 lowercase hex digits, not 'zz'"),
    (_set("provenance.time_unix", 10 ** 17), "field provenance.time_unix must be an integer from 0 to 253,402,300,799"),
    (_set("provenance.time", "x" * 1000), "field provenance.time must hold at most 64 characters"),
    (_set("provenance.notes", _nest(40)), "the header nests deeper than 32 levels"),
    (_set("version", "1"), "invalid library format version '1'"),
    (_set("version", 0), "invalid library format version 0"),
    (_set("version", FORMAT_VERSION + 1), f"library format version {FORMAT_VERSION + 1} is newer than this slearn"),
    (_set("format", None), "a Parquet file, but not a slearn pattern library (format None)"),
]


@pytest.mark.parametrize("change, message", MUTATIONS, ids=[m for _, m in MUTATIONS])
def test_a_damaged_field_is_refused_by_every_reader_with_one_line_naming_it(good, tmp_path, change, message):
    path = edited(good, tmp_path, change)
    for function in (load_library, describe, read_info):
        error = one_line_error(function, path)
        assert message in error
        assert re.search(r": (re-create|upgrade slearn|make libraries with)", error), error  # says what to do
    result = CliRunner().invoke(main, ["info", str(path)])
    assert result.exit_code == 1 and message in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("raw, message", [
    (b'{"format": NaN}', "not valid JSON (ValueError: NaN is not a JSON number)"),
    (b"[" * 5000 + b"]" * 5000, "not valid JSON (RecursionError"),
    (b'{"format": "slearn-library", "version": 1' + b"9" * 5000 + b"}", "not valid JSON (ValueError"),
    (b'{"format": "slearn-library\xff"}', "not valid JSON (UnicodeDecodeError"),
    (b"[]", "not a slearn pattern library (format None)"),
    (b"not json", "not valid JSON (JSONDecodeError"),
])
def test_a_header_that_is_not_json_or_not_an_object_is_refused(good, tmp_path, raw, message):
    path = with_header(good, tmp_path, raw)
    assert message in one_line_error(load_library, path)


def test_a_header_that_is_too_large_is_refused_before_parsing(good, tmp_path, monkeypatch):
    import slearn.io.library_header as header
    monkeypatch.setattr(header, "MAX_HEADER_BYTES", 100)
    assert "the header is" in one_line_error(load_library, good) and "(at most 100)" in one_line_error(load_library, good)


def test_a_flipped_bit_in_the_footer_is_a_library_error(good, tmp_path):
    data = bytearray(good.read_bytes())
    footer = len(data) - 8 - int.from_bytes(data[-8:-4], "little")
    data[data.index(b"value_text", footer)] |= 0x80  # a schema field name is no longer UTF-8:
    # pq.ParquetFile raised UnicodeDecodeError
    bad = tmp_path / "flipped.parquet"
    bad.write_bytes(bytes(data))
    assert "not a readable Parquet file" in one_line_error(load_library, bad)


def test_merge_checks_every_header_before_loading(good, tmp_path):
    bad = edited(good, tmp_path, _set("params.max_length", 10 ** 9))
    with pytest.raises(LibraryFormatError, match="params.max_length"):
        merge_files([good, bad], tmp_path / "out.parquet")
    assert not (tmp_path / "out.parquet").exists()


def test_a_folder_or_a_fifo_given_as_a_library_exits_1(tmp_path):
    import os
    os.mkfifo(tmp_path / "pipe.parquet")
    (tmp_path / "folder.parquet").mkdir()
    log = write_log(tmp_path / "x.mcap", [("/a", 0, {"v": 1})])
    for path, message in ((tmp_path / "folder.parquet", "is a folder, not a library file"),
                          (tmp_path / "pipe.parquet", "not a regular file")):
        for args in (["info", str(path)], ["replay", str(path), str(log)],
                     ["merge", str(path), str(path), "-o", str(tmp_path / "m.parquet")]):
            result = CliRunner().invoke(main, args)
            assert result.exit_code == 1 and message in result.stderr, (args, result.output)


def test_fields_of_later_versions_are_not_required_of_older_files():
    header = {**HEADER, "tables": Field("object", since=FORMAT_VERSION + 1)}
    import slearn.io.library_header as module
    doc = json.loads(json.dumps({"format": "slearn-library", "version": FORMAT_VERSION,
                                 "params": {"max_length": 3, "max_patterns": None},
                                 "library": {"clock": 0, "forgotten": 0, "patterns": 0, "channels": [],
                                             "rows": {"vocabulary": 0, "token": 0, "view": 0,
                                                      "pattern": 0}},
                                 "spec": None, "provenance": {}}))
    assert module._problem(doc, header, "", FORMAT_VERSION) is None
    assert module._problem(doc, header, "", FORMAT_VERSION + 1) == "field tables is missing"
    validate_header(doc, "x.parquet")


def test_a_footer_that_mislabels_a_column_is_refused_without_crashing(good, tmp_path):
    import subprocess
    import sys

    data = bytearray(good.read_bytes())
    footer = len(data) - 8 - int.from_bytes(data[-8:-4], "little")
    element = data.index(b"\x15\x0c%\x02\x18\x05table", footer)  # type BYTE_ARRAY, name "table"
    data[element + 1] = 0x08  # FLOAT: pyarrow aborted the process reading row-group metadata
    bad = tmp_path / "mislabelled.parquet"
    bad.write_bytes(bytes(data))
    check = ("import sys; from slearn.io.library_file import load_library; from slearn.io.library_info import describe\n"
             "from slearn.errors import LibraryFormatError\n"
             "for f in (load_library, describe):\n"
             "    try: f(sys.argv[1])\n"
             "    except LibraryFormatError as e: print(e)\n")
    done = subprocess.run([sys.executable, "-c", check, str(bad)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-500:]
    assert done.stdout.count("its columns are not the library's") == 2


def test_a_negative_pattern_count_is_refused(good, tmp_path):
    import pyarrow as pa
    import pyarrow.compute as pc

    table = pq.read_table(good)
    is_pattern = pc.equal(table.column("table"), "pattern")
    negative = pc.if_else(is_pattern, pa.scalar(-3, pa.int64()), table.column("count"))
    table = table.set_column(table.schema.get_field_index("count"), "count", negative)
    bad = tmp_path / "negative.parquet"
    with pq.ParquetWriter(bad, table.schema) as writer:  # one row group per table, as saved
        for name in ("vocabulary", "token", "view", "pattern"):
            rows = table.filter(pc.equal(table.column("table"), name))
            if len(rows):
                writer.write_table(rows)
    for function in (load_library, describe):
        assert "a pattern count is not positive" in one_line_error(function, bad)



def _body_edited(good, tmp_path, change):
    """The library with its row groups changed by ``change(groups) -> groups``, header kept."""
    source = pq.ParquetFile(good)
    groups = change([source.read_row_group(i) for i in range(source.num_row_groups)])
    path = tmp_path / "body.parquet"
    with pq.ParquetWriter(path, source.schema_arrow) as out:
        for group in groups:
            out.write_table(group, row_group_size=max(1, group.num_rows))
    return path


def _fewer_rows(groups):
    return [*groups[:-1], groups[-1].slice(0, groups[-1].num_rows - 1)]


def _pattern_token(groups, value):
    import pyarrow as pa

    for g, group in enumerate(groups):
        rows = group.column("pattern").to_pylist()
        first = next((i for i, row in enumerate(rows) if row), None)
        if first is not None:
            rows[first] = [value, *rows[first][1:]]
            index = group.schema.get_field_index("pattern")
            groups[g] = group.set_column(index, group.schema.field(index), pa.array(rows, group.schema.field(index).type))
            return groups
    raise AssertionError("no pattern")


@pytest.mark.parametrize("change, problem", [
    (_fewer_rows, "rows, but its header says"),
    (lambda groups: _pattern_token(groups, 10 ** 6), "a pattern names a token that does not exist"),
])
def test_damaged_tables_are_one_line_saying_to_re_create_the_library(good, tmp_path, change, problem):
    path = _body_edited(good, tmp_path, change)
    error = one_line_error(load_library, path)
    assert "corrupted pattern library (" in error and problem in error, error
    assert error.endswith("re-create it with `slearn learn`"), error
