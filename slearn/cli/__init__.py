"""The ``slearn`` command line: each subcommand lives in its own module here.

Commands parse options, call one library function and render its result: results on
stdout, progress and diagnostics on stderr, ``--json`` prints one JSON document only.
Exit codes: 0 ok, 1 bad input (``SlearnError``, or a file the system cannot read or
write), 2 usage error (click), 3 a truncated log was salvaged, 4 a ``--fail-under``
threshold was missed.
"""

from __future__ import annotations

import importlib
import sys

import click

from slearn import __version__
from slearn.errors import SlearnError

EXIT_TRUNCATED = 3
EXIT_BELOW_THRESHOLD = 4

# Subcommand modules; each defines one click command (or group) named ``command``.
_COMMAND_MODULES = ("demo", "record", "info", "learn", "merge", "replay", "control", "datasets")


class _Group(click.Group):
    """Turns slearn's own errors into a one-line message and an exit code."""

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except SlearnError as err:
            click.echo(f"slearn: error: {err}", err=True)
            sys.exit(err.exit_code)
        except OSError as err:  # a file the system refuses, wherever it was met: one line
            where = f"{err.filename}: " if err.filename is not None else ""
            click.echo(f"slearn: error: {where}{err.strerror or err}", err=True)
            sys.exit(SlearnError.exit_code)
        except KeyboardInterrupt:
            click.echo("slearn: interrupted", err=True)
            sys.exit(130)


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="slearn")
def main() -> None:
    """S-learning: learn how a system behaves from its MCAP logs, then predict and control it.

    \b
    Environment:
      SLEARN_MAX_CHUNK_MB  most MiB of decompressed MCAP chunk data held at once (default
                           256, 1 to 1048576); a larger chunk is skipped with a warning (exit 3)
      SOURCE_DATE_EPOCH    the time recorded in a library's provenance (0 to 253402300799)
    """


def _register() -> None:
    for name in _COMMAND_MODULES:
        main.add_command(importlib.import_module(f"slearn.cli.{name}").command)


_register()
