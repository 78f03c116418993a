"""``slearn merge``: merge pattern libraries learned separately with the same spec."""

from __future__ import annotations

import json

import click

from slearn.cli.common import warnings_on_stderr
from slearn.jobs.merge import merge_files


@click.command("merge")
@click.argument("libraries", nargs=-1, required=True, type=click.Path())
@click.option("-o", "--output", required=True, type=click.Path(),
              help="The merged library file (Parquet) to write.")
@click.option("--force", is_flag=True, help="Overwrite the output file.")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as one JSON document.")
def command(libraries: tuple[str, ...], output: str, force: bool, as_json: bool) -> None:
    """Merge LIBRARIES (two or more .parquet files): counts add, recency is the newest.

    Values are matched by channel and value, so libraries whose symbols were numbered in
    another order merge correctly. Libraries with other channels, roles, bins or maximum
    length are refused.
    """
    with warnings_on_stderr():
        summary = merge_files(list(libraries), output, overwrite=force)
    if as_json:
        click.echo(json.dumps({**summary.to_dict(), "inputs": list(libraries)}))
    else:
        click.echo(f"merged {len(libraries)} libraries into {summary.path}: {summary.n_patterns:,} "
                   f"patterns, {summary.size_bytes:,} bytes ({summary.bytes_per_pattern:.1f} bytes/pattern)")
