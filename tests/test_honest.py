"""Honest replay: intervals, the persistence baseline, data-sized windows, small samples."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from slearn.replay.honest import SMALL_SAMPLE, HonestScores
from slearn.replay.intervals import paired_difference, wilson
from slearn.replay.windows import data_window, round_up


def test_wilson_matches_the_textbook_values():
    assert wilson(0, 10) == pytest.approx((0.0, 0.2775), abs=1e-4)
    assert wilson(27, 31) == pytest.approx((0.7115, 0.9487), abs=2e-4)
    lo, hi = wilson(9500, 10000)
    assert lo < 0.95 < hi and hi - lo < 0.01
    assert all(math.isnan(x) for x in wilson(0, 0))


def test_the_paired_lift_interval_covers_the_true_difference_about_95_percent_of_the_time():
    rng = np.random.default_rng(0)
    n, trials, covered = 200, 800, 0
    for _ in range(trials):
        library = rng.random(n) < 0.8
        baseline = np.where(rng.random(n) < 0.7, library, rng.random(n) < 0.75)  # correlated
        truth = 0.8 - (0.7 * 0.8 + 0.3 * 0.75)
        _, lo, hi = paired_difference(int(library.sum()), int(baseline.sum()),
                                      int((library & ~baseline).sum()), int((baseline & ~library).sum()), n)
        covered += lo <= truth <= hi
    assert 0.92 < covered / trials < 0.98


def test_identical_predictors_have_a_lift_of_zero_and_a_narrow_interval():
    difference, lo, hi = paired_difference(900, 900, 0, 0, 1000)
    assert difference == 0 and lo <= 0 <= hi and hi - lo < 0.01
    assert all(math.isnan(x) for x in paired_difference(0, 0, 0, 0, 0))


def test_windows_hold_enough_events_and_never_exceed_the_log():
    assert [round_up(x) for x in (0.3, 1, 3, 7, 11, 450)] == [1, 1, 5, 10, 20, 500]
    assert data_window(100_000, 100_000) == 2000  # about 50 windows
    assert data_window(1234, 1234) == 100  # at least 100 events each
    assert data_window(31, 31) == 50  # one window holds a tiny log
    assert data_window(1000, 100) == 1000  # steps without observations count too


class _Decoder:
    """One observation channel; tokens are its values."""

    channels = ["/s"]

    def split(self, tokens):
        return np.asarray(tokens, np.int64)[:, None]


def test_honest_scores_count_pairs_and_warn_about_small_channels():
    actual = np.array([1, 1, 2, 2, 2, 3])
    outcome = SimpleNamespace(evaluated=np.ones(6, bool), actual=actual,
                              predicted=np.array([1, 1, 2, 2, 2, 2]),
                              top_k=np.array([1, 1, 1, 1, 1, 0], bool),
                              frequency=np.array([1, 2, 2, 2, 1, 3]), markov=np.full(6, -1),
                              persistence=np.array([-1, 1, 1, 2, 2, 2]))
    scores = HonestScores()
    scores.add(outcome, _Decoder())
    doc = scores.to_dict()
    # library right on 5; persistence (prev value) right on steps 1, 3, 4
    assert (scores.correct, scores.right["persistence"], scores.right["frequency"]) == (5, 3, 4)
    assert (scores.only_library["frequency"], scores.only_baseline["frequency"]) == (2, 1)
    assert doc["baselines"]["persistence"]["lift_points"] == pytest.approx(100 * 2 / 6, abs=1e-3)
    lo, hi = doc["baselines"]["markov"]["lift_interval_points"]
    assert lo < 100 * 5 / 6 < hi
    assert doc["channels"][0]["persistence_accuracy"] == pytest.approx(0.5)
    assert doc["small_sample"] == [{"channel": "/s", "events": 6}]
    [warning] = scores.warnings()
    assert "'/s': only 6 predicted events" in warning and f"{SMALL_SAMPLE:,}" in warning
