"""``slearn record``: write episodes into MCAP files (one group, a subcommand per source)."""

from __future__ import annotations

import json
from pathlib import Path

import click

from slearn.cli.common import check_distinct_outputs
from slearn.cli.limits import MAX_TRIALS, FiniteFloat
from slearn.errors import InputError
from slearn.io.files import check_output
from slearn.recorders.live import spec_toml, write_text
from slearn.recorders.pointer import CONDITIONS, PointerConfig
from slearn.recorders.record_pointer import RecordSummary, record_pointer
from slearn.recorders.record_stream import DEFAULT_CHANNEL, FORMATS, TICK_NS, StreamSummary, convert_stream, stream_spec


@click.group(name="record")
def command() -> None:
    """Record episodes into MCAP files."""


@command.command("pointer")
@click.option("--condition", type=click.Choice(CONDITIONS), required=True,
              help="Pointer dynamics (the paper's six conditions).")
@click.option("--trials", type=click.IntRange(1, MAX_TRIALS), default=10_000, show_default=True,
              help="Number of trials.")
@click.option("--seed", type=click.IntRange(0), default=0, show_default=True, help="Seed of all randomness.")
@click.option("--switch-trial", type=click.IntRange(0, MAX_TRIALS), default=5_000, show_default=True,
              help="First trial of the scramble or reversal.")
@click.option("--error-deg", type=FiniteFloat(0, 10), default=5.0, show_default=True,
              help="Half-width of the uniform move error (error), 0 to 10.")
@click.option("--delay-prob", type=FiniteFloat(0, 1), default=0.5, show_default=True,
              help="Chance that a command is delayed by one trial (delay), 0 to 1.")
@click.option("-o", "--output", type=click.Path(path_type=Path), required=True,
              help="The MCAP file to write.")
@click.option("--force", is_flag=True, help="Overwrite an existing output file.")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as one JSON document.")
@click.pass_context
def pointer(ctx: click.Context, condition: str, trials: int, seed: int, switch_trial: int, error_deg: float,
            delay_prob: float, output: Path, force: bool, as_json: bool) -> None:
    """Record one simulated rotary-pointer episode."""
    effects = set(condition.split("+"))
    for option, name, needs in (("--error-deg", "error_deg", {"error"}), ("--delay-prob", "delay_prob", {"delay"}),
                                ("--switch-trial", "switch_trial", {"scramble", "reversal"})):
        if ctx.get_parameter_source(name) is click.core.ParameterSource.COMMANDLINE and not effects & needs:
            raise click.UsageError(f"{option} applies to the {' and '.join(sorted(needs))} condition(s): "
                                   f"{condition!r} would ignore it")
    check_output(output, force)
    config = PointerConfig(condition, trials, seed, switch_trial, error_deg, delay_prob)
    summary = record_pointer(config, output, overwrite=force)
    click.echo(json.dumps(summary.to_dict()) if as_json else _summary_line(summary))


def _summary_line(summary: RecordSummary) -> str:
    messages = sum(summary.messages.values())
    return (f"wrote {summary.path}: pointer {summary.condition}, seed {summary.seed}, "
            f"{summary.trials} trials, {messages} messages, {summary.size_bytes / 1024:.0f} KiB")


def _parse_roles(options: tuple[str, ...]) -> dict[str, str]:
    roles = {}
    for option in options:
        name, eq, role = option.rpartition("=")
        if not eq or not name:
            raise InputError(f"--role {option!r}: expected CHANNEL=ROLE, e.g. cmd=action")
        roles[name] = role
    return roles


@command.command("stream")
@click.argument("source", type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--output", type=click.Path(path_type=Path), required=True,
              help="The MCAP file (all episodes in one, marked on /slearn/episode), or an "
                   "existing folder.")
@click.option("--format", "fmt", type=click.Choice(FORMATS), default="auto", show_default=True,
              help="Input format.")
@click.option("--per-file", is_flag=True, help="Make the whole file one episode.")
@click.option("--role", "roles", multiple=True, metavar="CHANNEL=ROLE",
              help="Role of a channel: action or observation (default observation). Repeatable.")
@click.option("--channel", default=DEFAULT_CHANNEL, show_default=True,
              help="Channel of tokens written without NAME=.")
@click.option("--tick-ms", type=FiniteFloat(1e-6, 86_400_000), default=TICK_NS / 1e6,
              show_default=True, help="Log time between ticks of token and SPMF sequences.")
@click.option("--spec-out", type=click.Path(path_type=Path),
              help="Also write the TOML spec that learns the output.")
@click.option("--force", is_flag=True, help="Overwrite existing output files.")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as one JSON document.")
def stream(source: Path, output: Path, fmt: str, per_file: bool, roles: tuple[str, ...],
           channel: str, tick_ms: float, spec_out: Path | None, force: bool,
           as_json: bool) -> None:
    """Convert a categorical sequence file (tokens, SPMF, CSV, JSON Lines) into one MCAP file
    holding each sequence as an episode."""
    if spec_out is not None:
        check_distinct_outputs([("-o", str(output)), ("--spec-out", str(spec_out))])
        check_output(spec_out, force, inputs=[source, output])
    summary = convert_stream(source, output, fmt=fmt, per_file=per_file,
                             roles=_parse_roles(roles), channel=channel,
                             tick_ns=round(tick_ms * 1e6), overwrite=force)
    if spec_out is not None:
        write_text(spec_out, spec_toml(stream_spec(summary), f"spec for {source.name}"),
                   overwrite=force, inputs=[source, *summary.paths])
    click.echo(json.dumps(summary.to_dict()) if as_json else _stream_line(summary))


def _stream_line(summary: StreamSummary) -> str:
    where = f"{summary.paths[0]} ({summary.episodes:,} episode{'s' if summary.episodes > 1 else ''})"
    channels = ", ".join(f"{name} ({role})" for name, role in summary.channels.items())
    return (f"wrote {where}: {summary.format}, {summary.events} events on {channels}, "
            f"{summary.size_bytes / 1024:.0f} KiB")
