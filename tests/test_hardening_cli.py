"""Hostile inputs through the commands: inputs never overwritten, salvage semantics, value
limits, one-line errors (the regression cases of issue 15)."""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys

import mcap_bytes as mb
import pytest
from click.testing import CliRunner
from fixtures import POINTER_TOML, write_log
from test_library_header import _set, edited

from slearn.cli import EXIT_TRUNCATED, main
from slearn.io.library_file import load_library


def run(*args, env=None):
    return CliRunner().invoke(main, [str(a) for a in args], env=env)


def one_line(result, code=1):
    assert result.exit_code == code, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    return lines[0]


def copies(tmp_path, *paths):
    out = []
    for path in paths:
        target = tmp_path / path.name
        target.write_bytes(path.read_bytes())
        out.append(target)
    return out


# --- an input is never overwritten -------------------------------------------------------

def test_learn_refuses_to_write_over_its_log_even_with_force(simple_pointer, tmp_path):
    log, library = copies(tmp_path, *simple_pointer)
    before = log.read_bytes()
    os.link(log, tmp_path / "alias.mcap")
    for output in (log, tmp_path / "alias.mcap", tmp_path / "." / log.name):
        line = one_line(run("learn", "-q", log, "-o", output, "--force"))
        assert "is also an input" in line and "even with --force" in line
    resumed = run("learn", "-q", log, "--resume", library, "-o", library, "--force")
    assert "is also an input" in one_line(resumed)
    assert log.read_bytes() == before and load_library(library)


def test_merge_replay_info_and_record_refuse_their_inputs(simple_pointer, tmp_path):
    log, library = copies(tmp_path, *simple_pointer)
    before = {p: p.read_bytes() for p in (log, library)}
    cases = [
        ("merge", library, library, "-o", library, "--force"),
        ("replay", library, log, "--write-mcap", log, "--force", "-q"),
        ("replay", library, log, "--plot", library, "--force", "-q"),
        ("replay", library, log, "--report", log, "--force", "-q"),
        ("info", log, "--suggest-spec", log, "--force"),
        ("control", "--condition", "simple", "--goals", "1", "--library", library, "--record", library,
         "--force", "--agents", "slearn"),
    ]
    for args in cases:
        assert "is also an input" in one_line(run(*args)), args
    source = tmp_path / "events.csv"
    source.write_text("time,channel,value\n0,cmd,L\n1,pos,3\n")
    assert "is also an input" in one_line(run("record", "stream", source, "-o", source, "--force"))
    out = tmp_path / "events.mcap"
    assert "is also an input" in one_line(run("record", "stream", source, "-o", out, "--spec-out", source,
                                              "--force"))
    assert all(p.read_bytes() == b for p, b in before.items())


def test_replay_never_writes_over_the_training_logs_its_library_names(pointer_log, tmp_path):
    """Replay counts its baselines on the library's training logs, so they are inputs too:
    --plot, --report and --write-mcap refuse them even with --force (relative to the
    working folder or the library's)."""
    train = tmp_path / "train.mcap"
    train.write_bytes(pointer_log("simple", 500).read_bytes())
    library, heldout = tmp_path / "lib.parquet", pointer_log("simple", 500, seed=1)
    assert run("learn", "-q", train, "-o", library).exit_code == 0
    before = train.read_bytes()
    for option in ("--plot", "--report", "--write-mcap"):
        line = one_line(run("replay", "-q", library, heldout, option, train, "--force"))
        assert "is also an input" in line and "train.mcap" in line, option
    assert train.read_bytes() == before
    assert run("replay", "-q", library, heldout).exit_code == 0  # the baselines still find it


def test_replay_says_a_plain_folder_is_no_log_as_learn_does(pointer_log, tmp_path):
    """A folder that is not a rosbag2 bag is named as a folder, not as a missing file."""
    library = tmp_path / "lib.parquet"
    assert run("learn", "-q", pointer_log("simple", 300), "-o", library).exit_code == 0
    (tmp_path / "logs").mkdir()
    for args in (("replay", "-q", library, tmp_path / "logs"),
                 ("learn", "-q", tmp_path / "logs", "-o", tmp_path / "x.parquet")):
        result = run(*args)
        assert result.exit_code == 1
        assert "logs is a folder, not a log file (or rosbag2 folder with metadata.yaml)" in one_line(result), args[0]
    result = run("replay", "-q", library, tmp_path / "missing.mcap")
    assert result.exit_code == 1 and "missing.mcap: no such log file" in one_line(result)


def test_a_truncated_baseline_training_log_is_warned_and_exits_3(pointer_log, tmp_path):
    """--baseline-train logs are inputs too: one that breaks is counted as far as it reads,
    with a warning naming it and exit status 3, as a truncated held-out log."""
    train = pointer_log("simple", 600)
    library = tmp_path / "lib.parquet"
    assert run("learn", "-q", train, "-o", library).exit_code == 0
    data = train.read_bytes()
    broken = tmp_path / "broken.mcap"
    broken.write_bytes(data[: len(data) * 2 // 3])
    result = run("replay", "-q", library, pointer_log("simple", 300, seed=1), "--baseline-train", broken)
    assert result.exit_code == EXIT_TRUNCATED
    assert "baselines: " in result.output and "broken.mcap: truncated or corrupt log" in result.output



def test_replay_notes_name_the_baseline_training_logs_it_was_given(pointer_log, tmp_path):
    """With --baseline-train the baselines were not counted on the library's training logs:
    the note says which logs they were."""
    library = tmp_path / "lib.parquet"
    assert run("learn", "-q", pointer_log("simple", 300), "-o", library).exit_code == 0
    held_out, other = pointer_log("simple", 200, seed=1), pointer_log("simple", 300, seed=2)
    doc = json.loads(run("replay", "-q", "--json", library, held_out, "--baseline-train", other).stdout)
    assert any("counted on the --baseline-train logs" in note for note in doc["notes"]), doc["notes"]
    assert not any("library's training logs" in note for note in doc["notes"]), doc["notes"]
    doc = json.loads(run("replay", "-q", "--json", library, held_out).stdout)
    assert any("counted on the library's training logs" in note for note in doc["notes"]), doc["notes"]


def test_merge_refuses_counts_that_would_overflow_instead_of_writing_a_library_it_refuses(pointer_log, tmp_path):
    """Counts past int64 are only reachable by editing a file; merging two such libraries
    wrapped them negative and wrote a library that load refused."""
    from slearn.io.library_file import save_library

    library = tmp_path / "lib.parquet"
    assert run("learn", "-q", pointer_log("simple", 200), "-o", library).exit_code == 0
    loaded = load_library(library)
    tree = loaded.library.tree
    tree.count[: int(tree.size[1])] = 2**62 + 1
    big = tmp_path / "big.parquet"
    save_library(big, loaded.library, loaded.vocabulary, spec=loaded.spec, params=loaded.params,
                 provenance=loaded.provenance)
    message = one_line(run("merge", big, library, big, "-o", tmp_path / "merged.parquet"))
    assert "cannot merge" in message and "pattern counts would sum past 9,223,372,036,854,775,807" in message
    assert "re-create it with slearn learn" in message
    assert sorted(p.name for p in tmp_path.iterdir() if p.suffix == ".parquet") == ["big.parquet", "lib.parquet"]


def test_merge_refuses_literal_counts_that_would_overflow(pointer_log, tmp_path):
    from slearn.io.library_file import save_library

    library = tmp_path / "lit.parquet"
    assert run("learn", "-q", pointer_log("simple", 200), "--scoring", "literal", "-o", library).exit_code == 0
    loaded = load_library(library)
    assert loaded.library.max_count() == int(loaded.library.export()["count"].max()) > 0
    loaded.library._count[loaded.library._count > 0] = 2**62 + 1
    big = tmp_path / "big.parquet"
    save_library(big, loaded.library, loaded.vocabulary, spec=loaded.spec, params=loaded.params,
                 provenance=loaded.provenance)
    message = one_line(run("merge", big, big, "-o", tmp_path / "merged.parquet"))
    assert "pattern counts would sum past 9,223,372,036,854,775,807" in message
    assert not (tmp_path / "merged.parquet").exists()


def test_an_existing_folder_given_as_an_output_is_one_line_naming_it(pointer_log, tmp_path):
    """Every output option: a folder is bad input (one line, exit 1, what to do), not a
    four-line usage message, and is refused even with --force."""
    log = pointer_log("simple", 200)
    library = tmp_path / "lib.parquet"
    assert run("learn", "-q", log, "-o", library).exit_code == 0
    folder = tmp_path / "out"
    folder.mkdir()
    for args in (("learn", "-q", log, "-o", folder), ("learn", "-q", log, "-o", folder, "--force"),
                 ("merge", library, library, "-o", folder),
                 ("record", "pointer", "--condition", "simple", "--trials", "10", "-o", folder),
                 ("info", log, "--suggest-spec", folder),
                 ("replay", "-q", library, log, "--plot", folder),
                 ("replay", "-q", library, log, "--report", folder),
                 ("control", "--condition", "simple", "--record", folder)):
        assert one_line(run(*args)) == f"slearn: error: {folder} is a folder: give a file name to write", args
    assert list(folder.iterdir()) == []

# --- salvage semantics --------------------------------------------------------------------

def _damaged_pointer(tmp_path, good_log):
    """The simple_pointer log with every chunk's CRC wrong: nothing can be salvaged."""
    data = bytearray(good_log.read_bytes())
    pos = 8
    while pos + 9 <= len(data):
        op, length = struct.unpack_from("<BQ", data, pos)
        if op == 0x06:
            struct.pack_into("<I", data, pos + 9 + 24, 12345)
        if op == 0x02:
            break
        pos += 9 + length
    path = tmp_path / "damaged.mcap"
    path.write_bytes(bytes(data))
    return path


def test_nothing_salvaged_exits_1_and_leaves_the_old_library(simple_pointer, tmp_path):
    log, library = copies(tmp_path, *simple_pointer)
    before = library.read_bytes()
    damaged = _damaged_pointer(tmp_path, log)
    spec = tmp_path / "spec.toml"
    spec.write_text(POINTER_TOML)
    line = one_line(run("learn", "-q", damaged, "--spec", spec, "-o", library, "--force"))
    assert "nothing could be salvaged, so nothing was written" in line
    assert f"{damaged}: truncated or corrupt log" in line and "chunk CRC mismatch" in line
    assert library.read_bytes() == before

    # channels defined only inside a damaged chunk, no summary: no topic can be read
    lost = tmp_path / "lost.mcap"
    lost.write_bytes(mb.MAGIC + mb.header() + mb.chunk(mb.schema() + mb.channel() + mb.message(0), crc=1))
    line = one_line(run("learn", "-q", lost, "-o", tmp_path / "new.parquet"))
    assert line.startswith(f"slearn: error: nothing could be read: {lost}: truncated or corrupt log")
    assert "1 unreadable chunk(s) skipped" in line
    assert "not a simple_pointer log" not in line and not (tmp_path / "new.parquet").exists()


def test_a_damaged_log_among_good_ones_is_skipped_with_exit_3(simple_pointer, tmp_path):
    log, _ = copies(tmp_path, *simple_pointer)
    damaged = _damaged_pointer(tmp_path, log)
    result = run("learn", "-q", log, damaged, "-o", tmp_path / "both.parquet")
    assert result.exit_code == EXIT_TRUNCATED and "chunk CRC mismatch" in result.stderr
    assert load_library(tmp_path / "both.parquet").library.clock == 501  # the good log only


def test_undecodable_payloads_are_counted_per_channel_and_skipped(tmp_path):
    payloads = [b'{"v": %d}' % (i % 3) if i not in (4, 9) else b'{"v": 2!' for i in range(12)]
    path = tmp_path / "x.mcap"
    path.write_bytes(mb.log(*(mb.message(i, p) for i, p in enumerate(payloads))))
    result = run("learn", "-q", path, "--channel", "/a:v:observation", "-o", tmp_path / "lib.parquet")
    assert result.exit_code == EXIT_TRUNCATED, result.output
    no_action, warning = result.stderr.strip().splitlines()  # the spec has observations only
    assert "the spec has no action channel" in no_action
    offset = len(mb.MAGIC + mb.header() + mb.schema() + mb.channel()) + 4 * len(mb.message(0, b'{"v": 0}'))
    assert warning == (f"slearn: warning: {path}: skipped 2 message(s) that do not decode (2 on /a; "
                       f"first at byte {offset}: channel '/a': a message does not decode: Expecting ',' "
                       f"delimiter: line 1 column 8 (char 7))")
    assert load_library(tmp_path / "lib.parquet").library.clock == 10  # 10 steps


def test_quantile_fitting_on_a_damaged_log_says_the_log_is_damaged(simple_pointer, tmp_path):
    damaged = _damaged_pointer(tmp_path, simple_pointer[0])
    line = one_line(run("learn", "-q", damaged, "-o", tmp_path / "lib.parquet",
                        "--channel", "/pointer/position:position:observation:quantiles=4"))
    assert "no numeric value in the training logs to fit quantile bins on (the log is damaged: " in line


# --- cheap checks before long work ---------------------------------------------------------

def test_a_bad_provenance_stops_resume_before_any_learning(simple_pointer, tmp_path, monkeypatch):
    import slearn.jobs.learn as learn

    log, library = simple_pointer
    bad = edited(library, tmp_path, _set("provenance.inputs.0.sha256", "nope"))
    monkeypatch.setattr(learn, "_learn_episodes", lambda *a: pytest.fail("learned before checking"))
    line = one_line(run("learn", "-q", log, "--resume", bad, "-o", tmp_path / "out.parquet"))
    assert "field provenance.inputs[0].sha256 must be 64 lowercase hex digits" in line


@pytest.mark.parametrize("epoch", ["100000000000000000", "-1", "soon"])
def test_a_bad_source_date_epoch_stops_before_learning(simple_pointer, tmp_path, monkeypatch, epoch):
    import slearn.jobs.learn as learn

    monkeypatch.setattr(learn, "_learn_episodes", lambda *a: pytest.fail("learned before checking"))
    line = one_line(run("learn", "-q", simple_pointer[0], "-o", tmp_path / "out.parquet",
                        env={"SOURCE_DATE_EPOCH": epoch}))
    assert "SOURCE_DATE_EPOCH must be an integer from 0 to 253402300799" in line


# --- value limits -------------------------------------------------------------------------

@pytest.mark.parametrize("options, message", [
    ("range=0;1,count=1000000000", "`count` must be an integer from 1 to 1,000,000"),
    ("range=0;1,count=-3", "`count` must be an integer from 1 to 1,000,000"),
    ("quantiles=1000000000", "`quantiles` must be an integer from 1 to 1,000,000"),
    ("width=5e-324", "`width` must be a number from 1e-300 to 1e+300"),
    ("width=inf", "`width` must be a number from 1e-300"),
    ("width=1,origin=nan", "`origin` must be a finite number"),
    ("range=-inf;inf,count=4", "`range` must be a list of finite numbers"),
    ("range=0;1e308;1,count=4", "`range` must be [low, high]"),
    ("edges=0;nan;2", "`edges` must be a list of finite numbers"),
    ("edges=2;1", "strictly increasing"),
    ("values=a;a", "`values` must be distinct"),
    ("values=1;1.0", "`values` must be distinct"),
    ("max_symbols=0", "`max_symbols` must be an integer from 1 to 2,147,483,647"),
])
def test_spec_values_out_of_range_are_one_line_errors(simple_pointer, tmp_path, options, message):
    line = one_line(run("learn", "-q", simple_pointer[0], "-o", tmp_path / "lib.parquet",
                        "--channel", f"/pointer/position:position:observation:{options}",
                        "--channel", "/pointer/command:command:action"))
    assert message in line


@pytest.mark.parametrize("text, message", [
    ('mode = "tick"\ntick_ms = 1e-9\n', "`tick_ms` must be a number from 1e-06 to 8.64e+07 (1 ns to a day)"),
    ('mode = "tick"\ntick_ms = inf\n', "`tick_ms` must be a number"),
    ('mode = "tick"\ntick_ms = nan\n', "`tick_ms` must be a number"),
    ('mode = "tick"\ntick_ms = "100"\n', "`tick_ms` must be a number"),
    ('mode = "tick"\ntick_ns = 0\n', "`tick_ns` must be a number from 1 to 8.64e+13"),
])
def test_tick_periods_out_of_range_are_one_line_errors(simple_pointer, tmp_path, text, message):
    spec = tmp_path / "spec.toml"
    spec.write_text(text + POINTER_TOML.replace('mode = "message"\n', ""))
    assert message in one_line(run("learn", "-q", simple_pointer[0], "--spec", spec, "-o", tmp_path / "lib.parquet"))


@pytest.mark.parametrize("args, message", [
    (["--max-length", "1000000000"], "1000000000 is not in the range 1<=x<=64"),
    (["--max-patterns", "100000000000000000000"], "is not in the range 16<=x<=2147483647"),
    (["--max-patterns", "-4"], "is not in the range 16<=x<=2147483647"),
])
def test_learner_options_out_of_range_are_usage_errors_naming_the_range(simple_pointer, tmp_path, args, message):
    result = run("learn", "-q", simple_pointer[0], "-o", tmp_path / "lib.parquet", *args)
    assert result.exit_code == 2 and message in result.stderr


def test_option_limits_are_stated_in_help():
    assert "1<=x<=64" in run("learn", "--help").stdout
    assert "1<=x<=100" in run("replay", "--help").stdout
    assert "SLEARN_MAX_CHUNK_MB" in run("--help").stdout


def test_nan_fail_under_is_refused(simple_pointer, tmp_path):
    result = run("replay", simple_pointer[1], simple_pointer[0], "--fail-under", "nan", "-q")
    assert result.exit_code == 2 and "not a finite number" in result.stderr


def test_values_too_large_for_the_bins_are_skipped(tmp_path):
    path = tmp_path / "big.mcap"
    payloads = [b'{"v": 1' + b"0" * 400 + b"}", b'{"v": 1e308}', b'{"v": -1e308}', b'{"v": 3.5}']
    path.write_bytes(mb.log(mb.chunk(b"".join(mb.message(i, p) for i, p in enumerate(payloads)))))
    result = run("learn", "-q", path, "-o", tmp_path / "lib.parquet", "--channel", "/a:v:observation:width=1")
    assert result.exit_code == 0, result.output  # was OverflowError
    assert [v for _, _, v in load_library(tmp_path / "lib.parquet").vocabulary.items()] == [3]


def test_a_channel_with_more_values_than_its_limit_is_refused(tmp_path):
    path = write_log(tmp_path / "x.mcap", [("/a", i, {"v": i}) for i in range(20)])
    result = run("learn", "-q", path, "-o", tmp_path / "lib.parquet",
                 "--channel", "/a:v:observation:max_symbols=5")
    assert result.exit_code == 1, result.output
    no_action, line = result.stderr.strip().splitlines()  # the spec has observations only
    assert "the spec has no action channel" in no_action
    assert "channel '/a' has more than 5 distinct values: use coarser bins, or raise the entry's max_symbols" in line
    assert run("learn", "-q", path, "-o", tmp_path / "lib.parquet",
               "--channel", "/a:v:observation:max_symbols=20").exit_code == 0


def test_nan_readings_of_a_categorical_channel_are_not_symbols(tmp_path):
    path = tmp_path / "nan.mcap"
    payloads = [b'{"v": NaN}' if i % 2 else b'{"v": %d}' % (i % 4) for i in range(50)]
    path.write_bytes(mb.log(mb.chunk(b"".join(mb.message(i, p) for i, p in enumerate(payloads)))))
    result = run("learn", "-q", path, "-o", tmp_path / "lib.parquet", "--channel", "/a:v:observation")
    assert result.exit_code == 0, result.output
    assert [v for _, _, v in load_library(tmp_path / "lib.parquet").vocabulary.items()] == [0, 2]


def test_a_spec_whose_values_give_no_event_writes_nothing(tmp_path):
    # every reading NaN, or text under bins: an empty library would hide the spec's mistake
    nan, text = tmp_path / "nan.mcap", tmp_path / "text.mcap"
    nan.write_bytes(mb.log(mb.chunk(b"".join(mb.message(i, b'{"v": NaN}') for i in range(50)))))
    text.write_bytes(mb.log(mb.chunk(b"".join(mb.message(i, b'{"v": "up"}') for i in range(50)))))
    for path, channel in ((nan, "/a:v:observation"), (text, "/a:v:observation:range=[0,1],count=4")):
        result = run("learn", "-q", path, "-o", tmp_path / "lib.parquet", "--channel", channel)
        assert result.exit_code == 1, result.output
        assert f"{path}: no event to learn, so nothing was written: the spec's channels (/a:v) gave no value" \
            in result.stderr.strip().splitlines()[-1]
        assert not (tmp_path / "lib.parquet").exists()


def test_info_on_a_fifo_does_not_hang(tmp_path):
    import threading

    fifo = tmp_path / "pipe.mcap"
    os.mkfifo(fifo)
    results = []
    thread = threading.Thread(target=lambda: results.append(run("info", fifo)), daemon=True)
    thread.start()
    thread.join(20)
    assert results, "slearn info blocked on a FIFO"
    assert "not a regular file" in one_line(results[0])


def test_ros1_strings_that_are_not_utf8_keep_the_output_one_line(tmp_path, capfd):
    from mcap.writer import Writer

    path = tmp_path / "ros1.mcap"
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start(profile="ros1", library="test")
        schema = writer.register_schema("std_msgs/String", "ros1msg", b"string data")
        channel = writer.register_channel("/s", "ros1", schema)
        for i, text in enumerate([b"ok", b"bad \xff\xfe", b"ok"]):
            writer.add_message(channel, log_time=i, publish_time=i, data=struct.pack("<I", len(text)) + text)
        writer.finish()
    result = run("learn", "-q", path, "-o", tmp_path / "lib.parquet", "--channel", "/s:data:observation")
    assert result.exit_code == 0, result.output
    assert "Characters replaced" not in result.output + capfd.readouterr().err
    values = [v for _, _, v in load_library(tmp_path / "lib.parquet").vocabulary.items()]
    assert values == ["ok", "bad \ufffd\ufffd"]


def test_json_output_of_a_salvaged_learn_is_one_document(simple_pointer, tmp_path):
    log, _ = copies(tmp_path, *simple_pointer)
    damaged = _damaged_pointer(tmp_path, log)
    result = run("learn", "-q", log, damaged, "-o", tmp_path / "both.parquet", "--json")
    assert result.exit_code == EXIT_TRUNCATED
    assert json.loads(result.stdout)["truncated"][0].startswith(str(damaged))


def test_a_log_time_past_int64_is_damage_not_a_traceback(tmp_path):
    good = mb.chunk(b"".join(mb.message(i, b'{"v": %d}' % (i % 2)) for i in range(5)))
    bad = mb.chunk(mb.message(2**64 - 1, b'{"v": 1}'))
    path = tmp_path / "x.mcap"
    path.write_bytes(mb.log(good, bad))
    result = run("learn", "-q", path, "--channel", "/a:v:observation", "-o", tmp_path / "lib.parquet")
    assert result.exit_code == EXIT_TRUNCATED, result.output
    assert "past the year 2262" in result.stderr
    assert load_library(tmp_path / "lib.parquet").library.clock == 5



def test_bounds_past_any_log_time_are_the_end_of_time(tmp_path):
    path = write_log(tmp_path / "x.mcap", [("/a", i, {"v": i % 3}) for i in range(20)])
    whole = run("learn", "-q", path, "-o", tmp_path / "a.parquet", "--channel", "/a:v:observation")
    ended = run("learn", "-q", path, "-o", tmp_path / "b.parquet", "--channel", "/a:v:observation",
                "--end", "1e300")  # was OverflowError
    assert whole.exit_code == ended.exit_code == 0, ended.output
    assert len(load_library(tmp_path / "a.parquet").library) == len(load_library(tmp_path / "b.parquet").library)
    late = run("learn", "-q", path, "-o", tmp_path / "c.parquet", "--channel", "/a:v:observation",
               "--start", "1e300")
    assert late.exit_code == 1
    assert "1e300 to end of each log leaves no time of this log" in late.stderr.splitlines()[-1]


# --- signals ------------------------------------------------------------------------------

# Runs `slearn record pointer` in a fresh interpreter that sends itself a signal while the
# output is being written (at its tenth message). The signal's disposition is first set as
# a shell's foreground job has it (the test runner may run under nohup or in the
# background, which ignore SIGHUP or SIGINT), or left ignored ("ignored").
_SIGNALLED = """
import os, signal, sys
signum = getattr(signal, sys.argv[1])
if sys.argv[3] == "ignored":
    signal.signal(signum, signal.SIG_IGN)
else:
    signal.signal(signum, signal.default_int_handler if signum == signal.SIGINT else signal.SIG_DFL)
from slearn.recorders import mcap_episode
from slearn.cli import main
write, written = mcap_episode.EpisodeWriter.write_encoded, []
def write_then_signal(self, *args):
    written.append(1)
    if len(written) == 10:
        assert os.path.exists(self._out.tmp_path)
        os.kill(os.getpid(), signum)
    return write(self, *args)
mcap_episode.EpisodeWriter.write_encoded = write_then_signal
main(["record", "pointer", "--condition", "simple", "--trials", "50", "-o", sys.argv[2]])
"""


@pytest.mark.parametrize("name, code", [("SIGTERM", 143), ("SIGHUP", 129), ("SIGINT", 130)])
def test_a_signal_stops_a_command_without_leaving_its_temporary_file(tmp_path, name, code):
    """SIGTERM (what `kill`, systemd and job schedulers send) and SIGHUP (a closed terminal)
    stop a command as Ctrl-C does: the half-written output is removed, nothing is left
    next to it, and the exit status is 128 + the signal."""
    target = tmp_path / "run.mcap"
    done = subprocess.run([sys.executable, "-c", _SIGNALLED, name, str(target), "default"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == code, done.stderr
    assert list(tmp_path.iterdir()) == [], sorted(p.name for p in tmp_path.iterdir())
    assert done.stderr.strip().splitlines()[-1] in (f"slearn: stopped by {name}", "slearn: interrupted")


def test_a_signal_the_caller_ignores_stays_ignored(tmp_path):
    """`nohup slearn ...` ignores SIGHUP: the command keeps running and writes its output."""
    target = tmp_path / "run.mcap"
    done = subprocess.run([sys.executable, "-c", _SIGNALLED, "SIGHUP", str(target), "ignored"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert [p.name for p in tmp_path.iterdir()] == ["run.mcap"] and "50 trials" in done.stdout


def test_record_stream_refuses_one_file_as_both_outputs(tmp_path):
    """-o and --spec-out on one path: the spec would overwrite the log just written (it said
    the path was 'also an input')."""
    source = tmp_path / "s.txt"
    source.write_text("a b a b\nb a b a\n")
    target = tmp_path / "s.mcap"
    message = one_line(run("record", "stream", source, "-o", target, "--spec-out", target))
    assert message == f"slearn: error: -o and --spec-out both write {target}: give each output its own path"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.txt"]
