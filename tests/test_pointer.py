"""The pointer simulator: dynamics per condition, determinism, configuration errors."""

import time

import numpy as np
import pytest

from slearn.errors import InputError, SlearnError
from slearn.recorders.pointer import CONDITIONS, N_BINS, L, PointerConfig, R, pointer_vocabulary, simulate


def _run(condition, trials=4000, seed=0, **kwargs):
    kwargs.setdefault("switch_trial", trials // 2)
    return simulate(PointerConfig(condition, trials=trials, seed=seed, **kwargs))


def _bins(run):
    return np.floor(run.angles / 10).astype(int) % N_BINS


def _turns_deg(run):
    """Signed angle change per trial in (-180, 180]."""
    return -((-np.diff(run.angles) + 180) % 360 - 180)


@pytest.mark.parametrize("condition", CONDITIONS)
def test_shapes_types_and_ranges(condition):
    run = _run(condition, trials=1000, switch_trial=500)
    assert run.commands.dtype == np.uint8 and len(run.commands) == 1000
    assert set(np.unique(run.commands)) == {L, R}
    assert len(run.positions) == len(run.angles) == 1001
    assert run.positions.min() >= 1 and run.positions.max() <= N_BINS
    assert ((run.angles >= 0) & (run.angles < 360)).all()
    assert run.angles[0] % 10 == 5  # the centre of a bin


def test_simple_moves_one_bin_per_command():
    run = _run("simple")
    step = np.where(run.commands == R, 1, -1)
    expected = (run.positions[:-1] - 1 + step) % N_BINS + 1
    np.testing.assert_array_equal(run.positions[1:], expected)
    np.testing.assert_allclose(np.abs(_turns_deg(run)), 10)


def test_hardstop_blocks_crossing_zero_and_nothing_else():
    run = _run("hardstop", trials=20000)
    before, after, commands = run.positions[:-1], run.positions[1:], run.commands
    blocked = ((before == N_BINS) & (commands == R)) | ((before == 1) & (commands == L))
    assert blocked.sum() > 10  # the walk does reach the stop
    np.testing.assert_array_equal(after[blocked], before[blocked])
    step = np.where(commands == R, 1, -1)
    np.testing.assert_array_equal(after[~blocked], before[~blocked] + step[~blocked])
    assert not (np.abs(np.diff(run.positions)) == N_BINS - 1).any()  # never wraps


def test_reversal_swaps_commands_from_the_switch_trial():
    run = _run("reversal", switch_trial=2000)
    step = np.where(run.commands == R, 1, -1)
    step[2000:] *= -1
    expected = (run.positions[:-1] - 1 + step) % N_BINS + 1
    np.testing.assert_array_equal(run.positions[1:], expected)


def test_scramble_is_a_fixed_permutation_after_the_switch():
    run = _run("scramble", switch_trial=2000)
    true_labels = _bins(run) + 1
    np.testing.assert_array_equal(run.positions[:2001], true_labels[:2001])
    after = run.positions[2001:]
    mapping = dict(zip(true_labels[2001:].tolist(), after.tolist()))
    assert len(mapping) == N_BINS and sorted(mapping.values()) == list(range(1, N_BINS + 1))
    np.testing.assert_array_equal(after, run.sensor_labels[true_labels[2001:] - 1])
    assert (run.sensor_labels != np.arange(1, N_BINS + 1)).sum() > N_BINS // 2


def test_error_moves_between_5_and_15_degrees_in_the_commanded_direction():
    run = _run("error", trials=10000)
    turns = _turns_deg(run)
    step = np.where(run.commands == R, 1, -1)
    assert ((turns * step >= 5) & (turns * step <= 15)).all()
    assert abs(np.mean(turns * step) - 10) < 0.1
    assert (turns * step < 6).any() and (turns * step > 14).any()  # the whole range is used
    label_shift = (np.diff(run.positions) * step) % N_BINS
    assert set(np.unique(label_shift)) == {0, 1, 2}  # bins skipped or unchanged


def test_error_deg_zero_is_simple():
    noisy = _run("error", error_deg=0.0)
    np.testing.assert_array_equal(noisy.positions, _run("simple").positions)


def test_delay_executes_zero_one_or_two_moves_a_quarter_half_quarter():
    run = _run("delay", trials=20000)
    share = np.bincount(run.executed, minlength=3) / len(run)
    np.testing.assert_allclose(share, [0.25, 0.5, 0.25], atol=0.015)
    turns = np.abs(_turns_deg(run))
    assert set(np.unique(np.round(turns))) == {0, 10, 20}
    assert (turns[run.executed == 0] == 0).all()
    assert (turns[run.executed == 1] == 10).all()


def test_delay_order_previous_delayed_command_then_current():
    run = _run("delay", trials=3000)
    turns = np.round(_turns_deg(run) / 10).astype(int)
    step = np.where(run.commands == R, 1, -1)
    # A trial moving by two bins ran its own command and the previous (delayed) one.
    two = np.flatnonzero(np.abs(turns) == 2)
    assert (two > 0).all()
    np.testing.assert_array_equal(turns[two], step[two] + step[two - 1])
    assert run.executed[0] in (0, 1)  # nothing can be pending before the first trial


def test_delay_prob_extremes():
    np.testing.assert_array_equal(_run("delay", delay_prob=0.0).positions,
                                  _run("simple").positions)
    late = _run("delay", delay_prob=1.0)
    np.testing.assert_array_equal(late.positions[2:], _run("simple").positions[1:-1])


def test_same_seed_same_arrays_and_different_seeds_differ():
    for condition in CONDITIONS:
        first, again = _run(condition, seed=7), _run(condition, seed=7)
        for name in ("commands", "positions", "angles", "executed", "sensor_labels"):
            np.testing.assert_array_equal(getattr(first, name), getattr(again, name))
        assert not np.array_equal(first.commands, _run(condition, seed=8).commands)


def test_one_seed_shares_start_and_commands_across_conditions():
    runs = [_run(condition) for condition in CONDITIONS]
    for run in runs[1:]:
        np.testing.assert_array_equal(run.commands, runs[0].commands)
        assert run.angles[0] == runs[0].angles[0]


def test_no_global_random_state_is_used():
    np.random.seed(0)
    before = np.random.get_state()[1].copy()
    _run("error")
    np.testing.assert_array_equal(np.random.get_state()[1], before)


@pytest.mark.parametrize("kwargs, fragment", [
    ({"condition": "wobble"}, "condition 'wobble' is unknown"),
    ({"condition": "simple", "trials": 0}, "trials must be an integer from 1 to 10,000,000"),
    ({"condition": "simple", "trials": 10**12}, "trials must be an integer from 1 to 10,000,000"),
    ({"condition": "simple", "trials": 2.5}, "trials must be an integer"),
    ({"condition": "simple", "seed": -1}, "seed must be an integer >= 0"),
    ({"condition": "reversal", "trials": 100}, "switch would never happen"),
    ({"condition": "error", "error_deg": -1.0}, "error_deg must be a number in [0, 10]"),
    ({"condition": "error", "error_deg": float("nan")}, "error_deg"),
    ({"condition": "delay", "delay_prob": 1.5}, "delay_prob must be a number in [0, 1]"),
])
def test_bad_config_is_a_clear_input_error(kwargs, fragment):
    with pytest.raises(InputError) as caught:
        PointerConfig(**kwargs)
    assert fragment in str(caught.value)
    assert isinstance(caught.value, SlearnError)


def test_switch_trial_is_ignored_where_it_does_not_apply():
    assert PointerConfig("simple", trials=100).switch_trial == 5000


def test_episode_uses_the_fixed_vocabulary():
    run = _run("simple", trials=50)
    episode = run.to_episode()
    vocabulary = pointer_vocabulary()
    assert len(episode) == 51 and episode.n_events == 101
    steps = episode.steps()
    assert steps[0] == ((), (int(run.positions[0]) + 1,))
    for i, (actions, observations) in enumerate(steps[1:]):
        assert vocabulary.name(actions[0]) == ("/pointer/command", "LR"[run.commands[i]])
        assert vocabulary.name(observations[0]) == ("/pointer/position", run.positions[i + 1])
    assert vocabulary.symbol("/pointer/command", "L") == 0
    assert vocabulary.symbol("/pointer/command", "R") == 1
    assert vocabulary.symbol("/pointer/position", 17) == 18
    assert len(vocabulary) == 38


def test_ten_thousand_trials_are_fast():
    for condition in CONDITIONS:
        start = time.perf_counter()
        simulate(PointerConfig(condition))
        assert time.perf_counter() - start < 0.1
