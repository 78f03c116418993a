"""Small memory pages: the command line and slearn's Ray tasks turn transparent huge pages
off for their process (slearn.jobs.pages), and nothing they write depends on it."""

from __future__ import annotations

import subprocess
import sys

import pytest

from slearn.io.spec import pointer_spec
from slearn.jobs import distributed, merge_tree
from slearn.recorders.pointer import PointerConfig
from slearn.recorders.record_pointer import record_pointer

linux_only = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="a Linux process setting")

# Runs the command line in a fresh interpreter (``system`` first: small_pages does nothing),
# then prints the process's transparent huge page setting. The setting is inherited, and
# this test process may have run the command line already: the child starts it afresh.
_CHILD = """
import ctypes, sys
import slearn.jobs.pages as pages
ctypes.CDLL(None).prctl(pages.PR_SET_THP_DISABLE, 0, 0, 0, 0)  # as a fresh shell would start it
if sys.argv[1] == "system":
    pages.small_pages = lambda: False
from slearn.cli import main
try:
    main(sys.argv[2:], standalone_mode=False)
except SystemExit:
    pass
status = [line for line in open("/proc/self/status") if line.startswith("THP_enabled:")]
print(status[0].split()[1] if status else "unknown", file=sys.stderr)
"""


def _cli(pages: str, *args) -> str:
    done = subprocess.run([sys.executable, "-c", _CHILD, pages, *map(str, args)],
                          capture_output=True, text=True, check=True)
    return done.stderr.strip().splitlines()[-1]


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    folder = tmp_path_factory.mktemp("pages")
    return record_pointer(PointerConfig(condition="error", trials=300, seed=3), folder / "p.mcap").path


@linux_only
def test_small_pages_turns_huge_pages_off_for_its_process():
    code = ("import ctypes\n"
            "from slearn.jobs.pages import PR_SET_THP_DISABLE, small_pages\n"
            "ctypes.CDLL(None).prctl(PR_SET_THP_DISABLE, 0, 0, 0, 0)\n"
            "before = [l.split()[1] for l in open('/proc/self/status') if l.startswith('THP_enabled:')]\n"
            "print(small_pages(), before)\n"
            "print([l.split()[1] for l in open('/proc/self/status') if l.startswith('THP_enabled:')])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    said, after = out.stdout.splitlines()
    if "[]" in said:
        pytest.skip("this kernel does not report THP_enabled")
    assert said == "True ['1']"
    assert after == "['0']"


@linux_only
def test_the_command_line_runs_with_small_pages_and_writes_the_same_bytes(log, tmp_path):
    small, system = tmp_path / "small.parquet", tmp_path / "system.parquet"
    said = _cli("small", "learn", log, "-o", small, "-q"), _cli("system", "learn", log, "-o", system, "-q")
    assert small.read_bytes() == system.read_bytes()
    if "unknown" in said:
        pytest.skip("this kernel does not report THP_enabled")
    assert said == ("0", "1")


def test_ray_tasks_take_small_pages_for_their_worker(log, monkeypatch):
    """On a cluster joined with --ray, a task's worker was not started by the command line."""
    calls = []
    monkeypatch.setattr(distributed, "small_pages", lambda: calls.append("read") or True)
    monkeypatch.setattr(merge_tree, "small_pages", lambda: calls.append("merge_tree") or True)
    spec = pointer_spec()
    list(distributed.read_log(str(log), spec.to_dict(), spec.source, None))
    stats, library = merge_tree.learn_log(str(log), spec.to_dict(), spec.source, 4, None)
    merge_tree.merge_pair(library, None)
    merge_tree.merge_pair(library, library)
    assert calls == ["read", "merge_tree", "merge_tree", "merge_tree"]  # learn_log, two merge_pair
