"""The 2 m move in 4 s of ``tests/test_px4_sitl.py`` (the velocity-step reference at 2 m) flown by ``slung fly`` against
the emulator's PX4 flavour with the ``px4-sih`` vehicle and ``--ekf px4-sih``, judged on the emulator's truth: the
tilt p95 and peak over the flight window (the live time series' first to last vehicle time), the figure
docs/emulator.md sets beside real PX4's (docs/deploy.md section 2a: 8.4-9.5 deg).

    python bench/emulator_move_tilt.py --seed N [--out DIR]

The emulator runs in this process (real time) and its truth is sampled every 2 ms; ``slung fly`` is a subprocess.
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

from offboard.logs.timeseries_file import read_table

#: the move of tests/test_px4_sitl.py: rest 1 s, 2 m along x in 4 s with the velocity step, at 2 m
MOVE_TOML = 'shape = "velocity"\n' + "".join(
    f"[[waypoint]]\nt = {t}\nx = {x}\ny = 0.0\nz = 2.0\n" for t, x in ((0.0, 0.0), (1.0, 0.0), (5.0, 2.0))
)


def main() -> int:
    from sim_bridge.emulator_api import EmulatorConfig, start_emulator

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0, help="the emulator's seed (its EKF error, origin, noise)")
    ap.add_argument("--out", type=Path, default=None, help="folder for the flight (default: a temporary one)")
    args = ap.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="emulator-move-"))
    out.mkdir(parents=True, exist_ok=True)
    traj = out / "move.toml"
    traj.write_text(MOVE_TOML, encoding="utf-8")
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    cfg = EmulatorConfig(
        flavor="px4", vehicle="px4-sih", mavlink=(f"udpout:127.0.0.1:{port}",), seed=args.seed, ekf="px4-sih"
    )
    running = start_emulator(cfg)
    emu = running.emulator
    samples: list[tuple[float, float]] = []
    stop = threading.Event()

    def sample() -> None:
        while not stop.is_set():
            tr = emu.truth()
            phi, theta = tr.euler_rad[0], tr.euler_rad[1]
            samples.append((tr.time_s, math.acos(max(-1.0, min(1.0, math.cos(phi) * math.cos(theta))))))
            time.sleep(0.002)

    th = threading.Thread(target=sample, daemon=True)
    th.start()
    cmd = [sys.executable, "-m", "offboard.cli", "-v", "fly", "--connect", f"udpin:127.0.0.1:{port}"]
    cmd += ["--vehicle", "px4-sih", "--trajectory", str(traj), "--duration", "8", "--no-figures"]
    try:
        p = subprocess.run([*cmd, "--out", str(out / "fly")], capture_output=True, text=True, timeout=300)
    finally:
        stop.set()
        th.join()
        running.stop()
    if p.returncode != 0:
        print(f"slung fly exited {p.returncode}: {p.stderr.strip().splitlines()[-1:]}", file=sys.stderr)
        return 1
    t_vehicle = read_table(out / "fly" / "timeseries_live.slts")["t_vehicle"]
    t0, t1 = float(t_vehicle[0]), float(t_vehicle[-1])
    s = np.array(samples)
    tilt = s[(s[:, 0] >= t0) & (s[:, 0] <= t1), 1]
    p95, peak = math.degrees(float(np.percentile(tilt, 95))), math.degrees(float(tilt.max()))
    print(
        f"seed {args.seed}: flight window {t0:.2f}-{t1:.2f} s of vehicle time, {len(tilt)} truth samples: "
        f"tilt p95 {p95:.2f} deg, peak {peak:.2f} deg"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
