"""``slearn control``: steer the simulated pointer to goals with a library (see :mod:`slearn.control`)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import click

from slearn.control import (DEFAULT_BUDGET, OFFLINE_TRIALS, ControlConfig, ControlResult, Summary,
                            run_control, write_control_mcap)
from slearn.cli.limits import MAX_GOALS, MAX_STEPS, MAX_TRIALS, FiniteFloat
from slearn.files import check_output
from slearn.planner import PlannerSettings
from slearn.recorders.pointer import CONDITIONS, N_BINS


@click.command("control")
@click.option("--library", "library_path", type=click.Path(path_type=Path),
              default=None, help="Library to start from (default: learn one offline from random trials).")
@click.option("--condition", type=click.Choice(CONDITIONS), required=True, help="Pointer dynamics.")
@click.option("--goals", type=click.IntRange(1, MAX_GOALS), default=100, show_default=True,
              help="Random goals to reach one after another.")
@click.option("--goal", type=click.IntRange(1, N_BINS), default=None,
              help="Reach this one position label instead.")
@click.option("--seed", type=click.IntRange(0), default=0, show_default=True, help="Seed of everything.")
@click.option("--budget", type=click.IntRange(1, MAX_STEPS), default=DEFAULT_BUDGET, show_default=True,
              help="Steps allowed per goal.")
@click.option("--blocks", type=click.IntRange(1, MAX_GOALS), default=10, show_default=True,
              help="Report the goals in this many blocks (the recovery curve).")
@click.option("--switch-goal", type=click.IntRange(0, MAX_GOALS), default=None,
              help="reversal/scramble: the goal at which the world changes (default: halfway).")
@click.option("--trials", type=click.IntRange(1, MAX_TRIALS), default=OFFLINE_TRIALS, show_default=True,
              help="Random trials learned offline without --library (and the Q-learner's data).")
@click.option("--order", type=click.IntRange(0, 4), default=PlannerSettings.order, show_default=True,
              help="Steps of history in a planning state.")
@click.option("--half-life", type=FiniteFloat(0), default=0.0, show_default=True,
              help="Fade library weights with this half-life in steps (0: never).")
@click.option("--no-qlearning", is_flag=True, help="Skip the Q-learning baseline.")
@click.option("--record", "record_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Log the run to this MCAP file (pointer channels and /pointer/goal).")
@click.option("--force", is_flag=True, help="Overwrite an existing --record file.")
@click.option("--json", "as_json", is_flag=True, help="Print the result as one JSON document.")
def command(library_path, condition, goals, goal, seed, budget, blocks, switch_goal, trials, order,
            half_life, no_qlearning, record_path, force, as_json):
    """Steer the simulated pointer to random goals in closed loop, learning as it goes."""
    if record_path is not None:
        check_output(record_path, force, inputs=[library_path] if library_path else [])
    config = ControlConfig(condition, goals, seed, budget, goal, switch_goal, blocks, trials,
                           qlearning=not no_qlearning, planner=PlannerSettings(order=order, half_life=half_life))
    result = run_control(config, *_load(library_path))
    if record_path is not None:
        write_control_mcap(result, record_path, overwrite=force)
        click.echo(f"slearn control: wrote {record_path}", err=True)
    click.echo(json.dumps(result.to_dict()) if as_json else render(result))


def _load(path: Path | None):
    if path is None:
        return None, None, None
    from slearn.storage import load_library  # pyarrow is imported only when a library is given

    loaded = load_library(path)
    return loaded.library, loaded.vocabulary, str(path)


def _percent(x: float) -> str:
    return "    - " if math.isnan(x) else f"{100 * x:5.1f} %"


def _number(x: float) -> str:
    return "    -" if x is None or math.isnan(x) else f"{x:5.2f}"


def _row(name: str, s: Summary) -> str:
    return (f"{name:<12} {s.goals:>5} {_percent(s.success)} {_percent(s.within_1_1x)} "
            f"{_percent(s.within_2x)} {_percent(s.within_3x)}   {_number(s.steps_ratio)}   "
            f"{_number(s.mean_steps)} {_number(s.mean_shortest)}")


def render(result: ControlResult) -> str:
    """The result as a text report."""
    c = result.config
    lines = [f"slearn control: pointer {c.condition}, seed {c.seed}, {c.n_goals} goal(s), "
             f"budget {c.budget} steps per goal",
             f"library: {result.library_source}; {result.patterns_before} -> {result.patterns_after} "
             f"patterns (+{result.patterns_after - result.patterns_before} learned online in "
             f"{result.steps} steps)",
             "",
             f"{'':<12} goals  reached  <=1.1x    <=2x    <=3x   steps/shortest  mean  shortest",
             _row("slearn", result.slearn)]
    if result.qlearning is not None:
        q = result.qlearning
        lines += [_row("q-learning", q.new_goals), "",
                  f"q-learning trained for goal {q.trained_goal}: {_percent(q.trained_goal_success)} "
                  "reached from random starts; new goals make that experience obsolete"]
    lines += ["", f"planning: {result.plan_ms_per_step:.2f} ms per step, "
                  f"{result.slearn.explored_steps} curious steps"]
    if len(result.blocks) > 1:
        lines += ["", *_block_lines(result)]
    return "\n".join(lines)


def _block_lines(result: ControlResult) -> list[str]:
    switch = result.config.switch_at
    title = "per block of goals" + (f" (the world changes at goal {switch}, marked *)" if switch is not None else "")
    lines = [title, f"  {'goals':<11} reached    <=2x  steps/shortest  patterns"]
    for i, block in enumerate(result.blocks):
        last = result.blocks[i + 1].first_goal - 1 if i + 1 < len(result.blocks) else result.config.n_goals - 1
        mark = "*" if block.after_switch else " "
        s = block.summary
        lines.append(f"{mark} {block.first_goal:>4}-{last:<5} {_percent(s.success)} {_percent(s.within_2x)}"
                     f"   {_number(s.steps_ratio)}        {block.patterns:>6}")
    return lines
