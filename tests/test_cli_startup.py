"""The lazy command line: subcommands load when called, and commands that compile nothing
import no numba."""

from __future__ import annotations

import json
import subprocess
import sys

import click
import pytest
from click.testing import CliRunner
from fixtures import write_log

from slearn.cli import _COMMANDS, main

# Runs the CLI in a fresh interpreter and prints which heavy modules it imported.
_CHILD = """
import json, sys
from slearn.cli import main
try:
    main(sys.argv[1:], standalone_mode=False)
except SystemExit:
    pass
print(json.dumps({m: m in sys.modules for m in ("numba", "slearn.library", "slearn.cli.learn")}),
      file=sys.stderr)
"""


def imported(*args) -> dict:
    done = subprocess.run([sys.executable, "-c", _CHILD, *map(str, args)], capture_output=True,
                          text=True, check=True)
    return json.loads(done.stderr.strip().splitlines()[-1])


@pytest.fixture
def log(tmp_path):
    return write_log(tmp_path / "small.mcap",
                     [("/cmd", i * 10**8, {"command": "LR"[i % 2]}) for i in range(20)])


@pytest.mark.parametrize("args", [["--help"], ["datasets", "list"], ["info", "LOG"], ["info", "--help"]])
def test_commands_that_compile_nothing_import_no_numba(args, log):
    seen = imported(*[log if a == "LOG" else a for a in args])
    assert seen == {"numba": False, "slearn.library": False, "slearn.cli.learn": False}


def test_import_slearn_imports_no_numba():
    done = subprocess.run([sys.executable, "-c", "import sys, slearn; print('numba' in sys.modules); "
                           "slearn.SequenceModel; print('numba' in sys.modules)"],
                          capture_output=True, text=True, check=True)
    assert done.stdout.split() == ["False", "True"]


def test_help_summaries_match_each_commands_own_help():
    ctx = click.Context(main)
    for name, summary in _COMMANDS.items():
        own = main.get_command(ctx, name).get_short_help_str(limit=10**6)
        assert click.Command(name, help=summary).get_short_help_str(limit=10**6) == own, name


def test_help_lists_what_an_eager_group_would():
    eager = click.Group(name=main.name, help=main.help,
                        context_settings={"help_option_names": ["-h", "--help"]})
    eager.params = main.params
    for name in _COMMANDS:
        eager.add_command(main.get_command(click.Context(main), name), name)
    lazy_help = CliRunner().invoke(main, ["--help"]).output
    assert lazy_help == CliRunner().invoke(eager, ["--help"]).output
    assert "replay" in lazy_help


def test_unknown_command_is_a_usage_error():
    result = CliRunner().invoke(main, ["nope"])
    assert result.exit_code == 2 and "No such command 'nope'" in result.output
