"""Pointer variants: bin counts, combined effects, switching back, a drifting error; their
ceiling; and the paper's six conditions unchanged seed for seed."""

import hashlib

import numpy as np
import pytest

from slearn.errors import InputError
from slearn.recorders.pointer import CONDITIONS, PointerConfig, command_directions, scrambled_readings, simulate
from slearn.recorders.pointer_oracle import oracle_correct, oracle_predict
from slearn.recorders.record_pointer import record_pointer

# sha256 prefixes of (commands, positions, angles, executed, sensor_labels) and of the
# oracle's labels, from the simulator and oracle before the variants existed
# (trials 3000, switch_trial 1500).
BEFORE = {
    ("simple", 0): ("d80ae0aa5bea0a1e", "405d40cfb2258645"),
    ("simple", 1): ("34688fceb8c48133", "5238adf6acc7d78f"),
    ("hardstop", 0): ("89f80e774f954cd4", "ed7120be798edc3d"),
    ("hardstop", 1): ("606f43699c117a77", "01727915b5c626c0"),
    ("scramble", 0): ("8c96d082a056fe44", "c4d48132fe67fa3f"),
    ("scramble", 1): ("43ca0007f044568d", "874fc35a002354c2"),
    ("reversal", 0): ("e9888f67ef35b857", "22994b3c25a5c661"),
    ("reversal", 1): ("d1c9a5bd216736f2", "d8733762eb4e28bf"),
    ("error", 0): ("2b531c0644afb84b", "13ffa9a5c88c9e03"),
    ("error", 1): ("8cb1b84e7d2a80d1", "b08b311c87448b1c"),
    ("delay", 0): ("789fb22c68be7a0a", "cf78bbbe4499c5af"),
    ("delay", 1): ("42e437b5ac500357", "d9efb61254c9e069"),
}


def _digest(*arrays):
    h = hashlib.sha256()
    for array in arrays:
        h.update(np.ascontiguousarray(array).tobytes())
    return h.hexdigest()[:16]


def _turns_deg(run):
    return -((-np.diff(run.angles) + 180) % 360 - 180)


@pytest.mark.parametrize("condition, seed", sorted(BEFORE))
def test_the_six_conditions_are_unchanged_seed_for_seed(condition, seed):
    run = simulate(PointerConfig(condition, trials=3000, seed=seed, switch_trial=1500))
    arrays = (run.commands, run.positions, run.angles, run.executed, run.sensor_labels)
    assert (_digest(*arrays), _digest(oracle_predict(run).labels)) == BEFORE[condition, seed]
    assert set(run.config.parameters()) == {"condition", "trials", "seed", "switch_trial",
                                           "error_deg", "delay_prob"}


@pytest.mark.parametrize("bins", [12, 72])
def test_bin_counts_move_one_bin_per_command(bins):
    run = simulate(PointerConfig("simple", trials=2000, bins=bins))
    step = np.where(run.commands == 1, 1, -1)
    assert run.positions.min() >= 1 and run.positions.max() <= bins
    assert len(np.unique(run.positions)) == bins
    np.testing.assert_array_equal(run.positions[1:], (run.positions[:-1] - 1 + step) % bins + 1)
    np.testing.assert_allclose(np.abs(_turns_deg(run)), 360 / bins)
    assert oracle_correct(run).all()


def test_error_scales_with_the_bin():
    run = simulate(PointerConfig("error", trials=5000, bins=12, error_deg=15.0))
    turns = _turns_deg(run) * np.where(run.commands == 1, 1, -1)
    assert turns.min() >= 15 and turns.max() <= 45 and turns.max() > 43
    with pytest.raises(InputError, match=r"error_deg must be a number in \[0, 5\]"):
        PointerConfig("error", bins=72, error_deg=8.0)


def test_error_and_delay_combine_per_command():
    run = simulate(PointerConfig("error+delay", trials=4000, error_deg=5.0))
    delay_only = simulate(PointerConfig("delay", trials=4000))
    np.testing.assert_array_equal(run.executed, delay_only.executed)  # delays drawn first
    turns = np.abs(_turns_deg(run))
    assert (turns[run.executed == 0] == 0).all()
    one = turns[run.executed == 1]
    assert one.min() >= 5 and one.max() <= 15
    two = np.abs(turns[run.executed == 2])
    assert two.max() <= 30 and (two < 1).any()  # two moves may cancel out


def test_reversal_and_error_reverse_the_noisy_move():
    run = simulate(PointerConfig("reversal+error", trials=4000, switch_trial=2000))
    turns = _turns_deg(run) * np.where(run.commands == 1, 1, -1)
    assert (turns[:2000] >= 5).all() and (turns[2000:] <= -5).all()
    assert np.abs(turns).max() <= 15


def test_scramble_and_delay_read_delayed_moves_through_the_permutation():
    run = simulate(PointerConfig("scramble+delay", trials=4000, switch_trial=2000))
    plain = simulate(PointerConfig("delay", trials=4000))
    np.testing.assert_array_equal(run.angles, plain.angles)
    np.testing.assert_array_equal(run.positions[:2001], plain.positions[:2001])
    np.testing.assert_array_equal(run.positions[2001:],
                                  run.sensor_labels[plain.positions[2001:] - 1])


@pytest.mark.parametrize("condition", ["reversal", "scramble"])
def test_switching_back_restores_the_original_dynamics(condition):
    config = PointerConfig(condition, trials=6000, switch_trial=2000, switch_back_trial=4000)
    run, simple = simulate(config), simulate(PointerConfig("simple", trials=6000))
    step = np.where(run.commands == 1, 1, -1)
    moved = (np.diff(_true_labels(run)) + 18) % 36 - 18
    np.testing.assert_array_equal(moved[:2000], step[:2000])
    np.testing.assert_array_equal(moved[4000:], step[4000:])
    expected = -step[2000:4000] if condition == "reversal" else step[2000:4000]
    np.testing.assert_array_equal(moved[2000:4000], expected)
    if condition == "scramble":
        assert (run.positions[2001:4001] != simple.positions[2001:4001]).mean() > 0.8
        np.testing.assert_array_equal(run.positions[4001:], simple.positions[4001:])
    assert scrambled_readings(config) == ((2001, 4001) if condition == "scramble" else (6001, 6001))
    assert oracle_correct(run).all()


def _true_labels(run):
    labels = run.positions.astype(int)
    first, end = scrambled_readings(run.config)
    labels[first:end] = np.argsort(run.sensor_labels)[labels[first:end] - 1] + 1
    return labels


def test_error_drift_grows_the_noise_linearly():
    config = PointerConfig("error", trials=10000, error_deg=0.0, error_end_deg=10.0)
    run = simulate(config)
    noise = np.abs(np.abs(_turns_deg(run)) - 10)
    amplitudes = config.error_amplitudes()
    assert amplitudes[0] == 0 and amplitudes[-1] == 10
    assert (noise <= amplitudes + 1e-9).all()
    assert noise[:500].max() < 0.5 and noise[-500:].max() > 9
    assert config.parameters()["error_end_deg"] == "10.0"


def test_hardstop_blocks_each_move_of_a_combination():
    run = simulate(PointerConfig("hardstop+error+delay", trials=20000, error_deg=8.0))
    assert (run.angles >= 0).all() and (run.angles < 360).all()
    assert not (np.abs(np.diff(run.angles)) > 180).any()  # never wraps around the stop


def test_variants_are_deterministic():
    config = PointerConfig("reversal+error+delay", trials=3000, seed=4, switch_trial=1000,
                           switch_back_trial=2000, bins=72, error_deg=2.5, error_end_deg=4.0)
    first, again = simulate(config), simulate(config)
    for name in ("commands", "positions", "angles", "executed", "sensor_labels"):
        np.testing.assert_array_equal(getattr(first, name), getattr(again, name))


@pytest.mark.parametrize("kwargs, fragment", [
    ({"condition": "error+wobble"}, "condition 'error+wobble' is unknown"),
    ({"condition": "error+error"}, "distinct effects"),
    ({"condition": "simple+error"}, "is unknown"),
    ({"condition": "simple", "bins": 5}, "bins must be an integer from 10 to 720"),
    ({"condition": "simple", "bins": 36.0}, "bins must be an integer"),
    ({"condition": "error", "switch_back_trial": 7000}, "ends a switch; add reversal or scramble"),
    ({"condition": "reversal", "switch_back_trial": 5000}, "switch_back_trial must be an integer >= 5001"),
    ({"condition": "reversal", "switch_back_trial": 10000}, "switch back would never happen"),
    ({"condition": "delay", "error_end_deg": 3.0}, "add the error effect"),
    ({"condition": "error", "error_end_deg": 11.0}, "error_end_deg must be a number in [0, 10]"),
    ({"condition": "reversal+delay", "trials": 100}, "switch would never happen"),
])
def test_bad_variant_is_a_clear_input_error(kwargs, fragment):
    with pytest.raises(InputError) as caught:
        PointerConfig(**kwargs)
    assert fragment in str(caught.value)


def test_recording_other_bin_counts_is_refused(tmp_path):
    with pytest.raises(InputError, match="pointer logs have 36 bins, not 12"):
        record_pointer(PointerConfig("simple", trials=10, bins=12), tmp_path / "p.mcap")
    assert not (tmp_path / "p.mcap").exists()


def _particle_probabilities(run, particles=20_000):
    """The predictive probability of each oracle guess, by brute-force sampling of the
    run's own dynamics (the definition), conditioned on every reading."""
    config, rng = run.config, np.random.default_rng(1)
    predicted = oracle_predict(run)
    angle, pending = np.full(particles, run.angles[0]), np.zeros(particles, bool)
    turns, amplitudes = command_directions(run.commands, config), config.error_amplitudes()
    inverse, (first, end) = np.argsort(run.sensor_labels), scrambled_readings(config)
    shares = []
    for k, turn in enumerate(turns):
        moved = angle.copy()
        delayed = rng.random(particles) < config.delay_prob if "delay" in config.effects else \
            np.zeros(particles, bool)
        if k and "delay" in config.effects:
            ran = _move(config, moved, turns[k - 1], amplitudes[k - 1], rng)
            moved = np.where(pending, ran, moved)
        moved = np.where(delayed, moved, _move(config, moved, turn, amplitudes[k], rng))
        bins = np.floor(moved / config.bin_deg).astype(int) % config.bins
        true = int(run.positions[k + 1]) - 1
        guess = int(predicted.labels[k]) - 1
        if first <= k + 1 < end:
            true, guess = inverse[true], inverse[guess]
        shares.append((bins == guess).mean())
        keep = np.flatnonzero(bins == true)
        pick = rng.choice(keep, particles)
        angle, pending = moved[pick], delayed[pick]
    return np.array(shares), predicted.probabilities


def _move(config, angle, turn, amplitude, rng):
    noise = rng.uniform(-amplitude, amplitude, len(angle)) if "error" in config.effects else 0.0
    target = angle + turn * (config.bin_deg + noise)
    if "hardstop" in config.effects:
        return np.where((target >= 0) & (target < 360), target, angle)
    return target % 360


@pytest.mark.parametrize("config", [
    PointerConfig("error+delay", trials=100, seed=3),
    PointerConfig("hardstop+error+delay", trials=100, seed=5, error_deg=8.0),
    PointerConfig("error", trials=100, seed=3, bins=72, error_deg=2.5, error_end_deg=5.0),
    PointerConfig("reversal+scramble+error", trials=100, seed=3, switch_trial=30,
                  switch_back_trial=60),
    PointerConfig("delay+hardstop+reversal", trials=200, seed=2, delay_prob=0.3,
                  switch_trial=100),
], ids=lambda c: c.condition)
def test_ceiling_matches_a_particle_filter(config):
    sampled, exact = _particle_probabilities(simulate(config))
    assert np.abs(sampled - exact).max() < 0.025


@pytest.mark.parametrize("condition", ["hardstop+reversal+scramble", "reversal", "scramble"])
def test_deterministic_variants_have_a_perfect_ceiling(condition):
    config = PointerConfig(condition, trials=3000, bins=12, switch_trial=1000,
                           switch_back_trial=2000)
    assert oracle_correct(simulate(config)).all()


def test_ceiling_of_delay_variants():
    low = oracle_predict(simulate(PointerConfig("delay", delay_prob=0.3, trials=4000)))
    high = oracle_predict(simulate(PointerConfig("delay", delay_prob=0.7, trials=4000)))
    assert 0.6 < low.expected_accuracy < 0.75 and 0.5 < high.expected_accuracy < 0.7
    both = oracle_predict(simulate(PointerConfig("error+delay", trials=2000)))
    assert 0.4 < both.expected_accuracy < 0.5  # below either effect alone


def test_full_bin_error_has_a_ceiling():
    """error_deg equal to one bin once broke the filter (a kernel tail left its window)."""
    run = simulate(PointerConfig("error", trials=500, error_deg=10.0))
    assert 0.45 < oracle_predict(run).expected_accuracy < 0.55


def test_every_condition_still_has_its_ceiling():
    for condition in CONDITIONS:
        accuracy = oracle_correct(simulate(PointerConfig(condition, trials=1000,
                                                         switch_trial=500))).mean()
        assert accuracy > 0.4
