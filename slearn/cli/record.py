"""``slearn record``: write episodes into MCAP files (one group, a subcommand per source)."""

from __future__ import annotations

import json
from pathlib import Path

import click

from slearn.errors import InputError
from slearn.recorders.pointer import CONDITIONS, PointerConfig
from slearn.recorders.record_pointer import RecordSummary, record_pointer


@click.group(name="record")
def command() -> None:
    """Record episodes into MCAP files."""


@command.command("pointer")
@click.option("--condition", type=click.Choice(CONDITIONS), required=True,
              help="Pointer dynamics (the paper's six conditions).")
@click.option("--trials", type=int, default=10_000, show_default=True, help="Number of trials.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of all randomness.")
@click.option("--switch-trial", type=int, default=5_000, show_default=True,
              help="First trial of the scramble or reversal.")
@click.option("--error-deg", type=float, default=5.0, show_default=True,
              help="Half-width of the uniform move error (error).")
@click.option("--delay-prob", type=float, default=0.5, show_default=True,
              help="Chance that a command is delayed by one trial (delay).")
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="The MCAP file to write.")
@click.option("--force", is_flag=True, help="Overwrite an existing output file.")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as one JSON document.")
def pointer(condition: str, trials: int, seed: int, switch_trial: int, error_deg: float,
            delay_prob: float, output: Path, force: bool, as_json: bool) -> None:
    """Record one simulated rotary-pointer episode."""
    if output.exists() and not force:
        raise InputError(f"{output} already exists: pass --force to overwrite it")
    config = PointerConfig(condition, trials, seed, switch_trial, error_deg, delay_prob)
    summary = record_pointer(config, output, overwrite=force)
    click.echo(json.dumps(summary.to_dict()) if as_json else _summary_line(summary))


def _summary_line(summary: RecordSummary) -> str:
    messages = sum(summary.messages.values())
    return (f"wrote {summary.path}: pointer {summary.condition}, seed {summary.seed}, "
            f"{summary.trials} trials, {messages} messages, {summary.size_bytes / 1024:.0f} KiB")
