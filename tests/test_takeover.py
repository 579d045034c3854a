"""Taking over a load that already swings (issue 38), over MAVLink against the emulator in lockstep, both flavours.

A stock-like cascade without swing feedback moves 10 m in 4 s on a 10 m line and hands over to the autopilot's hold
with the load swinging 20-30 deg; ``slung fly --no-takeoff`` then hovers there, the swing estimated from the IMU
alone (the emulator's cable-angle stream is dropped by the decoder: ArduPilot SITL and most vehicles have none).
Before the tension-aware cable row (``estimators.model.cable.cable_pull``) the PX4 flavour's estimate ran to
+46 deg against a true +10 deg within 1 s and the swing watchdog ended the flight (``bench/emulator_takeover.py``).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from estimators.model.measurements import LoadAngle
from estimators.model.vehicle import load_vehicle
from offboard.control.controllers.registry import CONTROLLERS
from offboard.control.reference_patterns import hover, rest_to_rest
from offboard.flight.fly_cli import configure, fly
from offboard.flight.link.telemetry import TelemetryDecoder
from offboard.harness.demo_cli import EmulatorThread, free_udp_port
from offboard.logs.runlog import Scenario
from offboard.logs.timeseries_file import read_table

BUNDLED = Path(__file__).resolve().parents[1] / "estimators" / "model" / "vehicles" / "ardupilot-sitl-quad.toml"
LINE_M, MOVE_M, MOVE_S, HOVER_S = 10.0, 10.0, 4.0, 15.0
#: from here on (s after control starts) the estimate must have found the swing's sign; measured 7 Dec 2026: no
#: disagreement above 2 deg of true swing from 0.1 s on, in either flavour
CONVERGED_S = 0.5
#: the planar true swing (deg) above which the estimate's sign must be the truth's (on all but 2 % of the ticks),
#: and the most the estimate may point the wrong way
SIGN_FROM_DEG = 3.0


@pytest.mark.slow
@pytest.mark.parametrize("flavour", ["px4", "ardupilot"])
def test_a_swinging_load_taken_over_is_damped_not_chased(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, flavour: str
) -> None:
    decode = TelemetryDecoder.decode

    def without_cable_sensor(self: TelemetryDecoder, msg: Any) -> Any:
        m = decode(self, msg)
        return None if isinstance(m, LoadAngle) else m

    monkeypatch.setattr(TelemetryDecoder, "decode", without_cable_sensor)
    veh = tmp_path / "vehicle.toml"
    veh.write_text(BUNDLED.read_text().replace("cable_length_m = 1.0", f"cable_length_m = {LINE_M!r}"))
    v = load_vehicle(veh)
    h = LINE_M + 2.0
    port = free_udp_port()

    def args(folder: Path, *extra: str) -> argparse.Namespace:
        p = argparse.ArgumentParser()
        configure(p)
        return p.parse_args(
            [*("--connect", f"udpin:127.0.0.1:{port}", "--scenario", "hover", "--lockstep", "--vehicle", str(veh)),
             *("--no-figures", "--settle", "0", "--out", str(folder), *extra)]
        )  # fmt: skip

    emu = EmulatorThread(flavour, port, lockstep=True, period=0.004, vehicle=str(veh), sensors="px4-typical")
    emu.start()
    try:
        move = rest_to_rest((0.0, 0.0, h), (MOVE_M, 0.0, h), 1.0, MOVE_S)
        stock = Scenario("stock-move", "cascade", MOVE_S + 1.5, move.replace(duration=MOVE_S + 1.5))
        fly(
            args(tmp_path / "stock", "--force", "--law", "torque"),
            lockstep=True,
            quiet=True,
            scenario=stock,
            controller=CONTROLLERS["cascade"](v),
        )
        sc = Scenario("take-over", "hover", HOVER_S, hover(MOVE_M, 0.0, h).replace(duration=HOVER_S))
        m, folder = fly(
            args(tmp_path / "slung"), lockstep=True, takeoff=False, quiet=True, scenario=sc, truth_probe=emu.truth
        )
    finally:
        emu.stop()
    assert m["flight"]["ended_by"] == "completed", m["flight"]
    d = read_table(folder / "timeseries_live.slts")
    t = d["t_vehicle"] - d["t_vehicle"][0]
    true_y = np.degrees(np.arctan2(d["truth_x12"], -d["truth_x14"]))  # alpha_y: the swing along x
    true_x = np.degrees(np.arctan2(d["truth_x13"], -d["truth_x14"]))
    swing = np.hypot(true_x, true_y)
    assert swing[0] > 8.0, f"the stock move left only {swing[0]:.1f} deg to take over"
    end = float(swing[t > t[-1] - 2.0].max())
    assert end < 0.25 * swing[0], f"{swing[0]:.1f} deg at the take-over, still {end:.2f} deg at the end"
    for true, est in ((true_y, np.degrees(d["est_alpha_y"])), (true_x, np.degrees(d["est_alpha_x"]))):
        judged = (t >= CONVERGED_S) & (np.abs(true) > SIGN_FROM_DEG)
        # chasing is an estimate on the wrong side of the vertical by more than the swing it is judged on (main at
        # 06f65b8: -36 deg against a true +4.5); an estimate that lags through zero for a few ticks is not (CI, quiet
        # machine, 7 Dec 2026: 2-5 ticks of 3751 at 0.0-0.2 deg against a true 3.2 deg, the emulator not being
        # deterministic from run to run), so that is bounded as a share
        wrong_side = judged & (np.sign(est) != np.sign(true))
        chased = wrong_side & (np.abs(est) > SIGN_FROM_DEG)
        assert not chased.any(), (
            f"the estimate chases the swing at {t[chased][:5]} s: estimate {est[chased][:5]} deg, "
            f"truth {true[chased][:5]} deg"
        )
        assert wrong_side.sum() <= 0.02 * judged.sum(), (
            f"the estimate's sign is not the truth's on {wrong_side.sum()} of {judged.sum()} ticks, e.g. at "
            f"{t[wrong_side][:5]} s: estimate {est[wrong_side][:5]} deg, truth {true[wrong_side][:5]} deg"
        )
