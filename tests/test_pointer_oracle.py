"""The oracle ceiling: exact on deterministic conditions, about 75 % on error, 50 % on delay."""

import time

import numpy as np
import pytest

from slearn.errors import InputError
from slearn.recorders.pointer import PointerConfig, PointerRun, command_directions, simulate
from slearn.recorders.pointer_oracle import noise_kernel, oracle_correct, oracle_predict


def _run(condition, trials=4000, seed=0, **kwargs):
    return simulate(PointerConfig(condition, trials=trials, seed=seed, switch_trial=trials // 2,
                                  **kwargs))


@pytest.mark.parametrize("condition", ["simple", "hardstop", "scramble", "reversal"])
def test_deterministic_conditions_are_predicted_perfectly(condition):
    correct = oracle_correct(_run(condition))
    assert correct.dtype == bool and len(correct) == 4000
    assert correct.all()


def test_error_ceiling_is_about_75_percent():
    accuracy = np.mean([oracle_correct(_run("error", seed=seed)).mean() for seed in range(2)])
    assert 0.70 <= accuracy <= 0.80
    expected = oracle_predict(_run("error")).expected_accuracy
    assert 0.73 <= expected <= 0.77


def test_delay_ceiling_is_about_50_percent():
    accuracy = np.mean([oracle_correct(_run("delay", seed=seed)).mean() for seed in range(2)])
    assert 0.45 <= accuracy <= 0.55
    np.testing.assert_allclose(oracle_predict(_run("delay")).probabilities, 0.5)


def test_error_filter_matches_a_particle_filter():
    """A naive sampling filter (the definition, by brute force) agrees with the grid filter."""
    run = _run("error", trials=150, seed=3)
    predicted = oracle_predict(run)
    rng = np.random.default_rng(1)
    particles = np.full(50_000, run.angles[0])
    turns = command_directions(run.commands, run.config)
    agree = []
    for k, turn in enumerate(turns):
        moved = (particles + turn * (10 + rng.uniform(-5, 5, len(particles)))) % 360
        labels = np.floor(moved / 10).astype(int) % 36 + 1
        shares = np.bincount(labels, minlength=37) / len(labels)
        agree.append(abs(shares[predicted.labels[k]] - predicted.probabilities[k]) < 0.02)
        particles = rng.choice(moved[labels == run.positions[k + 1]], len(particles))
    assert all(agree)


def test_a_finer_grid_gives_the_same_guesses():
    run = _run("error", trials=1000)
    coarse, fine = oracle_predict(run), oracle_predict(run, cells_per_bin=800)
    assert (coarse.labels == fine.labels).mean() > 0.995
    assert np.abs(coarse.probabilities - fine.probabilities).max() < 0.01


def test_delay_guess_after_an_unambiguous_reading():
    """A two-bin move shows both commands ran: nothing is pending, so the ceiling is 1/2."""
    run = _run("delay", trials=2000)
    predicted = oracle_predict(run)
    two = np.flatnonzero(np.abs(np.diff(run.positions) % 36 - 18) == 16)  # moved two bins
    two = two[two + 1 < len(run)]
    assert len(two) > 0
    np.testing.assert_allclose(predicted.probabilities[two + 1], 0.5)


@pytest.mark.parametrize("half_width", [0.0, 2.5, 5.0, 7.3])
def test_noise_kernel_is_a_distribution_centred_on_zero(half_width):
    first, kernel = noise_kernel(half_width, 0.05)
    shifts = first + np.arange(len(kernel))
    assert (kernel >= 0).all() and abs(kernel.sum() - 1) < 1e-9
    assert abs(np.dot(shifts, kernel)) < 1e-9
    variance_deg = np.dot(shifts ** 2, kernel) * 0.05 ** 2
    assert abs(variance_deg - half_width ** 2 / 3) < 0.01  # U[-e, e] has variance e^2 / 3
    assert np.abs(shifts[kernel > 0]).max() * 0.05 <= half_width + 0.05


def test_an_impossible_reading_is_an_input_error():
    run = _run("error", trials=20)
    positions = run.positions.copy()
    positions[10] = (positions[9] + 17) % 36 + 1  # half a turn in one trial
    broken = PointerRun(run.config, run.commands, positions, run.angles, run.executed,
                        run.sensor_labels)
    with pytest.raises(InputError, match="trial 9 is impossible"):
        oracle_predict(broken)


def test_ten_thousand_trials_take_about_a_second_at_most():
    for condition in ("error", "delay"):
        run = simulate(PointerConfig(condition))
        start = time.perf_counter()
        oracle_correct(run)
        assert time.perf_counter() - start < 1.5
