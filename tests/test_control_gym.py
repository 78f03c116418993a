"""Control of Gymnasium environments with discrete spaces (real environments, small budgets)."""

import json

import pytest
from click.testing import CliRunner

from slearn.cli import main
from slearn.control.closed_loop import ControlConfig, goal_candidates, run_control
from slearn.control.envs import GymnasiumEnv, make_env
from slearn.errors import InputError

gymnasium = pytest.importorskip("gymnasium")

LAKE_4 = (("map_name", "4x4"), ("is_slippery", False))


def test_the_adapter_resets_after_an_ended_episode():
    env = GymnasiumEnv("FrozenLake-v1", dict(LAKE_4))
    assert env.observation == 0 and env.n_actions == 4 and env.n_observations == 16
    assert env.step(1) == 4 and env.step(1) == 8  # down, down
    assert env.step(2) == 9 and env.step(1) == 13 and env.step(2) == 14 and env.step(2) == 15  # the goal
    assert env.done and not env.failed
    assert env.step(3) == 0  # the next action is ignored: the episode restarts
    assert env.step(2) == 1 and env.step(1) == 5 and env.done and env.failed  # a hole
    assert env.describe(5) == "row 1, col 1 'H'" and env.shortest((15,)) == 7  # 5 -> 0 -> ... -> 15


def test_holes_are_not_goals_and_unreachable_cells_are_left_out():
    env = make_env("gymnasium:FrozenLake-v1", dict(LAKE_4))
    candidates = goal_candidates(env, None)
    assert sorted(candidates) == [0, 1, 2, 3, 4, 6, 8, 9, 10, 13, 14, 15]


def test_deterministic_lake_every_goal_by_the_shortest_path():
    result = run_control(ControlConfig("gymnasium:FrozenLake-v1", LAKE_4, goals=40, trials=300, directed=1_000,
                                       agents=("slearn", "count-model", "goal-q")))
    slearn = result.agent("slearn").summary
    assert slearn.goals >= 35 and slearn.success == 1.0 and slearn.within_1_05x == 1.0
    assert slearn.success >= result.agent("goal-q").summary.success


def test_cliff_walking_never_walks_off_the_cliff_for_long():
    result = run_control(ControlConfig("gymnasium:CliffWalking-v1", goals=20, trials=1_000, directed=2_000,
                                       agents=("slearn",)))
    assert result.slearn.success == 1.0 and result.slearn.within_1_05x == 1.0
    assert all(o.goal[0] < 37 or o.goal[0] == 47 for o in result.agents[0].outcomes)  # cliff cells never seen


def test_taxi_delivers_passenger_after_passenger():
    taxi = gymnasium.make("Taxi-v4").unwrapped
    delivered = tuple(int(taxi.encode(*taxi.locs[d], d, d)) for d in range(4))
    result = run_control(ControlConfig("gymnasium:Taxi-v4", goal=delivered, repeat_goal=True, goals=8,
                                       trials=2_000, directed=6_000, budget=200, agents=("slearn",)))
    assert result.slearn.goals == 8 and result.slearn.success == 1.0


def test_slippery_lake_is_close_to_value_iteration_on_the_true_model():
    config = ControlConfig("gymnasium:FrozenLake-v1", (("map_name", "4x4"), ("is_slippery", True)), goals=60,
                           trials=5_000, directed=1_000, agents=("slearn", "true-model"))
    result = run_control(config)
    slearn, truth = result.agent("slearn").summary, result.agent("true-model").summary
    assert truth.success > 0.5 and slearn.success >= truth.success - 0.1


@pytest.mark.parametrize("spec,args,message", [
    ("gymnasium:CartPole-v1", {}, "Box observation space"),
    ("gymnasium:NoSuchEnv-v0", {}, "doesn't exist"),
    ("gymnasium:FrozenLake-v1", {"colour": "blue"}, "rejects its arguments"),
    ("gymnasium:FrozenLake-v1", {"map_name": "99x99"}, r"rejects its arguments \(map_name=.99x99.\): KeyError"),
    ("arm:left", {}, "use pointer:CONDITION or gymnasium:ID"),
])
def test_bad_environments_are_one_line_errors(spec, args, message):
    with pytest.raises(InputError, match=message) as caught:
        make_env(spec, args)
    assert "\n" not in str(caught.value)


def test_cli_records_a_gymnasium_run_that_learn_reads_back(tmp_path):
    path = tmp_path / "lake.mcap"
    args = ["control", "--env", "gymnasium:FrozenLake-v1", "--env-arg", "map_name=4x4", "--env-arg",
            "is_slippery=false", "--goals", "10", "--trials", "300", "--directed", "1000", "--agents", "slearn"]
    out = CliRunner().invoke(main, [*args, "--record", str(path), "--json"])
    assert out.exit_code == 0, out.stderr
    assert json.loads(out.stdout)["agents"][0]["summary"]["success"] == 1.0
    learned = CliRunner().invoke(main, ["learn", str(path), "-o", str(tmp_path / "lib.parquet"), "-q",
                                        "--channel", "/env/action:action:action",
                                        "--channel", "/env/observation:observation:observation"])
    assert learned.exit_code == 0, learned.stderr
    again = CliRunner().invoke(main, [*args[:7], "--goals", "10", "--trials", "0", "--agents", "slearn",
                                      "--library", str(tmp_path / "lib.parquet"), "--json", "--seed", "1"])
    assert again.exit_code == 0, again.stderr
    assert json.loads(again.stdout)["agents"][0]["summary"]["success"] == 1.0  # the recorded run, then online


def test_cli_goal_out_of_range_or_never_seen():
    base = ["control", "--env", "gymnasium:FrozenLake-v1", "--env-arg", "is_slippery=false"]
    out = CliRunner().invoke(main, [*base, "--goal", "16"])
    assert out.exit_code == 1 and "goal 16 is not an observation of FrozenLake-v1" in out.stderr
    out = CliRunner().invoke(main, [*base, "--goal", "15", "--trials", "3", "--agents", "slearn"])
    assert out.exit_code == 0 and "never observed while exploring" in out.stderr


def test_the_readme_control_loop_runs_as_written():
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    section = text.split("## Control\n", 1)[1].split("\n## ", 1)[0]
    (example,) = re.findall(r"```python\n(.+?)\n```", section, flags=re.S)
    namespace = {}
    exec(compile(example, "README.md", "exec"), namespace)  # noqa: S102 - the README's own code
    assert namespace["env"].observation == 15
