"""slearn's kernel cache: its own folder, named after every kernel module's sources, set only
while slearn decorates, and pruned."""

from __future__ import annotations

import ast
import json
import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

from slearn.core import _jit

# A kernel in one module calling a helper in another, and another library's cached kernel
# decorated after them. The fingerprint is taken over the files of this small package.
_HELPER = "from slearn.core._jit import helper\n\n@helper\ndef bump(x):\n    return x + {step}\n"
_KERNEL = textwrap.dedent("""
    from slearn.core._jit import kernel
    from pkgx.a import bump

    @kernel
    def total(values):
        s = 0
        for v in values:
            s += bump(v)
        return s
""")
_OTHER = "import numba\n\n@numba.njit(cache=True)\ndef other(x):\n    return x * 2\n"
_CHILD = textwrap.dedent("""
    import json, sys
    from pathlib import Path
    import numba, numpy as np
    sys.path.insert(0, sys.argv[1])
    import slearn.core._jit as jit
    covered = sys.argv[2].split(",")
    jit.kernel_sources = lambda: [Path(sys.argv[1], "pkgx", name) for name in covered]
    before = numba.config.CACHE_DIR
    from pkgx import b
    from pkgx.other import other
    result = int(b.total(np.arange(4, dtype=np.int64)))
    other(3)
    print(json.dumps({"result": result, "hits": sum(b.total.stats.cache_hits.values()),
                      "restored": numba.config.CACHE_DIR == before, "folder": jit.cache_folder()}))
""")


def _package(root: Path, step: int) -> None:
    pkg = root / "pkgx"
    pkg.mkdir(exist_ok=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text(_HELPER.format(step=step))
    (pkg / "b.py").write_text(_KERNEL)
    (pkg / "other.py").write_text(_OTHER)


def _run(root: Path, covered: str) -> dict:
    env = dict(os.environ, SLEARN_CACHE_DIR=str(root / "slearn-cache"),
               NUMBA_CACHE_DIR=str(root / "numba-cache"))
    done = subprocess.run([sys.executable, "-c", _CHILD, str(root), covered], env=env,
                          capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_a_changed_callee_in_another_module_recompiles(tmp_path):
    _package(tmp_path, step=1)
    first = _run(tmp_path, "a.py,b.py")
    assert first == {**first, "result": 10, "hits": 0, "restored": True}
    assert _run(tmp_path, "a.py,b.py")["hits"] == 1  # unchanged sources: loaded from the cache
    _package(tmp_path, step=100)
    changed = _run(tmp_path, "a.py,b.py")
    assert changed["result"] == 0 + 1 + 2 + 3 + 4 * 100 and changed["hits"] == 0
    assert changed["folder"] != first["folder"]


def test_numba_alone_would_serve_the_stale_kernel(tmp_path):
    """Why the fingerprint covers the callee's module: without it the caller's cached code
    (the old callee compiled in) is loaded again."""
    _package(tmp_path, step=1)
    assert _run(tmp_path, "b.py")["result"] == 10
    _package(tmp_path, step=100)
    assert _run(tmp_path, "b.py")["result"] == 10


def test_other_librarys_kernels_keep_their_own_cache(tmp_path):
    _package(tmp_path, step=1)
    folder = Path(_run(tmp_path, "a.py,b.py")["folder"])
    ours = {p.name for p in folder.rglob("*.nbi")}
    assert any(name.startswith("b.total") for name in ours)
    assert not any(name.startswith("other.") for name in ours)
    assert any(p.name.startswith("other.") for p in (tmp_path / "numba-cache").rglob("*.nbi"))


def test_fingerprint_covers_every_kernel_module():
    """Every module that decorates a kernel or helper, in any of the installed folders."""
    names = {f"{p.parent.name}/{p.name}" for p in _jit.kernel_sources()}
    root = Path(__file__).resolve().parents[1]
    decorating = {f"{p.parent.name}/{p.name}" for folder in ("slearn", "replay", "recorders")
                  for p in (root / folder).rglob("*.py") if re.search(r"^@(kernel|helper)\b", p.read_text(), re.M)}
    assert {"core/online.py", "core/tokens.py", "core/views.py", "io/mcap_scan.py"} <= decorating <= names
    assert "core/_jit.py" in names  # its intrinsic is compiled into the kernels
    assert "slearn/errors.py" not in names


def test_prune_drops_unused_and_surplus_folders(tmp_path):
    now = 1_000_000_000.0
    current = tmp_path / ("c" * 16)
    current.mkdir()
    ages = {f"{i:016x}": i * 3600.0 for i in range(1, 12)}  # hours since last use
    ages["old0000000000000"] = _jit.STALE_S + 1
    for name, age in ages.items():
        (tmp_path / name).mkdir()
        os.utime(tmp_path / name, (now - age, now - age))
    (tmp_path / "not-a-fingerprint").mkdir()
    _jit.prune(tmp_path, current, now=now)
    left = sorted(p.name for p in tmp_path.iterdir())
    newest = [f"{i:016x}" for i in range(1, _jit.KEEP_FOLDERS)]
    assert left == sorted(newest + [current.name, "not-a-fingerprint"])


def test_a_helper_compiles_once_for_literal_and_narrow_arguments():
    """A constant (``Literal[int]``) or an ``int32`` scalar argument compiles no second
    version of a callee: one plain signature serves every call."""
    import numpy as np

    @_jit.helper
    def add(a, b):
        return a + b

    @_jit.kernel
    def calls(values):
        return add(0, values[0]) + add(values[0], np.int64(1)) + add(np.int32(2), values[1])

    assert calls(np.array([5, 7], np.int32)) == 5 + 6 + 9
    assert add.signatures == [(_jit.types.int64, _jit.types.int64)]



def test_a_direct_call_skips_the_dispatcher_and_answers_the_same():
    import numpy as np

    @_jit.kernel
    def first(values):
        return values[0] * 2

    values = np.array([21, 1], np.int64)
    direct = _jit.direct_call(first, values)
    assert direct is not first and direct(values) == first(values) == 42
    assert first.signatures == [(_jit.types.int64[::1],)]  # compiled once, for that type
    assert _jit.direct_call(first, object()) is first  # a type numba has not: the plain call

def _decorator(node) -> str:
    """``helper``, ``helper-python`` (``@helper(python=True)``), ``kernel`` or ""."""
    if isinstance(node, ast.Call):
        python = any(k.arg == "python" and getattr(k.value, "value", False) for k in node.keywords)
        return "helper-python" if getattr(node.func, "id", "") == "helper" and python else ""
    return getattr(node, "id", "") if getattr(node, "id", "") in ("helper", "kernel") else ""


def test_helpers_called_from_python_are_the_ones_marked_so():
    """Helpers get no wrapper for calls from Python (about a sixth of a cold demo's
    compile): a helper that Python calls must say so, or the call would crash the
    process. Parsed, so it fails before anything runs: every helper called from a function
    that is not compiled (by its name in its own module, by a name imported from its
    module, or as ``module.name``) is ``@helper(python=True)``, and every one so marked is."""
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    parsed = {}
    for folder, package in (("slearn", "slearn"), ("replay", "slearn.replay"), ("recorders", "slearn.recorders")):
        for path in (root / folder).rglob("*.py"):
            parts = path.relative_to(root / folder).with_suffix("").parts
            parsed[".".join((package, *parts))] = ast.parse(path.read_text())
    kinds = {(module, n.name): _decorator(d) for module, tree in parsed.items() for n in tree.body
             if isinstance(n, ast.FunctionDef) for d in n.decorator_list if _decorator(d)}
    called = set()
    for module, tree in parsed.items():
        names = {n.name: (module, n.name) for n in tree.body if isinstance(n, ast.FunctionDef)}
        modules = {}
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module:
                for alias in node.names:
                    names[alias.asname or alias.name] = (node.module, alias.name)
                    modules[alias.asname or alias.name] = f"{node.module}.{alias.name}"
        for function in ast.walk(tree):
            if not isinstance(function, ast.FunctionDef) or any(_decorator(d) for d in function.decorator_list):
                continue
            for call in ast.walk(function):
                if not isinstance(call, ast.Call):
                    continue
                f = call.func
                if isinstance(f, ast.Name):
                    target = names.get(f.id)
                elif isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name) and f.value.id in modules:
                    target = (modules[f.value.id], f.attr)
                else:
                    continue
                if kinds.get(target, "").startswith("helper"):
                    called.add(target)
    marked = {key for key, kind in kinds.items() if kind == "helper-python"}
    assert len(kinds) > 50 and len(marked) >= 5
    assert called - marked == set(), "called from Python without a wrapper"
    assert marked - called == set(), "marked for Python, but Python does not call it"
