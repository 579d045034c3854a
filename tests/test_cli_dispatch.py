"""The ``slung`` front end imports only the chosen command's module: ``slung fly`` and ``slung replay`` load nothing
of the emulator's package (``sim_bridge``), ``slung --help`` lists every command without importing any."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

PROBE = """
import sys
from offboard.cli import main
try:
    main(sys.argv[1:])
except SystemExit:
    pass
import json
print(json.dumps(sorted(m for m in sys.modules if m == "sim_bridge" or m.startswith("sim_bridge."))))
print(json.dumps(sorted(m for m in sys.modules if m.startswith("offboard.") and m.endswith("_cli"))))
"""


def _loaded(*argv: str) -> tuple[list[str], list[str], str]:
    r = subprocess.run([sys.executable, "-c", PROBE, *argv], cwd=ROOT, capture_output=True, text=True, timeout=120)
    lines = r.stdout.strip().splitlines()
    return json.loads(lines[-2]), json.loads(lines[-1]), r.stdout + r.stderr


@pytest.mark.parametrize(
    ("argv", "cli"),
    [
        (("fly", "--help"), "offboard.flight.fly_cli"),
        (("replay", "--help"), "offboard.logs.replay_cli"),
        (("-v", "replay", "/nonexistent.tlog"), "offboard.logs.replay_cli"),
    ],
)
def test_flight_commands_load_no_emulator_module(argv: tuple[str, ...], cli: str) -> None:
    sim_bridge, clis, out = _loaded(*argv)
    assert sim_bridge == [], out
    assert clis == [cli], out


def test_top_level_help_lists_every_command_and_imports_none() -> None:
    sim_bridge, clis, out = _loaded("--help")
    assert sim_bridge == [] and clis == [], out
    for name in ("sim", "bench", "emulate", "fly", "demo", "replay"):
        assert name in out


def test_emulate_still_gets_its_options() -> None:
    _, _, out = _loaded("emulate", "--help")
    assert "--flavor" in out and "--lockstep" in out
