"""``slung fly --vehicle ardupilot-sitl-quad`` against the real ArduPilot Copter SITL carrying ArduPilot's own slung
payload (``shared/ardupilot-sitl``: payload physics this project did not write), judged on the simulation's truth in
ArduPilot's DataFlash log (``SLUP``, ``SIM2``, ``ATT``, read with pymavlink's DFReader through
``sim_bridge.sitl.ardupilot_dataflash``) and on the payload's own position report (MAVLink system 2, watched on
SERIAL1 by ``sim_bridge.sitl.ardupilot_monitor``). Neither is given to ``slung fly``: it estimates the swing from the
IMU alone.

One SITL boot (instance 0, 1.2 kg on 1 m; boot to EKF3 position is about 40 s) serves the module, and two flights
are flown in it with the real command line (``slung -v fly`` in a subprocess):

- **move**: take-off to 2 m, then the move as a user gives it (``--move 3,0,2 --arrive-by 4``: a 2 s hover, 3 m north
  arriving in 4 s, the load at rest at both ends), 15 s at the goal, ``--end land``;
- **hold**: take-off again, a hover, then Ctrl-C (a real SIGINT): the hand-over to ArduPilot's hold (BRAKE), which
  must keep the vehicle and its load where they were; the test then lands it as a ground station would.

The bounds are generous (a loaded shared machine flies these; issue 37's table has the figures measured on a quiet
one) but each can fail: completed, arrival within 1.5 s of the asked 4 s, swing peak under 2x the physical bound at
the arrival time (the move's profile flew 1.4x on a quiet machine; the waypoints, 2.5-2.8x, would fail it), residual
swing under 2 deg, overshoot under 0.3 m, ArduPilot's own tilt (ATT) within the tilt limit ``slung fly`` announced.
Payload flights run one at a time on the machine (the payload simulation always connects to instance 0): on a shared
machine run this file under ``flock /tmp/ardupilot-instance0.lock``; ``.ci/run`` needs nothing beyond the SITL folder.
Without the SITL the tests skip saying so; ``SLUNG_REQUIRE_REAL=1`` fails instead.
"""

from __future__ import annotations

import json
import math
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from real_components import require_ardupilot_sitl

from offboard.logs.timeseries_file import Table, read_table
from sim_bridge.sitl.ardupilot_dataflash import (
    MODES,
    ArduPilotFlightLog,
    move_figures,
    physical_bound,
    read_dataflash,
)
from sim_bridge.sitl.ardupilot_guided import GuidedLink
from sim_bridge.sitl.ardupilot_sitl import ArduPilotSitl, ArduPilotSitlError, why_no_ardupilot_sitl

HEIGHT_M = 2.0
MOVE_M, MOVE_S, REST_S, AFTER_S = 3.0, 4.0, 2.0, 15.0
#: what each flight is asked: the move as a user gives it (its 2 s rest before the move is ``REST_S``), the hold a hover
REFERENCES = {
    "move": [
        "--move",
        f"{MOVE_M},0,{HEIGHT_M}",
        "--arrive-by",
        str(MOVE_S),
        "--duration",
        str(REST_S + MOVE_S + AFTER_S),
    ],
    "hold": ["--trajectory", "trajectory.toml"],
}
HOLD_TRAJECTORY = f'kind = "hover"\nx = 0.0\ny = 0.0\nz = {HEIGHT_M}\n'
#: Ctrl-C this long (wall s) after offboard control started, and the hold judged for this long after the hand-over
SIGINT_AFTER_S = 6.0
HOLD_JUDGED_S = 6.0


@dataclass
class Flight:
    """What one flight left: the CLI's exit code and output, its report folder and the DataFlash log holding it."""

    name: str
    out: Path
    returncode: int | None = None
    stderr: str = ""
    log: ArduPilotFlightLog | None = None
    #: boot-clock seconds of the hand-over's end for the hold flight (the test landed the vehicle after it)
    t_landing: float | None = None

    @property
    def metrics(self) -> dict[str, Any]:
        return json.loads((self.out / "fly" / "metrics.json").read_text())

    def ticks(self) -> Table:
        """The flight's tick log (``timeseries_live.slts``), columns by name."""
        return read_table(self.out / "fly" / "timeseries_live.slts")

    def announced_tilt_limit(self) -> float:
        """The tilt limit ``slung fly`` announced for its setpoints (rad), from its output."""
        m = re.search(r"setpoints within ([0-9.]+) deg", self.stderr)
        assert m, f"{self.name}: no announced tilt limit in the output:\n{self.stderr[-3000:]}"
        return math.radians(float(m.group(1)))


def _fly(sitl: ArduPilotSitl, name: str, base: Path) -> Flight:
    out = base / name
    out.mkdir(parents=True, exist_ok=True)
    (out / "trajectory.toml").write_text(HOLD_TRAJECTORY, encoding="utf-8")
    flight = Flight(name, out)
    cmd = [
        sys.executable,
        "-m",
        "offboard.cli",
        "-v",
        "fly",
        "--connect",
        sitl.connection_url,
        "--vehicle",
        "ardupilot-sitl-quad",
        *REFERENCES[name],
        "--no-figures",
        "--end",
        "land",
        # the SITL and this loop share a 2-core machine with the rest of the suite (see test_px4_sitl.py)
        "--stale-limit",
        "0.25",
        "--out",
        str(out / "fly"),
    ]
    if name == "hold":
        cmd += ["--duration", "60", "--on-signal", "hold"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=out)
    if name == "hold":
        lines: list[str] = []
        assert proc.stderr is not None
        for line in proc.stderr:
            lines.append(line)
            if "offboard control started" in line:
                break
        time.sleep(SIGINT_AFTER_S)
        proc.send_signal(signal.SIGINT)
        _, rest_err = proc.communicate(timeout=60)
        flight.stderr = "".join(lines) + rest_err
    else:
        _, flight.stderr = proc.communicate(timeout=240)
    flight.returncode = proc.returncode
    if name == "hold":  # slung left the vehicle holding (BRAKE); watch the hold, then land it as a ground station
        link = GuidedLink(sitl.connection_url)
        try:
            link.pump(HOLD_JUDGED_S)
            flight.t_landing = link.t_boot
            link.land()
        finally:
            link.close()
    logs = sitl.dataflash_logs()  # ArduPilot logs from the first arming on; later armings may share its file
    assert logs, f"{name}: ArduPilot wrote no DataFlash log"
    time.sleep(1.0)  # let the log's last blocks after the disarm reach the file
    flight.log = read_dataflash(logs[-1])
    return flight


@pytest.fixture(scope="module")
def flights(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[ArduPilotSitl, dict[str, Flight]]]:
    root = require_ardupilot_sitl()
    base = tmp_path_factory.mktemp("ardupilot-sitl")
    sitl = ArduPilotSitl(instance=0, workdir=base / "sitl", root=root)
    try:
        sitl.start()
        yield sitl, {name: _fly(sitl, name, base) for name in ("move", "hold")}
    finally:
        sitl.stop()


pytestmark = pytest.mark.slow


def _control_start(f: Flight) -> float:
    return float(f.ticks()["t_vehicle"][0])


def test_the_sitl_boots_ready_and_the_payload_reports_itself(flights: tuple[ArduPilotSitl, dict[str, Flight]]) -> None:
    """Readiness is the pre-arm checks plus EKF3's local position; the payload (system 2) reported itself on SERIAL1
    throughout and, in flight, hung below the vehicle on its 1 m line."""
    sitl, fl = flights
    assert sitl.ready_after_s is not None and sitl.ready_after_s < 110.0
    mon = sitl.monitor
    assert mon is not None and mon.payload_heartbeats > 10
    t0 = _control_start(fl["move"])
    t, off = mon.payload_offsets(t0, t0 + REST_S)  # hovering at 2 m before the move
    assert len(t) >= 5, f"only {len(t)} payload reports while hovering"
    length = np.linalg.norm(off, axis=1)
    assert np.all(np.abs(length - 1.0) < 0.1), f"payload line length {length.min():.2f}..{length.max():.2f} m"


def test_move_completes_and_lands(flights: tuple[ArduPilotSitl, dict[str, Flight]]) -> None:
    f = flights[1]["move"]
    assert f.returncode == 0, f.stderr[-3000:]
    fl = f.metrics["flight"]
    assert fl["ended_by"] == "completed" and fl["end_state"] == "landed, disarmed"
    assert f.log is not None and f.log.mode["mode"][-1] == MODES["land"]


def test_move_is_judged_on_the_payload_truth(flights: tuple[ArduPilotSitl, dict[str, Flight]]) -> None:
    """3 m in 4 s at 2 m: arrival, swing peak against the physical bound, residual swing, overshoot (DataFlash)."""
    f = flights[1]["move"]
    assert f.log is not None
    t_move = _control_start(f) + REST_S
    fig = move_figures(f.log, t_move, t_move + MOVE_S + AFTER_S, MOVE_M)
    summary = {k: round(v, 3) for k, v in fig.as_dict().items()}
    assert fig.arrival_s <= MOVE_S + 1.5, summary
    assert fig.peak_rad <= 2.0 * fig.bound_rad, summary
    assert fig.peak_rad >= 0.5 * physical_bound(MOVE_M, MOVE_S + 1.5), summary  # the load did swing: a live judge
    assert fig.residual_span_s >= 9.0 and fig.residual_rad <= math.radians(2.0), summary
    assert fig.overshoot_m <= 0.3, summary


def test_tilt_stays_within_the_announced_limit(flights: tuple[ArduPilotSitl, dict[str, Flight]]) -> None:
    """ArduPilot's own attitude (ATT), from the start of control to the hand-over, within the limit slung announced
    for its setpoints (issue 38: the rate feed-forward once pitched ArduPilot past it)."""
    for f in flights[1].values():
        assert f.log is not None
        ticks = f.ticks()
        t0, t1 = float(ticks["t_vehicle"][0]), float(ticks["t_vehicle"][-1])
        limit = f.announced_tilt_limit()
        assert f.log.max_tilt(t0, t1) <= limit + math.radians(1.0), (
            f"{f.name}: tilt {math.degrees(f.log.max_tilt(t0, t1)):.1f} deg, limit {math.degrees(limit):.1f}"
        )


def test_ctrl_c_hands_over_to_a_hold_that_keeps_vehicle_and_load(
    flights: tuple[ArduPilotSitl, dict[str, Flight]],
) -> None:
    f = flights[1]["hold"]
    assert f.returncode == 1, f.stderr[-3000:]
    fl = f.metrics["flight"]
    assert fl["ended_by"] == "signal", fl
    assert f.log is not None and f.t_landing is not None
    t_end = float(f.ticks()["t_vehicle"][-1])
    assert f.log.mode_at(t_end + 1.0) == MODES["brake"]
    pos = f.log.sim_pos.window(t_end, f.t_landing)
    assert len(pos) > 100
    drift = np.hypot(pos["pn"] - pos["pn"][0], pos["pe"] - pos["pe"][0])
    assert float(np.max(drift)) < 0.5, f"the hold drifted {np.max(drift):.2f} m"
    assert float(np.max(np.abs(pos["pd"] - pos["pd"][0]))) < 0.3
    swing = f.log.swing(_control_start(f) + 1.0, f.t_landing)
    assert float(np.max(swing["swing"])) < math.radians(3.0)


def test_launcher_reports_an_absent_sitl(tmp_path: Path) -> None:
    why = why_no_ardupilot_sitl(tmp_path / "nowhere")
    assert why is not None and "nowhere" in why
    with pytest.raises(ArduPilotSitlError, match="no ArduPilot SITL launcher"):
        ArduPilotSitl(root=tmp_path / "nowhere").start()


def test_dataflash_reader_refuses_what_is_not_dataflash(tmp_path: Path) -> None:
    bad = tmp_path / "x.BIN"
    bad.write_bytes(b"not a log")
    with pytest.raises(ValueError, match="not a DataFlash log"):
        read_dataflash(bad)


def test_no_false_alarms_and_no_sag_at_the_start(flights: tuple[ArduPilotSitl, dict[str, Flight]]) -> None:
    """Issue 38's messages printed on every ArduPilot flight are gone (the DEBUG_VECT stream ArduPilot does not have,
    a priming of 0 setpoints over 0 s, a hover throttle compared with a thrust fraction), and the hover throttle
    that maps the thrust is the loaded vehicle's: with ArduPilot's unlearnt MOT_THST_HOVER (0.39 against 0.51) the
    vehicle sagged 12.6 cm in the first 2 s of control (2026-12-07, this SITL)."""
    for f in flights[1].values():
        for text in ("DEBUG_VECT at", "0 setpoints over 0 s", "total weight / max thrust"):
            assert text not in f.stderr, f"{f.name}: {text!r} in the output"
        ticks = f.ticks()
        first = (ticks["t_vehicle"] - ticks["t_vehicle"][0]) < 5.0
        sag = float(np.min(ticks["est_z"][first] - ticks["ref_z0"][first]))
        assert sag > -0.06, f"{f.name}: the vehicle sagged {-sag:.3f} m in the first 5 s of control"
