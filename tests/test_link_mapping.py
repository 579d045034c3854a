"""Command mapping: N and N m -> normalized setpoints; the torque -> attitude inversion checked against an
autopilot attitude / rate cascade (the emulator's, ``sim_bridge.inner.airframe``); limits; NaN never passes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimators.model import frames
from estimators.model.control_state import ControlState
from estimators.model.rotations import body_rates
from estimators.model.vehicle import Vehicle
from offboard.control.smc import Command
from offboard.flight.command_mapping import CommandMapper, MappingConfig
from offboard.flight.link.autopilot_model import AutopilotModel
from offboard.flight.link.setpoints import ActuatorTarget, AttitudeTarget, encode
from sim_bridge.inner.airframe import AttitudeController


def _state(phi=0.0, theta=0.0, psi=0.0, dphi=0.0, dtheta=0.0, dpsi=0.0) -> ControlState:
    z6 = (0.0,) * 6
    return ControlState(z6, z6, 2.0, 0.0, phi, theta, psi, dphi, dtheta, dpsi, 0.0, 0.0, 0.0, 0.0)


def _cmd(thrust: float, tp: float = 0.0, tt: float = 0.0, ts: float = 0.0, valid: bool = True) -> Command:
    return Command(thrust, tp, tt, ts, 0.0, 0.0, 0.0, 0.0, False, valid)


def _realized_torque(v: Vehicle, est: ControlState, sp: AttitudeTarget) -> tuple[float, float, float]:
    """Torque the emulator's P attitude + P rate cascade produces for this setpoint, at this state."""
    ac = AttitudeController(v, 0.001)
    q = frames.euler_to_quaternion(est.phi, est.theta, est.psi)
    qd = frames.ned_quaternion_to_model(*sp.q)
    rate_sp = ac.attitude_to_rates(q, qd)
    w = body_rates(est.phi, est.theta, est.phi_rate, est.theta_rate, est.psi_rate)
    return ac.rates_to_torque(rate_sp, w, integrate=False)


def test_attitude_setpoint_delivers_the_commanded_torque_through_the_cascade() -> None:
    v = Vehicle()
    rng = np.random.default_rng(3)
    worst = 0.0
    for _ in range(200):
        est = _state(*rng.uniform(-0.4, 0.4, 2), rng.uniform(-3, 3), *rng.uniform(-0.5, 0.5, 3))
        tau = rng.uniform(-0.5, 0.5, 3) * np.array([v.roll_pitch_torque_max, v.roll_pitch_torque_max, v.yaw_torque_max])
        m = CommandMapper(v, MappingConfig(max_tilt=1.0, max_rate=10.0))
        sp = m.map(0.0, _cmd(v.hover_thrust, *tau), est)
        got = _realized_torque(v, est, sp)
        scale = np.array([v.roll_pitch_torque_max, v.roll_pitch_torque_max, v.yaw_torque_max])
        worst = max(worst, float(np.max(np.abs((np.array(got) - tau) / scale))))
    # the inversion is exact for that cascade (float rounding only), at any heading and with rotation
    assert worst < 1e-9


def test_without_the_rate_term_the_cascade_would_fight_the_motion() -> None:
    """Negative control: dropping the eta'/K_att look-ahead term gives a torque opposing the current rate."""
    v = Vehicle()
    est = _state(dphi=0.5)
    m = CommandMapper(v)
    sp = m.map(0.0, _cmd(v.hover_thrust), est)
    assert abs(_realized_torque(v, est, sp)[0]) < 1e-3
    level = AttitudeTarget(frames.model_quaternion_to_ned(1.0, 0.0, 0.0, 0.0), 0.0, 0.0, 0.0, 0.5, 7)
    assert _realized_torque(v, est, level)[0] < -0.05


def test_hover_thrust_maps_to_the_autopilot_hover_throttle() -> None:
    v = Vehicle()
    m = CommandMapper(v)
    sp = m.map(0.0, _cmd(v.hover_thrust), _state())
    assert sp.thrust == pytest.approx(v.hover_thrust_normalized)
    m2 = CommandMapper(v, autopilot=AutopilotModel(hover_thrust_norm=0.5))
    assert m2.map(0.0, _cmd(v.hover_thrust), _state()).thrust == pytest.approx(0.5)


def test_ardupilot_angle_boost_is_pre_compensated() -> None:
    v = Vehicle()
    est = _state(phi=0.3)
    px4 = CommandMapper(v).map(0.0, _cmd(v.hover_thrust), est)
    ap = CommandMapper(v, autopilot=AutopilotModel(flavour="ardupilot", angle_boost=True)).map(
        0.0, _cmd(v.hover_thrust), est
    )
    assert ap.thrust == pytest.approx(px4.thrust * math.cos(0.3), rel=1e-9)
    # what ArduPilot does with it (throttle / cos(current tilt), the emulator's copy of it) gives back the thrust
    from sim_bridge.inner.airframe import angle_boost

    assert angle_boost(ap.thrust, 0.3, 0.0) == pytest.approx(px4.thrust, rel=1e-9)
    off = CommandMapper(v, autopilot=AutopilotModel(flavour="ardupilot", angle_boost=False)).map(
        0.0, _cmd(v.hover_thrust), est
    )
    assert off.thrust == pytest.approx(px4.thrust, rel=1e-12)


def test_actuator_output_normalizes_and_flips_to_frd() -> None:
    v = Vehicle()
    m = CommandMapper(v, MappingConfig(output="actuator"))
    tmax = v.roll_pitch_torque_max
    sp = m.map(0.0, _cmd(v.hover_thrust, 0.5 * tmax, 0.25 * tmax, 0.1 * v.yaw_torque_max), _state())
    assert isinstance(sp, ActuatorTarget)
    assert (sp.roll, sp.pitch, sp.yaw) == pytest.approx((0.5, -0.25, -0.1))
    assert sp.thrust == pytest.approx(v.hover_thrust / v.thrust_max)
    sp = m.map(0.001, _cmd(1e6, 1e6, -1e6, 0.0), _state())
    assert sp.roll <= 1.0 and sp.pitch >= -1.0 and sp.thrust <= 0.98


def test_actuator_output_normalizes_by_the_autopilots_unit_torque_when_known() -> None:
    """PX4's allocator turns a unit normalized torque into the CA_ROTOR* geometry's torque (SIH: 1.36 / 1.36 /
    0.256 N m for the paper vehicle's motors), not the vehicle file's hover-margin maximum; the mapping divides by
    the allocator's, so the delivered torque is the commanded one, before and after set_autopilot."""
    v = Vehicle()
    unit = (1.36, 1.4, 0.256)
    cmd = _cmd(v.hover_thrust, 0.5, 0.25, 0.05)
    m = CommandMapper(v, MappingConfig(output="actuator"), AutopilotModel(unit_torque=unit))
    sp = m.map(0.0, cmd, _state())
    assert (sp.roll, sp.pitch, sp.yaw) == pytest.approx((0.5 / 1.36, -0.25 / 1.4, -0.05 / 0.256))
    late = CommandMapper(v, MappingConfig(output="actuator"))
    late.set_autopilot(AutopilotModel(unit_torque=unit))
    assert late.map(0.0, cmd, _state()).roll == pytest.approx(sp.roll, rel=1e-12)


def test_slew_limits_bound_the_change_per_tick() -> None:
    v = Vehicle()
    m = CommandMapper(v, MappingConfig(output="actuator", thrust_slew=10.0, torque_slew=20.0))
    a = m.map(0.0, _cmd(0.0), _state())
    b = m.map(0.01, _cmd(v.thrust_max, v.roll_pitch_torque_max), _state())
    assert b.thrust - a.thrust == pytest.approx(0.1) and b.roll - a.roll == pytest.approx(0.2)


def test_tilt_and_rate_limits() -> None:
    v = Vehicle()
    m = CommandMapper(v, MappingConfig(max_tilt=0.3, max_rate=1.0))
    sp = m.map(0.0, _cmd(v.hover_thrust, 100.0, -100.0, 0.0), _state(dphi=5.0))
    phi, theta, _ = frames.quaternion_to_euler(*frames.ned_quaternion_to_model(*sp.q))
    assert abs(phi) <= 0.3 + 1e-9 and abs(theta) <= 0.3 + 1e-9
    assert max(abs(sp.roll_rate), abs(sp.pitch_rate), abs(sp.yaw_rate)) <= 1.0 + 1e-12


@pytest.mark.parametrize("output", ["attitude", "actuator"])
@pytest.mark.parametrize("where", ["thrust", "torque", "estimate", "invalid"])
def test_nan_anywhere_gives_a_finite_encodable_setpoint(output: str, where: str) -> None:
    import os

    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink import mavutil

    v = Vehicle()
    m = CommandMapper(v, MappingConfig(output=output))
    good = m.map(0.0, _cmd(v.hover_thrust, 0.01), _state(psi=1.0))
    cmd, est = _cmd(v.hover_thrust, 0.01), _state(psi=1.0)
    if where == "thrust":
        cmd = _cmd(math.nan)
    elif where == "torque":
        cmd = _cmd(v.hover_thrust, 0.0, math.inf)
    elif where == "estimate":
        est = _state(phi=math.nan)
    else:
        cmd = _cmd(v.hover_thrust, valid=False)
    soon = m.map(0.01, cmd, est)
    assert soon == good and m.events[-1].kind == "hold_last_setpoint"
    late = m.map(1.0, cmd, est)
    assert m.events[-1].kind == "hover_setpoint" and m.fallbacks == 2
    mav = mavutil.mavlink.MAVLink(None, 255, 191)
    for sp in (soon, late):
        buf = encode(mav, sp, 1.0, 1, 1).pack(mav)
        assert all(math.isfinite(x) for x in (sp.q if isinstance(sp, AttitudeTarget) else sp)) and len(buf) > 10
    if output == "attitude" and where != "estimate":
        # hover keeps the current heading
        assert frames.quaternion_to_euler(*frames.ned_quaternion_to_model(*late.q))[2] == pytest.approx(1.0)
