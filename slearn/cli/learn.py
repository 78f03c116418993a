"""``slearn learn``: learn a pattern library from MCAP logs and save it as Parquet."""

from __future__ import annotations

import json
import sys
import warnings

import click

from slearn.cli import EXIT_TRUNCATED
from slearn.cli.common import (
    CHANNEL_HELP,
    echo_progress,
    make_slice,
    ray_options,
    reader_for,
    slice_options,
    topic_list,
    warnings_on_stderr,
)
from slearn.cli.limits import LENGTH, PATTERNS, FiniteFloat
from slearn.errors import TruncatedLogWarning
from slearn.io.files import refuse_inputs
from slearn.io.spec import DEFAULT_MODE, MODES, Spec, load_spec, spec_from_options
from slearn.jobs.learn import SCORING_RULES, LearnResult, expand_paths, learn_files

AUTO = "auto"  # --spec auto: the suggested spec of the logs


def _spec(spec_path: str | None, channels: tuple[str, ...], mode: str | None,
          tick_ms: float | None, phase_ms: float | None) -> Spec | None:
    if spec_path and channels:
        raise click.UsageError("give --spec or --channel, not both")
    if spec_path:
        if mode or tick_ms or phase_ms:
            raise click.UsageError("--mode, --tick-ms and --phase-ms go with --channel; a spec file "
                                   "has its own")
        return None if spec_path == AUTO else load_spec(spec_path)
    if channels:
        return spec_from_options(channels, mode or DEFAULT_MODE, tick_ms, phase_ms)
    if mode or tick_ms or phase_ms:
        raise click.UsageError("--mode, --tick-ms and --phase-ms need --channel")
    return None


def _auto_spec(paths: list[str], window) -> Spec:
    """``--spec auto``: the suggested spec of the logs' learned part, said on stderr."""
    from slearn.jobs.suggest import suggested_spec  # (profiling imports the decoders)

    spec = suggested_spec(paths, window)

    def listed(role: str) -> str:
        names = [c.name for c in spec.channels if c.role == role]
        return ", ".join(names) or "none"
    click.echo(f"slearn: --spec auto: observations {listed('observation')}; actions "
               f"{listed('action')} (the library keeps the spec: slearn info LIBRARY shows it; "
               f"slearn info {paths[0]} --suggest-spec spec.toml writes it to edit)", err=True)
    return spec


def _summary(result: LearnResult) -> str:
    resumed = f" (resumed from {result.resumed_from})" if result.resumed_from else ""
    return (f"learned {result.n_episodes} episode(s), {result.n_steps:,} steps, "
            f"{result.n_events:,} events in {result.seconds:.2f} s{resumed}\n"
            f"wrote {result.output}: {result.n_patterns:,} patterns, {result.size_bytes:,} bytes "
            f"({result.bytes_per_pattern:.1f} bytes/pattern), {result.n_symbols} symbols"
            + (f", {result.forgotten:,} forgotten" if result.forgotten else ""))


def _progress(total: int):
    def show(result: LearnResult, path: str) -> None:
        click.echo(f"learned {result.n_episodes}/{total} logs: {result.n_steps:,} steps, "
                   f"{result.n_patterns:,} patterns", err=True)
    return show


@click.command("learn")
@click.argument("logs", nargs=-1, required=True)
@click.option("-o", "--output", required=True, type=click.Path(),
              help="The library file (Parquet) to write.")
@click.option("--spec", "spec_path", type=click.Path(dir_okay=False),
              help="Channel spec (TOML), or auto: the spec `slearn info --suggest-spec` writes, "
                   "suggested from the logs (their --split part; a spec file named auto: ./auto) "
                   "[default: the pointer's channels for pointer logs].")
@click.option("--channel", "channels", multiple=True, metavar="TOPIC:FIELD:ROLE[:OPTIONS]",
              help=CHANNEL_HELP)
@click.option("--mode", type=click.Choice(MODES),
              help="Event mode for --channel (default message: every message is an event).")
@click.option("--tick-ms", type=FiniteFloat(1e-6, 86_400_000), help="Tick period for --mode tick.")
@click.option("--phase-ms", type=FiniteFloat(0, 86_400_000),
              help="--mode tick: sample the observations this long after each tick's commands "
                   "(default one tick).")
@click.option("--max-length", type=LENGTH, help="Longest context in steps [default 6; 5 for --scoring literal].")
@click.option("--max-patterns", type=PATTERNS,
              help="Forget the rarest, oldest patterns beyond this many (down to 90 % of it) "
                   "[default: keep all].")
@click.option("--scoring", type=click.Choice(SCORING_RULES),
              help="adaptive: every occurrence counted, contexts mixed by their record; literal: "
                   "the paper's parse library, longest match first [default adaptive].")
@click.option("--resume", type=click.Path(),
              help="Go on learning from this library (its spec, vocabulary and parameters).")
@click.option("--force", is_flag=True, help="Overwrite the output file.")
@slice_options(split=True)
@ray_options
@click.option("--merge-tree", is_flag=True,
              help="With --workers/--ray: learn each log in its own task and merge the partial "
                   "libraries (scales past one core's learning rate; patterns, counts and recency "
                   "as one process, the scoring weights by the merge rule).")
@click.option("-q", "--quiet", is_flag=True, help="No progress on stderr.")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as one JSON document.")
@click.pass_context
def command(ctx: click.Context, logs: tuple[str, ...], output: str, spec_path: str | None,
            channels: tuple[str, ...], mode: str | None, tick_ms: float | None,
            phase_ms: float | None, max_length: int | None, max_patterns: int | None, scoring: str | None,
            resume: str | None, force: bool, start: str | None, end: str | None,
            topics: str | None, split: float | None, workers: int | None, ray_address: str | None,
            merge_tree: bool, quiet: bool, as_json: bool) -> None:
    """Learn a pattern library from LOGS: MCAP files, rosbag2 folders, .db3 or ROS 1 .bag files.

    Each log is an episode (or several, when it marks episode boundaries). Exits 3 when a
    log was truncated: what could be read is learned and saved. With --workers or --ray,
    Ray tasks read the logs (every node must see them at the same path) and this process
    learns them in order: the same library, byte for byte, as without.
    """
    auto = spec_path == AUTO
    spec = _spec(spec_path, channels, mode, tick_ms, phase_ms)
    if auto and resume:
        raise click.UsageError("--resume learns with the library's own spec: leave out --spec auto")
    refuse_inputs(output, [spec_path] if spec_path and not auto else [])
    if topics is not None and spec is None and not auto:
        raise click.UsageError("--topics selects entries of a spec: give --spec or --channel")
    window = make_slice(start, end, split)
    paths = expand_paths(list(logs))
    if auto:
        spec = _auto_spec(paths, window)
    if topics is not None:
        assert spec is not None
        spec = spec.only_topics(topic_list(topics) or [])
    progress = not quiet and sys.stderr.isatty()
    with warnings.catch_warnings(), warnings_on_stderr():
        warnings.simplefilter("ignore", TruncatedLogWarning)  # reported below, once
        if merge_tree:
            from slearn.jobs.merge_tree import learn_on_ray

            if workers is None and ray_address is None:
                raise click.UsageError("--merge-tree runs on Ray: give --workers N or --ray ADDRESS")
            result = learn_on_ray(paths, output, workers=workers, address=ray_address, spec=spec,
                                  resume=resume, max_length=max_length, max_patterns=max_patterns,
                                  scoring=scoring, overwrite=force, progress=progress,
                                  echo=echo_progress if progress else None, window=window)
        else:
            with reader_for(workers, ray_address, "learned" if progress else None) as reader:
                result = learn_files(paths, output, spec=spec, resume=resume, max_length=max_length,
                                     max_patterns=max_patterns, scoring=scoring, overwrite=force,
                                     progress=progress, window=window, reader=reader,
                                     on_episode=_progress(len(paths)) if progress and
                                     workers is None and ray_address is None else None)
    click.echo(json.dumps(result.to_dict()) if as_json else _summary(result))
    for report in result.truncated:
        click.echo(f"slearn: warning: {report.describe()}", err=True)
    if result.truncated:
        ctx.exit(EXIT_TRUNCATED)
