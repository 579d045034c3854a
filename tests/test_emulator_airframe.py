"""Mixer, motor lag and inner loops of the emulated airframe (in process, no network)."""

from __future__ import annotations

import math

import pytest

from estimators.model.frames import euler_to_quaternion, quaternion_to_euler
from estimators.model.vehicle import Vehicle
from sim_bridge.inner.airframe import (
    AttitudeController,
    Mixer,
    PositionController,
    angle_boost,
    quat_from_thrust_dir_yaw,
)
from sim_bridge.plant.dynamics import make_input, make_state, plant_params, rk4_step

V = Vehicle()


def _settle(m: Mixer, n: int = 2000) -> tuple[float, float, float, float]:
    out = (0.0, 0.0, 0.0, 0.0)
    for _ in range(n):
        out = m.step()
    return out


@pytest.mark.parametrize(
    "wrench", [(6.86, 0.1, 0.0, 0.0), (6.86, 0.0, -0.2, 0.0), (8.0, 0.05, 0.05, 0.02), (5.0, -0.1, 0.08, -0.03)]
)
def test_mixer_reproduces_feasible_wrench(wrench: tuple[float, float, float, float]) -> None:
    m = Mixer(V, 0.001)
    m.allocate(*wrench)
    got = _settle(m)
    for a, b in zip(got, wrench):
        assert a == pytest.approx(b, abs=1e-9)
    assert all(0.0 <= f <= V.motor_thrust_max for f in m.cmd)


def test_mixer_limits_and_priorities() -> None:
    m = Mixer(V, 0.001)
    # far more yaw than available: roll/pitch kept exactly, yaw reduced, motors within limits
    m.allocate(6.86, 0.2, 0.0, 5.0)
    t, tx, _ty, tz = _settle(m)
    assert all(0.0 <= f <= V.motor_thrust_max + 1e-12 for f in m.cmd)
    assert tx == pytest.approx(0.2, abs=1e-9) and t == pytest.approx(6.86, abs=1e-9)
    assert 0.0 < tz < 5.0
    # full thrust with a roll torque: the collective gives way, the torque stays
    m.allocate(100.0, 0.3, 0.0, 0.0)
    t, tx, _, _ = _settle(m)
    assert tx == pytest.approx(0.3, abs=1e-9) and t < V.thrust_max
    # zero thrust: no negative motor thrust, torque scaled to zero
    m.allocate(0.0, 0.3, 0.3, 0.1)
    assert all(f >= 0.0 for f in m.cmd)


def test_motor_lag_is_first_order_with_the_vehicle_time_constant() -> None:
    m = Mixer(V, 0.001)
    m.allocate(8.0, 0.0, 0.0, 0.0)
    n = round(V.motor_time_constant / 0.001)
    t = 0.0
    for _ in range(n):
        t = m.step()[0]
    assert t == pytest.approx(8.0 * (1.0 - math.exp(-1.0)), rel=2e-3)


def test_quaternion_from_thrust_direction_and_yaw() -> None:
    for phi, theta, psi in [(0.0, 0.0, 0.3), (0.2, -0.1, 1.0), (-0.3, 0.25, -2.0)]:
        n = (
            math.sin(phi) * math.sin(psi) + math.cos(phi) * math.cos(psi) * math.sin(theta),
            math.cos(phi) * math.sin(psi) * math.sin(theta) - math.cos(psi) * math.sin(phi),
            math.cos(phi) * math.cos(theta),
        )
        q = quat_from_thrust_dir_yaw(*n, psi)
        # same thrust direction: rotate e3 by q
        w, x, y, z = q
        nz = (2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y))
        for a, b in zip(nz, n):
            assert a == pytest.approx(b, abs=1e-9)
        assert quaternion_to_euler(*q)[2] == pytest.approx(psi, abs=0.35)  # heading near psi for small tilt


def _fly_attitude(target: tuple[float, float, float], seconds: float) -> list[tuple[float, float, float, float]]:
    """Attitude loop + mixer + rigid plant, hover thrust; returns (t, phi, theta, psi) samples."""
    p = plant_params(V, "rigid")
    dt = 0.001
    mixer = Mixer(V, dt)
    att = AttitudeController(V, 2 * dt)
    x = make_state((0, 0, 10))
    qd = euler_to_quaternion(*target)
    out = []
    rate_sp = (0.0, 0.0, 0.0)
    from sim_bridge.inner.airframe import body_rates

    for k in range(int(seconds / dt)):
        if k % 4 == 0:
            rate_sp = att.attitude_to_rates(euler_to_quaternion(x[6], x[7], x[8]), qd)
        if k % 2 == 0:
            w = body_rates(x[6], x[7], x[9], x[10], x[11])
            mixer.allocate(V.hover_thrust / (math.cos(x[6]) * math.cos(x[7])), *att.rates_to_torque(rate_sp, w, True))
        t, tx, ty, tz = mixer.step()
        x = rk4_step(x, make_input(t, (tx, ty, tz)), p, dt)
        out.append((k * dt, x[6], x[7], x[8]))
    return out


def test_attitude_loop_tracks_a_step_with_realistic_bandwidth() -> None:
    target = (math.radians(10.0), 0.0, 0.0)
    trace = _fly_attitude(target, 2.0)
    rise = next(t for t, phi, _, _ in trace if phi >= 0.9 * target[0])
    peak = max(phi for _, phi, _, _ in trace)
    assert 0.15 < rise < 0.8  # PX4-like: a few hundred milliseconds, not instantaneous
    assert peak < 1.25 * target[0]
    assert trace[-1][1] == pytest.approx(target[0], abs=math.radians(0.5))


def test_position_controller_outputs_hover_at_rest_and_tilts_toward_the_target() -> None:
    pc = PositionController(V.gravity)
    q, thr = pc.update((0, 0, 2), (0, 0, 0), (0, 0, 2), (0, 0, 0), 0.0, 0.43, 0.004)
    assert thr == pytest.approx(0.43, abs=1e-9)
    assert q == pytest.approx((1.0, 0.0, 0.0, 0.0), abs=1e-9)
    pc.reset()
    q, thr = pc.update((0, 0, 2), (0, 0, 0), (5, 0, 2), (0, 0, 0), 0.0, 0.43, 0.004)
    phi, theta, _ = quaternion_to_euler(*q)
    assert theta > 0.05 and abs(phi) < 1e-9  # model frame: positive pitch tilts thrust toward +x
    assert thr > 0.43


def test_angle_boost_divides_by_cos_tilt_with_a_floor() -> None:
    assert angle_boost(0.5, 0.0, 0.0) == 0.5
    assert angle_boost(0.5, math.radians(30), 0.0) == pytest.approx(0.5 / math.cos(math.radians(30)))
    assert angle_boost(0.5, math.radians(80), 0.0) == pytest.approx(1.0)


def test_thrust_semantics_px4_and_ardupilot() -> None:
    from sim_bridge.inner.airframe import ardupilot_climb_rate, ardupilot_throttle_newtons, px4_thrust_newtons

    assert px4_thrust_newtons(V.hover_thrust_normalized, V.thrust_max) == pytest.approx(V.hover_thrust)
    assert px4_thrust_newtons(1.7, V.thrust_max) == V.thrust_max and px4_thrust_newtons(-0.2, V.thrust_max) == 0.0
    # ArduPilot: 0.5 = no climb, 1 = WPNAV_SPEED_UP, 0 = WPNAV_SPEED_DN down
    assert ardupilot_climb_rate(0.5, 2.5, 1.5) == 0.0
    assert ardupilot_climb_rate(1.0, 2.5, 1.5) == pytest.approx(2.5)
    assert ardupilot_climb_rate(0.0, 2.5, 1.5) == pytest.approx(-1.5)
    assert ardupilot_climb_rate(0.75, 2.5, 1.5) == pytest.approx(1.25)
    tilt = math.radians(20.0)
    assert ardupilot_throttle_newtons(0.4, tilt, 0.0, True, 16.0) == pytest.approx(0.4 / math.cos(tilt) * 16.0)
    assert ardupilot_throttle_newtons(0.4, tilt, 0.0, False, 16.0) == pytest.approx(0.4 * 16.0)
    assert ardupilot_throttle_newtons(0.95, tilt, 0.0, True, 16.0) == pytest.approx(16.0)
