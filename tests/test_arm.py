"""recorders.arm: dynamics, determinism, layouts, MCAP recording = in-memory episode."""

import hashlib

import numpy as np
import pytest
from fixtures import online_correct

from slearn.core.library import PatternLibrary
from slearn.core.vocabulary import Vocabulary
from slearn.errors import InputError
from slearn.io.serialize import read_episodes
from slearn.recorders.arm import (
    SENSORS,
    ArmConfig,
    arm_oracle_correct,
    arm_spec,
    arm_vocabulary,
    record_arm,
    simulate_arm,
)


def test_each_trial_moves_only_the_commanded_joint_by_one_bin():
    run = simulate_arm(ArmConfig(joints=3, trials=500, seed=1))
    step = np.diff(run.positions.astype(int), axis=0)
    moved = step != 0
    assert (moved.sum(axis=1) == 1).all()
    assert (np.argmax(moved, axis=1) == run.joint).all()
    delta = step[np.arange(500), run.joint]
    expected = np.where(run.commands == 1, 1, -1)
    assert ((delta - expected) % 36 == 0).all()
    assert run.positions.min() >= 1 and run.positions.max() <= 36


def test_seeded_and_every_joint_gets_commands():
    a, b = (simulate_arm(ArmConfig(joints=4, trials=400, seed=7)) for _ in range(2))
    assert np.array_equal(a.positions, b.positions) and np.array_equal(a.joint, b.joint)
    other = simulate_arm(ArmConfig(joints=4, trials=400, seed=8))
    assert not np.array_equal(a.joint, other.joint)
    assert set(a.joint.tolist()) == {0, 1, 2, 3}


@pytest.mark.parametrize("sensors", SENSORS)
@pytest.mark.parametrize("joints", [1, 3])
def test_recorded_file_reads_back_as_the_in_memory_episode(tmp_path, sensors, joints):
    config = ArmConfig(joints=joints, trials=300, seed=2, sensors=sensors)
    summary = record_arm(config, tmp_path / "arm.mcap")
    per_trial = 1 if sensors == "moved" else joints
    assert sum(summary.messages.values()) == 300 + 300 * per_trial + joints
    vocabulary = Vocabulary()
    [(_, episode, _)] = read_episodes([tmp_path / "arm.mcap"], arm_spec(joints), vocabulary)
    expected = simulate_arm(config).to_episode()
    for name in ("symbols", "step_offsets", "n_actions"):
        assert np.array_equal(getattr(episode, name), getattr(expected, name))
    assert list(vocabulary.items()) == list(arm_vocabulary(joints).items())


def test_step_layouts():
    moved = simulate_arm(ArmConfig(joints=2, trials=5, sensors="moved")).to_episode()
    every = simulate_arm(ArmConfig(joints=2, trials=5, sensors="all")).to_episode()
    assert [len(o) for _, o in moved.steps()] == [2, 1, 1, 1, 1, 1]
    assert [len(o) for _, o in every.steps()] == [2, 2, 2, 2, 2, 2]
    assert all(len(a) == 1 for a, _ in moved.steps()[1:])


def test_one_joint_is_learned_like_the_simple_pointer():
    episode = simulate_arm(ArmConfig(joints=1, trials=3000, seed=0)).to_episode()
    assert online_correct(PatternLibrary(), episode)[-1000:].mean() == 1.0


@pytest.mark.parametrize("sensors", SENSORS)
@pytest.mark.parametrize("joints", [2, 3, 4])
def test_every_joint_is_predicted_from_its_own_reading_and_the_command(joints, sensors):
    """Issue 11's acceptance: >= 99 % of whole steps in thousands 6-10 (seed 0 here)."""
    episode = simulate_arm(ArmConfig(joints=joints, trials=10_000, seed=0, sensors=sensors)).to_episode()
    library = PatternLibrary(vocabulary=arm_vocabulary(joints))
    assert online_correct(library, episode)[5000:].mean() >= 0.99


def test_the_error_arm_is_learned_to_its_ceiling():
    run = simulate_arm(ArmConfig(joints=3, trials=10_000, seed=0, sensors="all", condition="error"))
    library = PatternLibrary(vocabulary=arm_vocabulary(3))
    got = online_correct(library, run.to_episode())[5000:].mean()
    ceiling = arm_oracle_correct(run)[5000:].mean()
    assert got >= ceiling - 0.02


@pytest.mark.parametrize("kwargs, message", [
    ({"joints": 0}, "joints must be an integer in 1..4"),
    ({"joints": 5}, "joints must be an integer in 1..4"),
    ({"trials": 0}, "trials must be an integer >= 1"),
    ({"seed": -1}, "seed must be an integer >= 0"),
    ({"sensors": "some"}, "sensors 'some' is unknown"),
    ({"condition": "delay"}, "condition 'delay' is unknown"),
    ({"condition": "error", "error_deg": 11.0}, r"error_deg must be a number in \[0, 10\]"),
])
def test_bad_config(kwargs, message):
    with pytest.raises(InputError, match=message):
        ArmConfig(**kwargs)


def test_existing_file_is_refused(tmp_path):
    path = tmp_path / "a.mcap"
    path.write_bytes(b"x")
    with pytest.raises(InputError, match="already exists"):
        record_arm(ArmConfig(trials=10), path)
    assert path.read_bytes() == b"x"


def test_bench_arm_smoke():
    import importlib.util
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
    path = Path(__file__).resolve().parents[1] / "bench" / "bench_arm.py"
    spec = importlib.util.spec_from_file_location("bench_arm", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    results = bench.run(trials=2000, seeds=1, max_length=5, layouts=["moved"])
    assert [r["joints"] for r in results] == [1, 2, 3, 4]
    assert results[0]["accuracy"][-1] == 1.0 and len(results[0]["accuracy"]) == 2
    assert all(r["accuracy"][-1] > 0.9 for r in results)  # every joint from its own reading
    assert len(bench.render(results).splitlines()) == 2 + 4


@pytest.mark.parametrize("args, digest", [((3, 2000, 2, "all"), "d677959385ed2555"),
                                          ((4, 2000, 1, "moved"), "c3b7653730b93c17")])
def test_simple_arm_is_unchanged_seed_for_seed(args, digest):
    """Digests of the arm before the error condition existed."""
    run = simulate_arm(ArmConfig(*args))
    data = run.positions.tobytes() + run.joint.tobytes() + run.commands.tobytes()
    assert hashlib.sha256(data).hexdigest()[:16] == digest
    assert set(run.config.parameters()) == {"joints", "trials", "seed", "sensors"}
    assert arm_oracle_correct(run).all()


def test_error_moves_the_commanded_joint_with_noise_and_nothing_else():
    run = simulate_arm(ArmConfig(joints=3, trials=3000, seed=4, condition="error", error_deg=5.0))
    turns = -((-np.diff(run.angles, axis=0) + 180) % 360 - 180)
    moved = turns[np.arange(3000), run.joint] * np.where(run.commands == 1, 1, -1)
    assert moved.min() >= 5 and moved.max() <= 15 and moved.max() > 14.5
    turns[np.arange(3000), run.joint] = 0
    assert (turns == 0).all()  # the other joints stand still
    np.testing.assert_array_equal(run.positions, np.floor(run.angles / 10).astype(int) % 36 + 1)
    assert run.config.parameters()["condition"] == "error"


@pytest.mark.parametrize("sensors", SENSORS)
def test_error_arm_ceiling_is_the_pointer_ceiling(sensors):
    run = simulate_arm(ArmConfig(joints=2, trials=6000, seed=1, sensors=sensors,
                                 condition="error"))
    ceiling = arm_oracle_correct(run)
    assert len(ceiling) == 6000 and 0.72 <= ceiling.mean() <= 0.79
    one = simulate_arm(ArmConfig(joints=1, trials=2000, condition="error", error_deg=0.0))
    assert arm_oracle_correct(one).all()  # no noise: exact


def test_error_arm_recording_reads_back_as_the_in_memory_episode(tmp_path):
    config = ArmConfig(joints=2, trials=200, seed=3, sensors="all", condition="error")
    record_arm(config, tmp_path / "arm.mcap")
    [(_, episode, _)] = read_episodes([tmp_path / "arm.mcap"], arm_spec(2), Vocabulary())
    assert np.array_equal(episode.symbols, simulate_arm(config).to_episode().symbols)
