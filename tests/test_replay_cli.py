"""``slearn replay``: table, --json, --plot, --report, --write-mcap, exit codes, errors."""

from __future__ import annotations

import json

import pytest
from click.testing import CliRunner
from fixtures import POINTER_TOML

from slearn.cli import EXIT_BELOW_THRESHOLD, EXIT_TRUNCATED, main
from slearn.core.library import PatternLibrary
from slearn.core.vocabulary import Vocabulary
from slearn.io import library_file as storage
from slearn.io.serialize import read_episodes
from slearn.io.spec import pointer_spec
from slearn.recorders.pointer import PointerConfig
from slearn.recorders.record_pointer import record_pointer


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("replay_cli")
    out = {"folder": folder}
    configs = {"train": PointerConfig("simple", trials=3000, seed=0),
               "test": PointerConfig("simple", trials=1500, seed=3),
               "reversal": PointerConfig("reversal", trials=2000, seed=4, switch_trial=800)}
    for name, config in configs.items():
        out[name] = folder / f"{name}.mcap"
        record_pointer(config, out[name])
    library, vocabulary = PatternLibrary(), Vocabulary()
    for _, episode, _ in read_episodes([out["train"]], pointer_spec(), vocabulary):
        library.learn(episode)
    out["library"] = folder / "library.parquet"
    storage.save_library(out["library"], library, vocabulary, spec=pointer_spec(),
                         params={"scoring": "adaptive"}, provenance={})
    out["spec"] = folder / "pointer.toml"
    out["spec"].write_text(POINTER_TOML)
    return out


def run(*args):
    return CliRunner().invoke(main, ["replay", *map(str, args)])


def test_table_on_stdout_progress_on_stderr(files):
    result = run(files["library"], files["test"])
    assert result.exit_code == 0, result.stderr
    out = result.stdout
    assert "frozen" in out and "library " in out and "frequency baseline" in out
    assert "markov baseline" in out and "/pointer/position" in out and "test.mcap" in out
    assert "100.00 %" in out
    assert "replay: test.mcap" in result.stderr


def test_json_is_the_only_thing_on_stdout(files):
    result = run(files["library"], files["test"], files["reversal"], "--json", "--window", "100",
                 "--top-k", "2")
    assert result.exit_code == 0, result.stderr
    doc = json.loads(result.stdout)
    assert doc["schema"] == "slearn.replay/3" and doc["mode"] == "frozen"
    assert doc["top_k"] == 2 and doc["window"] == 100
    assert doc["totals"]["events"] == 3500
    assert [e["events"] for e in doc["episodes"]] == [1500, 2000]
    assert doc["episodes"][0]["accuracy"] >= 0.995
    assert doc["baselines"]["fit"] == "prequential"  # provenance names no inputs
    assert doc["outputs"] == {}


def test_online_recovers_from_the_reversal_in_the_curve(files):
    frozen = json.loads(run(files["library"], files["reversal"], "--json", "--window", "200").stdout)
    online = json.loads(run(files["library"], files["reversal"], "--json", "--window", "200",
                            "--online").stdout)
    frozen_curve = [w["accuracy"] for w in frozen["episodes"][0]["curve"]]
    online_curve = [w["accuracy"] for w in online["episodes"][0]["curve"]]
    assert min(frozen_curve[:4]) >= 0.99 and max(frozen_curve[4:]) <= 0.05
    assert online["mode"] == "online" and online_curve[4] < 0.95
    assert min(online_curve[-3:]) >= 0.97 and online_curve[-1] >= 0.99


def test_fail_under_exits_4_below_the_threshold(files):
    assert run(files["library"], files["test"], "--fail-under", "99.5").exit_code == 0
    below = run(files["library"], files["reversal"], "--fail-under", "90")
    assert below.exit_code == EXIT_BELOW_THRESHOLD
    assert "below --fail-under 90" in below.stderr


def test_plot_report_and_annotated_mcap_are_written(files, tmp_path):
    from mcap.reader import make_reader

    plot, report, annotated = tmp_path / "c.png", tmp_path / "r.html", tmp_path / "a.mcap"
    result = run(files["library"], files["reversal"], "--plot", plot, "--report", report,
                 "--write-mcap", annotated, "--json", "--quiet")
    assert result.exit_code == 0, result.stderr
    assert result.stderr == ""
    assert plot.read_bytes().startswith(b"\x89PNG")
    assert "data:image/png;base64," in report.read_text()
    with open(annotated, "rb") as f:
        topics = [c.topic for _, c, _ in make_reader(f).iter_messages()]
    assert topics.count("/slearn/prediction") == 2000 == topics.count("/slearn/surprise")
    doc = json.loads(result.stdout)
    assert doc["outputs"]["annotated"][0]["predictions"] == 2000
    again = run(files["library"], files["reversal"], "--plot", plot)
    assert again.exit_code == 1 and "--force" in again.stderr
    assert run(files["library"], files["reversal"], "--plot", plot, "--force").exit_code == 0


def test_spec_without_library_starts_empty_and_learns_online(files):
    result = run("--spec", files["spec"], files["train"], files["test"], "--json", "--quiet")
    assert result.exit_code == 0, result.stderr
    doc = json.loads(result.stdout)
    assert doc["mode"] == "online" and doc["library"] is None
    assert doc["episodes"][1]["accuracy"] > doc["episodes"][0]["accuracy"]


def test_truncated_log_exits_3_after_scoring_what_was_salvaged(files, tmp_path):
    from slearn.recorders.pointer import simulate
    from tests.test_replay import write_small_chunks

    whole, cut = tmp_path / "whole.mcap", tmp_path / "cut.mcap"
    write_small_chunks(simulate(PointerConfig("simple", trials=1500, seed=3)), whole)
    cut.write_bytes(whole.read_bytes()[: whole.stat().st_size // 2])
    result = run(files["library"], cut, "--json", "--quiet")
    assert result.exit_code == EXIT_TRUNCATED
    doc = json.loads(result.stdout)
    assert doc["episodes"][0]["truncated"] and 0 < doc["totals"]["events"] < 1500
    assert "slearn: warning:" in result.stderr and "truncated" in result.stderr


@pytest.mark.parametrize("args, message", [
    (["{test}"], "is a log, not a library"),
    (["{library}", "{test}", "--spec", "{spec}"], "carries the spec"),
    (["{test}", "{test}"], "is a log, not a library"),
    (["{spec}", "{test}"], "pointer.toml"),
    (["{library}", "{folder}/missing.mcap"], "missing.mcap: no such log file"),
    (["{library}", "{test}", "{test}", "--write-mcap", "{folder}/x.mcap"], "existing folder"),
])
def test_bad_inputs_are_one_line_errors(files, args, message):
    result = run(*[a.format(**files) for a in args])
    assert result.exit_code == 1
    assert result.stderr.startswith("slearn: error:") and message in result.stderr
    assert result.stderr.count("\n") == 1 and result.stdout == ""


def test_a_library_without_logs_is_a_usage_error_as_a_missing_argument_is(files):
    # as `slearn learn` with no logs: click's exit 2, with the usage line
    result = run(files["library"])
    assert result.exit_code == 2 and result.stdout == ""
    assert " replay [OPTIONS] [LIB] LOGS..." in result.stderr.splitlines()[0]
    assert "Missing argument 'LOGS...': give a library and at least one log" in result.stderr


def test_a_log_with_nothing_salvaged_is_an_error_and_writes_nothing(files, tmp_path):
    # as for every command (README): exit 1, one line, no output; some salvaged: exit 3
    stub = tmp_path / "stub.mcap"
    stub.write_bytes(files["test"].read_bytes()[:300])
    for extra in ([], ["--json"], ["--fail-under", "1"]):
        result = run(files["library"], stub, "--quiet", "--report", tmp_path / "r.html", *extra)
        assert result.exit_code == 1, result.output
        assert f"slearn: error: nothing could be salvaged from {stub}, so nothing was scored or written" \
            in result.stderr.splitlines()
        assert result.stdout == "" and not (tmp_path / "r.html").exists()
    both = run(files["library"], stub, files["test"], "--json", "--quiet")
    assert both.exit_code == EXIT_TRUNCATED and json.loads(both.stdout)["totals"]["accuracy"] is not None


def test_two_outputs_on_one_file_are_refused_before_replaying(files, tmp_path):
    for a, b in (("--plot", "--report"), ("--report", "--write-mcap")):
        result = run(files["library"], files["test"], a, tmp_path / "x.out", b, tmp_path / "x.out", "--quiet")
        assert result.exit_code == 1
        assert f"both write {tmp_path / 'x.out'}: give each output its own path" in result.stderr
        assert not (tmp_path / "x.out").exists()


def test_a_slice_overlap_is_known_when_the_bounds_decide_it():
    from slearn.io.slicing import HELDOUT, overlap, shares_time, time_slice

    train, held = time_slice(split=0.7), time_slice(split=0.7, part=HELDOUT)
    assert overlap(train, held) is False and overlap(held, train) is False
    assert overlap(None, held) is True and overlap(train, None) is True and overlap(None, None) is True
    assert overlap(time_slice(split=0.8), held) is True  # learned 80 %, replays the last 30 %
    assert overlap(time_slice("60.0", split=0.5), time_slice("60", split=0.5, part=HELDOUT)) is False
    assert overlap(train, time_slice(split=0.8, part=HELDOUT)) is False
    assert overlap(time_slice(end="60"), time_slice(start="60")) is False
    assert overlap(time_slice(end="61"), time_slice(start="60", end="90")) is True
    assert overlap(time_slice(start="100"), time_slice(end="50")) is False
    # these depend on the log's own time range
    assert overlap(time_slice(end="60"), time_slice(start="2024-01-01T00:00:00Z")) is None
    assert overlap(time_slice(end="60", split=0.5), held) is None
    assert shares_time([], held) is False and shares_time([train], held) is False
    assert shares_time([time_slice(end="60", split=0.5), None], held) is True
    assert shares_time([train, time_slice(end="60", split=0.5)], held) is None


def test_replaying_what_the_library_learned_is_warned_about(files, tmp_path):
    """A held-out log with the bytes of a training log (provenance sha256) whose replayed
    time overlaps the learned time is no held-out figure: a warning, in JSON too."""
    learned = tmp_path / "lib.parquet"
    assert CliRunner().invoke(main, ["learn", str(files["train"]), "-o", str(learned), "-q"]).exit_code == 0
    copy = tmp_path / "same-bytes.mcap"
    copy.write_bytes(files["train"].read_bytes())
    result = run(learned, files["test"], copy, "--json", "-q")
    assert result.exit_code == 0, result.output
    [warning] = [w for w in json.loads(result.stdout)["warnings"] if "learned this log" in w]
    assert warning.startswith(f"{copy}: the library learned this log (same bytes)")
    assert "overlaps the time it learned: its accuracy is no held-out figure" in warning
    assert f"slearn: warning: {copy}: the library learned this log" in result.stderr
    assert str(files["test"]) not in result.stderr
    split = tmp_path / "split.parquet"
    assert CliRunner().invoke(main, ["learn", str(files["train"]), "-o", str(split), "--split", "0.7",
                                     "-q"]).exit_code == 0
    assert "learned this log" not in run(split, files["train"], "--split", "0.7", "-q").stderr
    assert "overlaps the time it learned" in run(split, files["train"], "-q").stderr
    assert "may overlap the time it learned" in run(split, files["train"], "--start", "1", "-q").stderr


def test_options_a_saved_library_ignores_and_replays_of_nothing_say_so(files):
    sized = run(files["library"], files["test"], "--max-length", "3")  # (accepted and ignored)
    assert sized.exit_code == 2 and "a saved library keeps the length it learned with" in sized.stderr
    empty = run(files["library"], files["test"], "--start", "149.95", "--quiet")  # the last reading alone
    assert empty.exit_code == 0, empty.output
    assert "slearn: warning: nothing was predicted: the logs (or the time replayed) hold no observation " \
        "after a first one, so there is no accuracy: replay more of them" in empty.stderr.splitlines()
    assert "uncertain" not in empty.stderr  # (it said: 0 predicted events, see the 95 % interval)
