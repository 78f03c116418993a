"""``slearn info``: text and JSON profiles, spec skeletons, exit codes."""

from __future__ import annotations

import json
import re

import pytest
from click.testing import CliRunner
from fixtures import SHARED_MCAP, write_log

from slearn.cli import EXIT_TRUNCATED, main
from slearn.io.spec import load_spec
from slearn.jobs.info import describe_log, suggest_spec

SHARED = SHARED_MCAP


@pytest.fixture
def log(tmp_path):
    messages = []
    for i in range(11):  # 10 Hz for one second
        messages.append(("/cmd", i * 100_000_000, {"command": "LR"[i % 2]}))
        messages.append(("/state", i * 100_000_000 + 1, {"pose": {"x": i / 4, "ok": True},
                                                         "name": ["a", "b"], "position": [i, -i]}))
    messages.append(("/raw", 5, {"v": 1}))
    return write_log(tmp_path / "log.mcap", messages, encodings={"/raw": "wrong_format"}, chunk_size=1024)


def run(*args):
    return CliRunner().invoke(main, ["info", *map(str, args)])


def test_text_output(log):
    result = run(log)
    assert result.exit_code == 0, result.output
    out = result.stdout
    assert "library slearn-tests" in out and "23 messages" in out and "1.000 s" in out
    assert re.search(r"/cmd\s+Thing\s+json\s+11\s+10\.0 Hz", out)
    assert "pose.x" in out and "position[name=b]" in out
    assert "cannot be decoded: no decoder for message encoding 'wrong_format'" in out
    assert result.stderr == ""


def test_json_output(log):
    result = run("--json", log)
    assert result.exit_code == 0
    [doc] = json.loads(result.stdout)["files"]
    channels = {c["topic"]: c for c in doc["channels"]}
    assert doc["n_messages"] == 23 and doc["truncated"] is None
    assert channels["/cmd"]["count"] == 11 and channels["/cmd"]["rate_hz"] == pytest.approx(10.0)
    fields = {f["path"]: f for f in channels["/state"]["fields"]}
    x = fields["pose.x"]
    assert x["examples"] == [0.0, 0.5, 1.25, 2.0, 2.5] and x["type"] == "float"  # across the log
    assert (x["min"], x["max"], x["n_distinct"], x["constant"], x["changes"]) == (0.0, 2.5, 11, False, 10)
    assert fields["pose.ok"]["type"] == "bool" and fields["pose.ok"]["constant"] is True
    assert fields["position[name=b]"]["min"] == -10
    assert channels["/cmd"]["fields"][0]["examples"] == ["L", "R"]
    assert channels["/raw"]["decodable"] is False
    assert doc["start_time"] == "1970-01-01T00:00:00.000000000Z" and doc["end_s"] == pytest.approx(1.0)


def test_suggest_spec_learns_as_written(log, tmp_path):
    target = tmp_path / "spec.toml"
    assert run(log, "--suggest-spec", target).exit_code == 0
    text = target.read_text()
    assert "cannot be decoded" in text and "skipped (constant): pose.ok" in text
    spec = load_spec(target)
    entries = {(c.topic, c.field): c for c in spec.channels}
    assert spec.mode == "message" and entries[("/cmd", "command")].role == "action"
    assert entries[("/cmd", "command")].symbolizer.values == ("L", "R")
    assert {f for t, f in entries if t == "/state"} == {"position[name=a]", "position[name=b]", "pose.x"}
    learned = CliRunner().invoke(main, ["learn", str(log), "--spec", str(target), "-o",
                                        str(tmp_path / "lib.parquet")])
    assert learned.exit_code == 0, learned.output
    refused = run(log, "--suggest-spec", target)
    assert refused.exit_code == 1 and "already exists: pass --force" in refused.stderr
    forced = run(log, "--suggest-spec", target, "--force")
    assert forced.exit_code == 0 and "warning" not in forced.stderr


@pytest.mark.parametrize("command", [False, True])
def test_a_spec_with_nothing_to_predict_says_so_and_learn_refuses_it(tmp_path, command):
    """Logs whose every field is free text (rosbag2's test bags), with or without a command
    topic: the suggestion has no observation entry, says so in its header and on stderr,
    and learn and replay refuse it in one line, writing nothing."""
    messages = [(topic, 2 * i + k, {"data": f"Hello, world! {i} - {k}"})
                for i in range(200) for k, topic in enumerate(("AAA", "BBB"))]
    messages += [("/cmd", 2 * i, {"command": "LR"[i % 3 == 0]}) for i in range(200)] if command else []
    path = write_log(tmp_path / "text.mcap", messages)
    target = tmp_path / "spec.toml"
    result = run(path, "--suggest-spec", target)
    assert result.exit_code == 0
    assert f"warning: {target} has no observation entry" in result.stderr
    text = target.read_text()
    assert "It learns as written" not in text and "it learns nothing as written" in text
    assert text.count("skipped (free text (many distinct values)): data") == 2
    assert ('\nrole = "action"' in text) == command  # an entry, not the header's advice
    learned = CliRunner().invoke(main, ["learn", str(path), "--spec", str(target), "-o",
                                        str(tmp_path / "lib.parquet")])
    expected = "no [[channel]] entries" if not command else "no observation entry, so nothing to predict"
    assert learned.exit_code == 1 and expected in learned.stderr and len(learned.stderr.splitlines()) == 1
    assert not (tmp_path / "lib.parquet").exists()
    if command:
        replayed = CliRunner().invoke(main, ["replay", str(path), "--spec", str(target)])
        assert replayed.exit_code == 1 and "no observation entry" in replayed.stderr


def test_bursts_have_no_rate_and_topics_and_windows_select(tmp_path):
    path = write_log(tmp_path / "b.mcap", [("/static", 5 + i, {"v": i}) for i in range(3)]
                     + [("/s", i * 100_000_000, {"v": i}) for i in range(20)])
    doc = json.loads(run("--json", path).stdout)["files"][0]
    static = next(c for c in doc["channels"] if c["topic"] == "/static")
    assert static["burst"] is True and static["rate_hz"] is None
    assert "burst in 0.000 ms" in run(path).stdout
    only = json.loads(run("--json", "--topics", "/s", "--start", "0.5", "--end", "1", path).stdout)
    [channel] = only["files"][0]["channels"]
    assert channel["topic"] == "/s" and channel["count"] == 5
    missing = run("--topics", "/s,/nope", path)  # (it showed 0 messages and exited 0)
    assert missing.exit_code == 1 and f"{path}: --topics /nope not in this log" in missing.stderr


def test_suggest_spec_reads_logs_not_libraries(tmp_path):
    path = write_log(tmp_path / "b.mcap", [("/s", i * 100_000_000, {"v": i % 3}) for i in range(20)])
    library = tmp_path / "lib.parquet"
    assert CliRunner().invoke(main, ["learn", "-q", str(path), "-o", str(library),
                                     "--channel", "/s:v:observation"]).exit_code == 0
    result = run(library, "--suggest-spec", tmp_path / "s.toml")  # (it wrote an empty spec)
    assert result.exit_code == 1 and "is a library, not a log: --suggest-spec reads logs" in result.stderr
    assert not (tmp_path / "s.toml").exists()


def test_truncated_log_exits_3_and_still_reports(log, tmp_path):
    cut = tmp_path / "cut.mcap"
    data = log.read_bytes()
    cut.write_bytes(data[:len(data) * 2 // 3])
    result = run("--json", cut)
    assert result.exit_code == EXIT_TRUNCATED
    doc = json.loads(result.stdout)["files"][0]
    assert doc["truncated"]["broken_at"] > 0 and doc["n_messages"] > 0
    assert "truncated or corrupt log: salvaged" in result.stderr and "cut.mcap" in result.stderr


def test_bad_inputs_exit_1(tmp_path):
    not_mcap = tmp_path / "x.mcap"
    not_mcap.write_text("hello")
    result = run(not_mcap)
    assert result.exit_code == 1 and "not an MCAP file" in result.stderr
    result = run(tmp_path / "lib.parquet")
    assert result.exit_code == 1 and ".parquet" in result.stderr
    assert "Traceback" not in result.output


def test_suggest_spec_merges_logs(log):
    text = suggest_spec([describe_log(log), describe_log(log)])
    assert text.count("# --- /state") == 1


@pytest.mark.shared
def test_real_logs_profile():
    pr2 = SHARED / "robot" / "ros2_cdr" / "pr2_pr1012_sensors_ros2.mcap"
    if not pr2.exists():
        pytest.skip("PR2 log not available")
    profile = describe_log(pr2)
    assert profile.profile == "ros2" and profile.n_messages == 6933
    assert profile.duration_s == pytest.approx(13.45, abs=0.01)
    counts = {c.topic: c.count for c in profile.channels}
    assert counts["/joint_states"] == 1325 and counts["/tf"] == 3734
    joints = next(c for c in profile.channels if c.topic == "/joint_states")
    assert any(f.path.startswith("position[name=") for f in joints.fields)


def test_an_angle_in_degrees_on_a_full_turn_grid_is_suggested_wrapping(tmp_path):
    path = write_log(tmp_path / "a.mcap", [("/p", i * 100_000_000, {"angle_deg": 5.0 + 10 * (i * 7 % 36)})
                                           for i in range(200)])
    assert run(path, "--suggest-spec", tmp_path / "s.toml").exit_code == 0
    [entry] = [c for c in load_spec(tmp_path / "s.toml").channels if c.field == "angle_deg"]
    bins = entry.symbolizer
    assert bins.wrap and bins.range == (0.0, 360.0) and bins.count == 36 and bins.unit == "deg"
    assert bins.symbol_value(355) == 35 and bins.symbol_value(365) == 0  # (past the turn: wrapped)


@pytest.mark.parametrize("field, values, expected", [
    # off any grid (the pointer's error condition): the name, or a span of one turn of degrees
    ("angle_deg", lambda i: (i * 47.3) % 360.0, ((0.0, 360.0), "deg")),
    ("heading", lambda i: (i * 47.3) % 360.0 - 180.0, ((-180.0, 180.0), "deg")),
    ("yaw", lambda i: (i * 0.713) % 6.28 - 3.14, ((-3.141592653589793, 3.141592653589793), "rad")),
    ("theta_rad", lambda i: i * 0.713, ((0.0, 6.283185307179586), "rad")),  # turns past one wrap onto it
])
def test_an_angle_off_any_grid_is_suggested_in_its_own_unit(tmp_path, field, values, expected):
    """An angle in degrees off any grid was suggested as a range of 2 pi radians, so every
    reading past 6.3 degrees wrapped."""
    path = write_log(tmp_path / "a.mcap", [("/p", i * 100_000_000, {field: values(i)}) for i in range(300)])
    assert run(path, "--suggest-spec", tmp_path / "s.toml").exit_code == 0
    [entry] = [c for c in load_spec(tmp_path / "s.toml").channels if c.field == field]
    bins = entry.symbolizer
    assert bins.wrap and (bins.range, bins.unit) == expected and bins.count == 36
