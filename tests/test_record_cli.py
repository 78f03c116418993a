"""``slearn record pointer`` through click's CliRunner."""

import json

from click.testing import CliRunner
from mcap.reader import make_reader

from slearn.cli import main


def _record(*args):
    return CliRunner().invoke(main, ["record", "pointer", *args])


def _message_count(path):
    with open(path, "rb") as f:
        return make_reader(f).get_summary().statistics.message_count


def test_record_pointer_writes_an_mcap_and_a_summary_line(tmp_path):
    path = tmp_path / "simple.mcap"
    result = _record("--condition", "simple", "--trials", "200", "--seed", "4", "-o", str(path))
    assert result.exit_code == 0, result.output
    assert _message_count(path) == 200 + 2 * 201
    lines = result.stdout.splitlines()
    assert len(lines) == 1 and "simple" in lines[0] and "200 trials" in lines[0]


def test_record_pointer_refuses_to_overwrite_without_force(tmp_path):
    path = tmp_path / "p.mcap"
    path.write_bytes(b"precious")
    refused = _record("--condition", "delay", "--trials", "50", "-o", str(path))
    assert refused.exit_code == 1
    assert refused.stdout == ""
    assert refused.stderr.strip().splitlines() == [
        f"slearn: error: {path} already exists: pass --force to overwrite it"]
    assert path.read_bytes() == b"precious"
    forced = _record("--condition", "delay", "--trials", "50", "-o", str(path), "--force")
    assert forced.exit_code == 0
    assert _message_count(path) == 50 + 2 * 51


def test_record_pointer_json_is_one_document(tmp_path):
    path = tmp_path / "r.mcap"
    result = _record("--condition", "reversal", "--trials", "300", "--switch-trial", "100",
                     "--seed", "2", "-o", str(path), "--json")
    assert result.exit_code == 0, result.output
    summary = json.loads(result.stdout)
    assert summary["condition"] == "reversal" and summary["seed"] == 2
    assert summary["messages"] == {"/pointer/command": 300, "/pointer/position": 301,
                                   "/pointer/angle": 301}
    assert summary["size_bytes"] == path.stat().st_size


def test_parameters_reach_the_metadata(tmp_path):
    for condition, option, value, key in (("error", "--error-deg", "2.5", "error_deg"),
                                          ("delay", "--delay-prob", "0.25", "delay_prob")):
        path = tmp_path / f"{condition}.mcap"
        result = _record("--condition", condition, "--trials", "20", option, value, "-o", str(path))
        assert result.exit_code == 0
        with open(path, "rb") as f:
            (record,) = list(make_reader(f).iter_metadata())
        assert record.metadata[key] == value


def test_bad_parameters_are_usage_errors_that_write_nothing(tmp_path):
    # out of range, as --trials is, or a parameter the condition would ignore
    for args, message in ((["--condition", "error", "--error-deg", "30"], "30.0 is not in the range 0<=x<=10"),
                          (["--condition", "simple", "--delay-prob", "0.2"],
                           "--delay-prob applies to the delay condition(s): 'simple' would ignore it")):
        result = _record(*args, "-o", str(tmp_path / "x.mcap"))
        assert result.exit_code == 2 and message in result.stderr
    assert not list(tmp_path.iterdir())


def test_unknown_condition_is_a_usage_error(tmp_path):
    result = _record("--condition", "wobble", "-o", str(tmp_path / "x.mcap"))
    assert result.exit_code == 2
