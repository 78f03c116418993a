"""The change detector: alarms at changes of dynamics, not on streams that are merely
random (its expected miss rates calibrated per cell, :mod:`slearn.core.mixer`)."""

from __future__ import annotations

import numba
import numpy as np
import pytest

from slearn import SequenceModel
from slearn.core.library import PatternLibrary
from slearn.core.mixer import (
    ASLEEP,
    CELLS,
    FREQUENT,
    FRESH,
    HITS,
    OCTAVES,
    RECENT,
    SEEN,
    calibration_cell,
    detect,
    new_mixer,
)
from slearn.io.library_file import load_library
from slearn.jobs.merge import merge_libraries
from slearn.recorders.pointer import PointerConfig, simulate


def learned(items: list, chunk: int = 5000) -> SequenceModel:
    model = SequenceModel()
    for i in range(0, len(items), chunk):
        model.learn(items[i:i + chunk])
    return model


def alarms(model: SequenceModel) -> int:
    return int(model.library.mixer.epoch.sum())


@pytest.mark.parametrize("faces", [4, 1000])
def test_a_random_stream_raises_no_alarm(faces):
    # PPM-C gives a context seen once 1/2 for its outcome; taken at face value, each miss
    # of a die of 1,000 faces looked like a change (about 170 alarms in these 50,000 rolls)
    rolls = np.random.default_rng(faces).integers(0, faces, 50_000).tolist()
    assert alarms(learned(rolls)) <= 1


def test_a_random_walk_over_many_states_raises_no_alarm():
    rng = np.random.default_rng(7)
    successors = rng.integers(0, 2000, (2000, 50))
    state, walk = 0, []
    for _ in range(50_000):
        state = int(successors[state, rng.integers(0, 50)])
        walk.append(state)
    assert alarms(learned(walk)) <= 1


def test_a_change_of_a_deterministic_cycle_is_caught_at_once():
    before = list(range(10)) * 2000
    after = [(3 * i) % 10 for i in range(10)] * 2000  # the same symbols, another order
    model = learned(before)
    assert alarms(model) == 0
    model.learn(after[:30])
    assert alarms(model) == 1
    model.learn(after[30:])
    assert alarms(model) == 1
    assert model.predict(after[-5:]) == after[0]  # and the new order is what it predicts


def test_a_change_among_noise_is_still_caught():
    rng = np.random.default_rng(3)

    def noisy(cycle, n):  # the cycle's next item 90 % of the time, else a random one
        items = [cycle[i % len(cycle)] for i in range(n)]
        return [int(rng.integers(0, 10)) if rng.random() < 0.1 else x for x in items]

    model = learned(noisy(list(range(10)), 20_000))
    assert alarms(model) <= 1
    quiet = alarms(model)
    model.learn(noisy([(3 * i) % 10 for i in range(10)], 300))
    assert alarms(model) > quiet


def test_calibration_cells_are_the_octaves_of_count_and_odds():
    cell_of = calibration_cell.py_func  # a helper is called from compiled code only
    assert cell_of(1, 1, 1) == 0 * OCTAVES + 1  # seen once: a share of 1/2, odds 2
    assert cell_of(100, 100, 1) == 6 * OCTAVES + 6  # 100 of 100: odds 101
    assert cell_of(1, 100, 50) == 6 * OCTAVES + 0  # a rare outcome: odds below 2
    assert cell_of(1 << 40, 1 << 40, 1) == CELLS - 1  # both octaves saturate
    for c, total, distinct in [(1, 1, 1), (3, 7, 2), (50, 100, 3), (99, 100, 2), (7, 1000, 40)]:
        cell = cell_of(c, total, distinct)
        count_octave, odds_octave = divmod(cell, OCTAVES)
        assert count_octave == min(int(np.floor(np.log2(total))), OCTAVES - 1)
        odds = (total + distinct) / (total + distinct - c)
        assert odds_octave == min(int(np.floor(np.log2(odds) + 1e-12)), OCTAVES - 1)


def test_calibration_counts_every_test_and_merges_by_adding(tmp_path):
    rng = np.random.default_rng(11)
    a = learned(rng.integers(0, 6, 3000).tolist())
    b = learned(rng.integers(0, 6, 2000).tolist())
    cal = a.library.mixer.calibration
    assert cal.shape == (1, CELLS, 2)
    assert 0 < cal[0, :, SEEN].sum() < 3000 and np.all(cal[..., HITS] <= cal[..., SEEN])
    hit_rate = cal[0, :, HITS].sum() / cal[0, :, SEEN].sum()
    assert abs(hit_rate - 1 / 6) < 0.05  # the trusted expert of a fair die is right 1 time in 6
    a.save(tmp_path / "a.parquet")
    b.save(tmp_path / "b.parquet")
    merged = merge_libraries(load_library(tmp_path / "a.parquet"), load_library(tmp_path / "b.parquet"))
    np.testing.assert_array_equal(merged.library.mixer.calibration, cal + b.library.mixer.calibration)



@numba.njit
def first_alarm(mixer_weight, detector, calibration, misses, c, total, distinct):
    """Feed ``misses`` misses of one share to view 0's test; the index of the first alarm."""
    for i in range(misses):
        if detect(mixer_weight, detector, calibration, 0, False, c, total, distinct):
            return i
    return -1


def test_misses_of_a_well_seen_context_count_in_a_cell_never_used():
    # a context seen 1,000 times that gave its outcome 990 times: its share speaks for the
    # first predictions of a new cell, so a run of misses (a change) is caught in a few;
    # had the cell's own few trials weighed as much, they would have taught the test to
    # expect the misses (about 6 nats after 10 of them; the alarm is at 13.8)
    mixer = new_mixer(1, 6)
    assert 0 <= first_alarm(mixer.weight, mixer.detector, mixer.calibration, 10, 990, 1000, 2) <= 4
    cell = calibration_cell.py_func(990, 1000, 2)
    assert mixer.calibration[0, cell, HITS] == 0 and 1 <= mixer.calibration[0, cell, SEEN] <= 5


def test_an_alarm_starts_each_lengths_fresh_counts_at_that_lengths_best_weight():
    # The alarm declares the counts stale, not what a context length is worth: at each
    # length the fresh counts take the best weight of the length and speak at once, the
    # all-time counts just below them (a regime that comes back finds them there), and the
    # latest outcome keeps its own record
    mixer = new_mixer(1, 3)
    w = mixer.weight
    w[0] = [[0.2, 0.9, ASLEEP], [1.0, 0.5, ASLEEP], [0.3, 0.1, 0.7]]
    recent = w[0, :, RECENT].copy()
    assert first_alarm(w, mixer.detector, mixer.calibration, 20, 990, 1000, 2) >= 0
    np.testing.assert_array_equal(w[0, :, FRESH], [0.9, 1.0, 0.7])
    assert np.all(w[0, :, FREQUENT] < w[0, :, FRESH])
    np.testing.assert_allclose(w[0, :, FREQUENT], w[0, :, FRESH], rtol=1e-8)
    np.testing.assert_array_equal(w[0, :, RECENT], recent)


@pytest.mark.parametrize("condition", ["reversal", "scramble"])
def test_a_switch_back_is_predicted_as_well_as_the_dynamics_were_before(condition):
    # After the switch back the all-time counts hold the first dynamics again; the fresh
    # counts start over. With the fresh experts just below the all-time ones (until
    # 2026-12-07) the thousand after the switch back scored 96.0 % (scramble 96.1)
    config = PointerConfig(condition, trials=5000, switch_trial=2000, switch_back_trial=4000)
    library = PatternLibrary()
    codes = library.encode(simulate(config).to_episode())
    assert len(codes.token) == len(codes)  # one reading per step
    reports = library.run(codes, learn=True, record=True, top_k=1)
    correct = (reports.context & (reports.predicted == codes.token))[1:]  # trial t is step t + 1
    first, after, back = (100 * correct[t:t + 1000].mean() for t in (0, 2000, 4000))
    assert back >= 99.0 and after >= first


def test_a_new_epoch_counts_the_reports_since_the_change_it_dates():
    # The test alarms some reports after a change; Page's CUSUM dates the change where its
    # statistic was last zero, and the reports in between already showed the new
    # dynamics. They count as fresh in the new epoch, as an empty library started at the
    # change would count them: every occurrence of the item that only follows the change
    # is fresh. (Counting from the alarm left out the first few.)
    before = [0, 1] * 3000
    after = [0, 2] * 40  # 0 is now followed by 2, never seen before
    model = SequenceModel()
    model.learn(before + after)
    assert alarms(model) == 1
    data = model.library.export()
    ends = data["pattern_tokens"][data["pattern_offsets"][1:] - 1]
    new_outcome = ends[-1]  # the last pattern first seen: one ending in the new item
    mine = ends == new_outcome
    assert mine.sum() > 0
    np.testing.assert_array_equal(data["fresh"][mine], data["count"][mine])
    assert np.all(data["fresh"] <= data["count"])


def test_counting_again_stays_within_an_episode_and_forgetting():
    # The reports kept for counting again belong to the current episode, and forgetting
    # renumbers the tree's nodes: neither may carry them over. Here the change begins at
    # the end of one episode (one miss: no alarm yet) and alarms at the first report of
    # the next, so that first occurrence of 0 -> 2 stays out of the new epoch.
    model = SequenceModel()
    model.learn([0, 1] * 3000 + [0, 2])
    assert alarms(model) == 0
    model.learn([0, 2] * 40)
    assert alarms(model) == 1
    data = model.library.export()
    ends = data["pattern_tokens"][data["pattern_offsets"][1:] - 1]
    after_one = (np.diff(data["pattern_offsets"]) == 2) & (ends == ends[-1])  # 0 -> 2
    assert after_one.sum() == 1
    assert data["count"][after_one][0] == 41 and data["fresh"][after_one][0] == 40
    assert np.all(data["fresh"] <= data["count"])
    small = SequenceModel(max_patterns=64)  # forgets many times within one episode
    small.learn(np.random.default_rng(0).integers(0, 50, 4000).tolist() + [0, 2] * 200)
    data = small.library.export()
    assert np.all(data["fresh"] <= data["count"])
