"""The emulator judged against real PX4 carrying a load: the 2 m move in 4 s of ``tests/test_px4_hil.py`` (velocity-
step reference at 2 m, ``px4-hil-load``, 100 Hz cable-angle sensor) flown by ``slung fly`` against (1) real PX4
SITL whose simulator is ``sim_bridge.sitl.px4_hil`` and (2) the emulator's PX4 flavour, each judged on its own truth
over the time under offboard control: the load's path against the reference (RMS), the peak swing, the tilt p95,
where the load comes to rest.

    python bench/emulator_vs_px4_hil.py [--seed N] [--instance I] [--sensors ideal|px4-typical] [--out DIR]

Both vehicles are the same file and the same plant code; what differs is the autopilot (real PX4's commander, EKF2,
attitude and rate control, allocator against the emulator's imitation of them) and the telemetry (EKF2 on the HIL
sensors against the emulator's sensor preset). The emulator runs in this process (real time) and its truth is
sampled every 2 ms; the HIL server writes its truth CSV; ``slung fly`` is a subprocess both times.
"""

from __future__ import annotations

import argparse
import math
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
from emulator_move_tilt import MOVE_TOML  # the 2 m move of the PX4 tests (bench/ is on the path of its scripts)

from offboard.logs.timeseries_file import read_table

VEHICLE = "px4-hil-load"
DURATION_S = 14.0


def _fly(url: str, traj: Path, out: Path) -> None:
    cmd = [sys.executable, "-m", "offboard.cli", "fly", "--connect", url, "--vehicle", VEHICLE, "--trajectory"]
    cmd += [str(traj), "--duration", str(DURATION_S), "--no-figures", "--stale-limit", "0.25", "--out", str(out)]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    if p.returncode != 0:
        raise SystemExit(f"slung fly exited {p.returncode}: {p.stderr.strip().splitlines()[-1:]}")


def _figures(fly: Path, t: np.ndarray, load: np.ndarray, tilt: np.ndarray) -> dict[str, float]:
    """The figures over the time under control: ``t`` (s, the autopilot's clock), the load's position (n, 3, NWU),
    the vehicle's tilt (rad), judged against the reference in ``fly``'s live time series."""
    live = read_table(fly / "timeseries_live.slts")
    keep = (t >= live["t_vehicle"][0]) & (t <= live["t_vehicle"][-1])
    t, load, tilt = t[keep], load[keep], tilt[keep]
    rx = np.interp(t, live["t_vehicle"], live["ref_fx0"])
    ry = np.interp(t, live["t_vehicle"], live["ref_fy0"])
    end = t >= t[-1] - 3.0
    return {
        "path_rms_m": float(np.sqrt(np.mean((load[:, 0] - rx) ** 2 + (load[:, 1] - ry) ** 2))),
        "tilt_p95_deg": math.degrees(float(np.percentile(tilt, 95))),
        "rest_x_m": float(np.mean(load[end, 0]) - load[0, 0]),
    }


def hil(traj: Path, out: Path, seed: int, instance: int) -> dict[str, float]:
    from estimators.model.vehicle import load_vehicle
    from sim_bridge.sitl.px4_hil import HIL_MODEL, Px4HilServer, hil_params
    from sim_bridge.sitl.px4_sitl import Px4Sitl

    v = load_vehicle(VEHICLE)
    out.mkdir(parents=True, exist_ok=True)
    server = Px4HilServer(v, instance=instance, seed=seed, truth_path=out / "truth.csv", load_sensor_hz=100.0)
    sitl = Px4Sitl(
        instance=instance, workdir=out / "px4", model=HIL_MODEL, params={**hil_params(v), "COM_OBL_RC_ACT": 5}
    )
    server.start()
    try:
        sitl.start()
        _fly(sitl.connection_url, traj, out / "fly")
    finally:
        sitl.stop()
        server.stop()
    tr = np.genfromtxt(out / "truth.csv", delimiter=",", names=True)
    load = np.stack([tr["load_x_m"], tr["load_y_m"], tr["load_z_m"]], axis=1)
    tilt = np.arccos(np.clip(np.cos(tr["phi_rad"]) * np.cos(tr["theta_rad"]), -1.0, 1.0))
    figs = _figures(out / "fly", tr["t_s"], load, tilt)
    figs["peak_swing_rad"] = float(tr["swing_rad"][tr["z_m"] > 0.5].max())
    return figs


def emulator(traj: Path, out: Path, seed: int, sensors: str) -> dict[str, float]:
    from estimators.model.vehicle import load_vehicle
    from sim_bridge.emulator_api import EmulatorConfig, start_emulator

    ell = load_vehicle(VEHICLE).cable_length
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    cfg = EmulatorConfig(
        flavor="px4", vehicle=VEHICLE, mavlink=(f"udpout:127.0.0.1:{port}",), seed=seed, sensors=sensors
    )
    running = start_emulator(cfg)
    emu = running.emulator
    rows: list[tuple[float, ...]] = []
    stop = threading.Event()

    def sample() -> None:
        while not stop.is_set():
            tr = emu.truth()
            p, r = tr.position_m, tr.cable_direction
            tilt = math.acos(max(-1.0, min(1.0, math.cos(tr.euler_rad[0]) * math.cos(tr.euler_rad[1]))))
            swing = math.atan2(math.hypot(r[0], r[1]), -r[2])
            rows.append((tr.time_s, p[0] + ell * r[0], p[1] + ell * r[1], p[2] + ell * r[2], tilt, swing, p[2]))
            time.sleep(0.002)

    th = threading.Thread(target=sample, daemon=True)
    th.start()
    try:
        _fly(f"udpin:127.0.0.1:{port}", traj, out / "fly")
    finally:
        stop.set()
        th.join()
        running.stop()
    a = np.array(rows)
    figs = _figures(out / "fly", a[:, 0], a[:, 1:4], a[:, 4])
    figs["peak_swing_rad"] = float(a[a[:, 6] > 0.5, 5].max())
    return figs


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0, help="sensor noise seed of both")
    ap.add_argument("--instance", type=int, default=5, help="PX4 instance of the HIL flight")
    ap.add_argument("--sensors", default="px4-typical", help="the emulator's sensor preset (ideal, px4-typical)")
    ap.add_argument("--out", type=Path, default=None, help="folder for the flights (default: a temporary one)")
    args = ap.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="emulator-vs-hil-"))
    out.mkdir(parents=True, exist_ok=True)
    traj = out / "move.toml"
    traj.write_text(MOVE_TOML, encoding="utf-8")
    results = {
        "real PX4 (HIL)": hil(traj, (out / "hil"), args.seed, args.instance),
        f"emulator ({args.sensors})": emulator(traj, (out / "emulator"), args.seed, args.sensors),
    }
    print(f"{'autopilot':<26} {'path RMS m':>10} {'peak swing rad':>15} {'tilt p95 deg':>13} {'rest x m':>9}")
    for name, f in results.items():
        print(
            f"{name:<26} {f['path_rms_m']:>10.3f} {f['peak_swing_rad']:>15.3f} {f['tilt_p95_deg']:>13.2f} "
            f"{f['rest_x_m']:>9.3f}"
        )
    print(f"flights: {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
