"""Closed-loop control: the step-wise pointer, acceptance per condition, Q-learning, the CLI."""

import json

import numpy as np
import pytest
from click.testing import CliRunner
from mcap.reader import make_reader

from slearn.cli import main
from slearn.control import (ControlConfig, PointerEnv, PointerSymbols, goal_sequence, offline_library,
                            run_control)
from slearn.errors import InputError
from slearn.library import PatternLibrary
from slearn.qlearning import QLearner
from slearn.recorders.pointer import PointerConfig, pointer_vocabulary, simulate
from slearn.stream import Episode
from slearn.vocabulary import Vocabulary


@pytest.mark.parametrize("condition", ["simple", "hardstop", "error", "delay"])
def test_env_replays_the_simulator_exactly(condition):
    run = simulate(PointerConfig(condition, 2_000, 5))
    env = PointerEnv(condition, 5)
    labels = [env.label] + [env.step(int(c)) for c in run.commands]
    assert labels == run.positions.tolist()
    assert env.steps == 2_000


def test_env_switches_reversal_and_scramble():
    env = PointerEnv("reversal", 1, start_bin=10)
    assert env.step(1) == 12
    env.switch()
    assert env.step(1) == 11 and env.step(0) == 12
    env = PointerEnv("scramble", 1, start_bin=10)
    env.switch()
    label = env.label
    assert label != 11 or env.bin_of_label(label) == 10
    assert env.bin_of_label(label) == 10
    assert env.shortest(label) == 0


def test_env_shortest_moves():
    assert PointerEnv("simple", start_bin=1).shortest(36) == 2  # around the circle
    assert PointerEnv("hardstop", start_bin=1).shortest(36) == 34  # not across the stop
    env = PointerEnv("hardstop", start_bin=0)
    assert env.step(0) == 1  # blocked at the stop


def test_env_rejects_bad_parameters():
    with pytest.raises(InputError):
        PointerEnv("sideways")
    with pytest.raises(InputError):
        PointerEnv("error", error_deg=20.0)
    with pytest.raises(InputError):
        ControlConfig("simple", goal=37)


def test_goal_sequence_is_seeded_and_changes_every_time():
    config = ControlConfig("simple", goals=500, seed=3)
    goals = goal_sequence(config, 7)
    assert goals == goal_sequence(config, 7)
    assert goals[0] != 7 and all(a != b for a, b in zip(goals, goals[1:]))
    assert set(goals) == set(range(1, 37))
    assert goal_sequence(ControlConfig("simple", goal=17), 4) == [17]


def test_pointer_symbols_need_the_pointer_channels():
    symbols = PointerSymbols.from_vocabulary(pointer_vocabulary())
    assert symbols.commands == (0, 1) and symbols.labels[16] == 18 and symbols.label_of(18) == 17
    with pytest.raises(InputError):
        PointerSymbols.from_vocabulary(Vocabulary())


def _run(condition, goals, seed, **kwargs):
    return run_control(ControlConfig(condition, goals=goals, seed=seed, **kwargs))


@pytest.mark.parametrize("condition,seed", [("simple", 11), ("hardstop", 12)])
def test_deterministic_conditions_reach_every_goal_by_the_shortest_route(condition, seed):
    result = _run(condition, 60, seed)
    assert result.slearn.success >= 0.99
    assert result.slearn.steps_ratio <= 1.1
    assert result.patterns_after >= result.patterns_before


def test_error_condition_reaches_goals_within_twice_the_shortest():
    result = _run("error", 100, 13, qlearning=False)
    assert result.slearn.within_2x >= 0.95


def test_delay_condition_reaches_goals_within_three_times_the_shortest():
    result = _run("delay", 100, 14, qlearning=False)
    assert result.slearn.within_3x >= 0.90


def test_control_recovers_after_the_reversal_as_the_library_relearns():
    result = _run("reversal", 80, 15, blocks=8, qlearning=False)
    before = [b for b in result.blocks if not b.after_switch]
    after = [b for b in result.blocks if b.after_switch]
    assert len(before) == len(after) == 4
    assert all(b.summary.success == 1.0 and b.summary.steps_ratio == 1.0 for b in before)
    assert after[0].summary.steps_ratio > 1.3  # the stale library misleads at first
    assert after[-1].summary.success == 1.0 and after[-1].summary.steps_ratio <= 1.2
    assert after[-1].patterns > before[-1].patterns  # relearned online


def test_a_library_that_never_saw_one_command_follows_known_routes_and_discovers_it():
    library = PatternLibrary()
    positions = list(range(1, 37)) + [36] * 20  # R only, from 1 up to the hard stop
    library.learn(Episode.from_pairs([positions[0] + 1], [1] * (len(positions) - 1),
                                     [p + 1 for p in positions[1:]]))
    result = run_control(ControlConfig("hardstop", goals=40, seed=0, blocks=4, qlearning=False), library)
    assert result.slearn.success == 1.0 and result.slearn.explored_steps > 0
    assert result.blocks[-1].summary.steps_ratio <= 1.1 and result.blocks[-1].summary.explored_steps == 0


def test_q_learning_masters_its_goal_but_not_new_ones():
    result = _run("simple", 60, 16)
    q = result.qlearning
    assert q.trained_goal_success >= 0.9
    assert q.new_goals.success < 0.8 < result.slearn.success


def test_q_learner_learns_a_fixed_goal_from_replayed_random_moves():
    run = simulate(PointerConfig("simple", 3_000, 2))
    learner = QLearner(36, 2, epsilon=0.0)
    positions = run.positions.astype(np.int64) - 1
    learner.train(positions[:-1], run.commands, positions[1:], goal=9)
    assert learner.q[5].argmax() == 1 and learner.q[14].argmax() == 0  # toward bin 9
    rng = np.random.default_rng(0)
    assert learner.act(5, rng) == 1


def test_a_given_library_keeps_learning():
    library, _ = offline_library(ControlConfig("simple", trials=3_000, seed=4))
    before = library.clock
    result = run_control(ControlConfig("simple", goals=10, seed=4, qlearning=False), library,
                         pointer_vocabulary(), "test")
    assert result.library_source == "test"
    assert library.clock == before + result.steps + 1  # and the first reading


def _cli(*args):
    return CliRunner().invoke(main, ["control", *map(str, args)])


def test_cli_json_is_one_document():
    out = _cli("--condition", "simple", "--goals", "5", "--seed", "1", "--trials", "3000", "--json")
    assert out.exit_code == 0, out.stderr
    doc = json.loads(out.stdout)
    assert doc["slearn"]["success"] == 1.0 and doc["qlearning"]["new_goals"]["goals"] >= 1
    assert len(doc["outcomes"]) == 5 and doc["patterns_after"] >= doc["patterns_before"]


def test_cli_text_and_single_goal():
    out = _cli("--condition", "hardstop", "--goal", "17", "--seed", "2", "--trials", "3000")
    assert out.exit_code == 0, out.stderr
    assert "slearn control: pointer hardstop" in out.stdout and "q-learning" in out.stdout


def test_cli_records_the_episode_with_the_goal_channel(tmp_path):
    path = tmp_path / "run.mcap"
    out = _cli("--condition", "simple", "--goals", "3", "--seed", "3", "--trials", "2000",
               "--no-qlearning", "--json", "--record", path)
    assert out.exit_code == 0, out.stderr
    doc = json.loads(out.stdout)
    with open(path, "rb") as f:
        messages = list(make_reader(f).iter_messages())
    topics = [channel.topic for _, channel, _ in messages]
    assert topics.count("/pointer/goal") == 3
    steps = sum(o["steps"] for o in doc["outcomes"])
    assert topics.count("/pointer/command") == steps and topics.count("/pointer/position") == steps + 1
    goals = [json.loads(m.data)["goal"] for _, c, m in messages if c.topic == "/pointer/goal"]
    assert goals == [o["goal"] for o in doc["outcomes"]]
    again = _cli("--condition", "simple", "--goals", "3", "--record", path)
    assert again.exit_code == 1 and "already exists" in again.stderr
    learned = CliRunner().invoke(main, ["learn", str(path), "-o", str(tmp_path / "lib.parquet"), "-q"])
    assert learned.exit_code == 0, learned.stderr  # a control log is a pointer log like any other


def test_cli_loads_a_saved_library(tmp_path):
    from slearn.storage import save_library

    library, _ = offline_library(ControlConfig("simple", trials=3_000, seed=5))
    path = tmp_path / "lib.parquet"
    save_library(path, library, pointer_vocabulary(), spec=None, params={"max_length": 5},
                 provenance={})
    out = _cli("--library", path, "--condition", "simple", "--goals", "5", "--no-qlearning")
    assert out.exit_code == 0, out.stderr
    assert str(path) in out.stdout
    bad = tmp_path / "bad.parquet"
    bad.write_bytes(b"not a library")
    out = _cli("--library", bad, "--condition", "simple", "--goals", "5")
    assert out.exit_code == 1 and out.stderr.startswith("slearn: error:")


def test_a_goal_already_reached_is_left_out_of_the_rates():
    start = PointerEnv("simple", 8).label
    result = run_control(ControlConfig("simple", goal=start, seed=8, trials=1_000, qlearning=False))
    assert result.outcomes[0].steps == 0 and result.slearn.goals == 0
    assert result.to_dict()["slearn"]["success"] is None
