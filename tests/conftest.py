"""Session fixtures (pointer logs recorded once), the ``shared`` marker for tests on the
real files in ``../shared/data/mcap``, and a summary line that counts those tests, so a
run without the shared data says so instead of passing quietly."""

from __future__ import annotations

import pytest
from click.testing import CliRunner
from fixtures import SHARED_MCAP

from slearn.cli import main
from slearn.recorders.pointer import PointerConfig
from slearn.recorders.record_pointer import record_pointer


def pytest_configure(config) -> None:
    config.addinivalue_line("markers", "shared: reads ../shared/data/mcap (skipped when it is absent)")


def pytest_collection_modifyitems(items) -> None:
    if SHARED_MCAP.exists():
        return
    skip = pytest.mark.skip(reason=f"{SHARED_MCAP} is not available")
    for item in items:
        if item.get_closest_marker("shared"):
            item.add_marker(skip)


def pytest_terminal_summary(terminalreporter) -> None:
    counts = {"passed": 0, "skipped": 0, "failed": 0}
    for outcome in counts:
        counts[outcome] = sum(1 for report in terminalreporter.stats.get(outcome, [])
                              if "shared" in getattr(report, "keywords", {}) and report.when in ("call", "setup"))
    total = sum(counts.values())
    if total:
        terminalreporter.write_line(f"shared-data tests ({SHARED_MCAP}): {counts['passed']} passed, "
                                    f"{counts['skipped']} skipped, {counts['failed']} failed")


@pytest.fixture(scope="session")
def pointer_log(tmp_path_factory):
    """``pointer_log(condition, trials, seed=0, switch_trial=None)``: a pointer log recorded
    once per session. Shared: copy it before changing it."""
    folder, cache = tmp_path_factory.mktemp("pointer-logs"), {}

    def get(condition: str = "simple", trials: int = 500, seed: int = 0, switch_trial: int | None = None):
        key = (condition, trials, seed, switch_trial)
        if key not in cache:
            path = folder / ("-".join(map(str, key)) + ".mcap")
            extra = {} if switch_trial is None else {"switch_trial": switch_trial}
            record_pointer(PointerConfig(condition, trials, seed, **extra), path)
            cache[key] = path
        return cache[key]

    return get


@pytest.fixture(scope="session")
def simple_pointer(pointer_log, tmp_path_factory):
    """``(log, library)``: a 500-trial simple pointer log and the library learned from it."""
    log = pointer_log("simple", 500)
    library = tmp_path_factory.mktemp("simple-library") / "lib.parquet"
    assert CliRunner().invoke(main, ["learn", "-q", str(log), "-o", str(library)]).exit_code == 0
    return log, library


@pytest.fixture(scope="session")
def two_simple_libraries(simple_pointer, tmp_path_factory):
    """Two libraries learned from the halves of ``simple_pointer``'s log (a merge of them
    counts nothing twice)."""
    log = simple_pointer[0]
    folder = tmp_path_factory.mktemp("two-libraries")
    halves = folder / "first.parquet", folder / "second.parquet"
    for path, bound in zip(halves, (["--end", "25"], ["--start", "25"])):
        assert CliRunner().invoke(main, ["learn", "-q", str(log), "-o", str(path), *bound]).exit_code == 0
    return halves
