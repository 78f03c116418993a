"""The wheel installs one import name, slearn, with recorders/replay/datasets inside it."""

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> zipfile.ZipFile:
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "-w", str(out), str(ROOT)],
                   check=True, capture_output=True)
    (path,) = out.glob("slearn-*.whl")
    return zipfile.ZipFile(path)


def test_only_top_level_package_is_slearn(wheel):
    tops = {name.split("/")[0] for name in wheel.namelist()}
    assert {t for t in tops if not t.endswith(".dist-info")} == {"slearn"}


def test_subpackages_are_installed_under_slearn(wheel):
    names = set(wheel.namelist())
    for module in ("slearn/recorders/pointer.py", "slearn/replay/__init__.py", "slearn/datasets/__init__.py",
                   "slearn/cli/__init__.py", "slearn/core/library.py", "slearn/io/mcap_read.py",
                   "slearn/jobs/learn.py", "slearn/py.typed"):
        assert module in names
    assert any(n.startswith("slearn/datasets/") and n.endswith(".toml") for n in names)


def test_console_script_and_module_entry_point(wheel):
    entry_points = wheel.read(next(n for n in wheel.namelist() if n.endswith("entry_points.txt"))).decode()
    assert "slearn = slearn.cli:main" in entry_points
    result = subprocess.run([sys.executable, "-m", "slearn", "--version"], capture_output=True, text=True)
    assert result.returncode == 0 and "slearn" in result.stdout


def test_the_wheel_ships_the_kernels_compiled_at_build_and_their_manifest(wheel):
    names = wheel.namelist()
    assert "slearn/core/kernel_signatures.json" in names
    if shutil.which("cc") or shutil.which("gcc"):  # (without a compiler the build skips them)
        assert any(n.startswith("slearn/core/_compiled.") for n in names)
