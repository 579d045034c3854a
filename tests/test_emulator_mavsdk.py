"""The real MAVSDK library (``mavsdk`` 4.x, native binding) flies ``slung emulate`` (started with the ``slung``
console script) over UDP on 127.0.0.1: connect, identify the autopilot, telemetry, arm, offboard attitude +
thrust, climb, stop offboard, land, disarm. PX4 flavour and ArduPilot flavour (MAVSDK maps its Offboard plugin
to GUIDED on ArduPilot; the thrust there is a climb-rate command, so 0.6 climbs at 0.5 m/s)."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from emulator_helpers import free_port
from mavsdk import Autopilot, ComponentType, Configuration, Mavsdk, Vehicle
from mavsdk.plugins.action import Action
from mavsdk.plugins.offboard import Attitude, Offboard
from mavsdk.plugins.param import Param
from mavsdk.plugins.telemetry import FlightMode, Telemetry

SLUNG = Path(sys.executable).with_name("slung")


def _wait(cond: Callable[[], bool], timeout: float, what: str) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


@pytest.mark.slow
@pytest.mark.parametrize(
    ("flavor", "autopilot", "thrust", "land_param", "land_speed"),
    [
        ("px4", Autopilot.PX4, 0.48, "MPC_LAND_SPEED", 1.5),  # hover is 0.43 of max thrust: climbs
        ("ardupilot", Autopilot.ARDUPILOT, 0.6, "LAND_SPEED", 100.0),  # climb-rate semantics: 0.5 m/s up
    ],
)
def test_mavsdk_flies_the_emulator(
    flavor: str, autopilot: Autopilot, thrust: float, land_param: str, land_speed: float
) -> None:
    port = free_port()
    proc = subprocess.Popen(
        [str(SLUNG), "emulate", "--flavor", flavor, "--mavlink", f"udpout:127.0.0.1:{port}", "--est-ready", "0.5"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    drone = Mavsdk(Configuration.create_with_component_type(ComponentType.COMPANION_COMPUTER))
    try:
        drone.add_any_connection(f"udpin://127.0.0.1:{port}")
        system = drone.first_autopilot(10.0)
        assert system is not None
        assert system.autopilot_type() == autopilot
        assert system.vehicle_type() == Vehicle.MULTICOPTER
        tel, act, off, par = Telemetry(system), Action(system), Offboard(system), Param(system)
        # parameter protocol through MAVSDK (PX4 bytewise / ArduPilot C-cast encodings)
        assert par.get_param_float(land_param) == pytest.approx(0.7 if flavor == "px4" else 50.0)
        par.set_param_float(land_param, land_speed)
        assert par.get_param_float(land_param) == pytest.approx(land_speed)
        # telemetry: position (GLOBAL_POSITION_INT) and attitude arrive
        _wait(lambda: tel.position().absolute_altitude_m > 400.0, 5.0, "position")
        pos0 = tel.position()
        assert pos0.latitude_deg == pytest.approx(47.397742, abs=1e-6)
        assert abs(pos0.relative_altitude_m) < 0.05
        att = tel.attitude_euler()
        assert abs(att.roll_deg) < 1.0 and abs(att.pitch_deg) < 1.0
        assert not tel.armed()

        act.arm()
        _wait(tel.armed, 3.0, "armed")
        off.set_attitude(Attitude(0.0, 0.0, 0.0, thrust))  # starts MAVSDK's 20 Hz setpoint stream
        time.sleep(0.3)
        off.start()
        _wait(lambda: tel.flight_mode() == FlightMode.OFFBOARD, 3.0, "offboard")
        time.sleep(2.5)
        climbed = tel.position().relative_altitude_m
        assert climbed > 0.8, climbed
        off.stop()
        _wait(lambda: tel.flight_mode() == FlightMode.HOLD, 3.0, "hold after offboard stop")
        act.land()
        _wait(lambda: tel.position().relative_altitude_m < 0.05 and not tel.in_air(), 20.0, "landed")
        if tel.armed():
            act.disarm()
        _wait(lambda: not tel.armed(), 3.0, "disarmed")
    finally:
        drone.destroy()
        proc.terminate()
        out, _ = proc.communicate(timeout=10)
    summary = json.loads([ln for ln in out.splitlines() if ln.startswith("{")][-1])
    assert summary["counters"]["setpoints_accepted"] > 40  # MAVSDK's stream
    assert summary["counters"]["arms"] == 1 and not summary["armed"]
    names = [m for _, m in summary["modes"]]
    assert ("OFFBOARD" if flavor == "px4" else "GUIDED") in names
    assert summary["link"]["rx"]["malformed"] == 0 and summary["link"]["rx"]["bad_crc"] == 0
    assert summary["counters"]["handler_errors"] == 0  # every MAVSDK message handled without an internal error
