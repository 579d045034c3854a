"""The tilt limit holds on what the autopilot does, not on one field (issue 38 item 2): ArduPilot adds the
SET_ATTITUDE_TARGET body rates to its attitude target, so a setpoint clipped at 30 deg with a 115 deg/s pitch-rate
feed-forward still pitched ArduPilot SITL to 45.9 deg. ``offboard.flight.attitude_mapping.within_tilt`` keeps the
combined tilt of the setpoint within the limit and cuts the feed-forward that tilts further."""

from __future__ import annotations

import math

import pytest

from estimators.model.control_state import ControlState
from estimators.model.frames import frd_to_model_body, ned_quaternion_to_model, quaternion_to_euler
from estimators.model.vehicle import load_vehicle
from offboard.control.smc_attitude import AttitudeCommand
from offboard.flight.attitude_mapping import AttitudeLawMapper, within_tilt
from offboard.flight.command_mapping import MappingConfig
from offboard.flight.link.autopilot_model import AutopilotModel

LIMIT = math.radians(30.0)
K_ATT = 4.5  # ArduPilot's ATC_ANG_RLL_P / _PIT_P default


def _tilt(phi: float, theta: float) -> float:
    return math.acos(math.cos(phi) * math.cos(theta))


def test_a_setpoint_beyond_the_limit_is_scaled_back_on_its_combined_tilt() -> None:
    phi, theta, _, _ = within_tilt(0.5, 0.5, 0.0, 0.0, 0.0, 0.0, LIMIT, K_ATT)  # 0.5 rad each way: 40.9 deg tilt
    assert _tilt(phi, theta) <= LIMIT + 1e-12
    assert phi == pytest.approx(theta)  # the direction kept
    phi, theta, _, _ = within_tilt(0.0, -0.9, 0.0, 0.0, 0.0, 0.0, LIMIT, K_ATT)
    assert (phi, theta) == (0.0, pytest.approx(-LIMIT))


def test_the_rate_feed_forward_that_tilts_further_is_cut_at_the_limit() -> None:
    # the case: pitch clipped at the limit, 115 deg/s pitching further
    _, theta, p, q = within_tilt(0.0, 0.8, 0.0, math.radians(115.0), 0.0, 0.3, LIMIT, K_ATT)
    assert theta == pytest.approx(LIMIT) and q == pytest.approx(0.0, abs=1e-12) and p == 0.0
    # a rate back towards level passes unchanged, and so does one across the tilt direction
    assert within_tilt(0.0, 0.8, 0.4, -1.5, 0.0, 0.3, LIMIT, K_ATT)[2:] == (0.4, -1.5)
    # the vehicle itself beyond the limit (the setpoint is not): no rate that tilts it further
    _, _, p, q = within_tilt(0.1, 0.0, 1.0, 0.0, 0.62, 0.0, LIMIT, K_ATT)
    assert p <= 1e-12 and q == 0.0


def test_far_from_the_limit_the_laws_feed_forward_is_untouched() -> None:
    """At 10 deg the headroom (20 deg at 4.5 1/s: 1.57 rad/s) leaves a 1 rad/s feed-forward alone."""
    args = (0.0, math.radians(10.0), 0.2, 1.0, 0.0, math.radians(9.0), LIMIT, K_ATT)
    assert within_tilt(*args) == (0.0, math.radians(10.0), 0.2, 1.0)
    # near it, only what closes the headroom faster than the attitude loop would is cut
    _, _, _, q = within_tilt(0.0, math.radians(25.0), 0.0, 2.0, 0.0, math.radians(25.0), LIMIT, K_ATT)
    assert q == pytest.approx(K_ATT * math.radians(5.0))


def test_the_ardupilot_setpoint_on_the_wire_keeps_the_limit() -> None:
    """Through the mapper with ArduPilot's mask (attitude + rates): the quaternion's tilt and the FRD pitch rate."""
    vehicle = load_vehicle("ardupilot-sitl-quad")
    ap = AutopilotModel(flavour="ardupilot", attitude_p=(K_ATT, K_ATT, 4.5))
    mapper = AttitudeLawMapper(vehicle, MappingConfig(mask="attitude+rates", max_tilt=LIMIT), ap)
    hover = vehicle.hover_thrust
    cmd = AttitudeCommand(hover, 0, 0, 0, 0, 0, 0, 0, False, True, 0.2, 0.7, 0.0, 0.5, 2.0, 0.0)
    est = ControlState((0.0,) * 6, (0.0,) * 6, 2.0, 0.0, 0.1, 0.45, 0.0, 0, 0, 0, 0, 0, 0, 0)
    sp = mapper.map(0.0, cmd, est)
    phi, theta, _ = quaternion_to_euler(*ned_quaternion_to_model(*sp.q))
    assert _tilt(phi, theta) <= LIMIT + 1e-9
    p, q, _ = frd_to_model_body(sp.roll_rate, sp.pitch_rate, sp.yaw_rate)
    n = math.hypot(phi, theta)
    assert (p * phi + q * theta) / n <= 1e-9  # nothing that tilts further
