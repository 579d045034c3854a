"""Nominal flights and how they end (issue 39): ``slung fly --scenario paper`` against ``slung emulate --realtime``
(its own process, at ``SCHED_FIFO`` ``--emulator-priority``, default 10, as the issue's battery ran it) over UDP on
127.0.0.1, ``--flights`` times, each as its own ``slung fly`` process with the default watchdogs at the real-time
priority docs/deploy.md recommends on a busy computer (``--loop-priority``, default 20: ``slung fly --rt-priority``).
One JSON line per flight (ended_by, exit code, the staleness limit and what it was derived from, the longest gap
bridged, the hold's longest ATTITUDE gap, the load average), then a summary: the count by ``ended_by`` and of
``telemetry_stale``.

    python bench/nominal_flights.py [--flights 50] [--out DIR] [--emulator-priority 10] [--loop-priority 20]
                                    [--lockstep]

Needs the right to set SCHED_FIFO (root or CAP_SYS_NICE) for the emulator's priority; without it the emulator
runs at normal priority and the summary says so.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from emulator_helpers import emulator_process, stop_emulator_process  # noqa: E402 - after the path set-up

from offboard.harness.demo_cli import free_udp_port  # noqa: E402


def one(i: int, out: Path, priority: int, lockstep: bool, loop_priority: int = 0) -> dict:
    """One flight; its figures."""
    port = free_udp_port()
    emu = emulator_process(
        port, *(("--lockstep",) if lockstep else ("--realtime",)), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    prio = "normal"
    if priority > 0:
        try:
            os.sched_setscheduler(emu.pid, os.SCHED_FIFO, os.sched_param(priority))
            prio = f"SCHED_FIFO {priority}"
        except OSError as exc:
            prio = f"normal ({exc.strerror})"
    folder = out / f"flight-{i:03d}"
    cmd = [str(Path(sys.executable).parent / "slung"), "fly", "--connect", f"udpin:127.0.0.1:{port}"]
    cmd += ["--scenario", "paper", "--no-figures", "--out", str(folder), *(("--lockstep",) if lockstep else ())]
    if loop_priority > 0:
        cmd += ["--rt-priority", str(loop_priority)]
    load = os.getloadavg()[0]
    t0 = time.monotonic()
    try:
        p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600)
    finally:
        stop_emulator_process(emu)
    row: dict = {"flight": i, "exit": p.returncode, "wall_s": round(time.monotonic() - t0, 1), "load": load}
    row["emulator"], row["loop"] = prio, f"SCHED_FIFO {loop_priority}" if loop_priority > 0 else "normal"
    try:
        m = json.loads((folder / "metrics.json").read_text())
    except (OSError, ValueError):
        row["ended_by"] = "no metrics.json"
        row["stderr"] = p.stderr.strip().splitlines()[-1:] if p.stderr.strip() else []
        return row
    st = m["loop"].get("staleness", {})
    row.update(
        ended_by=m["flight"]["ended_by"],
        stale_limit_s=m["loop"].get("stale_limit_s"),
        derived_from=st.get("derived_from"),
        bridged_gaps=st.get("bridged_gaps"),
        bridged_gap_max_s=st.get("bridged_gap_max_s"),
        hold_attitude_gap_max_s=st.get("hold_gaps", {}).get("Attitude", {}).get("max_s"),
        rate_hz=m["loop"].get("rate_hz_achieved"),
        missed_fraction=m["loop"].get("missed_fraction"),
    )
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--flights", type=int, default=50)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--emulator-priority", type=int, default=10, help="SCHED_FIFO priority of the emulator (0: none)")
    ap.add_argument("--loop-priority", type=int, default=20, help="slung fly --rt-priority (0: normal scheduling)")
    ap.add_argument("--lockstep", action="store_true", help="emulator and loop in lockstep instead of real time")
    a = ap.parse_args()
    out = a.out or Path(tempfile.mkdtemp(prefix="slung-nominal-"))
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for i in range(a.flights):
        row = one(i, out, a.emulator_priority, a.lockstep, a.loop_priority)
        rows.append(row)
        print(json.dumps(row), flush=True)
    ends = collections.Counter(r["ended_by"] for r in rows)
    print(
        json.dumps(
            {
                "flights": len(rows),
                "ended_by": dict(ends),
                "telemetry_stale": ends.get("telemetry_stale", 0),
                "bridged_gaps": sum(r.get("bridged_gaps") or 0 for r in rows),
                "bridged_gap_max_s": max((r.get("bridged_gap_max_s") or 0.0 for r in rows), default=0.0),
                "out": str(out),
            }
        ),
        flush=True,
    )


if __name__ == "__main__":
    main()
