"""Sensor models: rates, latency, noise statistics, bias, exact values of the ideal preset, seeding."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimators.errors import UserError
from estimators.model.cable import cable_from_planar, planar_swing
from estimators.model.measurements import Attitude, Imu, LoadAngle, PositionVelocity, is_finite
from estimators.model.rotations import body_rates
from estimators.model.vehicle import Vehicle
from sim_bridge.plant import dynamics
from sim_bridge.plant.sensors import PRESETS, SensorSuite, preset_spec, specific_force_body

V = Vehicle()
P = dynamics.plant_params(V)
KINDS = {PositionVelocity: "position", Attitude: "attitude", Imu: "imu", LoadAngle: "load"}


def _hover_run(preset: str, seconds: float, seed: int, load_sensor: bool = True, h: float = 0.001):
    """Sample a vehicle held at rest in hover; returns [(delivery time, record)] and the suite."""
    rng = np.random.default_rng(seed)
    suite = SensorSuite(preset, V, rng, load_sensor=load_sensor)
    x = dynamics.make_state(position=(1.0, -2.0, 3.0), euler=(0.0, 0.0, 0.4))
    u = dynamics.hover_input(P)
    out = []
    for i in range(1, round(seconds / h) + 1):
        t = i * h
        out.extend((t, m) for m in suite.sample(t, x, u))
    return out, suite, x


def test_presets_and_unknown_preset() -> None:
    assert set(("ideal", "px4-typical")) <= set(PRESETS)
    with pytest.raises(UserError, match="unknown sensor preset 'px5'"):
        SensorSuite("px5", V, np.random.default_rng(0))


@pytest.mark.parametrize("preset", ["px4-typical", "px4-fast", "ideal"])
def test_rates_match_the_preset(preset: str) -> None:
    seconds = 10.0
    recs, suite, _ = _hover_run(preset, seconds, seed=1)
    spec = preset_spec(preset)
    for cls, kind in KINDS.items():
        n = sum(1 for _, m in recs if isinstance(m, cls))
        expected = getattr(spec, kind).rate_hz * seconds
        assert abs(n - expected) <= 2, (kind, n, expected)
        # sampling instants are one period apart (to within a plant step)
        ts = np.array([m.t for _, m in recs if isinstance(m, cls)])
        period = 1.0 / getattr(spec, kind).rate_hz
        assert np.all(np.abs(np.diff(ts) - period) <= 0.001 + 1e-9)
    assert sum(suite.sampled.values()) >= len(recs)


def test_latency_and_order_px4_typical() -> None:
    recs, _, _ = _hover_run("px4-typical", 5.0, seed=2)
    spec = preset_spec("px4-typical")
    per_kind: dict[str, list[float]] = {}
    for delivered, m in recs:
        s = getattr(spec, KINDS[type(m)])
        lat = delivered - m.t
        # delivered at the first plant step at or after sample time + latency + jitter
        assert s.latency_s - 1e-9 <= lat <= s.latency_s + s.jitter_s + 0.001 + 1e-9
        per_kind.setdefault(KINDS[type(m)], []).append(m.t)
    # each sensor delivers in sampling order; across sensors the stream is not in sampling order
    for ts in per_kind.values():
        assert ts == sorted(ts)
    all_t = [m.t for _, m in recs]
    assert all_t != sorted(all_t)


def test_ideal_preset_is_exact_and_immediate() -> None:
    recs, _, x = _hover_run("ideal", 1.0, seed=3)
    for delivered, m in recs:
        assert delivered == m.t
        if isinstance(m, PositionVelocity):
            assert m[1:] == pytest.approx(tuple(x[0:6]), abs=1e-12)
        elif isinstance(m, Attitude):
            assert m[1:] == pytest.approx((0.0, 0.0, 0.4, 0.0, 0.0, 0.0), abs=1e-12)
        elif isinstance(m, Imu):
            # at rest in hover the accelerometer reads +g along body z
            assert m[1:] == pytest.approx((0.0, 0.0, V.gravity, 0.0, 0.0, 0.0), abs=1e-9)
        else:
            assert m[1:] == pytest.approx((0.0, 0.0), abs=1e-12)


def test_noise_statistics_and_bias_px4_typical() -> None:
    recs, suite, x = _hover_run("px4-typical", 30.0, seed=4)
    spec = preset_spec("px4-typical")
    pos = np.array([m[1:] for _, m in recs if isinstance(m, PositionVelocity)]) - np.array(x[0:6])
    sxy, sz, svxy, svz = spec.position.noise
    assert np.std(pos, axis=0) == pytest.approx([sxy, sxy, sz, svxy, svxy, svz], rel=0.12)
    att = np.array([m[1:] for _, m in recs if isinstance(m, Attitude)]) - np.array((0.0, 0.0, 0.4, 0, 0, 0))
    sa, sy, sr = spec.attitude.noise
    assert np.std(att, axis=0) == pytest.approx([sa, sa, sy, sr, sr, sr], rel=0.1)
    imu = np.array([m[1:] for _, m in recs if isinstance(m, Imu)]) - np.array((0.0, 0.0, V.gravity, 0, 0, 0))
    s_acc, s_gyro = spec.imu.noise
    assert np.std(imu, axis=0) == pytest.approx([s_acc] * 3 + [s_gyro] * 3, rel=0.12)
    # the accelerometer's mean error is its bias (3 sigma of the mean of ~1500 samples: 0.016 m/s^2)
    assert np.mean(imu[:, :3], axis=0) == pytest.approx(suite.accel_bias, abs=0.016)
    assert max(abs(b) for b in suite.accel_bias) > 0.0
    assert np.all(np.abs(np.mean(imu[:, 3:], axis=0)) < 0.001)  # no gyro bias modelled
    load = np.array([m[1:] for _, m in recs if isinstance(m, LoadAngle)])
    assert np.std(load, axis=0) == pytest.approx([spec.load.noise[0]] * 2, rel=0.1)
    assert all(is_finite(m) for _, m in recs)


def test_seeding_reproducible() -> None:
    a, sa, _ = _hover_run("px4-typical", 2.0, seed=7)
    b, sb, _ = _hover_run("px4-typical", 2.0, seed=7)
    c, _, _ = _hover_run("px4-typical", 2.0, seed=8)
    assert a == b and sa.accel_bias == sb.accel_bias
    assert [m for _, m in a] != [m for _, m in c]


def test_no_load_sensor_no_load_records() -> None:
    recs, _, _ = _hover_run("px4-typical", 2.0, seed=5, load_sensor=False)
    assert recs and not any(isinstance(m, LoadAngle) for _, m in recs)


def test_specific_force_is_cable_pull_plus_thrust() -> None:
    """Independent check of the IMU model: thrust acts along body z, so the body-horizontal specific force
    is the cable tension's pull, T (R^T r) / M, and in free fall with the load at rest it is zero."""
    r, rd = cable_from_planar(0.3, -0.2, 0.5, 0.4)
    x = dynamics.make_state(euler=(0.1, -0.15, 0.7), euler_rate=(0.2, 0.1, -0.3), cable=r, cable_rate=rd)
    u = dynamics.make_input(7.5, (0.01, -0.02, 0.0))
    acc = dynamics.derivative(0.0, x, u, P)[3:6]
    f = specific_force_body(x, acc, V.gravity)
    tension = dynamics.tension(x, u, P)
    # R^T r by rotating r with the transpose of Rz Ry Rx
    phi, theta, psi = x[6:9]
    rz = np.array([[math.cos(psi), -math.sin(psi), 0], [math.sin(psi), math.cos(psi), 0], [0, 0, 1]])
    ry = np.array([[math.cos(theta), 0, math.sin(theta)], [0, 1, 0], [-math.sin(theta), 0, math.cos(theta)]])
    rx = np.array([[1, 0, 0], [0, math.cos(phi), -math.sin(phi)], [0, math.sin(phi), math.cos(phi)]])
    rb = (rz @ ry @ rx).T @ np.array(x[12:15])
    assert f[0] == pytest.approx(tension * rb[0] / V.mass_vehicle, abs=1e-9)
    assert f[1] == pytest.approx(tension * rb[1] / V.mass_vehicle, abs=1e-9)
    assert f[2] == pytest.approx((u[0] + tension * rb[2]) / V.mass_vehicle, abs=1e-9)
    x0 = dynamics.make_state(euler=(0.2, 0.1, 0.0))
    u0 = dynamics.make_input(0.0)
    f0 = specific_force_body(x0, dynamics.derivative(0.0, x0, u0, P)[3:6], V.gravity)
    assert f0 == pytest.approx((0.0, 0.0, 0.0), abs=1e-12)


def test_body_rates_and_load_angle_record() -> None:
    # pure roll rate is the body x rate; pure yaw rate at zero tilt is the body z rate
    assert body_rates(0.0, 0.0, 0.5, 0.0, 0.0) == pytest.approx((0.5, 0.0, 0.0))
    assert body_rates(0.0, 0.0, 0.0, 0.0, 0.7) == pytest.approx((0.0, 0.0, 0.7))
    # with pitch, a yaw rate shows on body x: p = phi' - sin(theta) psi'
    assert body_rates(0.0, 0.3, 0.0, 0.0, 1.0)[0] == pytest.approx(-math.sin(0.3))
    r, rd = cable_from_planar(0.2, -0.1, 0.0, 0.0)
    x = dynamics.make_state(cable=r, cable_rate=rd)
    suite = SensorSuite("ideal", V, np.random.default_rng(0))
    recs = suite.sample(0.001, x, dynamics.hover_input(P))
    load = next(m for m in recs if isinstance(m, LoadAngle))
    ay, ax, _, _ = planar_swing(*x[12:18])
    assert (load.alpha_x, load.alpha_y) == pytest.approx((ax, ay)) and ay == pytest.approx(0.2)
