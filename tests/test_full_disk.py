"""A full disk for every output: the old file is intact, no temp file is left, one line."""

from __future__ import annotations

import io
import os
from pathlib import Path

import pytest
from click.testing import CliRunner
from test_datasets import PR2_LOG
from test_files import FullDisk

from slearn.cli import main
from slearn.io import files

OLD = b"the previous output, which must survive\n"


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def full_disk(monkeypatch, suffix: str = "", quota: int = 100):
    """Writes to temp files of targets ending in ``suffix`` fail after ``quota`` bytes."""
    real = files.open_temp

    def opener(fd):
        name = os.path.basename(os.readlink(f"/proc/self/fd/{fd}"))
        if suffix and not name.split(".")[1:-2] or not name.rsplit(".", 2)[0].endswith(suffix):
            return real(fd)
        FullDisk.quota = quota
        return io.BufferedWriter(FullDisk(fd, "wb"), 64)

    monkeypatch.setattr(files, "open_temp", opener)


def temps(folder: Path) -> list[str]:
    return [p.name for p in folder.rglob("*") if p.name.endswith(".tmp")]


def assert_refused(result, folder: Path, old: Path | None = None):
    assert result.exit_code == 1, result.output
    lines = [line for line in result.stderr.splitlines() if not line.startswith("building ")]  # progress
    assert len(lines) == 1 and "No space left on device" in lines[0], result.stderr
    assert temps(folder) == []
    if old is not None:
        assert old.read_bytes() == OLD


def old_file(folder: Path, name: str) -> Path:
    path = folder / name
    path.write_bytes(OLD)
    return path


def test_learn_and_merge(simple_pointer, two_simple_libraries, tmp_path, monkeypatch):
    log, library = simple_pointer
    full_disk(monkeypatch, ".parquet")
    out = old_file(tmp_path, "out.parquet")
    assert_refused(run("learn", "-q", log, "-o", out, "--force"), tmp_path, out)
    assert_refused(run("merge", *two_simple_libraries, "-o", out, "--force"), tmp_path, out)


def test_info_suggest_spec(simple_pointer, tmp_path, monkeypatch):
    full_disk(monkeypatch, ".toml")
    out = old_file(tmp_path, "spec.toml")
    assert_refused(run("info", simple_pointer[0], "--suggest-spec", out, "--force"), tmp_path, out)


@pytest.mark.parametrize("option, name", [("--plot", "curve.png"), ("--report", "report.html"),
                                          ("--write-mcap", "annotated.mcap")])
def test_replay_outputs(simple_pointer, tmp_path, monkeypatch, option, name):
    full_disk(monkeypatch, Path(name).suffix)
    out = old_file(tmp_path, name)
    assert_refused(run("replay", simple_pointer[1], simple_pointer[0], option, out, "--force", "-q"), tmp_path, out)


def test_replay_foxglove_layout(simple_pointer, tmp_path, monkeypatch):
    full_disk(monkeypatch, ".layout.json")
    layout = old_file(tmp_path, "a.layout.json")
    result = run("replay", simple_pointer[1], simple_pointer[0], "--write-mcap", tmp_path / "a.mcap", "--force", "-q")
    assert_refused(result, tmp_path, layout)


def test_record_pointer(tmp_path, monkeypatch):
    full_disk(monkeypatch, ".mcap")
    out = old_file(tmp_path, "p.mcap")
    assert_refused(run("record", "pointer", "--condition", "simple", "--trials", "2000", "-o", out,
                       "--force"), tmp_path, out)


@pytest.mark.parametrize("suffix", [".mcap", ".toml"])
def test_record_stream_and_its_spec(tmp_path, monkeypatch, suffix):
    source = tmp_path / "events.csv"
    source.write_text("time,channel,value\n" + "".join(f"{i},pos,{i % 5}\n" for i in range(3000)))
    out, spec = old_file(tmp_path, "events.mcap"), old_file(tmp_path, "spec.toml")
    full_disk(monkeypatch, suffix)
    result = run("record", "stream", source, "-o", out, "--spec-out", spec, "--force")
    assert_refused(result, tmp_path, spec if suffix == ".toml" else out)
    if suffix == ".mcap":
        assert spec.read_bytes() == OLD


def test_control_record(tmp_path, monkeypatch):
    full_disk(monkeypatch, ".mcap")
    out = old_file(tmp_path, "run.mcap")
    assert_refused(run("control", "--condition", "simple", "--goals", "2", "--trials", "2000",
                       "--agents", "slearn", "--record", out, "--force"), tmp_path, out)


@pytest.mark.parametrize("suffix", ["README.md", "SHA256SUMS"])
def test_datasets_build_then_a_rerun_finishes(tmp_path, monkeypatch, suffix):
    out = tmp_path / "pr2"
    full_disk(monkeypatch, suffix)
    assert_refused(run("datasets", "build", "pr2-sample", "-o", out), tmp_path)
    assert (out / files.INCOMPLETE_MARKER).exists()
    monkeypatch.undo()
    result = run("datasets", "build", "pr2-sample", "-o", out)  # no --force needed after a failed run
    assert result.exit_code == 0, result.output
    assert (out / "README.md").exists() and not (out / files.INCOMPLETE_MARKER).exists()
    assert "README.md" in (out / "SHA256SUMS").read_text()


@pytest.mark.shared
@pytest.mark.parametrize("suffix", ["-train.mcap", "-heldout.mcap"])
def test_datasets_pr2_split_copies(tmp_path, monkeypatch, suffix):
    out = tmp_path / "pr2"
    full_disk(monkeypatch, suffix)
    assert_refused(run("datasets", "build", "pr2-sample", "-o", out, "--source", PR2_LOG), tmp_path)
    assert (out / files.INCOMPLETE_MARKER).exists()


@pytest.mark.parametrize("suffix", [".png", "summary.json", ".mcap"])
def test_demo_then_a_rerun_in_the_same_folder_finishes(tmp_path, monkeypatch, suffix):
    out = tmp_path / "demo"
    args = ("demo", "--out", out, "--seeds", "1", "--trials", "1000", "--quiet")
    full_disk(monkeypatch, suffix)
    assert_refused(run(*args), tmp_path)
    monkeypatch.undo()
    result = run(*args)
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in out.iterdir()) == ["figure2.png", "libraries", "logs", "summary.json"]


def read_only(monkeypatch):
    """Every new file in any folder fails as on a read-only file system."""
    real_open = os.open

    def refuse(path, flags, mode=0o777, **kwargs):
        if flags & os.O_CREAT:
            raise OSError(30, "Read-only file system", str(path))
        return real_open(path, flags, mode, **kwargs)

    monkeypatch.setattr(files.os, "open", refuse)


def test_a_read_only_folder_is_one_line_for_every_writer(simple_pointer, two_simple_libraries, tmp_path,
                                                         monkeypatch):
    log, library = simple_pointer
    out = tmp_path / "out"
    cases = [("learn", "-q", log, "-o", out / "lib.parquet"),
             ("merge", *two_simple_libraries, "-o", out / "lib.parquet"),
             ("record", "pointer", "--condition", "simple", "--trials", "1000", "-o", out / "p.mcap"),
             ("replay", library, log, "--write-mcap", out / "a.mcap", "-q"),
             ("replay", library, log, "--plot", out / "a.png", "-q"),
             ("info", log, "--suggest-spec", out / "spec.toml"),
             ("control", "--condition", "simple", "--goals", "1", "--trials", "1000", "--agents", "slearn",
              "--record", out / "run.mcap")]
    out.mkdir()
    read_only(monkeypatch)
    for args in cases:
        result = run(*args)
        assert result.exit_code == 1, (args, result.output)
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and "cannot create a file in folder" in lines[0] and \
            "Read-only file system" in lines[0], (args, result.stderr)
    assert list(out.iterdir()) == []
