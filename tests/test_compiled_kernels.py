"""slearn's kernels compiled at install (slearn/core/_aot.py): a cold run compiles nothing,
learns the same bytes as numba's own compilation, and anything the extension does not
cover, or covers from other sources, is compiled as before."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numba
import numpy as np
import pyarrow.parquet as pq
import pytest
from numba.core import types

from slearn.core import _aot, _jit, hashtable
from slearn.core.hashtrie import Trie

ROOT = Path(__file__).resolve().parents[1]


def _extension_or_skip():
    """The extension; a failure if a C compiler could have built it, else a skip."""
    module = _aot._extension()
    if module is None and os.environ.get("SLEARN_AOT", "1") != "0":
        if shutil.which("cc") or shutil.which("gcc"):
            pytest.fail("slearn.core._compiled is missing, or was built from other sources or by another "
                        "numba: reinstall (pip install -e .) after changing a kernel module")
        pytest.skip("no C compiler: the install compiles no kernels ahead of time")
    if module is None:
        pytest.skip("SLEARN_AOT=0")
    return module


@pytest.mark.parametrize("numba_type", [
    types.Array(types.uint8, 1, "C", readonly=True),
    types.Array(types.float64, 3, "A"),
    types.Array(types.int32, 2, "F", aligned=False),
    types.Array(types.boolean, 1, "C"),
    types.int64, types.boolean, types.float64, types.uint64,
    types.NumberClass(types.int32),
    types.UniTuple(types.int64, 2),
    types.Tuple((types.int64, types.Array(types.float64, 1, "C"))),
    numba.typeof(Trie(*(np.zeros(2, np.int32) for _ in range(3)), np.zeros(2, np.int64))),
])
def test_types_round_trip_through_the_manifest_encoding(numba_type):
    decoded = _aot.decode(json.loads(json.dumps(_aot.encode(numba_type))))
    assert decoded == numba_type and decoded._code == numba_type._code  # the dispatcher's key


def test_the_build_step_names_the_extension_the_core_looks_for():
    """(``slearn/_build.py`` runs before slearn is importable, so it spells the name out.)"""
    assert f'EXTENSION = "{_aot.EXTENSION}"' in (ROOT / "slearn" / "_build.py").read_text()


def test_a_type_without_an_encoding_is_refused():
    with pytest.raises(TypeError, match="no encoding"):
        _aot.encode(types.unicode_type)


def test_the_manifest_is_the_workload_recorded_again():
    """The manifest equals what ``tests/kernel_workload.py`` records now: a kernel whose
    arguments changed fails here until the manifest is written again."""
    done = subprocess.run([sys.executable, str(ROOT / "tests" / "kernel_workload.py")],
                          capture_output=True, text=True, check=True)
    recorded = json.loads(done.stdout)["signatures"]
    assert recorded == _aot.manifest(), "run: python tests/kernel_workload.py --write"
    assert "slearn.core.online.run_codes" in recorded and "slearn.core.views._encode" in recorded


_CHILD = textwrap.dedent("""
    import json, sys
    import numba.core.event as ev
    compiled = []

    class Compiles(ev.Listener):
        def on_start(self, event):
            pass

        def on_end(self, event):
            compiled.append(event.data["dispatcher"].py_func.__qualname__)

    ev.register("numba:compile", Compiles())
    from slearn.cli import main
    try:
        main(["demo", "--out", sys.argv[1], "--seeds", "1", "--trials", "1000", "--quiet"], standalone_mode=False)
    except SystemExit as stop:
        assert not stop.code, stop.code
    print(json.dumps(compiled))
""")


def _demo(folder: Path, **env: str) -> list[str]:
    done = subprocess.run([sys.executable, "-c", _CHILD, str(folder)], env=dict(os.environ, **env),
                          capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def _table(path: Path):
    table = pq.read_table(path)
    header = json.loads(table.schema.metadata[b"slearn"])
    header.pop("provenance")  # (the input's path and time)
    return table.replace_schema_metadata(None), header


def test_a_cold_demo_compiles_nothing_and_learns_what_numba_learns(tmp_path):
    _extension_or_skip()
    empty = tmp_path / "cache"
    shipped = _demo(tmp_path / "shipped", SLEARN_CACHE_DIR=str(empty / "slearn"), NUMBA_CACHE_DIR=str(empty))
    assert shipped == []
    assert _demo(tmp_path / "jit", SLEARN_AOT="0") is not None
    libraries = sorted((tmp_path / "shipped" / "libraries").glob("*.parquet"))
    assert len(libraries) == 6
    for path in libraries:
        (ours, our_header), (numbas, numba_header) = _table(path), _table(tmp_path / "jit" / "libraries" / path.name)
        assert ours.equals(numbas) and our_header == numba_header, path.name
    summary = [json.loads((tmp_path / run / "summary.json").read_text())["conditions"] for run in ("shipped", "jit")]
    assert [{c: v["accuracy_percent"] for c, v in s.items()} for s in summary][0] == \
        {c: v["accuracy_percent"] for c, v in summary[1].items()}


def test_other_argument_types_are_compiled_not_misread():
    """The extension's entry points read their arguments as the declared types: a call of
    other types goes through numba's dispatcher, which compiles for them instead."""
    _extension_or_skip()
    assert hashtable.rebuild.shipped  # int32 tables
    a_of, b_of = np.array([3, 5, 7], np.int64), np.array([1, 2, 1], np.int64)
    wide, narrow = np.full(8, -7, np.int64), np.full(8, -7, np.int32)
    hashtable.rebuild(wide, a_of, b_of, 0, 3)
    hashtable.rebuild(narrow, a_of.astype(np.int32), b_of.astype(np.int32), 0, 3)
    assert sorted(narrow[narrow >= 0]) == [0, 1, 2] and np.array_equal(wide, narrow)
    assert any(args[0].dtype == types.int64 for args in hashtable.rebuild.overloads)  # compiled for int64


@pytest.fixture
def fresh_extension_lookup():
    _aot._lookup.cache_clear()
    yield
    _aot._lookup.cache_clear()


def test_an_extension_from_other_sources_is_not_used(monkeypatch, fresh_extension_lookup):
    monkeypatch.setattr(_jit, "installed_fingerprint", lambda: "0" * 16)
    assert _aot._extension() is None


def test_slearn_aot_0_ignores_the_extension(monkeypatch, fresh_extension_lookup):
    monkeypatch.setenv("SLEARN_AOT", "0")
    assert _aot._extension() is None


def test_the_fingerprint_covers_the_manifest(tmp_path, monkeypatch):
    before = _aot.fingerprint("sources")
    copy = tmp_path / "kernel_signatures.json"
    copy.write_text(_aot.MANIFEST.read_text().replace("int64", "int32", 1))
    monkeypatch.setattr(_aot, "MANIFEST", copy)
    assert _aot.fingerprint("sources") != before
    assert _aot.fingerprint("other sources") != _aot.fingerprint("sources")


def test_why_the_extension_is_unused_is_named(monkeypatch, fresh_extension_lookup):
    _extension_or_skip()
    assert _aot.unused_reason() is None  # used
    monkeypatch.setattr(_jit, "installed_fingerprint", lambda: "0" * 16)
    _aot._lookup.cache_clear()
    assert "other sources" in _aot.unused_reason()
    monkeypatch.setenv("SLEARN_AOT", "0")
    _aot._lookup.cache_clear()
    assert _aot.unused_reason() is None  # asked for: nothing to explain


def test_a_cold_cache_that_fills_is_a_compilation_of_this_run(tmp_path, monkeypatch):
    monkeypatch.setenv("SLEARN_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(_jit, "_COLD", [])
    assert not _jit.compiled_this_run()  # no kernel looked for its cache
    try:
        for name, was_cold in (("a" * 16, True), ("b" * 16, False)):
            if not was_cold:
                (tmp_path / name / "core_x").mkdir(parents=True)
                (tmp_path / name / "core_x" / "tokens._intern-1.py311.nbi").write_bytes(b"")
            monkeypatch.setattr(_jit, "installed_fingerprint", lambda name=name: name)
            _jit.cache_folder.cache_clear()
            folder = Path(_jit.cache_folder())
            assert folder == tmp_path / name and not _jit.compiled_this_run()  # nothing new yet
            (folder / "core_x").mkdir(exist_ok=True)
            (folder / "core_x" / "hashtable.rebuild-2.py311.nbi").write_bytes(b"")
            assert _jit.compiled_this_run() == was_cold  # a warm cache that grew compiled a kernel or two
    finally:
        _jit.cache_folder.cache_clear()  # (the real folder again, found by the next caller)


@pytest.mark.parametrize("reason, compiled", [("the install compiled none (no C compiler?)", True),
                                              (None, True), ("the install compiled none (no C compiler?)", False)])
def test_the_cli_says_once_when_numba_compiled_what_the_install_did_not(monkeypatch, reason, compiled):
    from click.testing import CliRunner

    from slearn.cli import main
    monkeypatch.setattr(_aot, "unused_reason", lambda: reason)
    monkeypatch.setattr(_jit, "compiled_this_run", lambda: compiled)
    for args, code in ((["datasets", "list"], 0), (["learn", "no-such.mcap", "-o", "x.parquet"], 1)):
        result = CliRunner().invoke(main, args)
        assert result.exit_code == code, result.output
        notes = [line for line in result.stderr.splitlines() if line.startswith("slearn: note: numba compiled")]
        assert len(notes) == (1 if reason and compiled else 0), result.stderr
        if notes:
            assert reason in notes[0] and "--no-build-isolation" in notes[0]
