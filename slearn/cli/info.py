"""``slearn info``: what is in logs (MCAP, rosbag2 folders, .db3, .bag) and pattern libraries."""

from __future__ import annotations

import json
import tomllib

import click

from slearn.cli import EXIT_TRUNCATED
from slearn.cli.common import make_slice, slice_options, topic_list
from slearn.errors import InputError
from slearn.io.files import check_output, write_atomic
from slearn.jobs.info import ChannelProfile, FieldInfo, LogProfile, describe, iso_time
from slearn.jobs.suggest import suggested_text


def _fmt_value(value) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    return repr(value) if isinstance(value, str) else str(value)


def _field_line(info: FieldInfo) -> str:
    if info.constant:
        values = f"constant {_fmt_value(info.distinct[0])}"
    else:
        spread = f"{_fmt_value(info.min)} .. {_fmt_value(info.max)}, " if info.min is not None else ""
        distinct = f"{info.n_distinct} values" if info.n_distinct is not None else "many values"
        values = f"{spread}{distinct}, changes {info.changes}x; e.g. " + \
            ", ".join(_fmt_value(v) for v in info.examples)
    return f"        {info.path:<50} {info.type:<6} {values}"


def _channel_lines(channel: ChannelProfile, show_fields: bool) -> list[str]:
    if channel.rate_hz:
        rate = f"{channel.rate_hz:8.1f} Hz"
    elif channel.burst:
        rate = f"burst in {channel.span_ns / 1e6:.3f} ms"
    else:
        rate = "       - Hz"
    schema = channel.schema or "(schemaless)"
    lines = [f"  {channel.id:>4}  {channel.topic:<32} {schema:<34} "
             f"{channel.message_encoding:<9} {channel.count:>8} {rate}"]
    if channel.decode_error:
        lines.append(f"        cannot be decoded: {channel.decode_error}")
    elif show_fields and channel.fields:
        sampled = f" (statistics of {channel.decoded:,} decoded messages)" \
            if channel.decoded < channel.count else ""
        lines.append(f"        {len(channel.fields)} fields{sampled}:")
        lines += [_field_line(info) for info in channel.fields]
        if channel.more_fields:
            lines.append(f"        ... {channel.more_fields} more fields not listed")
    return lines


def _render(profile: LogProfile, show_fields: bool) -> str:
    span = "no messages"
    if profile.start_ns is not None and profile.end_ns is not None:
        span = (f"{iso_time(profile.start_ns)} ({profile.start_ns / 1e9:.3f} s) to "
                f"{iso_time(profile.end_ns)} ({profile.end_ns / 1e9:.3f} s)")
    window = f", {profile.window}" if profile.window else ""
    lines = [f"{profile.path}",
             f"  profile {profile.profile or '-'}, library {profile.library or '-'}, "
             f"{profile.size_bytes:,} bytes, {profile.n_messages:,} messages, "
             f"{profile.duration_s:.3f} s{window}",
             f"  {span}",
             f"  {'id':>4}  {'topic':<32} {'schema':<34} {'encoding':<9} {'count':>8} {'rate':>11}"]
    for channel in profile.channels:
        lines += _channel_lines(channel, show_fields)
    return "\n".join(lines)


def _as_dict(result) -> dict:
    return result.to_dict() if hasattr(result, "to_dict") else result


def _as_text(result, show_fields: bool) -> str:
    # libraries (slearn.io.library_file.describe) may bring their own text rendering
    if isinstance(result, LogProfile):
        return _render(result, show_fields)
    if hasattr(result, "render"):
        return result.render()
    return json.dumps(_as_dict(result), indent=2, default=str)


@click.command("info")
@click.argument("paths", nargs=-1, required=True, type=click.Path())
@click.option("--json", "as_json", is_flag=True, help="Print one JSON document.")
@click.option("--fields/--no-fields", default=True, help="List every field with its values.")
@click.option("--suggest-spec", "spec_out", type=click.Path(),
              help="Write a spec (TOML) that learns the logs as written: roles, fields and bins "
                   "guessed from the data, the reasons in comments.")
@click.option("--force", is_flag=True, help="Overwrite the --suggest-spec file.")
@slice_options(split=False)
@click.pass_context
def command(ctx: click.Context, paths: tuple[str, ...], as_json: bool, fields: bool,
            spec_out: str | None, force: bool, start: str | None, end: str | None,
            topics: str | None) -> None:
    """Show the header, time span, channels, rates and every field of logs (MCAP files,
    rosbag2 folders, .db3 and ROS 1 .bag files), or a pattern library (.parquet).

    Exits 3 when a log is truncated (what could be read is still shown).
    """
    if spec_out:
        check_output(spec_out, force, inputs=paths)
    window = make_slice(start, end, None)
    wanted = topic_list(topics)
    results = [describe(path, wanted, window) for path in paths]
    logs = [r for r in results if isinstance(r, LogProfile)]
    if spec_out and len(logs) < len(results):
        library = next(p for p, r in zip(paths, results) if not isinstance(r, LogProfile))
        raise InputError(f"{library} is a library, not a log: --suggest-spec reads logs (a library "
                         f"carries the spec it learned with: slearn info {library} shows it)")
    for log in logs:
        missing = sorted(set(wanted or ()) - {c.topic for c in log.channels})
        if missing and not log.report.truncated:
            raise InputError(f"{log.path}: --topics {', '.join(missing)} not in this log (slearn info "
                             f"{log.path} lists its topics)")
    if as_json:
        click.echo(json.dumps({"files": [_as_dict(r) for r in results]}, indent=2, default=str))
    else:
        click.echo("\n\n".join(_as_text(r, fields) for r in results))
    if spec_out:
        text = suggested_text(logs, window)
        write_atomic(spec_out, text, overwrite=force, inputs=paths)
        click.echo(f"slearn: wrote spec {spec_out}", err=True)
        if not any(e["role"] == "observation" for e in tomllib.loads(text).get("channel", [])):
            click.echo(f"slearn: warning: {spec_out} has no observation entry: no field of these logs "
                       "has values to predict (its comments say why); add one before slearn learn",
                       err=True)
    broken = [log for log in logs if log.report.truncated]
    for log in broken:
        click.echo(f"slearn: warning: {log.report.describe()}", err=True)
    if broken:
        ctx.exit(EXIT_TRUNCATED)
