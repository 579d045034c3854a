"""A run folder fits on a companion computer (issue 36): the 50 s ``slung demo`` at most 15 MB, a 10-minute lockstep
flight against the emulator at most 100 MB. Flying ten minutes in the suite would cost ten minutes; instead one
short lockstep demo (9 s of control, above the 2000 ticks at which report.html's plots reach their decimation cap)
is measured and projected, each file by what it grows with:

- ``flight.tlog``: the telemetry and setpoints stream at fixed rates of the vehicle's (simulated) clock, so its
  bytes per simulated second (its first to last ATTITUDE) times the flight's simulated span: the same take-off,
  priming and settling as this run, plus the longer control phase;
- ``timeseries_live.slts``: bytes per tick times the ticks (the settle after the reference's end included);
- ``timeseries.slts``: proportional to the reference's duration (10 Hz);
- every other file (report.html with its decimated plots, the figures, the JSON) as measured: their size does not
  grow with the flight's length.

Measured on 7 Dec 2026 (docs/results.md, "Run folders"): the real 10-minute flight's folder was 91.3 MB
(``slung demo --duration 600``) and this projection of it from a 9 s flight 91.9 MB (the tick log over-estimated:
one short block compresses less than many long ones); the real 50 s demo's folder 12.1 MB. The test takes about
30 s on a loaded 2-core machine.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from offboard.logs.tlog import read_messages

FLIGHT_S = 9.0
MB = 1e6


def _vehicle_span_s(tlog: Path) -> float:
    """Simulated seconds the tlog covers: its first to last ATTITUDE (vehicle clock)."""
    msgs, _ = read_messages(tlog)
    t = [m.time_boot_ms for _, m in msgs if m.get_type() == "ATTITUDE"]
    return (t[-1] - t[0]) / 1000.0


def _project(folder: Path, duration_s: float) -> dict[str, float]:
    """Bytes of each file of ``folder`` (a demo of :data:`FLIGHT_S`) projected to a flight of ``duration_s``."""
    m = json.loads((folder / "metrics.json").read_text())
    rate = m["config"]["rate_hz"]
    ticks = m["loop"]["ticks"]
    settle_s = ticks / rate - FLIGHT_S  # what the loop flew beyond the reference (its stop and the settle)
    span = _vehicle_span_s(folder / "flight.tlog")
    sizes = {p.name: float(p.stat().st_size) for p in folder.iterdir() if p.is_file()}
    out = dict(sizes)
    out["flight.tlog"] = sizes["flight.tlog"] / span * (span - FLIGHT_S + duration_s)
    out["timeseries_live.slts"] = sizes["timeseries_live.slts"] / ticks * rate * (duration_s + settle_s)
    out["timeseries.slts"] = sizes["timeseries.slts"] * duration_s / FLIGHT_S
    return out


@pytest.mark.slow
def test_a_ten_minute_flight_and_the_demo_fit_on_a_companion_computer(tmp_path: Path) -> None:
    out = tmp_path / "run"
    r = subprocess.run(
        [sys.executable, "-m", "offboard.cli", "demo", "--duration", str(FLIGHT_S), "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    assert not (out / "emulator.tlog").exists()  # the emulator's mirror of the link only with --emulator-tlog
    assert json.loads((out / "metrics.json").read_text())["loop"]["ticks"] > 2000  # report.html at its cap
    ten = _project(out, 600.0)
    demo = _project(out, 50.0)
    print({k: round(v / MB, 2) for k, v in ten.items() if v > 0.1 * MB}, f"total {sum(ten.values()) / MB:.1f} MB")
    assert sum(ten.values()) <= 100 * MB, {k: round(v / MB, 2) for k, v in ten.items()}
    assert sum(demo.values()) <= 15 * MB, {k: round(v / MB, 2) for k, v in demo.items()}
