"""The ``slearn`` command line: each subcommand lives in its own module here.

Commands parse options, call one library function and render its result: results on
stdout, progress and diagnostics on stderr, ``--json`` prints one JSON document only.
Exit codes: 0 ok, 1 bad input (``SlearnError``, or a file the system cannot read or
write), 2 usage error (click), 3 a truncated log was salvaged, 4 a ``--fail-under``
threshold was missed; 128 + N when stopped by signal N (SIGINT 130, SIGTERM 143,
SIGHUP 129), after removing the temporary file of any output being written.
"""

from __future__ import annotations

import contextlib
import importlib
import signal
import sys
import threading

import click

from slearn import __version__
from slearn.errors import SlearnError

EXIT_TRUNCATED = 3
EXIT_BELOW_THRESHOLD = 4

# Subcommand modules (each defines one click command or group named ``command``), imported
# only when called: most pull in numba and the kernels, and ``--help`` or ``info`` need
# neither. The summaries ``--help`` lists are kept here so that listing imports nothing;
# a test checks them against each command's own help.
_COMMANDS = {
    "control": "Steer a discrete system to goal observations in closed loop, next to honest peers.",
    "datasets": "Named, reproducible datasets (MCAP episodes, a card and a spec each).",
    "demo": "Record the pointer's six conditions, learn them online, and print Figure 2.",
    "info": "Show the header, time span, channels, rates and every field of logs (MCAP files, "
            "rosbag2 folders, .db3 and ROS 1 .bag files), or a pattern library (.parquet).",
    "learn": "Learn a pattern library from LOGS: MCAP files, rosbag2 folders, .db3 or ROS 1 "
             ".bag files.",
    "merge": "Merge LIBRARIES (two or more .parquet files): counts add, recency is the newest.",
    "record": "Record episodes into MCAP files.",
    "replay": "Evaluate library LIB on held-out LOGS: slearn replay LIB LOGS...",
}


class Stopped(BaseException):
    """A signal asked the command to stop (SIGTERM, SIGHUP): raised where the program is,
    like ``KeyboardInterrupt``, so that outputs being written discard their temporary
    files on the way out instead of leaving them behind."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def _raise_stopped(signum: int, frame: object) -> None:
    raise Stopped(signum)


@contextlib.contextmanager
def _stop_on_signals():
    """SIGTERM and SIGHUP raise :class:`Stopped` while a command runs (their default kills
    the process without cleanup). Handlers someone else installed are left alone; only the
    main thread can install any."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {}
    for signum in (signal.SIGTERM, signal.SIGHUP):
        if signal.getsignal(signum) is signal.SIG_DFL:
            previous[signum] = signal.signal(signum, _raise_stopped)
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


class _Group(click.Group):
    """Imports a subcommand when it is called; turns slearn's own errors into a one-line
    message and an exit code."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(_COMMANDS)

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        if name not in _COMMANDS:
            return None
        return importlib.import_module(f"slearn.cli.{name}").command

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        limit = formatter.width - 6 - max(len(name) for name in _COMMANDS)
        rows = [(name, click.Command(name, help=_COMMANDS[name]).get_short_help_str(limit))
                for name in self.list_commands(ctx)]
        with formatter.section("Commands"):
            formatter.write_dl(rows)

    def invoke(self, ctx: click.Context):
        try:
            with _stop_on_signals():
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
        except Stopped as stop:
            click.echo(f"slearn: stopped by {stop}", err=True)
            sys.exit(128 + stop.signum)
        finally:
            compile_notice()


def compile_notice() -> None:
    """One stderr line when numba compiled slearn's kernels on this run, into an empty
    cache, because the kernels compiled at install were not used (the twenty seconds a
    user would otherwise wonder about). Nothing when ``SLEARN_AOT=0`` asked for it, or when
    the command used no kernel."""
    aot = sys.modules.get("slearn.core._aot")
    if aot is None:
        return
    reason = aot.unused_reason()
    if reason is not None and sys.modules["slearn.core._jit"].compiled_this_run():
        click.echo(f"slearn: note: numba compiled slearn's kernels on this run ({reason}); later runs load "
                   "them from its cache, and `pip install --force-reinstall --no-build-isolation slearn` "
                   "(or `pip install --no-build-isolation .` in its source) compiles them at install", err=True)


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
    from slearn.jobs.pages import small_pages

    small_pages()  # before any job allocates: see slearn.jobs.pages
