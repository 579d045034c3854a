"""offboard/flight/px4_allocation.py: PX4's normalized allocation and the physical torque of its unit torque;
PARAM_VALUE decoding of PX4's bytewise integers (offboard/flight/link/connection.param_value)."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest

from estimators.model.vehicle import Vehicle, load_vehicle
from offboard.flight.link.connection import VehicleInfo, param_value
from offboard.flight.px4_allocation import Rotor, normalized_mix, unit_torques

#: PX4's quadrotor X layout (airframe 4001 / SIH 10040): front-right CCW, rear-left CCW, front-left CW, rear-right CW
QUAD_X = [Rotor(1, 1, 6.5, 0.05), Rotor(-1, -1, 6.5, 0.05), Rotor(1, -1, 6.5, -0.05), Rotor(-1, 1, 6.5, -0.05)]


def test_x_quad_unit_roll_torque_moves_each_motor_by_one_over_sqrt2() -> None:
    mix = normalized_mix(QUAD_X)
    np.testing.assert_allclose(np.abs(mix[:, 0]), 1.0 / math.sqrt(2.0), rtol=1e-9)
    np.testing.assert_allclose(np.abs(mix[:, 2]), 1.0, rtol=1e-9)  # yaw: the whole range
    np.testing.assert_allclose(mix[:, 5], -1.0, rtol=1e-9)  # unit thrust (FRD z up is negative): full thrust
    # a roll torque speeds the left motors (negative PY) up: positive roll is right wing down in FRD
    assert all((mix[i, 0] > 0) == (r.py < 0) for i, r in enumerate(QUAD_X))


def test_sih_unit_torque_is_2_83_n_m_not_the_hover_margin() -> None:
    """The figure issue 9 measured: PX4's unit roll torque on SIH is about 2.83 N m (4 / sqrt 2 x 5 N x 0.2 m), where
    the vehicle file's hover-margin torque is 1.96 N m."""
    v = load_vehicle("px4-sih")
    roll, pitch, yaw = unit_torques(QUAD_X, v)
    assert roll == pytest.approx(4.0 / math.sqrt(2.0) * 5.0 * 0.2) == pitch
    assert yaw == pytest.approx(4 * 5.0 * 0.02)
    assert v.roll_pitch_torque_max == pytest.approx(1.9613, abs=1e-3)


def test_plus_quad_uses_the_two_motors_off_each_axis() -> None:
    plus = [Rotor(1, 0, 6.5, 0.05), Rotor(-1, 0, 6.5, 0.05), Rotor(0, 1, 6.5, -0.05), Rotor(0, -1, 6.5, -0.05)]
    v = Vehicle(frame="+")
    mix = normalized_mix(plus)
    assert np.count_nonzero(mix[:, 0]) == 2 and np.count_nonzero(mix[:, 1]) == 2
    roll, pitch, _ = unit_torques(plus, v)
    # two motors, each moved by 1/sqrt(2) of their range, at the full arm
    assert roll == pytest.approx(2.0 / math.sqrt(2.0) * v.motor_thrust_max * v.arm_length) == pitch


def test_px4_integer_parameters_are_decoded_bytewise_ardupilot_s_as_numbers() -> None:
    px4 = VehicleInfo(1, 1, "px4", 2)
    ap = VehicleInfo(1, 1, "ardupilot", 2)
    raw = struct.unpack("<f", struct.pack("<i", 4))[0]  # how PX4 sends CA_ROTOR_COUNT = 4
    assert param_value(raw, 6, px4) == 4.0
    assert param_value(4.0, 6, ap) == 4.0  # ArduPilot: the integer as a float
    assert param_value(0.15, 9, px4) == pytest.approx(0.15)  # REAL32 untouched
    neg = struct.unpack("<f", struct.pack("<i", -3))[0]
    assert param_value(neg, 6, px4) == -3.0
