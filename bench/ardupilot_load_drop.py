"""A load that drops off in flight, on real ArduPilot SITL with its own slung payload (1.2 kg on 1 m): is it told?

``slung fly --vehicle ardupilot-sitl-quad`` hovers at ``--height`` for ``--hold`` s; ``--drop-after`` s after
offboard control started, the payload simulation is switched off through ArduPilot's second link (PARAM_SET
``SIM_SLUP_ENABLE`` 0 on SERIAL1, the load gone as if its hook opened; whether it went is read in the DataFlash log:
the payload's ``SLUP`` records stop). Prints when the drop was made, the
``load_lost`` event slung told (vehicle time after the start of control) and the hover throttle learned before and
after (``metrics.json`` ``config.hover_thrust_learning``).

    flock /tmp/ardupilot-instance0.lock python bench/ardupilot_load_drop.py [--hold 20] [--drop-after 8] [--out DIR]

About 45 s of boot and 70 s of flight.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from offboard.logs.timeseries_file import read_table
from sim_bridge.sitl.ardupilot_dataflash import read_dataflash
from sim_bridge.sitl.ardupilot_sitl import ArduPilotSitl


def drop_payload(sitl: ArduPilotSitl, times: int = 3) -> None:
    """PARAM_SET ``SIM_SLUP_ENABLE`` 0 on SERIAL1, through the SITL's own passive monitor's connection (SERIAL1
    takes one client; the monitor reads what comes back)."""
    assert sitl.monitor is not None
    conn = sitl.monitor._conn
    for _ in range(times):
        conn.mav.param_set_send(1, 1, b"SIM_SLUP_ENABLE", 0.0, 2)
        time.sleep(0.05)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--height", type=float, default=2.0, help="hover height above take-off, m (default 2)")
    p.add_argument("--hold", type=float, default=20.0, help="hover under slung's control, s (default 20)")
    p.add_argument("--drop-after", type=float, default=8.0, help="drop the load this long into control, s")
    p.add_argument("--out", type=Path, help="where the flight goes (default a new temporary folder)")
    a = p.parse_args(argv)
    out = a.out or Path(tempfile.mkdtemp(prefix="slung-ardupilot-drop-"))
    out.mkdir(parents=True, exist_ok=True)
    traj = out / "trajectory.toml"
    traj.write_text(f'kind = "hover"\nx = 0.0\ny = 0.0\nz = {a.height:g}\n', encoding="utf-8")
    sitl = ArduPilotSitl(instance=0, workdir=out / "sitl")
    dropped_wall = None
    try:
        sitl.start()
        print(f"ArduPilot SITL ready after {sitl.ready_after_s:.0f} s; flight in {out}", flush=True)
        cmd = [sys.executable, "-m", "offboard.cli", "-v", "fly", "--connect", sitl.connection_url]
        cmd += ["--vehicle", "ardupilot-sitl-quad", "--trajectory", str(traj), "--duration", f"{a.hold:g}"]
        cmd += ["--no-figures", "--end", "land", "--stale-limit", "0.5", "--latency-limit", "0.3"]
        cmd += ["--out", str(out / "fly")]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        lines: list[str] = []
        assert proc.stderr is not None
        for line in proc.stderr:
            lines.append(line)
            if "offboard control started" in line:
                t_started = time.monotonic()
                break
        else:
            t_started = None
        if t_started is not None:
            time.sleep(max(0.0, a.drop_after - (time.monotonic() - t_started)))
            drop_payload(sitl)
            dropped_wall = time.monotonic() - t_started
            print(f"payload switched off {dropped_wall:.1f} s (wall) into control", flush=True)
        _, rest = proc.communicate(timeout=300)
        stderr = "".join(lines) + rest
        (out / "stderr.txt").write_text(stderr, encoding="utf-8")
    finally:
        sitl.stop()
    logs = sitl.dataflash_logs()
    flog = read_dataflash(logs[-1]) if logs else None
    mpath = out / "fly" / "metrics.json"
    if not mpath.is_file():
        print("no metrics: " + stderr.strip().splitlines()[-1])
        return 1
    m = json.loads(mpath.read_text())
    t0 = float(read_table(out / "fly" / "timeseries_live.slts")["t_vehicle"][0])
    events = json.loads((out / "fly" / "events.json").read_text())["loop"]
    lost = [e for e in events if e["kind"] == "load_lost"]
    learn = m["config"]["hover_thrust_learning"] or {}
    print(f"ended by {m['flight']['ended_by']}")
    print(
        f"hover throttle at the start of control {((learn.get('at_control_start') or {}).get('hover_throttle'))}, "
        f"at the end {learn.get('hover_throttle')}"
    )
    if flog is not None and dropped_wall is not None:
        slup = flog.slup
        before = slup["tension"][(slup.t > t0) & (slup.t < t0 + dropped_wall)]
        after = slup["tension"][slup.t > t0 + dropped_wall + 1.0]
        print(
            f"DataFlash SLUP: tension {np.mean(before) if len(before) else float('nan'):.1f} N before the drop, "
            f"{len(after)} records after it (tension {np.mean(after) if len(after) else float('nan'):.1f} N)"
        )
    if lost:
        print(f"load_lost {lost[0]['t_vehicle'] - t0:.1f} s into control: {lost[0]['reason']}")
    else:
        print("no load_lost event")
    return 0


if __name__ == "__main__":
    sys.exit(main())
