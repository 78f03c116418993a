"""``slearn info``: what is in MCAP logs (and, later, pattern libraries)."""

from __future__ import annotations

import json

import click

from slearn.cli import EXIT_TRUNCATED
from slearn.files import check_output, write_atomic
from slearn.info import ChannelProfile, LogProfile, describe, suggest_spec


def _fmt_value(value) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    return repr(value) if isinstance(value, str) else str(value)


def _channel_lines(channel: ChannelProfile, show_fields: bool) -> list[str]:
    rate = f"{channel.rate_hz:8.1f} Hz" if channel.rate_hz else "       - Hz"
    schema = channel.schema or "(schemaless)"
    lines = [f"  {channel.id:>4}  {channel.topic:<32} {schema:<34} "
             f"{channel.message_encoding:<9} {channel.count:>8} {rate}"]
    if channel.decode_error:
        lines.append(f"        cannot be decoded: {channel.decode_error}")
    elif show_fields:
        for info in channel.fields:
            examples = ", ".join(_fmt_value(v) for v in info.examples)
            lines.append(f"        {info.path:<50} {info.type:<6} {examples}")
        if channel.more_fields:
            lines.append(f"        ... {channel.more_fields} more fields")
    return lines


def _render(profile: LogProfile, show_fields: bool) -> str:
    lines = [f"{profile.path}",
             f"  profile {profile.profile or '-'}, library {profile.library or '-'}, "
             f"{profile.size_bytes:,} bytes, {profile.n_messages:,} messages, "
             f"{profile.duration_s:.3f} s",
             f"  {'id':>4}  {'topic':<32} {'schema':<34} {'encoding':<9} {'count':>8} {'rate':>11}"]
    for channel in profile.channels:
        lines += _channel_lines(channel, show_fields)
    return "\n".join(lines)


def _as_dict(result) -> dict:
    return result.to_dict() if hasattr(result, "to_dict") else result


def _as_text(result, show_fields: bool) -> str:
    # libraries (slearn.storage.describe) may bring their own text rendering
    if isinstance(result, LogProfile):
        return _render(result, show_fields)
    if hasattr(result, "render"):
        return result.render()
    return json.dumps(_as_dict(result), indent=2, default=str)




@click.command("info")
@click.argument("paths", nargs=-1, required=True, type=click.Path())
@click.option("--json", "as_json", is_flag=True, help="Print one JSON document.")
@click.option("--fields/--no-fields", default=True, help="List decodable scalar fields.")
@click.option("--suggest-spec", "spec_out", type=click.Path(dir_okay=False),
              help="Write a commented TOML spec skeleton to this file.")
@click.option("--force", is_flag=True, help="Overwrite the --suggest-spec file.")
@click.pass_context
def command(ctx: click.Context, paths: tuple[str, ...], as_json: bool, fields: bool,
            spec_out: str | None, force: bool) -> None:
    """Show profile, duration, channels, counts, rates and fields of MCAP logs.

    Exits 3 when a log is truncated (what could be read is still shown). Pattern
    libraries (.parquet) are described by slearn.storage once it exists.
    """
    if spec_out:
        check_output(spec_out, force, inputs=paths)
    results = [describe(path) for path in paths]
    logs = [r for r in results if isinstance(r, LogProfile)]
    if as_json:
        click.echo(json.dumps({"files": [_as_dict(r) for r in results]}, indent=2, default=str))
    else:
        click.echo("\n\n".join(_as_text(r, fields) for r in results))
    if spec_out:
        write_atomic(spec_out, suggest_spec(logs), overwrite=force, inputs=paths)
        click.echo(f"slearn: wrote spec skeleton {spec_out}", err=True)
    broken = [log for log in logs if log.report.truncated]
    for log in broken:
        click.echo(f"slearn: warning: {log.report.describe()}", err=True)
    if broken:
        ctx.exit(EXIT_TRUNCATED)
