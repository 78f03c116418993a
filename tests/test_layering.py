"""The layers of docs/ARCHITECTURE.md, checked on every import statement (also those inside
functions): the core is pure, nothing below the command line imports it, I/O never
reaches up into the jobs."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = {"slearn": ROOT / "slearn", "slearn.recorders": ROOT / "recorders",
           "slearn.replay": ROOT / "replay", "slearn.datasets": ROOT / "datasets"}
CORE_MAY_IMPORT = {"numpy", "numba", "slearn.core", "slearn.errors"}
JIT_MAY_IMPORT = {"llvmlite"}  # numba's code generator, for the one intrinsic slearn.core._jit defines


def modules() -> dict[str, Path]:
    out = {}
    for package, folder in FOLDERS.items():
        for path in folder.rglob("*.py"):
            parts = path.relative_to(folder).with_suffix("").parts
            parts = parts[:-1] if parts[-1] == "__init__" else parts
            out[".".join((package, *parts))] = path
    return out


def imports(path: Path) -> set[str]:
    """Every module ``path`` imports, absolute (``from slearn import x`` counts as ``slearn.x``)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            found.add(node.module)
            found.update(f"{node.module}.{alias.name}" for alias in node.names if node.module == "slearn")
    return found


def within(name: str, prefix: str) -> bool:
    return name == prefix or name.startswith(prefix + ".")


MODULES = modules()


def test_the_tree_is_where_the_layers_say():
    for package in ("slearn.core", "slearn.io", "slearn.jobs", "slearn.cli"):
        assert sum(within(m, package) for m in MODULES) > 3, package


@pytest.mark.parametrize("module", sorted(m for m in MODULES if within(m, "slearn.core")))
def test_the_core_imports_only_numpy_numba_the_standard_library_and_itself(module):
    foreign = {name for name in imports(MODULES[module])
               if name.split(".")[0] not in sys.stdlib_module_names
               and not any(within(name, allowed) for allowed in CORE_MAY_IMPORT)
               and not (module == "slearn.core._jit" and name.split(".")[0] in JIT_MAY_IMPORT)
               and name != "slearn"}  # `from slearn import x` is checked as slearn.x
    assert not foreign, f"{module} imports {sorted(foreign)}"


def test_nothing_below_the_command_line_imports_it():
    offenders = {m: sorted(n for n in imports(p) if within(n, "slearn.cli"))
                 for m, p in MODULES.items() if not within(m, "slearn.cli") and m != "slearn.__main__"}
    assert {m: n for m, n in offenders.items() if n} == {}


def test_input_and_output_never_import_the_jobs():
    offenders = {m: sorted(n for n in imports(p) if within(n, "slearn.jobs"))
                 for m, p in MODULES.items() if within(m, "slearn.io")}
    assert {m: n for m, n in offenders.items() if n} == {}


def test_the_checker_sees_imports_inside_functions(tmp_path):
    path = tmp_path / "m.py"
    path.write_text("def f():\n    from slearn import cli\n    import slearn.jobs.learn\n")
    assert imports(path) == {"slearn", "slearn.cli", "slearn.jobs.learn"}
