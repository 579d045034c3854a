"""The README is for users: at most 150 lines, the two commands exactly, and its quick starts work. Every
```bash block of "Fly it" (the commands that need no SITL and no vehicle) is run as written, line after line, in a
fresh folder; every `slung` line of its ```sh blocks (SITL, a real vehicle) is parsed by the command's own parser,
so an option renamed in the code cannot leave the README stale."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from offboard.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")


def _blocks(lang: str) -> list[str]:
    fly_it = README.split("\n## Fly it\n", 1)[1].split("\n## ", 1)[0]
    return re.findall(rf"```{lang}\n(.*?)```", fly_it, flags=re.S)


def _commands(block: str) -> list[str]:
    text = block.replace("\\\n", " ")
    return [ln.strip() for ln in text.splitlines() if ln.strip() and not ln.strip().startswith("#")]


def test_readme_is_short_and_keeps_the_two_commands() -> None:
    assert len(README.splitlines()) <= 150
    assert "pip install -e . && slung demo" in README
    assert 'pip install -e ".[test]" && pytest' in README


def test_sitl_and_vehicle_quick_starts_parse() -> None:
    lines = [c for b in _blocks("sh") for c in _commands(b)]
    slung = [shlex.split(c.removesuffix("&").strip()) for c in lines if c.startswith("slung ")]
    assert {a[1] for a in slung} >= {"emulate", "fly", "px4-hil"}
    for argv in slung:
        build_parser(argv[1]).parse_args(argv[1:])  # argparse exits (code 2) on an unknown option


@pytest.mark.slow
def test_quick_starts_without_sitl_run_as_written(tmp_path: Path) -> None:
    commands = [c for b in _blocks("bash") for c in _commands(b)]
    assert any(c.startswith("slung demo") for c in commands) and any(c.startswith("slung replay") for c in commands)
    env = {**os.environ, "PATH": str(Path(sys.executable).parent) + os.pathsep + os.environ.get("PATH", "")}
    for command in commands:
        r = subprocess.run(["bash", "-c", command], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900)
        assert r.returncode == 0, f"{command}: exit {r.returncode}\n{r.stderr[-2000:]}"
    assert (tmp_path / "runs" / "demo" / "timeseries_live.csv").is_file()  # slung export --csv
    assert (tmp_path / "runs" / "replay" / "metrics.json").is_file()
