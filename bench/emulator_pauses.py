"""Does ``slung emulate`` itself pause? (issue 39: a loop saw 90-400 ms gaps in the emulator's ATTITUDE stream.)

Runs the emulator's own command line in this process, with two probes: every garbage collection timed by generation
(``gc.callbacks``), and every gap of more than ``--gap-ms`` (default 50) of wall time between two calls of the plant's
step loop (``sim_bridge.emulator.Emulator.step``: called every millisecond in real time). At the end one JSON line on
stderr: collections and the longest per generation (s), and the gaps (s). Any ``slung emulate`` option after ``--``:

    chrt -f 10 python bench/emulator_pauses.py -- --realtime --duration 60 --mavlink udpout:127.0.0.1:14540

(a ``slung fly`` on that port makes it a flight; without one the emulator streams to nobody.)
"""

from __future__ import annotations

import argparse
import atexit
import gc
import json
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sim_bridge import emulator as emulator_mod
from sim_bridge.emulator_cli import main as emulate


def install_probes(gap_s: float) -> dict[str, Any]:
    """The probes (module docstring); their figures, filled as the emulator runs."""
    figures: dict[str, Any] = {"gc": {g: {"n": 0, "max_s": 0.0} for g in (0, 1, 2)}, "step_gaps_s": []}
    started: dict[int, float] = {}

    def on_gc(phase: str, info: dict[str, int]) -> None:
        g = info["generation"]
        if phase == "start":
            started[g] = time.perf_counter()
            return
        d = time.perf_counter() - started.get(g, time.perf_counter())
        f = figures["gc"][g]
        f["n"] += 1
        f["max_s"] = max(f["max_s"], d)

    gc.callbacks.append(on_gc)
    step = emulator_mod.Emulator.step
    last = [0.0]

    def timed_step(self: Any, n: int) -> None:
        now = time.perf_counter()
        if last[0] and now - last[0] > gap_s:
            figures["step_gaps_s"].append(round(now - last[0], 4))
        last[0] = now
        step(self, n)

    emulator_mod.Emulator.step = timed_step  # type: ignore[method-assign]
    return figures


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--gap-ms", type=float, default=50.0)
    ap.add_argument("emulate", nargs=argparse.REMAINDER, help="slung emulate's options, after --")
    a = ap.parse_args()
    figures = install_probes(a.gap_ms * 1e-3)
    atexit.register(lambda: print(json.dumps(figures), file=sys.stderr, flush=True))
    args = a.emulate[1:] if a.emulate[:1] == ["--"] else a.emulate
    return emulate(args)


if __name__ == "__main__":
    sys.exit(main())
