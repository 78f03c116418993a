"""Closed-loop control on the pointer: the step-wise env, slearn against its peers, the CLI."""

import json

import numpy as np
import pytest
from click.testing import CliRunner
from mcap.reader import make_reader

from slearn.cli import main
from slearn.control.agents import CountModelAgent, GoalQAgent, SlearnAgent, explore
from slearn.control.closed_loop import ControlConfig, goal_sequence, run_control
from slearn.control.envs import PointerEnv, parse_env_args
from slearn.core.library import PatternLibrary
from slearn.core.stream import Episode
from slearn.errors import InputError
from slearn.recorders.pointer import PointerConfig, pointer_vocabulary, simulate


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
    assert env.shortest((label,)) == 0


def test_env_shortest_moves():
    assert PointerEnv("simple", start_bin=1).shortest((36,)) == 2  # around the circle
    assert PointerEnv("hardstop", start_bin=1).shortest((36,)) == 34  # not across the stop
    assert PointerEnv("hardstop", start_bin=1).shortest((36, 4)) == 2  # the nearer goal
    assert PointerEnv("hardstop", start_bin=70, bins=72).shortest((1,)) == 70
    env = PointerEnv("hardstop", start_bin=0)
    assert env.step(0) == 1  # blocked at the stop


def test_env_rejects_bad_parameters():
    with pytest.raises(InputError):
        PointerEnv("sideways")
    with pytest.raises(InputError):
        PointerEnv("error", error_deg=20.0)
    with pytest.raises(InputError):
        PointerEnv("simple", bins=5)
    with pytest.raises(InputError):
        run_control(ControlConfig("pointer:simple", goal=(37,), trials=10))
    with pytest.raises(InputError):
        ControlConfig("pointer:simple", agents=("slearn", "oracle"))


def test_goal_sequence_is_seeded_and_changes_every_time():
    config = ControlConfig("pointer:simple", goals=500, seed=3)
    goals = goal_sequence(config, list(range(1, 37)), 7)
    assert goals == goal_sequence(config, list(range(1, 37)), 7)
    assert goals[0] != (7,) and all(a != b for a, b in zip(goals, goals[1:]))
    assert {g for (g,) in goals} == set(range(1, 37))
    assert goal_sequence(ControlConfig("pointer:simple", goal=(17,)), [], 4) == [(17,)]


def _run(condition, goals, seed, **kwargs):
    return run_control(ControlConfig(f"pointer:{condition}", goals=goals, seed=seed, **kwargs))


@pytest.mark.parametrize("condition,seed", [("simple", 11), ("hardstop", 12)])
def test_deterministic_conditions_reach_every_goal_by_the_shortest_route(condition, seed):
    result = _run(condition, 40, seed, agents=("slearn", "count-model"))
    for agent in result.agents:
        assert agent.summary.success == 1.0 and agent.summary.steps_ratio <= 1.05, agent.name
    assert result.patterns_after >= result.patterns_before


def test_slearn_reaches_as_many_goals_as_its_peers_on_delay():
    result = _run("delay", 60, 14, trials=5_000, agents=("slearn", "count-model", "goal-q"))
    slearn, model, q = (result.agent(n).summary for n in ("slearn", "count-model", "goal-q"))
    assert slearn.success == 1.0 and slearn.within_3x >= 0.9
    assert slearn.success >= model.success and slearn.success >= q.success


@pytest.mark.parametrize("condition", ["reversal", "scramble"])
def test_control_recovers_right_after_the_switch(condition):
    result = _run(condition, 60, 15, blocks=6, trials=5_000, agents=("slearn",))
    blocks = result.agent("slearn").blocks
    after = [b for b in blocks if b.after_switch]
    assert len(after) == 3
    assert all(b.summary.success == 1.0 for b in blocks)  # the block right after the switch too
    assert result.patterns_after > result.patterns_before


def test_72_bin_hardstop_reaches_labels_exploration_never_saw():
    config = ControlConfig("pointer:hardstop", (("bins", 72),), goals=30, seed=0, trials=3_000,
                           agents=("slearn",))
    from slearn.control.closed_loop import exploration

    seen = set(exploration(config).observations.tolist())
    result = run_control(config)
    unseen = [o for o in result.agent("slearn").outcomes if o.goal[0] not in seen]
    assert unseen, "the exploration should leave labels unvisited"
    assert result.slearn.success == 1.0 and result.slearn.explored_steps > 0


def test_a_library_that_never_saw_one_command_follows_known_routes_and_discovers_it():
    library = PatternLibrary()
    positions = list(range(1, 37)) + [36] * 20  # R only, from 1 up to the hard stop
    library.learn(Episode.from_pairs([positions[0] + 1], [1] * (len(positions) - 1),
                                     [p + 1 for p in positions[1:]]))
    result = run_control(ControlConfig("pointer:hardstop", goals=40, seed=0, blocks=4, trials=0,
                                       agents=("slearn",)), library)
    assert result.slearn.success == 1.0 and result.slearn.explored_steps > 0
    last = result.agent("slearn").blocks[-1].summary
    assert last.steps_ratio <= 1.1 and last.explored_steps == 0


def test_single_goal_q_fails_new_goals_where_goal_conditioned_q_does_not():
    result = _run("simple", 40, 16, agents=("goal-q", "q-one-goal"))
    assert result.agent("q-one-goal").summary.success < 0.8 <= result.agent("goal-q").summary.success


def test_agents_work_from_a_users_own_loop():
    env = PointerEnv("simple", 2)
    log = explore(env, 2_000, np.random.default_rng(0))
    library = PatternLibrary()
    agents = [SlearnAgent(library, pointer_vocabulary(), env),
              CountModelAgent(37, 2, log, np.random.default_rng(1)),
              GoalQAgent(37, 2, log, np.random.default_rng(2), epsilon=0.0)]
    agents[0].learn(log)
    for agent in agents:
        goal = (env.observation + 17) % 36 + 1
        for _ in range(30):
            if env.observation == goal:
                break
            agent.observe(env.step(agent.act(env.observation, (goal,))))
        assert env.observation == goal, agent.name


def test_count_model_resets_a_pair_the_world_contradicts():
    env = PointerEnv("reversal", 1, start_bin=10)
    log = explore(env, 3_000, np.random.default_rng(0))
    model = CountModelAgent(37, 2, log, np.random.default_rng(0))
    env.switch()
    state = env.observation
    model.act(state, (state + 1,))
    model.observe(env.step(model.action))
    assert model.resets == 1 and model.counts[state, model.action].sum() == 1.0


def test_a_given_library_keeps_learning():
    library = PatternLibrary()
    library.learn(simulate(PointerConfig("simple", 3_000, 4)).to_episode())
    before = library.clock
    result = run_control(ControlConfig("pointer:simple", goals=10, seed=4, trials=0, agents=("slearn",)),
                         library, pointer_vocabulary(), "test")
    assert result.library_source == "test"
    assert library.clock == before + len(result.trace.actions) + 1  # and the first reading


def test_env_args_parse():
    assert parse_env_args(["map_name=8x8", "is_slippery=true", "bins=72", "p=0.5"]) == {
        "map_name": "8x8", "is_slippery": True, "bins": 72, "p": 0.5}
    with pytest.raises(InputError):
        parse_env_args(["novalue"])


def _cli(*args):
    return CliRunner().invoke(main, ["control", *map(str, args)])


def test_cli_json_is_one_document():
    out = _cli("--condition", "simple", "--goals", "5", "--seed", "1", "--trials", "3000", "--json")
    assert out.exit_code == 0, out.stderr
    doc = json.loads(out.stdout)
    names = [a["name"] for a in doc["agents"]]
    assert names == ["slearn", "count-model", "goal-q", "q-one-goal"]
    assert doc["agents"][0]["summary"]["success"] == 1.0 and len(doc["agents"][0]["outcomes"]) == 5
    assert doc["patterns_after"] >= doc["patterns_before"]


def test_cli_text_and_single_goal():
    out = _cli("--condition", "hardstop", "--goal", "17", "--seed", "2", "--trials", "3000")
    assert out.exit_code == 0, out.stderr
    assert "slearn control: pointer hardstop" in out.stdout and "goal-conditioned Q" in out.stdout
    assert "the paper's argument" in out.stdout


def test_cli_usage_errors():
    assert _cli("--goals", "3").exit_code == 2  # neither --env nor --condition
    assert _cli("--condition", "simple", "--env", "pointer:simple").exit_code == 2
    out = _cli("--env", "robot:arm")
    assert out.exit_code == 1 and out.stderr.startswith("slearn: error:") and "\n" == out.stderr[-1]
    out = _cli("--condition", "simple", "--agents", "slearn,magic", "--goals", "2")
    assert out.exit_code == 1 and "magic" in out.stderr


def test_cli_records_the_episode_with_the_goal_channel(tmp_path):
    path = tmp_path / "run.mcap"
    out = _cli("--condition", "simple", "--goals", "3", "--seed", "3", "--trials", "2000",
               "--agents", "slearn", "--json", "--record", path)
    assert out.exit_code == 0, out.stderr
    doc = json.loads(out.stdout)
    with open(path, "rb") as f:
        messages = list(make_reader(f).iter_messages())
    topics = [channel.topic for _, channel, _ in messages]
    assert topics.count("/pointer/goal") == 3
    steps = sum(o["steps"] for o in doc["agents"][0]["outcomes"])
    assert topics.count("/pointer/command") == steps and topics.count("/pointer/position") == steps + 1
    goals = [json.loads(m.data)["goal"] for _, c, m in messages if c.topic == "/pointer/goal"]
    assert goals == [o["goal"] for o in doc["agents"][0]["outcomes"]]
    again = _cli("--condition", "simple", "--goals", "3", "--record", path)
    assert again.exit_code == 1 and "already exists" in again.stderr
    learned = CliRunner().invoke(main, ["learn", str(path), "-o", str(tmp_path / "lib.parquet"), "-q"])
    assert learned.exit_code == 0, learned.stderr  # a control log is a pointer log like any other
    out = _cli("--library", tmp_path / "lib.parquet", "--condition", "simple", "--goals", "5",
               "--trials", "0", "--agents", "slearn", "--json")
    assert out.exit_code == 0, out.stderr
    assert json.loads(out.stdout)["agents"][0]["summary"]["success"] == 1.0  # learned from the log alone


def test_cli_refuses_a_bad_library(tmp_path):
    bad = tmp_path / "bad.parquet"
    bad.write_bytes(b"not a library")
    out = _cli("--library", bad, "--condition", "simple", "--goals", "5")
    assert out.exit_code == 1 and out.stderr.startswith("slearn: error:")


def test_cli_refuses_a_library_of_another_system(tmp_path):
    log = tmp_path / "p.mcap"
    assert CliRunner().invoke(main, ["record", "pointer", "--condition", "simple", "--trials", "300",
                                     "-o", str(log)]).exit_code == 0
    assert CliRunner().invoke(main, ["learn", str(log), "-o", str(tmp_path / "lib.parquet"), "-q"]).exit_code == 0
    for args, message in ((["--env-arg", "bins=72"], "its '/pointer/position' has 36 values, this pointer 72 bins"),
                          (["--env", "gymnasium:FrozenLake-v1"], "not this environment's action channel '/env/action'")):
        env = [] if "--env" in args else ["--condition", "simple"]
        out = _cli("--library", tmp_path / "lib.parquet", *env, *args, "--goals", "2", "--agents", "slearn")
        assert out.exit_code == 1 and message in out.stderr and out.stderr.count("\n") == 1, out.stderr


def test_a_goal_already_reached_is_left_out_of_the_rates():
    start = PointerEnv("simple", 8).observation
    result = run_control(ControlConfig("pointer:simple", goal=(start,), seed=8, trials=0, agents=("slearn",)))
    assert result.agents[0].outcomes[0].steps == 0 and result.slearn.goals == 0
    from slearn.cli.control import render
    assert "slearn: 1 goal(s) already reached where it started are left out of its rates" in render(result)
    assert result.to_dict()["agents"][0]["summary"]["success"] is None
