"""Taking over a swinging long-line load, over MAVLink against the emulator (issue 38).

The ArduPilot flavour of the emulator (lockstep, px4-typical sensors) flies the ArduPilot SITL quad with the line
changed (``/tmp``-free: the bundled file with ``cable_length_m`` replaced). A stock-like cascade without swing
feedback (``slung compare``'s ``cascade`` row, flown through ``slung fly``'s torque output) moves 10 m along x in
``--move`` s and hands over to the autopilot's hold with the load swinging; then ``slung fly --no-takeoff`` hovers
at the end point for ``--duration`` s. The emulator always streams its cable-angle sensor (LOADANG); ArduPilot SITL
has none, so the loop's decoder drops it here and the filter estimates the swing from the IMU alone. Prints the true
swing (the emulator's plant) and the estimate over the take-over.

    python bench/emulator_takeover.py [--line 10] [--move 4] [--duration 40] [--flavour ardupilot|px4] [--out DIR]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from estimators.model.measurements import LoadAngle  # noqa: E402 - after the path set-up
from estimators.model.vehicle import load_vehicle  # noqa: E402
from offboard.control.controllers.registry import CONTROLLERS  # noqa: E402
from offboard.control.reference_patterns import hover, rest_to_rest  # noqa: E402
from offboard.flight.fly_cli import configure, fly  # noqa: E402
from offboard.flight.link.telemetry import TelemetryDecoder  # noqa: E402
from offboard.harness.demo_cli import EmulatorThread, free_udp_port  # noqa: E402
from offboard.logs.runlog import Scenario  # noqa: E402
from offboard.logs.timeseries_file import read_table  # noqa: E402

BUNDLED = ROOT / "estimators" / "model" / "vehicles" / "ardupilot-sitl-quad.toml"


def without_cable_sensor() -> None:
    """The loop's decoder drops the emulator's LOADANG (ArduPilot SITL has no cable-angle sensor)."""
    decode = TelemetryDecoder.decode

    def drop(self: TelemetryDecoder, msg: Any) -> Any:
        m = decode(self, msg)
        return None if isinstance(m, LoadAngle) else m

    TelemetryDecoder.decode = drop  # type: ignore[method-assign]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--line", type=float, default=10.0, help="line length, m")
    ap.add_argument("--move", type=float, default=4.0, help="the stock move's duration (10 m), s")
    ap.add_argument("--duration", type=float, default=40.0, help="slung's hover after the take-over, s")
    ap.add_argument("--flavour", choices=("ardupilot", "px4"), default="ardupilot", help="the emulated autopilot")
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    out = a.out or Path(tempfile.mkdtemp(prefix="emulator-takeover-"))
    out.mkdir(parents=True, exist_ok=True)
    veh = out / "vehicle.toml"
    veh.write_text(BUNDLED.read_text().replace("cable_length_m = 1.0", f"cable_length_m = {a.line!r}"))
    v = load_vehicle(veh)
    h = a.line + 2.0
    without_cable_sensor()
    port = free_udp_port()

    def args(folder: Path, *extra: str) -> argparse.Namespace:
        p = argparse.ArgumentParser()
        configure(p)
        return p.parse_args(
            [*("--connect", f"udpin:127.0.0.1:{port}", "--scenario", "hover", "--lockstep", "--vehicle", str(veh)),
             *("--no-figures", "--settle", "0", "--out", str(folder), *extra)]
        )  # fmt: skip

    emu = EmulatorThread(a.flavour, port, lockstep=True, period=0.004, vehicle=str(veh), sensors="px4-typical")
    emu.start()
    try:
        move = rest_to_rest((0.0, 0.0, h), (10.0, 0.0, h), 1.0, a.move)
        stock = Scenario("stock-move", "cascade, 10 m", a.move + 1.5, move.replace(duration=a.move + 1.5))
        m1, _ = fly(
            args(out / "stock", "--force", "--law", "torque"),
            lockstep=True,
            quiet=True,
            scenario=stock,
            controller=CONTROLLERS["cascade"](v),
        )
        sc = Scenario("take-over", "hover", a.duration, hover(10.0, 0.0, h).replace(duration=a.duration))
        m2, folder = fly(
            args(out / "slung"), lockstep=True, takeoff=False, quiet=True, scenario=sc, truth_probe=emu.truth
        )
    finally:
        emu.stop()
    print(f"stock move: {m1['flight']['ended_by']}; slung take-over: {m2['flight']['ended_by']}")
    d = read_table(folder / "timeseries_live.slts")
    t = d["t_vehicle"] - d["t_vehicle"][0]
    true = np.degrees(np.arcsin(np.clip(np.hypot(d["truth_x12"], d["truth_x13"]), 0.0, 1.0)))
    est = np.degrees(np.hypot(d["est_alpha_x"], d["est_alpha_y"]))
    for t0 in (0, 1, 2, 3, 5, 10, 15, 20, 25, 30, 35, a.duration - 1):
        i = min(int(np.searchsorted(t, t0)), len(t) - 1)
        print(f"t {t[i]:5.1f} s  true swing {true[i]:6.2f} deg  estimate {est[i]:6.2f} deg")
    print(f"output: {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
