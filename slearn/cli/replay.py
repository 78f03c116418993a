"""``slearn replay``: how well a saved library predicts held-out logs, next to three baselines."""

from __future__ import annotations

import json
import math
import os
from typing import cast

import click

from slearn.cli import EXIT_BELOW_THRESHOLD, EXIT_TRUNCATED
from slearn.cli.common import check_distinct_outputs, make_slice, ray_options, reader_for, slice_options, topic_list
from slearn.cli.limits import LENGTH, MAX_TOP_K, FiniteFloat
from slearn.core.library import DEFAULT_MAX_LENGTH
from slearn.errors import InputError
from slearn.io.bags import is_log_path
from slearn.io.files import check_output
from slearn.io.slicing import HELDOUT

_MCAP_MAGIC = b"\x89MCAP"


def _is_log(path: str) -> bool:
    """An MCAP file, a rosbag2 folder, a .db3 or a .bag (not a library)."""
    if is_log_path(path):
        return True
    if not os.path.isfile(path):  # never open a FIFO: it would block
        return path.endswith(".mcap")
    try:
        with open(path, "rb") as f:
            return f.read(5) == _MCAP_MAGIC
    except OSError:
        return path.endswith(".mcap")


def _check_outputs(paths: list, force: bool, inputs: list[str]) -> None:
    """Refuse outputs that exist (without --force) or are inputs (always), before replaying."""
    for path in paths:
        if path:
            check_output(path, force, inputs)


@click.command("replay")
@click.argument("paths", nargs=-1, required=True, type=click.Path(), metavar="[LIB] LOGS...")
@click.option("--online", is_flag=True, help="Keep learning while replaying (prequential).")
@click.option("--spec", "spec", type=click.Path(dir_okay=False),
              help="Channel spec (TOML): start from an empty library (implies --online).")
@click.option("--window", type=click.IntRange(min=1), help="Steps per learning-curve window.")
@click.option("--top-k", type=click.IntRange(1, MAX_TOP_K), default=3, show_default=True,
              help="Ranked guesses that count for the top-k accuracy.")
@click.option("--max-length", type=LENGTH, default=DEFAULT_MAX_LENGTH,
              show_default=True, help="Context length (steps) of an empty library (--spec).")
@click.option("--baseline-train", "baseline_train", multiple=True, type=click.Path(dir_okay=False),
              help="Training log for the baselines (repeat; default: the library's own inputs "
                   "when still on disk).")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON document (slearn.replay/3).")
@click.option("--plot", type=click.Path(), help="Write the learning curves (PNG).")
@click.option("--report", type=click.Path(), help="Write a self-contained HTML report.")
@click.option("--write-mcap", "write_mcap", type=click.Path(),
              help="Write the log annotated with /slearn/prediction, /slearn/correct and "
                   "/slearn/surprise (a folder for several logs).")
@click.option("--force", is_flag=True, help="Overwrite existing output files.")
@click.option("--fail-under", type=FiniteFloat(0, 100),
              help="Exit 4 when the accuracy (percent) is below this.")
@slice_options(split=True)
@ray_options
@click.option("-q", "--quiet", is_flag=True, help="No progress on stderr.")
@click.pass_context
def command(ctx: click.Context, paths: tuple[str, ...], online: bool, spec: str | None,
            window: int | None, top_k: int, max_length: int,
            baseline_train: tuple[str, ...], as_json: bool, plot: str | None, report: str | None,
            write_mcap: str | None, force: bool, fail_under: float | None, start: str | None,
            end: str | None, topics: str | None, split: float | None, workers: int | None,
            ray_address: str | None, quiet: bool) -> None:
    """Evaluate library LIB on held-out LOGS: slearn replay LIB LOGS...

    LOGS are MCAP files, rosbag2 folders, .db3 or ROS 1 .bag files. Frozen by default: the
    library predicts every observation from the history and the actions issued, without
    learning. With --spec and no LIB, replay starts from an empty library and learns
    online. With --split, each log's held-out part (after the share learn --split read) is
    replayed. Every accuracy comes with a 95 % interval, next to the frequency, Markov and
    persistence baselines. Exits 3 when a log was truncated (what was salvaged is scored),
    4 when the accuracy is below --fail-under. With --workers or --ray, Ray tasks read
    the logs and this process scores them in order: the same report as without.
    """
    from slearn.replay.replay_logs import replay_logs

    library, logs = _split(paths, spec)
    if library is not None and ctx.get_parameter_source("max_length") is click.core.ParameterSource.COMMANDLINE:
        raise click.UsageError("--max-length sizes an empty library (--spec); a saved library keeps the "
                               "length it learned with")
    inputs = [*paths, *baseline_train, *([spec] if spec else [])]
    if library is not None:  # the baselines are counted on its training logs: never write over them
        from slearn.io.library_file import recorded_inputs

        inputs += recorded_inputs(library)
    outputs = [("--plot", plot), ("--report", report)]
    if write_mcap:
        from slearn.replay.annotate import annotated_paths, layout_path

        outputs += [("--write-mcap", str(p)) for t in annotated_paths(logs, write_mcap) for p in (t, layout_path(t))]
    _check_outputs([path for _, path in outputs], force, inputs)
    check_distinct_outputs(outputs)
    with reader_for(workers, ray_address, None if quiet else "read") as reader:
        evaluation = replay_logs(logs, library=library, spec=_spec(spec, library, topics),
                                 online=online, top_k=top_k, window=window, max_length=max_length,
                                 baseline_logs=baseline_train or None,
                                 keep_outcomes=write_mcap is not None, progress=not quiet,
                                 time_slice=make_slice(start, end, split, HELDOUT), reader=reader)
    if evaluation.truncated and not any(e.steps for e in evaluation.episodes):
        damaged = ", ".join(e.name for e in evaluation.episodes if e.truncated)
        raise InputError(f"nothing could be salvaged from {damaged}, so nothing was scored or written")
    written = _write_outputs(evaluation, plot, report, write_mcap, force, quiet, inputs)
    _render(evaluation, written, as_json)
    for warning in evaluation.warnings:
        click.echo(f"slearn: warning: {warning}", err=True)
    accuracy = evaluation.accuracy
    if fail_under is not None and (math.isnan(accuracy) or 100 * accuracy < fail_under):
        shown = "undefined (no observation event to predict)" if math.isnan(accuracy) \
            else f"{100 * accuracy:.2f} %"
        click.echo(f"slearn: accuracy {shown} is below --fail-under {fail_under:g} %", err=True)
        ctx.exit(EXIT_BELOW_THRESHOLD)
    if evaluation.truncated:
        ctx.exit(EXIT_TRUNCATED)


def _spec(spec: str | None, library: str | None, topics: str | None):
    """The spec to pass on: the file, or with --topics the file's entries of those topics.

    A saved library is replayed on the topics it learned; --topics must name them all.
    """
    wanted = topic_list(topics)
    if wanted is None:
        return spec
    if library is not None:
        from slearn.io.library_file import read_info

        learned = sorted({c["topic"] for c in (read_info(library).get("spec") or {}).get("channel", [])})
        if learned and sorted(set(wanted)) != learned:
            raise InputError(f"{library}: learned on topics {', '.join(learned)}; replay reads the "
                             f"same topics (drop --topics, or learn a library on the ones you want)")
        return spec
    from slearn.io.spec import load_spec

    return load_spec(cast(str, spec)).only_topics(wanted)  # no library: _split saw --spec


def _split(paths: tuple[str, ...], spec: str | None) -> tuple[str | None, list[str]]:
    """``(library or None, logs)``: with --spec, a first path that is a log means no library."""
    if _is_log(paths[0]):
        if spec is None:
            raise InputError(f"{paths[0]} is a log, not a library: give the library first "
                             "(slearn replay LIB LOGS...), or --spec FILE to start from an empty one")
        return None, list(paths)
    if len(paths) < 2:
        raise click.UsageError("Missing argument 'LOGS...': give a library and at least one log "
                               "(slearn replay LIB LOGS...), or --spec FILE and logs to start from an empty library")
    return paths[0], list(paths[1:])


def _write_outputs(evaluation, plot: str | None, report: str | None, write_mcap: str | None,
                   force: bool, quiet: bool, inputs: list[str]) -> dict:
    outputs: dict = {}
    if plot:
        from slearn.replay.plots import write_curves

        write_curves(evaluation, plot)
        outputs["plot"] = plot
    if report:
        from slearn.replay.report import write_html

        write_html(evaluation, report)
        outputs["report"] = report
    if write_mcap:
        from slearn.replay.annotate import write_annotated

        written = write_annotated(evaluation, write_mcap, overwrite=force, inputs=inputs)
        outputs["annotated"] = [w.to_dict() for w in written]
    for kind, value in outputs.items():
        if not quiet:
            names = ", ".join(w["path"] for w in value) if kind == "annotated" else value
            click.echo(f"slearn: wrote {kind} {names}", err=True)
    return outputs


def _render(evaluation, outputs: dict, as_json: bool) -> None:
    if as_json:
        click.echo(json.dumps({**evaluation.to_dict(), "outputs": outputs}, indent=2))
    else:
        from slearn.replay.report import format_table

        click.echo(format_table(evaluation))
