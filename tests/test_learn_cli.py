"""``slearn learn``, ``slearn merge`` and ``slearn info LIB.parquet`` on pointer logs."""

import json
import os
import shutil

import pytest
from click.testing import CliRunner

from slearn.cli import EXIT_TRUNCATED, main
from slearn.io.library_file import load_library
from slearn.io.library_info import describe
from slearn.jobs.learn import learn_files
from slearn.recorders.mcap_episode import EpisodeWriter
from slearn.recorders.pointer import PointerConfig
from slearn.recorders.record_pointer import record_pointer

TRIALS = 2_000


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """Pointer logs (2,000 trials each) by condition, and their folder."""
    folder = tmp_path_factory.mktemp("logs")
    paths = {}
    for condition, seed in [("simple", 0), ("delay", 1), ("reversal", 2), ("error", 3)]:
        paths[condition] = folder / f"{condition}.mcap"
        record_pointer(PointerConfig(condition, TRIALS, seed, switch_trial=1_000), paths[condition])
        os.utime(paths[condition], (1_600_000_000 + seed, 1_600_000_000 + seed))
    return paths


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def learn(*args):
    return run("learn", "-q", *args)


def test_learn_writes_a_library_and_a_summary(logs, tmp_path):
    out = tmp_path / "lib.parquet"
    result = learn(logs["simple"], logs["delay"], "-o", out)
    assert result.exit_code == 0, result.output
    loaded = load_library(out)
    assert len(loaded.library) > 100 and loaded.library.clock == 2 * (TRIALS + 1)  # and first readings
    assert loaded.params == {"max_length": 6, "max_patterns": None, "scoring": "adaptive",
                             "factored": True, "has_actions": True}
    assert [i["path"] for i in loaded.provenance["inputs"]] == [str(logs["simple"]), str(logs["delay"])]
    assert loaded.provenance["time_unix"] == 1_600_000_001
    assert loaded.provenance["time_source"] == "newest input mtime"
    assert loaded.vocabulary.name(0) == ("/pointer/command", "L")
    lines = result.stdout.splitlines()
    assert lines[0].startswith(f"learned 2 episode(s), {2 * (TRIALS + 1):,} steps, "
                               f"{2 * (2 * TRIALS + 1):,} events")
    assert f"{len(loaded.library):,} patterns, {out.stat().st_size:,} bytes" in lines[1]
    assert result.stderr == ""


def test_json_summary_is_one_document(logs, tmp_path):
    out = tmp_path / "lib.parquet"
    result = learn(logs["simple"], "-o", out, "--json")
    summary = json.loads(result.stdout)
    assert summary["episodes"] == 1 and summary["steps"] == TRIALS + 1
    assert summary["events"] == 2 * TRIALS + 1
    assert summary["patterns"] == len(load_library(out).library)
    assert summary["bytes"] == out.stat().st_size
    assert summary["bytes_per_pattern"] == pytest.approx(summary["bytes"] / summary["patterns"])
    assert summary["truncated"] == []


def test_learning_the_same_logs_twice_gives_the_same_bytes(logs, tmp_path):
    for name in ("a", "b"):
        assert learn(logs["simple"], logs["error"], "-o", tmp_path / f"{name}.parquet").exit_code == 0
    assert (tmp_path / "a.parquet").read_bytes() == (tmp_path / "b.parquet").read_bytes()


def test_resume_on_a_second_log_equals_one_run(logs, tmp_path):
    assert learn(logs["simple"], logs["delay"], "-o", tmp_path / "both.parquet").exit_code == 0
    assert learn(logs["simple"], "-o", tmp_path / "first.parquet").exit_code == 0
    resumed = learn(logs["delay"], "--resume", tmp_path / "first.parquet", "-o", tmp_path / "then.parquet")
    assert resumed.exit_code == 0, resumed.output
    assert "(resumed from" in resumed.stdout
    assert (tmp_path / "both.parquet").read_bytes() == (tmp_path / "then.parquet").read_bytes()


def test_resume_keeps_the_library_max_length(logs, tmp_path):
    learn(logs["simple"], "-o", tmp_path / "a.parquet", "--max-length", "3")
    result = learn(logs["delay"], "--resume", tmp_path / "a.parquet", "-o", tmp_path / "b.parquet",
                   "--max-length", "4")
    assert result.exit_code == 1
    assert "learned with max length 3; --resume keeps it" in result.stderr
    assert not (tmp_path / "b.parquet").exists()


def test_source_date_epoch_sets_the_time(logs, tmp_path, monkeypatch):
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1234567890")
    learn(logs["simple"], "-o", tmp_path / "lib.parquet")
    provenance = load_library(tmp_path / "lib.parquet").provenance
    assert provenance["time"] == "2009-02-13T23:31:30Z" and provenance["time_source"] == "SOURCE_DATE_EPOCH"


def test_a_glob_of_many_files_learns_each_file_as_an_episode(logs, tmp_path):
    folder = tmp_path / "many"
    folder.mkdir()
    for i in range(12):
        shutil.copy(logs["simple" if i % 2 else "delay"], folder / f"run{i:02d}.mcap")
    result = learn(str(folder / "run*.mcap"), "-o", tmp_path / "lib.parquet", "--json")
    assert result.exit_code == 0, result.output
    summary = json.loads(result.stdout)
    assert summary["episodes"] == 12 and summary["steps"] == 12 * (TRIALS + 1)
    inputs = load_library(tmp_path / "lib.parquet").provenance["inputs"]
    assert [os.path.basename(i["path"]) for i in inputs] == [f"run{i:02d}.mcap" for i in range(12)]


def test_learner_parameters_are_applied_and_stored(logs, tmp_path):
    out = tmp_path / "lib.parquet"
    result = learn(logs["error"], "-o", out, "--max-length", "3", "--max-patterns", "100",
                   "--scoring", "literal")
    assert result.exit_code == 0, result.output
    doc = describe(out)
    assert max(map(int, doc["length_histogram"])) == 3
    assert doc["patterns"] <= 100 and doc["forgotten"] > 0
    assert doc["params"] == {"max_length": 3, "max_patterns": 100, "scoring": "literal"}


def test_channel_options_with_quantile_bins_are_fitted_and_stored(logs, tmp_path):
    out = tmp_path / "angle.parquet"
    result = learn(logs["simple"], "-o", out, "--mode", "message",
                   "--channel", "/pointer/command:command:action",
                   "--channel", "/pointer/angle:angle_deg:observation:quantiles=4")
    assert result.exit_code == 0, result.output
    loaded = load_library(out)
    angle = loaded.spec.channels[1].symbolizer
    assert len(angle.edges) == 3 and angle.fitted
    assert [v for _, c, v in loaded.vocabulary.items() if c == "/pointer/angle"] == [0, 1, 2, 3]
    assert learn(logs["delay"], "--resume", out, "-o", tmp_path / "more.parquet").exit_code == 0
    assert load_library(tmp_path / "more.parquet").spec.to_dict() == loaded.spec.to_dict()


def test_refuses_to_overwrite_without_force(logs, tmp_path):
    out = tmp_path / "lib.parquet"
    out.write_bytes(b"precious")
    result = learn(logs["simple"], "-o", out)
    assert result.exit_code == 1 and result.stdout == ""
    assert result.stderr.strip() == f"slearn: error: {out} already exists: pass --force to overwrite it"
    assert out.read_bytes() == b"precious"
    assert learn(logs["simple"], "-o", out, "--force").exit_code == 0
    assert len(load_library(out).library) > 0


def test_a_spec_that_does_not_fit_the_logs_is_one_line_and_touches_nothing(logs, tmp_path):
    out = tmp_path / "lib.parquet"
    out.write_bytes(b"precious")
    result = learn(logs["simple"], "-o", out, "--force", "--channel", "/pointer/command:cmd:action",
                   "--channel", "/pointer/position:position:observation")
    assert result.exit_code == 1
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("slearn: error: ")
    assert "'cmd'" in lines[0] and str(logs["simple"]) in lines[0]
    assert out.read_bytes() == b"precious"
    assert os.listdir(tmp_path) == ["lib.parquet"]


def test_a_spec_file_is_used_and_a_topic_it_lacks_is_named(logs, tmp_path):
    spec = tmp_path / "spec.toml"
    spec.write_text('mode = "message"\n[[channel]]\ntopic = "/pointer/position"\nfield = "position"\n'
                    'role = "observation"\n')
    result = learn(logs["simple"], "-o", tmp_path / "pos.parquet", "--spec", spec, "--json")
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["events"] == TRIALS + 1  # positions only
    assert [c.name for c in load_library(tmp_path / "pos.parquet").spec.channels] == ["/pointer/position"]
    spec.write_text(spec.read_text().replace("/pointer/position", "/arm/joint"))
    result = learn(logs["simple"], "-o", tmp_path / "arm.parquet", "--spec", spec)
    assert result.exit_code == 1
    assert "the spec's topic '/arm/joint' is not in this log" in result.stderr
    assert not (tmp_path / "arm.parquet").exists()


def test_a_resumed_spec_that_does_not_fit_a_new_log_is_refused(logs, tmp_path):
    other = tmp_path / "other.mcap"
    with EpisodeWriter(other) as writer:
        channel = writer.register_channel("/robot/mode", "Mode", {"type": "object"})
        writer.write(channel, 0, {"mode": "idle"})
    learn(logs["simple"], "-o", tmp_path / "lib.parquet")
    result = learn(other, "--resume", tmp_path / "lib.parquet", "-o", tmp_path / "more.parquet")
    assert result.exit_code == 1
    assert "/pointer/command" in result.stderr and "is not in this log" in result.stderr
    assert not (tmp_path / "more.parquet").exists()
    plain = learn(other, "-o", tmp_path / "x.parquet")
    assert plain.exit_code == 1 and "not a pointer log (topics: /robot/mode): pass --spec auto" in plain.stderr
    auto = learn(other, "--spec", "auto", "-o", tmp_path / "x.parquet")  # one constant field
    assert auto.exit_code == 1 and "Traceback" not in auto.output
    assert auto.stderr.startswith("slearn: error: --spec auto: no [[channel]] entries") and \
        f"slearn info {other}` shows every field" in auto.stderr
    assert not (tmp_path / "x.parquet").exists()


def _drifting_log(path):
    """A command (+-1) and a reading that climbs from 0 to 10 over the log."""
    with EpisodeWriter(path) as writer:
        command = writer.register_channel("/robot/cmd", "Cmd", {"type": "object"})
        reading = writer.register_channel("/robot/level", "Level", {"type": "object"})
        for k in range(400):
            writer.write(command, 2 * k * 10**7, {"data": (-1) ** k})
            writer.write(reading, (2 * k + 1) * 10**7, {"value": k / 40 + 0.01 * (k % 7)})
    return path


def test_spec_auto_suggests_from_the_part_that_is_learned(tmp_path, monkeypatch):
    """`--spec auto` profiles what `--split` learns, not the held-out part: the reading's
    bins end where the training part's readings end (replay warns about the rest)."""
    log = _drifting_log(tmp_path / "drift.mcap")
    whole, part = tmp_path / "whole.parquet", tmp_path / "part.parquet"
    said = learn(log, "--spec", "auto", "-o", whole)
    assert said.exit_code == 0, said.output
    assert "--spec auto: observations /robot/level; actions /robot/cmd (" in said.stderr
    assert learn(log, "--spec", "auto", "--split", "0.3", "-o", part).exit_code == 0
    level = {lib: next(c for c in load_library(lib).spec.channels if c.topic == "/robot/level")
             for lib in (whole, part)}
    assert level[whole].symbolizer.range[1] > 9.9
    assert level[part].symbolizer.range[1] < 3.1
    resumed = learn(log, "--spec", "auto", "--resume", whole, "-o", tmp_path / "r.parquet")
    assert resumed.exit_code == 2 and "leave out --spec auto" in resumed.stderr
    assert not (tmp_path / "r.parquet").exists()
    (tmp_path / "auto").write_text('[[channel]]\ntopic = "/robot/level"\nfield = "value"\n'
                                   'role = "observation"\nrange = [0, 10]\ncount = 5\n')
    monkeypatch.chdir(tmp_path)  # a spec file named auto is ./auto
    by_file = learn(log, "--spec", "./auto", "-o", tmp_path / "file.parquet")
    assert by_file.exit_code == 0, by_file.output
    assert [c.name for c in load_library(tmp_path / "file.parquet").spec.channels] == ["/robot/level"]


def test_resuming_a_library_without_a_spec_needs_one_with_observations(logs, tmp_path):
    from slearn.io.library_file import save_library

    learn(logs["simple"], "-o", tmp_path / "lib.parquet")
    loaded = load_library(tmp_path / "lib.parquet")
    save_library(tmp_path / "bare.parquet", loaded.library, loaded.vocabulary, spec=None,
                 params=loaded.params, provenance={})
    args = (logs["delay"], "--resume", tmp_path / "bare.parquet", "-o", tmp_path / "more.parquet")
    result = learn(*args, "--channel", "/pointer/command:command:action")
    assert result.exit_code == 1 and result.stderr.count("\n") == 1
    assert "no observation entry, so nothing to predict" in result.stderr
    assert not (tmp_path / "more.parquet").exists()
    both = learn(*args, "--channel", "/pointer/command:command:action",
                 "--channel", "/pointer/position:position:observation")
    assert both.exit_code == 0, both.output


def test_resume_from_a_bad_library_is_a_one_line_error(logs, tmp_path):
    bad = tmp_path / "bad.parquet"
    bad.write_bytes(b"PAR1 this is not parquet")
    result = learn(logs["simple"], "--resume", bad, "-o", tmp_path / "out.parquet")
    assert result.exit_code == 1
    assert result.stderr.count("\n") == 1 and "not a readable Parquet file" in result.stderr
    assert not (tmp_path / "out.parquet").exists()


def test_a_truncated_log_is_learned_as_far_as_it_goes_then_exit_3(tmp_path):
    whole = tmp_path / "long.mcap"
    record_pointer(PointerConfig("simple", 8_000, 0), whole)  # several chunks
    data = whole.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    out = tmp_path / "lib.parquet"
    result = learn(cut, "-o", out, "--json")
    assert result.exit_code == EXIT_TRUNCATED
    summary = json.loads(result.stdout)
    assert 1_000 < summary["steps"] < 8_000 and len(summary["truncated"]) == 1
    assert "truncated or corrupt log" in result.stderr
    assert len(load_library(out).library) == summary["patterns"] > 0


def test_missing_logs_are_named(tmp_path):
    result = learn(tmp_path / "nope.mcap", "-o", tmp_path / "lib.parquet")
    assert result.exit_code == 1 and "nope.mcap: no such log file" in result.stderr
    result = learn(str(tmp_path / "none*.mcap"), "-o", tmp_path / "lib.parquet")
    assert result.exit_code == 1 and "no file matches" in result.stderr


def test_spec_and_channel_together_are_a_usage_error(logs, tmp_path):
    result = learn(logs["simple"], "-o", tmp_path / "l.parquet", "--spec", "x.toml", "--channel", "a:b:action")
    assert result.exit_code == 2


def test_info_describes_a_library(logs, tmp_path):
    out = tmp_path / "lib.parquet"
    learn(logs["simple"], "-o", out)
    result = run("info", out, "--json")
    assert result.exit_code == 0, result.output
    (doc,) = json.loads(result.stdout)["files"]
    loaded = load_library(out)
    assert doc["kind"] == "library" and doc["patterns"] == len(loaded.library)
    assert sum(doc["length_histogram"].values()) == doc["patterns"]
    assert doc["bytes_per_pattern"] == pytest.approx(out.stat().st_size / doc["patterns"])
    top = doc["top_patterns"][0]
    assert top["count"] == max(p.count for p in loaded.library.patterns())
    channels = [set(token) for token in top["tokens"]]  # a pattern's tokens alternate channels
    assert all(c in ({"/pointer/position"}, {"/pointer/command"}) for c in channels)
    assert all(a != b for a, b in zip(channels, channels[1:]))
    assert doc["provenance"]["inputs"][0]["sha256"] == loaded.provenance["inputs"][0]["sha256"]
    text = run("info", out)
    assert text.exit_code == 0 and "pattern library (format 6)" in text.stdout
    assert top["pattern"] in text.stdout


def test_info_on_a_bad_library_is_one_line(tmp_path):
    bad = tmp_path / "bad.parquet"
    bad.write_bytes(b"\x00" * 100)
    result = run("info", bad)
    assert result.exit_code == 1 and result.stderr.count("\n") == 1


def test_merge_adds_counts_and_matches_inputs(logs, tmp_path):
    learn(logs["simple"], "-o", tmp_path / "a.parquet")
    learn(logs["delay"], "-o", tmp_path / "b.parquet")
    result = run("merge", tmp_path / "a.parquet", tmp_path / "b.parquet", "-o", tmp_path / "c.parquet", "--json")
    assert result.exit_code == 0, result.output
    a, b, c = (describe(tmp_path / f"{n}.parquet") for n in "abc")
    assert c["total_count"] == a["total_count"] + b["total_count"]
    assert c["clock"] == a["clock"] + b["clock"]
    assert max(a["patterns"], b["patterns"]) <= c["patterns"] <= a["patterns"] + b["patterns"]
    assert json.loads(result.stdout)["patterns"] == c["patterns"]
    assert [i["path"] for i in c["provenance"]["inputs"]] == [str(logs["simple"]), str(logs["delay"])]
    assert [m["path"] for m in c["provenance"]["merged_from"]] == [str(tmp_path / "a.parquet"),
                                                                  str(tmp_path / "b.parquet")]
    refused = run("merge", tmp_path / "a.parquet", tmp_path / "b.parquet", "-o", tmp_path / "c.parquet")
    assert refused.exit_code == 1 and "already exists" in refused.stderr


def test_merge_refuses_libraries_with_other_parameters(logs, tmp_path):
    learn(logs["simple"], "-o", tmp_path / "a.parquet")
    learn(logs["delay"], "-o", tmp_path / "b.parquet", "--max-length", "4")
    result = run("merge", tmp_path / "a.parquet", tmp_path / "b.parquet", "-o", tmp_path / "c.parquet")
    assert result.exit_code == 1
    assert "max_length 6 vs 4" in result.stderr and result.stderr.count("\n") == 1
    assert not (tmp_path / "c.parquet").exists()


def test_learn_files_is_the_library_api(logs, tmp_path):
    result = learn_files([logs["reversal"]], tmp_path / "r.parquet")
    assert result.n_episodes == 1 and result.n_patterns == len(load_library(tmp_path / "r.parquet").library)


def test_a_log_learned_twice_is_warned_about(logs, tmp_path):
    """The same bytes learned twice into one library (a copy, the same path, or again with
    --resume) count double: a warning naming both; disjoint slices of one log are fine."""
    copy = tmp_path / "copy.mcap"
    copy.write_bytes(logs["simple"].read_bytes())
    twice = learn(logs["simple"], copy, "-o", tmp_path / "a.parquet")
    assert twice.exit_code == 0, twice.output
    assert f"slearn: warning: {copy}: has the bytes of {logs['simple']}, learned before into this library" \
        in twice.stderr and "counts double" in twice.stderr
    once = learn(logs["simple"], logs["delay"], "-o", tmp_path / "b.parquet")
    assert "learned before" not in once.stderr
    again = learn(logs["simple"], "--resume", tmp_path / "b.parquet", "-o", tmp_path / "c.parquet")
    assert f"{logs['simple']}: was learned before into this library" in again.stderr
    first = learn(logs["simple"], "--end", "100", "-o", tmp_path / "d.parquet")
    rest = learn(logs["simple"], "--start", "100", "--resume", tmp_path / "d.parquet", "-o", tmp_path / "e.parquet")
    assert first.exit_code == rest.exit_code == 0 and "learned before" not in rest.stderr
