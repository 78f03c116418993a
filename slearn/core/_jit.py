"""How slearn compiles its kernels: two decorators and a cache of its own.

* :func:`kernel` compiles a function called once per batch of work (a whole episode, a
  table to rebuild). It may allocate; it reads the arrays of its state into locals once.
* :func:`prefetch` asks the CPU for an array element ahead of its use (an intrinsic numba
  has no name for): lookups whose slots are known before they are made then wait for
  memory together, not one after another.
* :func:`helper` compiles a function called per step from a kernel. Helpers are compiled
  without numba's reference counting (``_nrt=False``): they take raw arrays and scalars,
  never allocate, and a call costs what a C call costs. (A helper inlined into its caller
  at numba's IR level, or compiled with reference counting, pays an atomic increment and
  decrement per array argument on every call: that was most of the learning time.)

Compiled code is cached on disk in a folder of slearn's own, named after a fingerprint
of the sources of every module that holds kernels, so that a change in any of them (a
callee in another module included) compiles everything once again; numba alone checks a
kernel against its own file only. The folder is set while slearn's kernels are decorated
and restored after, so other libraries' kernels in the same process keep their own
cache. Folders of other fingerprints unused for a week, or beyond the eight most recently
used, are removed (checkouts of several branches share the base). ``NUMBA_CACHE_DIR`` moves slearn's
folder under it; ``SLEARN_CACHE_DIR`` sets it outright.

Kernels, and helpers that Python calls, are also compiled at install (``_aot``): each
dispatcher made here gets those signatures entered, so a fresh install compiles nothing
for the calls slearn's commands make, and any other call compiles as described above.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import time
from functools import lru_cache
from pathlib import Path
from typing import Any

import numba
from llvmlite import ir
from numba.core import cgutils, types
from numba.extending import intrinsic

_MARKER = b"from slearn.core._jit import"
_PACKAGES = ("slearn", "slearn.replay", "slearn.recorders")
# Several checkouts (branches, worktrees, virtualenvs) share the cache base, each with its
# own fingerprint: a folder goes when unused for a week, or beyond the most recently used.
KEEP_FOLDERS = 8
STALE_S = 7 * 24 * 3600


def kernel(function):
    """Compile ``function`` as a cached kernel (it may allocate)."""
    with _slearn_cache():
        return _shipped(_plain_calls(numba.njit(cache=True)(function)))


def helper(function=None, *, python: bool = False):
    """Compile ``function`` as a cached per-step helper: no reference counting, no allocation.

    A helper is called from compiled code only, so numba builds no wrapper to call it from
    Python (a third of a small function's compile time); ``@helper(python=True)`` for one
    that Python calls too (a call from Python without the wrapper would crash).
    """
    if function is None:
        return lambda f: helper(f, python=python)
    options: dict[str, Any] = {"cache": True, "_nrt": False}
    if not python:
        options.update(no_cpython_wrapper=True, no_cfunc_wrapper=True)
    with _slearn_cache():
        dispatcher = _plain_calls(numba.njit(**options)(function))
    return _shipped(dispatcher) if python else dispatcher


@intrinsic
def prefetch(typingctx, array, index):
    """``prefetch(array, i)`` in compiled code: bring ``array[i]`` into the CPU's caches
    (LLVM's ``llvm.prefetch``; no effect on any result, no bounds check needed: a prefetch
    never faults). Learning a library of 650,000 patterns spent most of its time waiting for
    one hash slot after another; fetching the slots of a step's contexts first made it
    1.2x faster (``bench_learn.py``). llvmlite is numba's own, in the version numba pins."""
    if not isinstance(array, types.Array) or not isinstance(index, types.Integer):
        return None

    def codegen(context, builder, signature, args):
        array_type = signature.args[0]
        data = context.make_array(array_type)(context, builder, args[0])
        at = cgutils.get_item_pointer(context, builder, array_type, data, [args[1]], wraparound=False)
        i32 = ir.IntType(32)
        declared = builder.module.declare_intrinsic(  # named as this LLVM names it (p0i8 or p0)
            "llvm.prefetch", [cgutils.voidptr_t], ir.FunctionType(ir.VoidType(), [cgutils.voidptr_t, i32, i32, i32]))
        read, keep_in_all_levels, data_cache = (ir.Constant(i32, x) for x in (0, 3, 1))
        builder.call(declared, [builder.bitcast(at, cgutils.voidptr_t), read, keep_in_all_levels, data_cache])
        return context.get_dummy_value()
    return types.void(array, index), codegen


def direct_call(dispatcher, *example):
    """``dispatcher`` compiled (or loaded from the cache) for the types of ``example``, as
    its compiled entry point: a call that skips the dispatcher's typing of its arguments
    (0.2 us of a 0.4 us call with one array). Pass it arguments of exactly those types; a
    dispatcher that cannot give one is returned as it is."""
    try:
        args = tuple(numba.typeof(a) for a in example)
    except ValueError:  # a type numba has not: the plain call says so
        return dispatcher
    if args in getattr(dispatcher, "shipped", {}):  # compiled at install (_aot)
        return dispatcher.shipped[args]
    return _compile_direct(dispatcher, args)


def _compile_direct(dispatcher, args):
    try:
        return dispatcher.compile(args)
    except Exception:  # (an interface of numba's that changed: the plain call still works)
        return dispatcher


def _shipped(dispatcher):
    """``dispatcher`` with the signatures compiled at install entered (``_aot``); their entry
    points are kept as ``dispatcher.shipped``, by argument types."""
    from slearn.core import _aot
    dispatcher.shipped = _aot.attach(dispatcher)
    return dispatcher


def _plain_calls(dispatcher):
    """Called from compiled code, compile ``dispatcher`` for the plain types of its arguments.

    Numba types a constant argument as a literal (``Literal[int](0)`` for ``m = 0``) and
    compiles the callee once more for it, and once more for an ``int32`` where another call
    passes an ``int64``: a second (third, fourth) compilation of most helpers, a third of a
    cold start's compile time. One signature serves every call: literals as their plain
    type, signed integer scalars as ``int64`` (numba computes in ``int64`` anyway).
    """
    resolve = dispatcher.get_call_template

    def get_call_template(args, kws):
        return resolve(tuple(_plain(a) for a in args), {k: _plain(v) for k, v in kws.items()})

    dispatcher.get_call_template = get_call_template
    return dispatcher


def _plain(numba_type):
    numba_type = types.unliteral(numba_type)
    if isinstance(numba_type, types.Integer) and numba_type.signed and numba_type.bitwidth < 64:
        return types.int64
    return numba_type


class _slearn_cache:
    """Point numba's cache at slearn's folder for the duration of a decoration."""

    def __enter__(self) -> None:
        config: Any = numba.config  # numba sets its options at run time
        self.saved = config.CACHE_DIR
        config.CACHE_DIR = cache_folder()

    def __exit__(self, *exc) -> None:
        config: Any = numba.config
        config.CACHE_DIR = self.saved


@lru_cache(maxsize=1)
def cache_folder() -> str:
    """slearn's cache folder for the current sources (created, older ones pruned)."""
    base = cache_base()
    folder = base / installed_fingerprint()
    folder.mkdir(parents=True, exist_ok=True)
    _COLD[:] = [] if any(folder.rglob("*.nbi")) else [folder]
    folder.touch()
    prune(base, folder)
    return str(folder)


_COLD: list[Path] = []  # the cache folder, when it held no compiled kernel as this process found it


def compiled_this_run() -> bool:
    """Whether this process compiled kernels into a cache folder that held none when it
    found it (numba's index files, ``*.nbi``, appear as it compiles)."""
    return bool(_COLD) and any(_COLD[0].rglob("*.nbi"))


def cache_base() -> Path:
    """Where fingerprint folders live."""
    if os.environ.get("SLEARN_CACHE_DIR"):
        return Path(os.environ["SLEARN_CACHE_DIR"])
    if os.environ.get("NUMBA_CACHE_DIR"):
        return Path(os.environ["NUMBA_CACHE_DIR"]) / "slearn"
    home = os.environ.get("XDG_CACHE_HOME") or os.path.join(Path.home(), ".cache")
    return Path(home) / "slearn" / "numba"


def kernel_sources(folders: list[Path] | None = None) -> list[Path]:
    """The source files of every slearn module that compiles kernels, sorted: in the
    installed packages, or under ``folders`` (a source tree, at build time)."""
    import importlib.util
    if folders is None:
        specs = (importlib.util.find_spec(name) for name in _PACKAGES)
        folders = [Path(f) for spec in specs if spec is not None and spec.submodule_search_locations
                   for f in spec.submodule_search_locations]
    files = {p for folder in folders for p in Path(folder).rglob("*.py")}
    files = {p for p in files if _MARKER in p.read_bytes()} | {Path(__file__)}  # prefetch is compiled in
    return sorted(files, key=lambda p: (p.parent.name, p.name))


@lru_cache(maxsize=1)
def installed_fingerprint() -> str:
    """The fingerprint of the installed kernel modules (computed once)."""
    return source_fingerprint()


def source_fingerprint(files: list[Path] | None = None) -> str:
    """A short hash of the kernel modules' sources (names and contents)."""
    digest = hashlib.sha256()
    for path in kernel_sources() if files is None else files:
        digest.update(f"{path.parent.name}/{path.name}".encode() + b"\0" + path.read_bytes())
    digest.update(numba.__version__.encode())
    return digest.hexdigest()[:16]


def prune(base: Path, current: Path, now: float | None = None) -> None:
    """Remove fingerprint folders unused for ``STALE_S`` seconds or beyond the
    ``KEEP_FOLDERS`` most recently used (the current one counted and kept)."""
    now = time.time() if now is None else now
    try:
        folders = [p for p in base.iterdir() if p.is_dir() and p != current and len(p.name) == 16]
        folders.sort(key=lambda p: p.stat().st_mtime, reverse=True)
        for rank, folder in enumerate(folders, start=1):
            if rank >= KEEP_FOLDERS or now - folder.stat().st_mtime > STALE_S:
                shutil.rmtree(folder, ignore_errors=True)
    except OSError:
        pass  # a read-only or vanished cache is not an error: numba recompiles
