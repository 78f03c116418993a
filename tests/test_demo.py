"""The demo reproduces Figure 2: the issue's acceptance thresholds, seeds 0-4."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from slearn.cli import main
from slearn.jobs.demo import run_demo, windowed_percent


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    return {c.condition: c for c in run_demo(tmp_path_factory.mktemp("demo"), seeds=[0, 1, 2, 3, 4]).conditions}


def test_windowed_percent():
    assert windowed_percent(np.array([1, 0, 1, 1, 1]), 2) == [50.0, 100.0, 100.0]


@pytest.mark.parametrize("condition", ["simple", "hardstop"])
def test_deterministic_conditions_are_learned_within_a_thousand_trials(demo, condition):
    curve = demo[condition].accuracy["adaptive"]
    assert curve[0] >= 90
    assert min(curve[1:]) >= 99.5


@pytest.mark.parametrize("condition", ["scramble", "reversal"])
def test_switches_are_relearned_quickly(demo, condition):
    curve = demo[condition].accuracy["adaptive"]
    assert curve[0] >= 90 and min(curve[1:5]) >= 99.5
    assert curve[5] >= 92  # the thousand after the switch
    assert min(curve[7:]) >= 99
    # the paper's literal scoring recovers more slowly: the gain is visible
    assert demo[condition].accuracy["literal"][5] < curve[5] - 10


def test_random_error_reaches_near_the_ceiling(demo):
    error = demo["error"]
    assert np.mean(error.accuracy["adaptive"][5:]) >= 74.5
    assert np.mean(error.accuracy["literal"][5:]) < np.mean(error.accuracy["adaptive"][5:])
    assert 73 <= np.mean(error.ceiling) <= 77


def test_random_delay_reaches_the_target_under_the_ceiling(demo):
    delay = demo["delay"]
    assert np.mean(delay.accuracy["adaptive"][5:]) >= 49.0
    assert 48 <= np.mean(delay.ceiling) <= 52
    assert max(delay.accuracy["adaptive"]) < max(delay.ceiling)


def test_libraries_are_small_like_the_paper(demo):
    # the paper: 2155 patterns for the simple system, counted at parse boundaries
    assert 1000 <= demo["simple"].literal_patterns <= 3000
    # every occurrence of every context up to 6 steps: a few times more, still small
    assert demo["simple"].patterns <= 6 * demo["simple"].literal_patterns
    assert demo["simple"].library_file_bytes / demo["simple"].patterns < 20


def test_cli_writes_figure_summary_and_logs(tmp_path):
    out = tmp_path / "demo"
    result = CliRunner().invoke(main, ["demo", "--out", str(out), "--seeds", "1", "--trials", "2000",
                                       "--json", "--quiet"])
    assert result.exit_code == 0, result.output
    summary = json.loads(result.stdout)
    assert set(summary["conditions"]) == {"simple", "hardstop", "scramble", "reversal", "error", "delay"}
    assert (out / "figure2.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert json.loads((out / "summary.json").read_text())["trials"] == 2000
    assert len(list((out / "logs").glob("*.mcap"))) == 6


def test_cli_refuses_a_folder_with_files(tmp_path):
    (tmp_path / "keep.txt").write_text("mine")
    result = CliRunner().invoke(main, ["demo", "--out", str(tmp_path), "--quiet"])
    assert result.exit_code == 1
    assert "not empty" in result.output
    assert (tmp_path / "keep.txt").read_text() == "mine"
