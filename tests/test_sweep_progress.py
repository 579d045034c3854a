"""``slung sweep``'s progress suits where it goes: on a terminal one bar redrawn with carriage returns; to a file or
pipe one plain line every few seconds (a 10 000-run sweep had written one 12 kB line of 100 redraws into a log).
The bar's rules with a stepped clock, then a real sweep with its stderr a pipe and a pseudo-terminal."""

from __future__ import annotations

import os
import pty
import subprocess
import sys
from pathlib import Path

from sweep_helpers import short_file

from offboard.harness.sweep_cli import PLAIN_PROGRESS_PERIOD_S, _Progress


class _Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def _drive(tty: bool) -> str:
    out: list[str] = []
    clock = _Clock()
    bar = _Progress(100, write=out.append, tty=tty, clock=clock)
    for done in range(1, 101):  # 100 runs over 50 s
        clock.t += 0.5
        bar.update(done, 120.0)
    bar.close()
    return "".join(out)


def test_not_a_terminal_prints_a_plain_line_every_few_seconds() -> None:
    text = _drive(tty=False)
    assert "\r" not in text
    lines = text.splitlines()
    # the first update (at 0.5 s), then one each PLAIN_PROGRESS_PERIOD_S (5 s: 10 runs), and the last
    step = int(PLAIN_PROGRESS_PERIOD_S / 0.5)
    assert [int(ln.split("/")[0]) for ln in lines] == [*range(1, 100, step), 100]
    assert lines[0].startswith("  1/100 runs (1 %)") and lines[-1].startswith("  100/100 runs (100 %)")
    assert all(len(ln) < 120 for ln in lines)


def test_a_terminal_gets_the_bar_redrawn_in_place() -> None:
    text = _drive(tty=True)
    assert text.count("\r") == 100 and text.endswith("\n") and text.count("\n") == 1
    assert "[" + "#" * 30 + "] 100/100 runs" in text


def _sweep(tmp_path: Path, stderr: int) -> subprocess.Popen:
    f = short_file(tmp_path, engine="scalar")
    cmd = [sys.executable, "-m", "offboard.cli", "sweep", "--runs", "4", "--controllers", "smc"]
    cmd += ["--file", str(f), "--workers", "0", "--no-figures", "--out", str(tmp_path / "s")]
    return subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=stderr)


def test_real_sweep_into_a_pipe_writes_plain_lines(tmp_path: Path) -> None:
    proc = _sweep(tmp_path, subprocess.PIPE)
    _, err = proc.communicate(timeout=300)
    text = err.decode()
    assert proc.returncode == 0, text[-2000:]
    assert "\r" not in text
    assert "4/4 runs (100 %)" in text


def test_real_sweep_on_a_terminal_redraws_its_bar(tmp_path: Path) -> None:
    leader, follower = pty.openpty()
    proc = _sweep(tmp_path, follower)
    os.close(follower)
    chunks = []
    while True:
        try:
            data = os.read(leader, 4096)
        except OSError:  # the terminal closed with the process
            break
        if not data:
            break
        chunks.append(data)
    proc.wait(timeout=300)
    os.close(leader)
    text = b"".join(chunks).decode(errors="replace")
    assert proc.returncode == 0, text[-2000:]
    assert "\r  [" in text and "4/4 runs" in text
