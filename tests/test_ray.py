"""Learning and replaying on a local Ray of 2 CPUs: the bytes and reports of one process.

One Ray instance serves the whole module (starting Ray costs seconds); the multi-node
cluster is in ``test_ray_cluster.py``.
"""

import json
import os
import signal
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import ray
from click.testing import CliRunner

from slearn.cli import main
from slearn.core.vocabulary import Vocabulary
from slearn.errors import InputError
from slearn.io.library_file import load_library
from slearn.io.serialize import read_episodes
from slearn.io.slicing import time_slice
from slearn.io.spec import pointer_spec
from slearn.jobs import distributed
from slearn.jobs.cluster import check_visible, require_ray  # noqa: E402
from slearn.jobs.distributed import RayReader  # noqa: E402
from slearn.jobs.learn import learn_files
from slearn.recorders.arm import ArmConfig, arm_spec, record_arm
from slearn.recorders.pointer import PointerConfig
from slearn.recorders.record_pointer import record_pointer


@pytest.fixture(scope="module")
def local_ray():
    ray.init(num_cpus=2, include_dashboard=False, logging_level="ERROR", log_to_driver=False)
    yield ray
    ray.shutdown()


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """Pointer logs of different dynamics (values met in a different order) and arm logs."""
    folder = tmp_path_factory.mktemp("logs")
    pointer = [record_pointer(PointerConfig(condition=c, trials=1500, seed=i, switch_trial=700), folder / f"p{i}.mcap").path
               for i, c in enumerate(["simple", "error", "scramble", "reversal"])]
    arm = [record_arm(ArmConfig(joints=3, trials=1500, seed=i), folder / f"arm{i}.mcap").path
           for i in range(3)]
    return {"pointer": [str(p) for p in pointer], "arm": [str(p) for p in arm], "folder": folder}


@pytest.fixture(scope="module")
def big_logs(tmp_path_factory):
    """Two logs long enough that a read task can be caught running (and cut)."""
    folder = tmp_path_factory.mktemp("big")
    return [str(record_pointer(PointerConfig(condition="error", trials=12000, seed=s),
                               folder / f"big{s}.mcap").path) for s in range(2)]


def cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture(autouse=True)
def fixed_time(monkeypatch):
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "0")


def test_learn_cli_with_workers_writes_the_bytes_of_one_process(local_ray, logs, tmp_path):
    one, many = tmp_path / "one.parquet", tmp_path / "many.parquet"
    assert cli("learn", *logs["pointer"], "-o", one, "-q").exit_code == 0
    result = cli("learn", *logs["pointer"], "-o", many, "-q", "--workers", "2")
    assert result.exit_code == 0, result.output
    assert many.read_bytes() == one.read_bytes()
    assert load_library(many).library.mixer.epoch.max() > 0  # the scoring state is order-dependent


def test_arm_logs_learned_on_ray_are_the_bytes_of_one_process(local_ray, logs, tmp_path):
    window = time_slice(split=0.6)
    learn_files(logs["arm"], tmp_path / "one.parquet", spec=arm_spec(3), window=window)
    lines = []
    learn_files(logs["arm"], tmp_path / "many.parquet", spec=arm_spec(3), window=window,
                reader=RayReader(local_ray, lines.append, "learned"))
    assert (tmp_path / "many.parquet").read_bytes() == (tmp_path / "one.parquet").read_bytes()
    assert [line.split(":")[0] for line in lines] == [f"learned {i}/3 logs" for i in (1, 2, 3)]
    assert lines[-1].endswith("events/s") and "0 events," not in lines[-1]


def _report(result) -> dict:
    assert result.exit_code == 0, result.output
    document = json.loads(result.stdout)
    assert document["speed"]["predictions"] > 0
    document.pop("speed")  # seconds differ
    return document


@pytest.mark.parametrize("mode", [[], ["--online"]])
def test_replay_with_workers_reports_what_one_process_does(local_ray, logs, tmp_path, mode):
    library = tmp_path / "lib.parquet"
    learn_files(logs["pointer"][:2], library)
    args = ["replay", library, *logs["pointer"][2:], "--json", "-q", *mode]
    one, many = _report(cli(*args)), _report(cli(*args, "--workers", "2"))
    assert many == one
    assert one["totals"]["events"] > 2000 and one["baselines"]["fit"] == "training"


def test_merge_tree_counts_as_one_process_and_merges_like_slearn_merge(local_ray, logs, tmp_path):
    one, tree = tmp_path / "one.parquet", tmp_path / "tree.parquet"
    assert cli("learn", *logs["pointer"], "-o", one, "-q").exit_code == 0
    result = cli("learn", *logs["pointer"], "-o", tree, "-q", "--workers", "2", "--merge-tree")
    assert result.exit_code == 0, result.output
    parts = []
    for i, log in enumerate(logs["pointer"]):
        parts.append(tmp_path / f"part{i}.parquet")
        assert cli("learn", log, "-o", parts[-1], "-q").exit_code == 0
    assert cli("merge", *parts, "-o", tmp_path / "merged.parquet").exit_code == 0
    a, b, c = (load_library(p) for p in (one, tree, tmp_path / "merged.parquet"))
    ea, eb, ec = (x.library.export() for x in (a, b, c))
    for key in ("view", "pattern_offsets", "pattern_tokens", "count", "last_seen"):
        assert np.array_equal(ea[key], eb[key]), key
    for key in ea:
        assert np.array_equal(eb[key], ec[key]), key
    assert list(a.vocabulary.items()) == list(b.vocabulary.items())
    assert np.array_equal(b.library.mixer.weight, c.library.mixer.weight)
    assert b.provenance == a.provenance  # the inputs and time of one process
    single = tmp_path / "single.parquet"
    assert cli("learn", logs["pointer"][0], "-o", single, "-q", "--workers", "2", "--merge-tree").exit_code == 0
    assert single.read_bytes() == parts[0].read_bytes()


def test_merge_tree_refuses_what_would_change_the_library(local_ray, logs, tmp_path):
    for extra in (["--max-patterns", "1000"], ["--scoring", "literal"]):
        result = cli("learn", *logs["pointer"][:2], "-o", tmp_path / "x.parquet", "--workers", "2",
                     "--merge-tree", *extra)
        assert result.exit_code == 1 and "cannot be learned with --merge-tree" in result.output
        assert not (tmp_path / "x.parquet").exists()


def test_a_bad_log_stops_the_job_naming_it_and_keeps_the_saved_output(local_ray, logs, tmp_path):
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not an mcap file" * 8)
    out = tmp_path / "out.parquet"
    out.write_bytes(b"saved before")
    for extra in ([], ["--merge-tree"]):
        result = cli("learn", *logs["pointer"][:2], bad, "-o", out, "--force", "-q", "--workers", "2", *extra)
        assert result.exit_code == 1
        assert "bad.mcap: not an MCAP file" in result.output and "Traceback" not in result.output
        assert out.read_bytes() == b"saved before"


def test_a_truncated_log_is_salvaged_as_in_one_process(local_ray, logs, big_logs, tmp_path):
    data = Path(big_logs[0]).read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 7 // 10])
    one = cli("learn", logs["pointer"][0], cut, "-o", tmp_path / "one.parquet", "-q")
    many = cli("learn", logs["pointer"][0], cut, "-o", tmp_path / "many.parquet", "-q", "--workers", "2")
    assert one.exit_code == many.exit_code == 3
    assert "cut.mcap: truncated" in many.output
    assert (tmp_path / "many.parquet").read_bytes() == (tmp_path / "one.parquet").read_bytes()


def test_a_log_a_worker_cannot_see_is_one_clear_line(local_ray, tmp_path):
    missing = str(tmp_path / "elsewhere.mcap")
    with pytest.raises(InputError, match="not found on node .*shared filesystem"):
        list(RayReader(local_ray)([missing], pointer_spec(), Vocabulary()))
    with pytest.raises(InputError, match="elsewhere.mcap: not found on node"):
        check_visible(missing)


def _kill_a_reading_worker(deadline_s: float) -> int | None:
    """SIGKILL the first worker process seen running a read task (Ray titles it so)."""
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        for pid in os.listdir("/proc"):
            if not pid.isdigit():
                continue
            try:
                title = Path(f"/proc/{pid}/cmdline").read_bytes()
            except OSError:
                continue
            if title.startswith(b"ray::read_log"):
                os.kill(int(pid), signal.SIGKILL)
                return int(pid)
        time.sleep(0.005)
    return None


@pytest.mark.skipif(sys.platform != "linux", reason="finds the worker through /proc")
@pytest.mark.parametrize("piece_events", [distributed.STREAMED_EVENTS, 1500])
def test_a_killed_worker_is_retried_and_the_library_is_the_same(local_ray, big_logs, tmp_path, piece_events):
    # with pieces of 1,500 events a log streams one per chunk it reads, so the kill comes mid-stream,
    # after the driver learned some: the task runs again and the rest follows
    big = big_logs
    learn_files(big, tmp_path / "one.parquet")
    killed = []
    killer = threading.Thread(target=lambda: killed.append(_kill_a_reading_worker(60)))
    killer.start()
    learn_files(big, tmp_path / "many.parquet", reader=RayReader(local_ray, piece_events=piece_events))
    killer.join()
    assert killed[0] is not None, "no read task was seen running"
    assert (tmp_path / "many.parquet").read_bytes() == (tmp_path / "one.parquet").read_bytes()


def test_a_read_task_streams_its_log_in_pieces_with_the_names_they_need(big_logs):
    spec = pointer_spec()
    items = list(distributed.read_log(big_logs[0], spec.to_dict(), spec.source, None, 4000))
    pieces, end = items[:-1], items[-1]
    assert len(pieces) >= 2 and "report" not in pieces[0] and end["events"] == sum(len(p["symbols"]) for p in pieces)
    assert pieces[0]["first"] and pieces[-1]["last"] and not any(p["last"] for p in pieces[:-1])
    names = [n for p in pieces for n in p["names"]]
    assert len(names) == len(set(names)) == 1 + max(int(p["symbols"].max()) for p in pieces)
    known = 0
    for p in pieces:  # a piece uses only symbols named by then
        known += len(p["names"])
        assert int(p["symbols"].max()) < known
    (whole,) = [e for _, e, _ in read_episodes([big_logs[0]], spec, Vocabulary())]
    assert np.array_equal(np.concatenate([p["symbols"] for p in pieces]), whole.symbols)
    assert end["report"]["n_messages"] == 24001 and not end["warnings"]


def test_without_ray_workers_say_what_to_install(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray raises ImportError
    with pytest.raises(InputError, match=r"pip install 'slearn\[ray\]'"):
        require_ray()
    log = record_pointer(PointerConfig(condition="simple", trials=50, seed=1), tmp_path / "p.mcap").path
    result = cli("learn", log, "-o", tmp_path / "x.parquet", "--workers", "2")
    assert result.exit_code == 1
    assert result.output.strip().splitlines()[-1] == (
        "slearn: error: --workers and --ray need Ray, which is not installed: pip install 'slearn[ray]'")


def test_the_tasks_hash_the_logs_they_read_not_the_driver(local_ray, logs, tmp_path, monkeypatch):
    learn_files(logs["pointer"][:2], tmp_path / "one.parquet")
    import slearn.jobs.learn as learn_module

    def no_hashing(path):
        raise AssertionError(f"the driver hashed {path}")
    monkeypatch.setattr(learn_module, "log_record", no_hashing)
    learn_files(logs["pointer"][:2], tmp_path / "many.parquet", reader=RayReader(local_ray))
    assert (tmp_path / "many.parquet").read_bytes() == (tmp_path / "one.parquet").read_bytes()


_SESSION_KEEPS_HANDLERS = """
import signal
from slearn.cli import _raise_stopped, _stop_on_signals
from slearn.jobs.cluster import ray_session
for signum in (signal.SIGTERM, signal.SIGHUP):  # as a foreground job has them (CI runs under nohup)
    signal.signal(signum, signal.SIG_DFL)
with _stop_on_signals():
    with ray_session(workers=1):
        kept = [signal.getsignal(s) is _raise_stopped for s in (signal.SIGTERM, signal.SIGHUP)]
print(kept)
"""


def test_a_ray_session_keeps_the_command_lines_signal_handlers():
    """ray.init replaces SIGTERM's handler with its own (a C stack trace, exit 1, the
    temporary files of the output left): the session puts the command line's back."""
    import subprocess

    done = subprocess.run([sys.executable, "-c", _SESSION_KEEPS_HANDLERS], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1] == "[True, True]", done.stdout
