"""Synthetic .tlog files for the replay tests and benchmark, generated here (no binaries are committed).

:func:`flight_log` simulates the plant (``sim_bridge.dynamics``: hover thrust, an initial swing, small
sinusoidal torques) and encodes what a PX4-like autopilot would stream with ``sim_bridge.telemetry``'s message
builders and pymavlink: HEARTBEAT, ATTITUDE, LOCAL_POSITION_NED, HIGHRES_IMU and the cable-angle sensor
(DEBUG_VECT "LOADANG"), each at its own rate. Options switch parts off (no heartbeat, no load sensor, no local
position, fixed-wing heartbeat, MAVLink 1 framing) for the "what is missing" tests.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from estimators.cable import cable_from_planar
from estimators.vehicle import Vehicle
from offboard.tlog import encode_record
from sim_bridge import dynamics
from sim_bridge.telemetry import (
    Home,
    TelemetrySource,
    msg_attitude,
    msg_debug_vect,
    msg_highres_imu,
    msg_local_position_ned,
)

EPOCH_US = 1_790_000_000_000_000  # 2026-09-21, logger clock at the start of the log
PX4_OFFBOARD = 6 << 16


@dataclass(frozen=True)
class LogSpec:
    """What to put in a synthetic log. Rates in Hz; seconds of flight; mav_type 2 = quadrotor, 1 = fixed wing."""

    seconds: float = 4.0
    attitude_hz: float = 250.0
    position_hz: float = 50.0
    imu_hz: float = 250.0
    load_hz: float = 50.0
    heartbeat: bool = True
    load: bool = True
    local_position: bool = True
    mavlink1: bool = False
    mav_type: int = 2
    autopilot: int = 12
    custom_mode: int = PX4_OFFBOARD
    boot_s: float = 12.0


class _Ctx:
    home = Home()


def _due(t_us: int, hz: float, step_us: int) -> bool:
    period = round(1e6 / hz)
    return hz > 0 and (t_us % period) < step_us


def flight_log(spec: LogSpec = LogSpec()) -> bytes:
    """The bytes of a tlog of a hovering vehicle with a swinging load (see module docstring)."""
    v = Vehicle()
    p = dynamics.plant_params(v)
    r, rd = cable_from_planar(0.12, -0.06)
    x = dynamics.make_state(position=(0.0, 0.0, 2.0), cable=r, cable_rate=rd)
    src = TelemetrySource(p, _Ctx.home)
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    out = bytearray()
    dt_us = 1000
    n = int(spec.seconds * 1e6 / dt_us)
    boot_us = int(spec.boot_s * 1e6)
    for k in range(n + 1):
        t_us = k * dt_us
        t = t_us * 1e-6
        u = dynamics.hover_input(p)
        u[1] = 0.002 * math.sin(3.0 * t)
        u[2] = 0.002 * math.cos(2.0 * t)
        msgs = []
        vt = boot_us + t_us
        if spec.heartbeat and _due(t_us, 1.0, dt_us):
            msgs.append(mav.heartbeat_encode(spec.mav_type, spec.autopilot, 1 | 128, spec.custom_mode, 4))
        snap = None
        for hz, builder, on in ((spec.attitude_hz, msg_attitude, True),
                                (spec.position_hz, msg_local_position_ned, spec.local_position),
                                (spec.imu_hz, msg_highres_imu, True),
                                (spec.load_hz, msg_debug_vect, spec.load)):
            if on and _due(t_us, hz, dt_us):
                snap = snap or src.snapshot(vt, x, u)
                msgs.append(builder(mav, snap, _Ctx))
        for i, m in enumerate(msgs):
            out += encode_record(EPOCH_US + t_us + 400 + 8 * i, m.pack(mav, force_mavlink1=spec.mavlink1))
        x = dynamics.rk4_step(x, u, p, dt_us * 1e-6, t)
    return bytes(out)


__all__ = ["EPOCH_US", "LogSpec", "flight_log"]
