"""Every command's ``--help`` ends with an example line, and that example is a valid command line for it (its
options parse). ``slung COMMAND --help`` is run as a user runs it, through the console entry point's module."""

from __future__ import annotations

import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from offboard.cli import COMMANDS, EXAMPLES, build_parser

ROOT = Path(__file__).resolve().parents[1]


def test_every_command_has_an_example() -> None:
    assert set(EXAMPLES) == set(COMMANDS)


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_help_ends_with_an_example_that_parses(command: str) -> None:
    r = subprocess.run(
        [sys.executable, "-m", "offboard.cli", command, "--help"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    lines = [ln for ln in r.stdout.splitlines() if ln.strip()]
    assert lines[-2] == "example:"
    example = lines[-1].strip()
    assert example == EXAMPLES[command]
    argv = shlex.split(example)
    assert argv[:2] == ["slung", command]
    args = build_parser(command).parse_args(argv[1:])  # argparse exits (code 2) on an unknown option
    assert args.command == command
