"""Synthetic .tlog files for the replay tests and benchmark, generated here (no binaries are committed).

:func:`flight_log` simulates the plant (``sim_bridge.plant.dynamics``: hover thrust, an initial swing, small
sinusoidal torques) and encodes what a PX4-like autopilot would stream with ``sim_bridge.protocol.telemetry``'s message
builders and pymavlink: HEARTBEAT, ATTITUDE, LOCAL_POSITION_NED, HIGHRES_IMU and the cable-angle sensor
(DEBUG_VECT "LOADANG"), each at its own rate. Options switch parts off (no heartbeat, no load sensor, no local
position, fixed-wing heartbeat, MAVLink 1 framing) for the "what is missing" tests.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from estimators.model.cable import cable_from_planar
from estimators.model.vehicle import Vehicle
from offboard.logs.estimate_columns import EST_NAMES
from offboard.logs.tlog import encode_record
from sim_bridge.plant import dynamics
from sim_bridge.protocol.messages import (
    msg_attitude,
    msg_debug_vect,
    msg_global_position_int,
    msg_highres_imu,
    msg_load_global_position_int,
    msg_local_position_ned,
)
from sim_bridge.protocol.telemetry import Home, TelemetrySource

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
    landed_until_s: float | None = None  # EXTENDED_SYS_STATE at 5 Hz: ON_GROUND before, IN_AIR after (None: none)
    armed: bool = True  # the HEARTBEAT's armed flag
    position_jump: tuple[float, float] | None = None  # (from t, metres): LOCAL_POSITION_NED x shifted from then on
    payload_hz: float = 0.0  # > 0: the vehicle's and the payload's own GLOBAL_POSITION_INT (system 2, an airship)


class _Ctx:
    """What sim_bridge.protocol.telemetry's message builders read of the emulator: its home and its EKF error model
    (none: the local frame's origin is the ground)."""

    home = Home()
    ekf = None


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
    mav_load = mavlink2.MAVLink(None, srcSystem=2, srcComponent=25)  # as ArduPilot's slung-payload SITL reports
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
            base_mode = 1 | (128 if spec.armed else 0)
            msgs.append(mav.heartbeat_encode(spec.mav_type, spec.autopilot, base_mode, spec.custom_mode, 4))
        if spec.landed_until_s is not None and _due(t_us, 5.0, dt_us):
            msgs.append(mav.extended_sys_state_encode(0, 1 if t < spec.landed_until_s else 2))
        snap = None
        for hz, builder, on in (
            (spec.attitude_hz, msg_attitude, True),
            (spec.position_hz, msg_local_position_ned, spec.local_position),
            (spec.imu_hz, msg_highres_imu, True),
            (spec.load_hz, msg_debug_vect, spec.load),
        ):
            if on and _due(t_us, hz, dt_us):
                snap = snap or src.snapshot(vt, x, u)
                msg = builder(mav, snap, _Ctx)
                if builder is msg_local_position_ned and spec.position_jump and t >= spec.position_jump[0]:
                    msg.x += spec.position_jump[1]  # a planted jump of the autopilot's position (north, m)
                msgs.append(msg)
        load_msgs = []
        if spec.payload_hz > 0 and _due(t_us, spec.payload_hz, dt_us):
            snap = snap or src.snapshot(vt, x, u)
            msgs.append(msg_global_position_int(mav, snap, _Ctx))
            if _due(t_us, 1.0, dt_us):
                load_msgs.append(mav_load.heartbeat_encode(7, 8, 0, 0, 4))  # AIRSHIP, AUTOPILOT_INVALID, ACTIVE
            load_msgs.append(msg_load_global_position_int(mav_load, snap, _Ctx))
        for i, m in enumerate(msgs):
            out += encode_record(EPOCH_US + t_us + 400 + 8 * i, m.pack(mav, force_mavlink1=spec.mavlink1))
        for i, m in enumerate(load_msgs):
            out += encode_record(EPOCH_US + t_us + 600 + 8 * i, m.pack(mav_load, force_mavlink1=spec.mavlink1))
        x = dynamics.rk4_step(x, u, p, dt_us * 1e-6, t)
    return bytes(out)


__all__ = ["EPOCH_US", "LIVE_HEADER", "LogSpec", "flight_log", "offboard_log", "write_live_table"]


LIVE_HEADER = (
    "t_vehicle",
    "t_ref",
    "n_meas",
    *("est_" + n for n in EST_NAMES),
    *(f"sp{i}" for i in range(9)),
)


def offboard_log(
    seconds: float = 3.0,
    rate_hz: float = 250.0,
    output: str = "attitude",
    scenario: str = "hover",
    switch_s: float = 0.3,
) -> tuple[bytes, list[tuple[float, ...]]]:
    """A log of an offboard flight flown the way ``offboard.flight.loop.FlightLoop`` flies (for the replay tests when
    the live loop itself is not at hand), with the same building blocks.

    The plant (``sim_bridge.plant.dynamics``, off the reference with the load swinging) streams ATTITUDE and HIGHRES_IMU
    at 250 Hz, LOCAL_POSITION_NED and the cable-angle sensor at 50 Hz; the companion streams hover setpoints
    until the HEARTBEAT reports OFFBOARD (at ``switch_s``), then initializes the Kalman filter from the latest
    telemetry, shifts the reference to start where the vehicle is, and ticks every ``1 / rate_hz``: it pushes the
    measurements decoded since the previous tick (from the packed wire bytes), estimates at the tick's vehicle
    time, steps the controller at controller time ``t_ref = t - t0``, maps and logs the setpoint and feeds the
    command back. The plant flies the controller's thrust and torques. Returns the tlog bytes and the live tick
    rows (columns :data:`LIVE_HEADER`, like the loop's ``timeseries_live.csv``).
    """
    from estimators.filters.factory import make_estimator
    from offboard.control import smc
    from offboard.control.scenarios import make_scenario
    from offboard.flight.command_mapping import CommandMapper, MappingConfig
    from offboard.flight.link.setpoints import encode
    from offboard.flight.link.telemetry import TelemetryDecoder
    from offboard.logs.replay import initial_guess

    v = Vehicle()
    p = dynamics.plant_params(v)
    r0, rd0 = cable_from_planar(0.15, -0.1)
    x = dynamics.make_state(position=(0.2, -0.1, 1.1), cable=r0, cable_rate=rd0)
    src = TelemetrySource(p, _Ctx.home)
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    gcs = mavlink2.MAVLink(None, srcSystem=255, srcComponent=191)
    rx = mavlink2.MAVLink(None)
    dec = TelemetryDecoder(system=1)
    est_f = make_estimator("kf", v, load_sensor=True, rate_hz=rate_hz)
    from offboard.flight.loop import ActuatorLag

    lag = ActuatorLag(v.motor_time_constant)  # the live loop gives the filter what the motors deliver
    params = smc.ControllerParams.for_vehicle(v, switching="smooth", epsilon=1.0)
    mapper = CommandMapper(v, MappingConfig(output=output))
    ref = make_scenario(scenario).reference
    memory = smc.ControllerMemory()
    out = bytearray()
    live: list[tuple[float, ...]] = []
    last: dict[str, object] = {}
    ready = False
    n_meas = 0
    dt_us = 1000
    tick_us = round(1e6 / rate_hz)
    boot_us = 20_000_000
    switch_us = round(switch_s * 1e6)
    t0 = 0.0
    origin = (0.0, 0.0)
    u = dynamics.hover_input(p)
    nan = float("nan")
    for k in range(int(seconds * 1e6 / dt_us) + 1):
        t_us = k * dt_us
        vt = boot_us + t_us
        lt = EPOCH_US + t_us + 300
        msgs = []
        if _due(t_us, 1.0, dt_us) or t_us == switch_us:
            mode = PX4_OFFBOARD if t_us >= switch_us else 3 << 16
            msgs.append(mav.heartbeat_encode(2, 12, 1 | 128, mode, 4))
        snap = src.snapshot(vt, x, u)
        paused = ready and t_us <= switch_us + tick_us  # lockstep: no telemetry until the first setpoint
        for hz, builder in (
            (250.0, msg_attitude),
            (50.0, msg_local_position_ned),
            (250.0, msg_highres_imu),
            (50.0, msg_debug_vect),
        ):
            if _due(t_us, hz, dt_us) and not paused:
                msgs.append(builder(mav, snap, _Ctx))
        for i, m in enumerate(msgs):
            buf = m.pack(mav)
            out += encode_record(lt + 8 * i, buf)
            meas = dec.decode(rx.decode(bytearray(buf)))  # what the wire carries (float32 fields)
            if meas is not None:
                last[type(meas).__name__] = meas
                if ready:
                    est_f.push(meas)
                    n_meas += 1
        if t_us % tick_us != 0:
            pass
        elif t_us < switch_us:  # priming: hover setpoints, time 0 (as the loop sends before it starts)
            att = last.get("Attitude")
            sp = mapper.hover_setpoint(att.psi if att is not None else 0.0)  # type: ignore[attr-defined]
            out += encode_record(lt + 100, encode(gcs, sp, 0.0, 1, 1).pack(gcs))
        else:
            # the lockstep marker: SYSTEM_TIME with the tick's vehicle time in whole ms (as the emulator sends, except
            # before the first controller tick: the emulator only advances on a setpoint)
            if not (ready and t_us == switch_us + tick_us):
                marker = mav.system_time_encode(EPOCH_US + t_us, vt // 1000)
                out += encode_record(lt + 90, marker.pack(mav))
            t_v = (vt // 1000) * 1e-3
            if ready and t_us == switch_us + tick_us:
                t_v = t0 + tick_us * 1e-6  # the loop's first tick finds no new marker: predicted time
            if not ready:  # the loop: initialize, take t0 from this marker, tick from the next one on
                a, pv = last["Attitude"], last["PositionVelocity"]
                est_f.initialize(max(a.t, pv.t), initial_guess(v, pv, a, last.get("LoadAngle")))  # type: ignore
                ready = True
                t0 = t_v
                r0s = ref.sample(0.0)
                origin = (pv.x - r0s.fx[0], pv.y - r0s.fy[0])  # type: ignore[attr-defined]
                x = dynamics.rk4_step(x, u, p, dt_us * 1e-6, t_us * 1e-6)
                continue
            t_ref = t_v - t0
            est = est_f.estimate(t_v)
            r = ref.sample(t_ref)
            rfx = (r.fx[0] + origin[0], *r.fx[1:])
            rfy = (r.fy[0] + origin[1], *r.fy[1:])
            cmd, memory = smc.step(t_ref, est, rfx, rfy, r.z, r.psi, memory, params)
            sp = mapper.map(t_ref, cmd, est)
            out += encode_record(lt + 100, encode(gcs, sp, t_ref, 1, 1).pack(gcs))
            est_f.push_command(t_v, *lag(t_v, cmd.thrust, (cmd.tau_phi, cmd.tau_theta, cmd.tau_psi)))
            fields = (
                (*sp.q, sp.roll_rate, sp.pitch_rate, sp.yaw_rate, sp.thrust, float(sp.type_mask))
                if output == "attitude"
                else (*sp, nan, nan, nan, nan, nan)
            )
            live.append((t_v, t_ref, float(n_meas), *est.fx, *est.fy, *est[2:], *fields))
            u = dynamics.make_input(cmd.thrust, (cmd.tau_phi, cmd.tau_theta, cmd.tau_psi))
        x = dynamics.rk4_step(x, u, p, dt_us * 1e-6, t_us * 1e-6)
    return bytes(out), live


def write_live_table(path: object, rows: list[tuple[float, ...]]) -> None:
    """Write live tick rows as the loop's CSV (header :data:`LIVE_HEADER`, full precision)."""
    with open(path, "w", encoding="utf-8") as fh:  # type: ignore[call-overload]
        fh.write(",".join(LIVE_HEADER) + "\n")
        for r in rows:
            fh.write(",".join(repr(float(v)) for v in r) + "\n")
