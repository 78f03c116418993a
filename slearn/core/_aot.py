"""slearn's kernels compiled ahead of time, at install, so that a first run compiles nothing.

Numba compiles a kernel on its first call and caches it on disk; on a fresh install, a new
container or an empty cache, a first ``slearn demo`` spent 8-27 s of CPU typing and lowering
about seventy functions before it did any work. At install, the build compiles every
signature that slearn's commands call from Python (the manifest ``kernel_signatures.json``,
written by ``python tests/kernel_workload.py --write``) into one extension module,
``slearn.core._compiled``, with numba's own ahead-of-time compiler (``numba.pycc``): the same
source, the same numba, the same results. At import, each kernel's compiled signatures are
entered into its dispatcher as if numba had compiled them, so a call whose argument types
match runs the shipped code and any other call compiles as before.

The extension is used only when it was built from the sources in use (its exported
``fingerprint_<hex>`` names them, manifest included) by the numba in use; an edited kernel
module or another numba falls back to compiling, which is always correct. Without a C
compiler the install skips the extension and slearn compiles at first use.
``SLEARN_AOT=0`` ignores the extension.
"""

from __future__ import annotations

import hashlib
import importlib
import json
import os
import re
import sys
from functools import lru_cache
from pathlib import Path
from typing import Any, cast

import numba
import numpy as np
from numba.core import dispatcher as numba_dispatcher
from numba.core import types
from numba.core.registry import CPUDispatcher

from slearn.core import _jit

_Dispatcher: Any = numba_dispatcher.Dispatcher  # (its _compile_for_args is not in numba's stubs)

MANIFEST = Path(__file__).with_name("kernel_signatures.json")
EXTENSION = "slearn.core._compiled"


def encode(numba_type) -> Any:
    """A numba argument type as JSON (arrays, scalars, dtypes, tuples and named tuples of them)."""
    if isinstance(numba_type, types.Array):  # as numba prints it: "readonly array(uint8, 1d, C)"
        return (("" if numba_type.mutable else "readonly ") + ("" if numba_type.aligned else "unaligned ")
                + f"array({numba_type.dtype}, {numba_type.ndim}d, {numba_type.layout})")
    if isinstance(numba_type, types.BaseTuple):
        fields = [encode(t) for t in cast(Any, numba_type).types]  # (not in numba's stubs)
        cls = getattr(numba_type, "instance_class", tuple)
        if cls is tuple:
            return {"tuple": fields}
        return {"named": f"{cls.__module__}:{cls.__qualname__}", "fields": fields}
    if isinstance(numba_type, (types.Integer, types.Float, types.Boolean)):
        return str(numba_type)
    if isinstance(numba_type, types.NumberClass):  # a dtype passed as an argument: "class(int32)"
        return str(numba_type)
    raise TypeError(f"no encoding for the numba type {numba_type}")


_ARRAY = re.compile(r"(readonly )?(unaligned )?array\((\w+), (\d+)d, ([CFA])\)")
_CLASS = re.compile(r"class\((\w+)\)")


def _scalar(name: str):
    return numba.from_dtype(np.dtype(name))


def decode(value: Any):
    """The numba type that :func:`encode` wrote (named tuples' classes are imported)."""
    if isinstance(value, str):
        array = _ARRAY.fullmatch(value)
        if array:
            readonly, unaligned, dtype, ndim, layout = array.groups()
            array_type: Any = types.Array
            return array_type(_scalar(dtype), int(ndim), layout, readonly=bool(readonly), aligned=not unaligned)
        number_class = _CLASS.fullmatch(value)
        return types.NumberClass(_scalar(number_class.group(1))) if number_class else _scalar(value)
    if "tuple" in value:
        return types.BaseTuple.from_types([decode(v) for v in value["tuple"]])
    module, qualname = value["named"].split(":")
    cls: Any = importlib.import_module(module)
    for part in qualname.split("."):
        cls = getattr(cls, part)
    return types.BaseTuple.from_types([decode(v) for v in value["fields"]], cls)


def function_name(dispatcher) -> str:
    """``module.qualname`` of a dispatcher's Python function (the manifest's key)."""
    return f"{dispatcher.py_func.__module__}.{dispatcher.py_func.__qualname__}"


def symbol(name: str, index: int) -> str:
    """The extension's name for the ``index``-th signature of function ``name``."""
    return f"{name.replace('.', '_')}__{index}"


class PythonCalls:
    """Within ``with``, records the argument types of every call from Python that one of
    slearn's kernels (or helpers that Python calls) compiled for or loaded from the cache;
    :meth:`signatures` adds every signature they were compiled for as callees (a Python
    call of those types finds that one and records nothing). Run it on an empty cache, so
    that every callee compiles: the record is then the same on every run.
    """

    def __init__(self) -> None:
        self.calls: set = set()

    def __enter__(self) -> PythonCalls:
        self.original = original = _Dispatcher._compile_for_args
        calls = self.calls

        def compile_for_args(dispatcher, *args, **kws):
            if hasattr(dispatcher, "shipped"):  # (set by slearn.core._jit on what Python calls)
                calls.add((function_name(dispatcher), tuple(dispatcher.typeof_pyval(a) for a in args)))
            return original(dispatcher, *args, **kws)

        self.original_direct = original_direct = _jit._compile_direct

        def compile_direct(dispatcher, args):  # (_jit.direct_call's)
            calls.add((function_name(dispatcher), args))
            return original_direct(dispatcher, args)

        _Dispatcher._compile_for_args = compile_for_args
        _jit._compile_direct = compile_direct
        return self

    def __exit__(self, *exc) -> None:
        _Dispatcher._compile_for_args = self.original
        _jit._compile_direct = self.original_direct

    def signatures(self) -> dict[str, list]:
        """The signatures, encoded, by function name (sorted)."""
        compiled = {(function_name(d), args) for module_name, module in list(sys.modules.items())
                    if module_name.startswith("slearn") for d in vars(module).values()
                    if isinstance(d, CPUDispatcher) and hasattr(d, "shipped") for args in d.overloads}
        found: dict[str, list] = {}
        for name, args in self.calls | compiled:
            found.setdefault(name, []).append([encode(t) for t in args])
        return {name: sorted(sigs, key=json.dumps) for name, sigs in sorted(found.items())}


@lru_cache(maxsize=1)
def manifest() -> dict[str, list]:
    """The manifest: encoded argument types by function name."""
    try:
        return json.loads(MANIFEST.read_text())["signatures"]
    except (OSError, ValueError, KeyError):
        return {}


def fingerprint(sources_fingerprint: str) -> str:
    """The extension's fingerprint: the kernel sources' and the manifest's."""
    digest = hashlib.sha256(sources_fingerprint.encode())
    digest.update(MANIFEST.read_bytes() if MANIFEST.exists() else b"")
    return digest.hexdigest()[:16]


@lru_cache(maxsize=1)
def _lookup() -> tuple[Any, str | None]:
    """The extension module, or None and why (None when ``SLEARN_AOT=0`` asked for it)."""
    if os.environ.get("SLEARN_AOT", "1") == "0":
        return None, None
    try:
        module = importlib.import_module(EXTENSION)
    except ImportError:
        return None, "the install compiled none (no C compiler?)"
    if not hasattr(module, "fingerprint_" + fingerprint(_jit.installed_fingerprint())):
        return None, "the ones compiled at install come from other sources or another numba"
    return module, None


def _extension():
    """The extension module, or None: not built, disabled, or built from other sources."""
    return _lookup()[0]


def unused_reason() -> str | None:
    """Why the extension is not used, or None: it is, or ``SLEARN_AOT=0`` asked so."""
    return _lookup()[1]


def attach(dispatcher) -> dict:
    """Enter the shipped signatures of ``dispatcher`` into it; the entry points by argument
    types (empty when there are none)."""
    module = _extension()
    name = function_name(dispatcher)
    entries: dict = {}
    if module is None or name not in manifest():
        return entries
    for index, encoded in enumerate(manifest()[name]):
        compiled = getattr(module, symbol(name, index), None)
        if compiled is None:  # (a module the build could not import)
            continue
        args = tuple(decode(t) for t in encoded)
        dispatcher._insert([a._code for a in args], compiled, False)  # as numba's add_overload
        entries[args] = compiled
    return entries


def _built() -> int:
    return 0


def build(target: Path, root: Path) -> list[str]:
    """Compile the manifest's signatures from the sources under ``root`` into the extension
    file ``target``; the functions skipped (their module does not import here)."""
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # numba.pycc announces its own deprecation
        from numba.pycc import CC
    folders = [root / "slearn", root / "replay", root / "recorders"]
    sources = _jit.source_fingerprint(_jit.kernel_sources(folders))
    cc = CC(target.name.split(".")[0])
    cc.output_dir = str(target.parent)
    cc.output_file = target.name
    cc.export("fingerprint_" + fingerprint(sources), "int64()")(_built)
    skipped = []
    for name, signatures in manifest().items():
        module_name, _, attribute = name.rpartition(".")
        try:
            dispatcher = getattr(importlib.import_module(module_name), attribute)
        except Exception:  # a module that needs more than numpy and numba: compiled at first use
            skipped.append(name)
            continue
        for index, encoded in enumerate(signatures):
            cc.export(symbol(name, index), tuple(decode(t) for t in encoded))(dispatcher.py_func)
    cc.compile()
    return skipped


if __name__ == "__main__":  # python -m slearn.core._aot TARGET ROOT
    print("skipped:", build(Path(sys.argv[1]), Path(sys.argv[2])))
