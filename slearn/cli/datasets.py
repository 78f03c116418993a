"""``slearn datasets``: list the named datasets and build one into a folder."""

from __future__ import annotations

import json
from pathlib import Path

import click

from slearn.cli import EXIT_TRUNCATED
from slearn.cli.common import warnings_on_stderr
from slearn.datasets.registry import BuildSummary, build_dataset, list_datasets


@click.group(name="datasets")
def command() -> None:
    """Named, reproducible datasets (MCAP episodes, a card and a spec each)."""


@command.command("list")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON document.")
def list_command(as_json: bool) -> None:
    """List the datasets that can be built."""
    datasets = list_datasets()
    if as_json:
        click.echo(json.dumps([d.to_dict() for d in datasets]))
        return
    width = max(len(d.name) for d in datasets)
    for dataset in datasets:
        click.echo(f"{dataset.name:<{width}}  {dataset.summary} [{dataset.license}]")


@command.command("build")
@click.argument("name")
@click.option("-o", "--output", type=click.Path(file_okay=False, path_type=Path), required=True,
              help="The folder to build the dataset in.")
@click.option("--source", type=click.Path(path_type=Path),
              help="pr2-sample: your own log (MCAP, rosbag2 folder, .db3, .bag), split by "
                   "time into train/ (the first 70 %) and heldout/ (the rest).")
@click.option("--force", is_flag=True, help="Rebuild into a folder that is not empty.")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as one JSON document.")
def build(name: str, output: Path, source: Path | None, force: bool, as_json: bool) -> None:
    """Build dataset NAME into a folder: train/ and heldout/ episodes, README.md (with the
    replay figures to expect), spec.toml and SHA256SUMS."""
    click.echo(f"building {name} in {output} ...", err=True)
    with warnings_on_stderr():
        summary = build_dataset(name, output, overwrite=force, source=source)
    click.echo(json.dumps(summary.to_dict()) if as_json else _render(summary))
    if summary.damaged:
        click.get_current_context().exit(EXIT_TRUNCATED)


def _render(summary: BuildSummary) -> str:
    counts = {split: sum(e.split == split for e in summary.episodes) for split in ("train", "heldout")}
    lines = [f"built {summary.name} in {summary.folder}: {counts['train']} train and "
             f"{counts['heldout']} held-out episodes",
             f"  card: {', '.join(summary.cards)}",
             f"  spec: {', '.join(summary.specs)}",
             f"  sha256: {summary.checksums}"]
    lines += [f"  note: {note}" for note in summary.notes]
    return "\n".join(lines)
