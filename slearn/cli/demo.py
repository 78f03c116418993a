"""``slearn demo``: reproduce the paper's Figure 2 (see :mod:`slearn.jobs.demo`)."""

from __future__ import annotations

import json
import time
from pathlib import Path

import click

from slearn.io.files import claim_folder, release_folder, write_atomic
from slearn.jobs.demo import PAPER, RULES, DemoResult, run_demo
from slearn.recorders.pointer import CONDITIONS

# What the demo writes in its folder; a rerun after a killed run replaces these.
OUTPUTS = ("logs", "libraries", "figure2.png", "summary.json")


@click.command("demo")
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default=None,
              help="Folder for the logs, libraries, figure and summary (default: a new "
                   "slearn-demo-<time> folder here). It must be new or empty, or left by a "
                   "killed demo run (which is then redone).")
@click.option("--seeds", type=click.IntRange(1, 100), default=5, show_default=True,
              help="Seeds to average over (first-seed, first-seed + 1, ...).")
@click.option("--first-seed", type=click.IntRange(0), default=0, show_default=True)
@click.option("--trials", type=click.IntRange(1000, 1_000_000), default=10_000, show_default=True)
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON only.")
@click.option("--quiet", is_flag=True, help="No progress on stderr.")
def command(out_dir, seeds, first_seed, trials, as_json, quiet):
    """Record the pointer's six conditions, learn them online, and print Figure 2."""
    out = _fresh_folder(out_dir)
    started = time.perf_counter()

    def progress(condition):
        if not quiet:
            click.echo(f"  {condition.condition:<9} done in {condition.seconds:.2f} s", err=True)

    if not quiet:
        click.echo(f"slearn demo: {len(CONDITIONS)} conditions x {seeds} seeds x {trials} trials -> {out}",
                   err=True)
    result = run_demo(out, list(range(first_seed, first_seed + seeds)), trials, on_condition=progress)
    _write_outputs(result)
    release_folder(out)
    result.seconds = time.perf_counter() - started
    if as_json:
        click.echo(json.dumps(result.to_dict(), indent=2))
    else:
        click.echo(render_table(result))


def _fresh_folder(out_dir: str | None) -> Path:
    """The output folder, claimed: a killed run leaves it marked, and a rerun redoes it."""
    if out_dir is None:
        base = Path(f"slearn-demo-{time.strftime('%Y%m%d-%H%M%S')}")
        out, n = base, 1
        while out.exists():
            n += 1
            out = Path(f"{base}-{n}")
        return claim_folder(out)
    return claim_folder(out_dir, owned=OUTPUTS, advice="choose a new --out folder so nothing is overwritten")


def _write_outputs(result: DemoResult) -> None:
    from slearn.jobs.figure2 import plot_figure2

    out = Path(result.out_dir)
    result.figure_path = str(out / "figure2.png")
    plot_figure2(result, result.figure_path)
    result.summary_path = str(out / "summary.json")
    write_atomic(result.summary_path, json.dumps(result.to_dict(), indent=2) + "\n")


def render_table(result: DemoResult) -> str:
    """Figure 2 as text: percent accurate per thousand trials, per condition and scoring."""
    n = len(result.conditions[0].ceiling)
    head = f"{'condition':<9} {'scoring':<8} " + " ".join(f"{i + 1:>5}" for i in range(n))
    lines = [f"Percent accurate predictions per thousand trials (abstentions count as wrong), "
             f"mean over seeds {result.seeds[0]}-{result.seeds[-1]}", "", head, "-" * len(head)]
    for c in result.conditions:
        for rule in RULES:
            lines.append(f"{c.condition:<9} {rule:<8} " + " ".join(f"{x:5.1f}" for x in c.accuracy[rule]))
        lines.append(f"{'':<9} {'ceiling':<8} " + " ".join(f"{x:5.1f}" for x in c.ceiling))
        lines.append(f"{'':<9} {'paper':<8} {PAPER[c.condition]}")
    lines += ["", f"{'condition':<9} {'patterns':>8} {'memory':>10} {'file':>10}  time"]
    for c in result.conditions:
        lines.append(f"{c.condition:<9} {c.patterns:>8} {_kb(c.library_bytes):>10} "
                     f"{_kb(c.library_file_bytes):>10}  {c.seconds:.2f} s")
    lines += ["", f"figure:  {result.figure_path}", f"summary: {result.summary_path}",
              f"logs and libraries (seed {result.seeds[0]}): {result.out_dir}",
              f"total time: {result.seconds:.1f} s"]
    return "\n".join(lines)


def _kb(n: int) -> str:
    return f"{n / 1024:.1f} kB" if n else "-"
