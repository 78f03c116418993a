"""``slearn control``: steer a discrete system to goals, slearn next to honest peers
(see :mod:`slearn.control.closed_loop`)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import click

from slearn.cli.limits import MAX_GOALS, MAX_STEPS, MAX_TRIALS, FiniteFloat
from slearn.control.closed_loop import (
    AGENTS,
    DEFAULT_BUDGET,
    EXTRA_AGENTS,
    OFFLINE_TRIALS,
    ControlConfig,
    ControlResult,
    Summary,
    run_control,
    write_control_mcap,
)
from slearn.control.envs import parse_env_args
from slearn.control.planner import PlannerSettings
from slearn.io.files import check_output
from slearn.recorders.pointer import CONDITIONS


@click.command("control")
@click.option("--env", "env_spec", default=None, metavar="pointer:CONDITION|gymnasium:ID",
              help="The system: the simulated pointer, or a Gymnasium env with Discrete spaces "
                   "(gymnasium:FrozenLake-v1; needs the gym extra).")
@click.option("--env-arg", "env_args", multiple=True, metavar="NAME=VALUE",
              help="Argument of the environment (map_name=8x8, is_slippery=true; pointer: bins=72).")
@click.option("--condition", type=click.Choice(CONDITIONS), default=None,
              help="Shorthand for --env pointer:CONDITION.")
@click.option("--library", "library_path", type=click.Path(path_type=Path), default=None,
              help="Library slearn starts from (it learns the exploration too).")
@click.option("--goals", type=click.IntRange(1, MAX_GOALS), default=100, show_default=True,
              help="Goals to reach one after another.")
@click.option("--goal", "goal", type=click.IntRange(0), multiple=True,
              help="Reach this observation (repeat: any of them) instead of random ones; "
                   "pursued once, or --goals times with --repeat-goal.")
@click.option("--repeat-goal", is_flag=True, help="Pursue --goal --goals times (episode after episode).")
@click.option("--seed", type=click.IntRange(0), default=0, show_default=True, help="Seed of everything.")
@click.option("--budget", type=click.IntRange(1, MAX_STEPS), default=DEFAULT_BUDGET, show_default=True,
              help="Steps allowed per goal.")
@click.option("--blocks", type=click.IntRange(1, MAX_GOALS), default=10, show_default=True,
              help="Report the goals in this many blocks (the recovery curve).")
@click.option("--switch-goal", type=click.IntRange(0, MAX_GOALS), default=None,
              help="pointer reversal/scramble: the goal at which the world changes (default: halfway).")
@click.option("--trials", type=click.IntRange(0, MAX_TRIALS), default=OFFLINE_TRIALS, show_default=True,
              help="Random exploration steps every agent learns from.")
@click.option("--directed", type=click.IntRange(0, MAX_TRIALS), default=0, show_default=True,
              help="Then at most this many steps toward actions not tried yet.")
@click.option("--agents", default=",".join(AGENTS), show_default=True,
              help=f"Comma-separated agents ({', '.join(AGENTS + EXTRA_AGENTS)}).")
@click.option("--order", type=click.IntRange(0, 4), default=None,
              help="Steps of history in a planning state (default: 1 on the pointer, 0 on Gymnasium).")
@click.option("--half-life", type=FiniteFloat(0), default=0.0, show_default=True,
              help="Fade library weights with this half-life in steps (0: never).")
@click.option("--record", "record_path", type=click.Path(path_type=Path), default=None,
              help="Log slearn's run to this MCAP file (action, observation and goal channels).")
@click.option("--force", is_flag=True, help="Overwrite an existing --record file.")
@click.option("--json", "as_json", is_flag=True, help="Print the result as one JSON document.")
def command(env_spec, env_args, condition, library_path, goals, goal, repeat_goal, seed, budget, blocks,
            switch_goal, trials, directed, agents, order, half_life, record_path, force, as_json):
    """Steer a discrete system to goal observations in closed loop, next to honest peers.

    Every agent learns from the same exploration: slearn, an optimistic count model,
    goal-conditioned Q-learning, and Q-learning trained for one goal (the paper's argument).
    """
    if (env_spec is None) == (condition is None):
        raise click.UsageError("give --env or --condition (pointer shorthand), not both or neither")
    if repeat_goal and not goal:
        raise click.UsageError("--repeat-goal needs --goal")
    if record_path is not None:
        check_output(record_path, force, inputs=[library_path] if library_path else [])
    config = ControlConfig(env_spec or f"pointer:{condition}", tuple(parse_env_args(list(env_args)).items()),
                           goals, seed, budget, tuple(goal) or None, repeat_goal, switch_goal, blocks,
                           trials, directed, tuple(a.strip() for a in agents.split(",") if a.strip()))
    if order is not None or half_life:
        defaults = config.planner_settings
        config = ControlConfig(**{**config.__dict__, "planner": PlannerSettings(
            order=defaults.order if order is None else order, horizon=defaults.horizon,
            prior=defaults.prior, half_life=half_life)})
    result = run_control(config, *_load(library_path), warn=lambda text: click.echo(text, err=True))
    if record_path is not None:
        write_control_mcap(result, config.make_env(), record_path, overwrite=force)
        click.echo(f"slearn control: wrote {record_path}", err=True)
    click.echo(json.dumps(result.to_dict()) if as_json else render(result))


def _load(path: Path | None):
    if path is None:
        return None, None, None
    from slearn.io.library_file import load_library  # pyarrow is imported only when a library is given

    loaded = load_library(path)
    return loaded.library, loaded.vocabulary, str(path)


def _percent(x: float) -> str:
    return "    - " if x is None or math.isnan(x) else f"{100 * x:5.1f} %"


def _number(x: float) -> str:
    return "    -" if x is None or math.isnan(x) else f"{x:5.2f}"


def _row(name: str, s: Summary) -> str:
    return (f"{name:<28} {s.goals:>5} {_percent(s.success)} {_percent(s.within_1_05x)} "
            f"{_percent(s.within_2x)} {_percent(s.within_3x)}   {_number(s.steps_ratio)}")


def render(result: ControlResult) -> str:
    """The result as a text report."""
    c = result.config
    lines = [f"slearn control: {result.env_name}, seed {c.seed}, {c.n_goals} goal(s), "
             f"budget {c.budget} steps per goal",
             f"exploration: {result.exploration_steps} steps shared by every agent; slearn's library: "
             f"{result.library_source}, {result.patterns_before} -> {result.patterns_after} patterns",
             "",
             f"{'':<28} goals  reached  <=1.05x    <=2x    <=3x   steps/shortest",
             *[_row(a.label, a.summary) for a in result.agents]]
    slearn = result.agent("slearn")
    if slearn is not None:
        lines += ["", f"slearn planning: {slearn.ms_per_step:.2f} ms per step, "
                      f"{slearn.summary.explored_steps} exploring steps"]
    if result.agent("q-one-goal") is not None:
        lines += ["Q, one goal: trained for one goal, then given new ones (the paper's argument)"]
    for agent in result.agents:
        if agent.summary.goals < c.n_goals:
            lines += [f"{agent.label}: {c.n_goals - agent.summary.goals} goal(s) already reached where it "
                      f"started are left out of its rates"]
    if len(result.agents[0].blocks) > 1:
        lines += ["", *_block_lines(result)]
    return "\n".join(lines)


def _block_lines(result: ControlResult) -> list[str]:
    switch = result.config.switch_at
    title = "goals reached per block" + (f" (the world changes at goal {switch}, marked *)"
                                         if switch is not None else "")
    names = [a.name for a in result.agents]
    lines = [title, f"  {'goals':<11} " + " ".join(f"{n:>12}" for n in names)]
    for i, block in enumerate(result.agents[0].blocks):
        last = (result.agents[0].blocks[i + 1].first_goal - 1 if i + 1 < len(result.agents[0].blocks)
                else result.config.n_goals - 1)
        mark = "*" if block.after_switch else " "
        cells = " ".join(f"{_percent(a.blocks[i].summary.success):>12}" for a in result.agents)
        lines.append(f"{mark} {block.first_goal:>4}-{last:<5} {cells}")
    return lines
