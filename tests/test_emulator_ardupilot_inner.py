"""The emulator's ArduPilot flavour: input-shaped attitude, ANGLE_MAX, thrust expo, hover learning, LOITER on the
throttle stick (sim_bridge.inner.ardupilot_inner, driven in-process through the autopilot's own entry points)."""

from __future__ import annotations

import itertools
import math

import pytest

from estimators.model.frames import euler_to_quaternion, quaternion_to_euler
from sim_bridge.emulator_api import EmulatorConfig, build_emulator
from sim_bridge.inner.ardupilot_inner import (
    AttitudeShaper,
    limit_tilt,
    sqrt_controller,
    throttle_to_actuator,
    thrust_curve,
)


def test_sqrt_controller_is_linear_near_zero_and_square_root_beyond() -> None:
    assert sqrt_controller(0.01, 5.0, 10.0, 0.0) == pytest.approx(0.05)
    # beyond the linear band a / p^2 = 0.4: sqrt(2 a (e - a / (2 p^2)))
    assert sqrt_controller(1.0, 5.0, 10.0, 0.0) == pytest.approx(math.sqrt(2 * 10.0 * (1.0 - 0.2)))
    assert sqrt_controller(-1.0, 5.0, 10.0, 0.0) == pytest.approx(-math.sqrt(16.0))
    assert sqrt_controller(1.0, 5.0, 10.0, 0.5) == pytest.approx(2.0)  # never past the error in one step


def test_attitude_target_is_shaped_by_the_input_time_constant() -> None:
    sh = AttitudeShaper()
    level = euler_to_quaternion(0.0, 0.0, 0.0)
    sh.reset(level)
    roll = []
    for _ in range(250):  # 1 s at 250 Hz towards a 0.3 rad roll
        qt, _ff = sh.update(level, euler_to_quaternion(0.3, 0.0, 0.0), 0.004)
        roll.append(quaternion_to_euler(*qt)[0])
    # first-order-like with ATC_INPUT_TC 0.15 s: about 63 % after 0.15-0.2 s, settled after 1 s; never jumps
    assert 0.12 < roll[int(0.2 / 0.004)] < 0.24 and roll[-1] == pytest.approx(0.3, abs=0.005)
    assert max(b - a for a, b in itertools.pairwise(roll)) < 0.01
    # ANGLE_MAX: the tilt is limited, its direction and the heading kept
    ql = limit_tilt(euler_to_quaternion(0.8, 0.0, 1.0), math.radians(30.0))
    phi, theta, psi = quaternion_to_euler(*ql)
    assert (
        phi == pytest.approx(math.radians(30.0)) and theta == pytest.approx(0.0, abs=1e-9) and psi == pytest.approx(1)
    )


def test_thrust_expo_linearization_round_trips() -> None:
    for t in (0.0, 0.2, 0.5, 0.9, 1.0):
        assert thrust_curve(throttle_to_actuator(t, 0.65), 0.65) == pytest.approx(t)
    assert throttle_to_actuator(0.5, 0.65) > 0.6  # the actuator is well above the thrust fraction at mid
    # a mis-set MOT_THST_EXPO mis-linearizes: 0.5 throttle gives more than half thrust with expo 0.3 assumed
    assert thrust_curve(throttle_to_actuator(0.5, 0.3), 0.65) < 0.5


@pytest.mark.slow
def test_hover_is_learned_in_loiter_and_a_low_stick_descends() -> None:
    emu, ap, link = build_emulator(EmulatorConfig(flavor="ardupilot", mavlink=("udpout:127.0.0.1:9",), est_ready=0.1))
    try:
        emu.step(200)
        ap.params["MOT_THST_HOVER"].value = 0.35  # a stale saved value (ArduPilot's default)
        ap._apply_params("MOT_THST_HOVER")
        ap.ap_hover.value = 0.35
        assert ap.request_mode(ap.fl.by_name["GUIDED"]) == 0 and ap._arm(0.0) == 0
        assert ap._cmd_takeoff(3.0) == 0
        emu.step(8000)
        assert emu.x[2] == pytest.approx(3.0, abs=0.3)
        ap.rc_throttle = 0.5  # stick at mid: LOITER holds
        assert ap.request_mode(ap.fl.by_name["LOITER"]) == 0
        emu.step(40000)
        true_hover = ap.vehicle.hover_thrust_normalized
        assert emu.x[2] == pytest.approx(3.0, abs=0.3)
        assert ap._p("MOT_THST_HOVER") == pytest.approx(true_hover, abs=0.02)  # learned (0.35 -> 0.43)
        ap.rc_throttle = 0.0  # stick low (SITL's default RC input): LOITER descends and lands
        emu.step(6000)
        assert emu.on_ground or emu.x[2] < 0.5
    finally:
        link.close()
