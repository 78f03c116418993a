"""Writing outputs safely: every file slearn writes goes through :func:`atomic_write`.

An output is written to a new file next to its target, created with ``O_EXCL`` under an
unpredictable name (``.NAME.PID-RANDOM.tmp``), then flushed, fsynced and renamed onto the
target, and the folder is fsynced. A reader, or a run killed halfway, never sees a partial
output, and an existing file is replaced only by a complete one. On every error path (a
full disk, a read-only folder, an exception in the caller) the temporary file is removed
and the target is left as it was; the error is one line naming the target.

Temporary files of killed runs are swept when the same target is written again, once the
process that made them is gone and they are an hour old (recorders that keep partial
episodes opt out: their temporary files can be salvaged).

Outputs are refused when they resolve to one of the command's inputs (:func:`check_output`),
even with ``--force``: no input is ever overwritten. Folders built by a long job (``slearn
demo``, ``slearn datasets build``) carry a marker while incomplete (:func:`claim_folder`),
so a rerun after a killed run accepts the folder instead of refusing it as not empty.
"""

from __future__ import annotations

import errno
import io
import os
import re
import secrets
import stat
import time
from contextlib import suppress
from pathlib import Path
from typing import BinaryIO, Iterable

from slearn.errors import InputError

INCOMPLETE_MARKER = ".slearn-incomplete"
_STALE_SECONDS = 3600
_NAME_KEPT = 96  # characters of the target's name in a temp name (names are <= 255 bytes)
_TEMP_NAME = re.compile(r"\.(\d+)(?:-[0-9a-f]+)?\.tmp$")


class AtomicFile:
    """An output being written: ``file`` is open on a temporary file next to ``path``.

    Use :func:`atomic_write` as a context manager: a clean exit commits (fsync, rename),
    an exception discards. ``commit`` and ``discard`` are public for writers that manage
    their own lifetime (:class:`~slearn.recorders.mcap_episode.EpisodeWriter`).
    """

    def __init__(self, path: str | os.PathLike, *, overwrite: bool = False,
                 inputs: Iterable[str | os.PathLike] = (), sweep: bool = True) -> None:
        self.path = Path(path)
        self.overwrite = overwrite
        check_output(self.path, overwrite, inputs)
        if sweep:
            sweep_stale_temps(self.path)
        self.tmp_path, fd = _create_temp(self.path)
        self.file: BinaryIO = open_temp(fd)

    def write(self, data: bytes) -> int:
        """Write bytes to the temporary file."""
        return self.file.write(data)

    def commit(self) -> None:
        """Flush, fsync and rename the temporary file onto the target.

        Raises:
            InputError: the data could not be written (the target is left as it was).
        """
        try:
            self.file.flush()
            os.fsync(self.file.fileno())
            self.file.close()
            if not self.overwrite and os.path.lexists(self.path):
                raise InputError(f"{self.path} appeared while it was being written: "
                                 f"pass --force to overwrite it")
            os.replace(self.tmp_path, self.path)
        except OSError as err:
            self.discard()
            raise write_error(self.path, err) from err
        except BaseException:
            self.discard()
            raise
        fsync_folder(self.path.parent)

    def discard(self) -> None:
        """Close and remove the temporary file; never raises."""
        with suppress(OSError):
            self.file.close()
        with suppress(OSError):
            os.unlink(self.tmp_path)

    def __enter__(self) -> "AtomicFile":
        return self

    def __exit__(self, exc_type, exc, traceback) -> None:
        if exc_type is None:
            self.commit()
            return
        self.discard()
        if isinstance(exc, OSError):
            raise write_error(self.path, exc) from exc


def atomic_write(path: str | os.PathLike, *, overwrite: bool = False,
                 inputs: Iterable[str | os.PathLike] = (), sweep: bool = True) -> AtomicFile:
    """Open an output for writing, atomically; use as ``with atomic_write(p) as out: ...``.

    Args:
        path: the target file.
        overwrite: replace an existing target (``--force``).
        inputs: the command's inputs; a target that is one of them is refused.
        sweep: remove temporary files of this target left by killed runs.

    Raises:
        InputError: the target exists without ``overwrite``, is an input, is a folder,
            its folder is missing or not writable, or the disk is full; one line.
    """
    return AtomicFile(path, overwrite=overwrite, inputs=inputs, sweep=sweep)


def write_atomic(path: str | os.PathLike, data: bytes | str, *, overwrite: bool = False,
                 inputs: Iterable[str | os.PathLike] = ()) -> None:
    """Write ``data`` (text is UTF-8 encoded) to ``path`` with :func:`atomic_write`."""
    with atomic_write(path, overwrite=overwrite, inputs=inputs) as out:
        out.write(data.encode("utf-8") if isinstance(data, str) else data)


def write_error(path: str | os.PathLike, err: OSError) -> InputError:
    """The one-line error for an output that could not be written."""
    where = f" ({err.filename})" if err.filename and os.fspath(err.filename) != os.fspath(path) else ""
    hint = ": free some space or write elsewhere" if err.errno in (errno.ENOSPC, errno.EDQUOT) else ""
    return InputError(f"{path}: cannot write{where}: {err.strerror or err}{hint}; "
                      f"nothing was replaced")


def check_output(path: str | os.PathLike, overwrite: bool,
                 inputs: Iterable[str | os.PathLike] = ()) -> None:
    """Refuse an output that exists (unless ``overwrite``), is one of ``inputs`` (always),
    is a folder or a special file, or whose folder is missing.

    Raises:
        InputError: naming the file and what to do.
    """
    text = os.fspath(path)
    if text.endswith(("/", os.sep)) and not os.path.isdir(text):
        raise InputError(f"{text} names a folder that does not exist: give a file name to write")
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        raise InputError(f"{text.encode('utf-8', 'backslashreplace').decode()}: the file name is not "
                         f"valid UTF-8, which Parquet and MCAP writers need: choose another name") from None
    path = Path(path)
    refuse_inputs(path, inputs)
    if path.is_dir():
        raise InputError(f"{path} is a folder: give a file name to write")
    if os.path.lexists(path):
        if not overwrite:
            raise InputError(f"{path} already exists: pass --force to overwrite it")
        if path.exists() and not path.is_file():
            raise InputError(f"{path} is not a regular file: choose a file name to write")
    if not path.parent.is_dir():
        raise InputError(f"{path}: folder {path.parent} does not exist: create it first")


def refuse_inputs(path: str | os.PathLike, inputs: Iterable[str | os.PathLike]) -> None:
    """Refuse an output ``path`` that resolves to one of ``inputs`` (links followed), or to
    a file inside an input folder.

    Raises:
        InputError: the output is an input; ``--force`` does not lift this.
    """
    for source in inputs:
        where = "also an input" if same_file(path, source) else \
            "in an input folder" if _in_folder(path, source) else None
        if where:
            raise InputError(f"{path} is {where} ({source}): write the output to another file "
                             f"(inputs are never overwritten, even with --force)")


def _in_folder(path: str | os.PathLike, source: str | os.PathLike) -> bool:
    """Whether ``path`` is an existing file inside ``source``, an input folder (a rosbag2
    bag, also when given by its ``metadata.yaml``): its files are inputs too."""
    folder = Path(source)
    if folder.name == "metadata.yaml":
        folder = folder.parent
    if not folder.is_dir() or not os.path.lexists(path):
        return False
    return Path(os.path.realpath(path)).is_relative_to(os.path.realpath(folder))


def same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """True when ``a`` and ``b`` name the same file (hard links and symlinks included)."""
    try:
        return os.path.samefile(a, b)
    except (OSError, ValueError):
        return os.path.realpath(a) == os.path.realpath(b)


def regular_file(path: str | os.PathLike, what: str) -> Path:
    """``path`` as a :class:`Path` when it is an existing regular file.

    Never opens the file, so a FIFO or a device cannot block.

    Raises:
        InputError: missing, a folder, or not a regular file; names ``what`` it should be.
    """
    path = Path(path)
    try:
        mode = path.stat().st_mode
    except OSError as err:
        raise InputError(f"{path}: no such {what} ({err.strerror or err})") from err
    if stat.S_ISDIR(mode):
        raise InputError(f"{path} is a folder, not a {what}")
    if not stat.S_ISREG(mode):
        raise InputError(f"{path} is not a regular file (a pipe or a device?): give a {what}")
    return path


def fsync_folder(folder: str | os.PathLike) -> None:
    """Make a rename in ``folder`` durable (best effort: not every platform can open a folder)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def open_temp(fd: int) -> BinaryIO:
    """The buffered binary file every output's bytes go through (tests replace it to
    simulate a full disk)."""
    return io.open(fd, "wb")


def _create_temp(path: Path) -> tuple[Path, int]:
    """A new, empty file next to ``path`` (``O_EXCL``: never an existing one)."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_NOFOLLOW", 0)
    while True:
        tmp = path.with_name(f".{path.name[:_NAME_KEPT]}.{os.getpid()}-{secrets.token_hex(8)}.tmp")
        try:
            return tmp, os.open(tmp, flags, 0o666)  # the umask applies, as for open()
        except FileExistsError:
            continue
        except OSError as err:
            raise InputError(f"{path}: cannot create a file in folder {path.parent}: "
                             f"{err.strerror or err}") from err


def sweep_stale_temps(path: str | os.PathLike) -> int:
    """Remove temporary files of ``path`` left by killed runs; return how many.

    Only files named like this module's temporary files for this very target, whose
    process is gone (on this machine) and which are over an hour old.
    """
    path = Path(path)
    prefix = f".{path.name[:_NAME_KEPT]}."
    removed = 0
    try:
        candidates = [e for e in os.scandir(path.parent) if e.name.startswith(prefix)]
    except OSError:
        return 0
    for entry in candidates:
        m = _TEMP_NAME.fullmatch(entry.name[len(prefix) - 1:])
        with suppress(OSError):
            if m and not _alive(int(m.group(1))) and \
                    time.time() - entry.stat(follow_symlinks=False).st_mtime > _STALE_SECONDS:
                os.unlink(entry.path)
                removed += 1
    return removed


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, ValueError):
        return True  # someone else's process, or not a pid we can test: keep its file
    return True


# --- folders built by long jobs -----------------------------------------------------------

def claim_folder(folder: str | os.PathLike, *, overwrite: bool = False, owned: Iterable[str] = (),
                 advice: str = "choose a new folder so nothing is overwritten") -> Path:
    """Prepare an output folder for a build that may be killed midway.

    A missing or empty folder is created and marked incomplete. A folder that carries the
    marker (left by a killed build) is accepted, its ``owned`` entries removed so the build
    starts afresh. Another non-empty folder is refused unless ``overwrite`` (the error
    ends with ``advice``).

    Raises:
        InputError: a file is in the way, the folder is not empty, or cannot be created.
    """
    folder = Path(folder)
    if os.path.lexists(folder) and not folder.is_dir():
        raise InputError(f"{folder} is a file: give a folder")
    marked = (folder / INCOMPLETE_MARKER).exists()
    if folder.is_dir() and any(folder.iterdir()) and not (marked or overwrite):
        raise InputError(f"{folder} is not empty: {advice}")
    try:
        folder.mkdir(parents=True, exist_ok=True)
        if marked:
            _remove_entries(folder, owned)
        (folder / INCOMPLETE_MARKER).write_text("a slearn build was started here and has not "
                                                "finished; rerunning it replaces this folder's outputs\n")
    except OSError as err:
        raise InputError(f"{folder}: cannot prepare the folder: {err.strerror or err}") from err
    return folder


def release_folder(folder: str | os.PathLike) -> None:
    """Mark a folder claimed by :func:`claim_folder` complete."""
    with suppress(FileNotFoundError):
        os.unlink(Path(folder) / INCOMPLETE_MARKER)
    fsync_folder(folder)


def _remove_entries(folder: Path, names: Iterable[str]) -> None:
    import shutil

    for name in names:
        target = folder / name
        if target.is_dir() and not target.is_symlink():
            shutil.rmtree(target)
        elif os.path.lexists(target):
            target.unlink()
