"""Compilation once per machine, said (issue 35): the first compilation of a process prints one line on stderr
(``estimators.compile_notice``), a kernel loaded from numba's cache prints nothing. Each case runs in
its own interpreter (the line is said once per process) on a one-line kernel cached beside a module in a temporary
folder, not on slung's own kernels (their cold compilation takes minutes)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from estimators.compile_notice import LINE

KERNEL = """\
import numba

@numba.njit(cache=True)
def twice(x):
    return 2.0 * x
"""

RUN = """\
import sys
sys.path.insert(0, sys.argv[1])
import estimators.compile_notice
import tiny_kernel
assert tiny_kernel.twice(1.5) == 3.0
"""


def _stderr(folder: Path) -> str:
    done = subprocess.run(
        [sys.executable, "-c", RUN, str(folder)], capture_output=True, text=True, timeout=120, check=True
    )
    return done.stderr


def test_the_line_is_said_while_compiling_and_not_when_the_cache_is_warm(tmp_path: Path) -> None:
    (tmp_path / "tiny_kernel.py").write_text(KERNEL, encoding="utf-8")
    cold = _stderr(tmp_path)
    assert cold.count(LINE) == 1, cold
    assert "compiling slung's kernels once for this machine" in LINE
    assert list((tmp_path / "__pycache__").glob("tiny_kernel.twice-*.nbi")), "numba cached nothing"
    warm = _stderr(tmp_path)
    assert LINE not in warm, warm
