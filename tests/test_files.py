"""The atomic writer, output checks and build folders (slearn.io.files)."""

from __future__ import annotations

import errno
import io
import os
import threading
import time

import pytest

from slearn import SequenceModel
from slearn.errors import InputError, SlearnError
from slearn.io import files
from slearn.io.files import (
    INCOMPLETE_MARKER,
    atomic_write,
    check_output,
    claim_folder,
    regular_file,
    release_folder,
    sweep_stale_temps,
    write_atomic,
)


class FullDisk(io.FileIO):
    """A file that takes ``quota`` bytes, then fails like a full disk."""

    quota = 100

    def write(self, data):
        room = self.quota - self.tell()
        if room <= 0:
            raise OSError(errno.ENOSPC, "No space left on device")
        return super().write(bytes(data)[:room])


def full_disk(monkeypatch, quota=100):
    """Make every output slearn writes run out of space after ``quota`` bytes."""
    FullDisk.quota = quota
    monkeypatch.setattr(files, "open_temp", lambda fd: io.BufferedWriter(FullDisk(fd, "wb"), 64))


def listing(folder):
    return sorted(p.name for p in folder.iterdir())


def test_a_write_replaces_the_target_and_leaves_no_temp(tmp_path):
    target = tmp_path / "out.txt"
    target.write_text("old")
    with atomic_write(target, overwrite=True) as out:
        out.write(b"new")
        assert target.read_text() == "old"  # nothing is visible before the commit
        assert out.tmp_path.parent == tmp_path and out.tmp_path.name.startswith(".out.txt.")
    assert target.read_text() == "new" and listing(tmp_path) == ["out.txt"]


def test_temp_names_are_unpredictable_and_never_reuse_a_file(tmp_path, monkeypatch):
    names = iter(["aaaa", "aaaa", "bbbb"])
    monkeypatch.setattr(files.secrets, "token_hex", lambda n: next(names))
    planted = tmp_path / f".out.txt.{os.getpid()}-aaaa.tmp"
    planted.write_text("someone else's")
    with atomic_write(tmp_path / "out.txt") as out:
        assert out.tmp_path.name == f".out.txt.{os.getpid()}-bbbb.tmp"  # O_EXCL skipped aaaa
        out.write(b"x")
    assert planted.read_text() == "someone else's"


def test_an_error_in_the_block_keeps_the_old_file(tmp_path):
    target = tmp_path / "out.txt"
    target.write_text("old")
    with pytest.raises(ZeroDivisionError):
        with atomic_write(target, overwrite=True) as out:
            out.write(b"half")
            raise ZeroDivisionError("the writer fails halfway")
    assert target.read_text() == "old" and listing(tmp_path) == ["out.txt"]


@pytest.mark.parametrize("quota", [0, 10, 5000])
def test_a_full_disk_keeps_the_old_file_and_gives_one_line(tmp_path, monkeypatch, quota):
    target = tmp_path / "out.bin"
    target.write_bytes(b"old" * 1000)
    full_disk(monkeypatch, quota)
    with pytest.raises(InputError) as err:
        write_atomic(target, b"new" * 100_000, overwrite=True)
    message = str(err.value)
    assert "\n" not in message and message.startswith(f"{target}: cannot write: No space left")
    assert "nothing was replaced" in message
    assert target.read_bytes() == b"old" * 1000 and listing(tmp_path) == ["out.bin"]


def test_a_folder_that_cannot_take_files_gives_one_line(tmp_path, monkeypatch):
    real_open = os.open

    def read_only(path, flags, mode=0o777, **kwargs):
        if flags & os.O_CREAT:
            raise OSError(errno.EROFS, "Read-only file system", str(path))
        return real_open(path, flags, mode, **kwargs)

    monkeypatch.setattr(files.os, "open", read_only)
    with pytest.raises(InputError, match=r"cannot create a file in folder .*: Read-only file system$"):
        write_atomic(tmp_path / "x.txt", "text")
    assert listing(tmp_path) == []


def test_a_failing_rename_removes_the_temp(tmp_path, monkeypatch):
    def denied(src, dst):
        raise OSError(errno.EACCES, "Permission denied")

    monkeypatch.setattr(files.os, "replace", denied)
    with pytest.raises(InputError, match="cannot write: Permission denied"):
        write_atomic(tmp_path / "x.txt", "text")
    assert listing(tmp_path) == []


def test_stale_temps_of_killed_runs_are_swept_but_live_or_fresh_ones_kept(tmp_path):
    target = tmp_path / "lib.parquet"
    dead = 2 ** 22 + 12345  # above the default pid_max: no such process
    old = time.time() - 2 * 3600
    stale = tmp_path / f".lib.parquet.{dead}-0123abcd.tmp"
    legacy = tmp_path / f".lib.parquet.{dead}.tmp"  # the name storage used before
    fresh = tmp_path / f".lib.parquet.{dead}-feedbeef.tmp"
    live = tmp_path / f".lib.parquet.{os.getpid()}-00000000.tmp"
    other = tmp_path / f".other.parquet.{dead}-0123abcd.tmp"
    for path in (stale, legacy, fresh, live, other):
        path.write_text("partial")
    for path in (stale, legacy, live, other):
        os.utime(path, (old, old))
    assert sweep_stale_temps(target) == 2
    assert sorted(listing(tmp_path)) == sorted([fresh.name, live.name, other.name])


def test_outputs_that_are_inputs_are_refused_even_with_force(tmp_path):
    log = tmp_path / "x.mcap"
    log.write_bytes(b"input")
    os.link(log, tmp_path / "hard.mcap")
    (tmp_path / "soft.mcap").symlink_to(log)
    for name in ("x.mcap", "hard.mcap", "soft.mcap", "./sub/../x.mcap"):
        (tmp_path / "sub").mkdir(exist_ok=True)
        with pytest.raises(InputError, match="is also an input .* even with --force"):
            check_output(tmp_path / name, True, inputs=[log])
    assert log.read_bytes() == b"input"


def test_check_output_refuses_folders_missing_folders_and_existing_files(tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(InputError, match="is a folder"):
        check_output(tmp_path, True)
    with pytest.raises(InputError, match="folder .* does not exist"):
        check_output(tmp_path / "no" / "x", True)
    with pytest.raises(InputError, match="already exists: pass --force"):
        check_output(tmp_path / "f", False)
    check_output(tmp_path / "f", True)


def test_check_output_refuses_a_missing_folder_with_a_slash_and_a_name_not_utf8(tmp_path):
    """``-o out/`` means a folder: it wrote a file named ``out``; a name that is not UTF-8
    (a Latin-1 byte from the shell) went on to a traceback in pyarrow."""
    with pytest.raises(InputError, match="names a folder that does not exist"):
        check_output(f"{tmp_path}/new/", True)
    assert not (tmp_path / "new").exists()
    odd = os.fsdecode(os.fsencode(str(tmp_path)) + b"/out\xfe.parquet")
    with pytest.raises(InputError, match=r"out\\udcfe\.parquet: the file name is not valid UTF-8"):
        check_output(odd, True)
    model = SequenceModel()
    model.learn("abab")
    with pytest.raises(SlearnError, match="not valid UTF-8"):
        model.save(odd)
    assert os.listdir(tmp_path) == []


def test_regular_file_refuses_a_fifo_without_blocking(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    outcome = []
    thread = threading.Thread(target=lambda: outcome.append(_error_of(regular_file, fifo, "log file")),
                              daemon=True)
    thread.start()
    thread.join(5)
    assert outcome and "not a regular file" in outcome[0]
    assert "is a folder, not a library file" in _error_of(regular_file, tmp_path, "library file")
    assert "no such log file" in _error_of(regular_file, tmp_path / "none", "log file")


def _error_of(function, *args):
    try:
        function(*args)
    except InputError as err:
        return str(err)
    return ""


def test_claimed_folders_are_refused_when_foreign_and_redone_when_left_by_a_killed_build(tmp_path):
    out = tmp_path / "demo"
    claim_folder(out, owned=["logs"])
    (out / "logs").mkdir()
    (out / "logs" / "half.mcap").write_text("partial")
    assert (out / INCOMPLETE_MARKER).exists()
    claim_folder(out, owned=["logs"])  # the killed build's folder is accepted and cleaned
    assert listing(out) == [INCOMPLETE_MARKER]
    release_folder(out)
    assert listing(out) == []
    (out / "mine.txt").write_text("keep")
    with pytest.raises(InputError, match="is not empty: choose a new folder"):
        claim_folder(out, owned=["mine.txt"])
    assert (out / "mine.txt").read_text() == "keep"
