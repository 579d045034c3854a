"""Wire conventions of the emulator's telemetry (in process): NED / FRD signs, the LOADANG load-angle sensor,
global position around home, specific force, seeded noise."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimators.model.vehicle import Vehicle
from sim_bridge.plant.dynamics import hover_input, make_state, plant_params
from sim_bridge.protocol.telemetry import EARTH_RADIUS, Home, Snapshot, TelemetrySource

V = Vehicle()
P = plant_params(V, "rigid")
HOME = Home()


def _snap(x: list[float], noise: float = 0.0, seed: int = 0) -> Snapshot:
    return TelemetrySource(P, HOME, noise, np.random.default_rng(seed)).snapshot(1_234_000, x, hover_input(P))


def test_load_angle_sensor_signs() -> None:
    a = 0.2
    north = _snap(make_state((0, 0, 5), cable=(math.sin(a), 0.0, -math.cos(a))))
    assert (north.swing_n, north.swing_e, north.swing) == pytest.approx((a, 0.0, a), abs=1e-12)
    west = _snap(make_state((0, 0, 5), cable=(0.0, math.sin(a), -math.cos(a))))  # model y points west
    assert (west.swing_n, west.swing_e, west.swing) == pytest.approx((0.0, -a, a), abs=1e-12)
    diag = _snap(make_state((0, 0, 5), cable=(0.3, -0.3, -0.9)))
    assert diag.swing_n > 0 and diag.swing_e > 0  # north-east
    assert diag.swing == pytest.approx(math.atan2(math.hypot(0.3, 0.3), 0.9), abs=1e-12)


def test_position_attitude_and_rates_in_ned_frd() -> None:
    x = make_state((1.0, 2.0, 3.0), (0.5, -0.25, 1.0), euler=(0.1, 0.2, 0.3), euler_rate=(0.0, 0.0, 0.4))
    s = _snap(x)
    assert s.pos == pytest.approx((1.0, -2.0, -3.0))
    assert s.vel == pytest.approx((0.5, 0.25, -1.0))
    assert (s.roll, s.pitch, s.yaw) == pytest.approx((0.1, -0.2, -0.3))
    assert s.r < 0  # positive model yaw rate (counter-clockwise seen from above) is a negative FRD yaw rate
    assert s.t_us == 1_234_000
    # flat-earth global position: north -> latitude up, west (model +y) -> longitude down
    assert s.lat == round((HOME.lat + math.degrees(1.0 / EARTH_RADIUS)) * 1e7)
    assert s.lon < round(HOME.lon * 1e7)
    assert s.alt_mm == round((HOME.alt + 3.0) * 1000) and s.rel_alt_mm == 3000
    # the load hangs a cable length below
    assert s.rel_alt_mm - s.load_rel_alt_mm == round(V.cable_length * 1000)


def test_specific_force_reads_minus_g_on_frd_z_in_hover() -> None:
    s = _snap(make_state((0, 0, 5)))
    assert s.acc == pytest.approx((0.0, 0.0, -P.g), abs=1e-9)  # thrust minus cable pull, per vehicle mass
    assert (s.p, s.qr, s.r) == (0.0, 0.0, 0.0)


def test_noise_is_seeded_and_off_by_default() -> None:
    x = make_state((1.0, 0.0, 2.0), cable=(0.1, 0.0, -1.0))
    truth = _snap(x)
    a, b, c = _snap(x, 1.0, 5), _snap(x, 1.0, 5), _snap(x, 1.0, 6)
    assert a == b and a != c
    assert a.pos != truth.pos and a.pos == pytest.approx(truth.pos, abs=0.2)
    assert a.swing_n == pytest.approx(truth.swing_n, abs=0.05)
    assert all(math.isfinite(v) for v in (*a.pos, *a.vel, *a.acc, a.roll, a.pitch, a.yaw, a.swing_n))


def test_accelerometer_reads_one_g_up_on_the_ground_and_zero_in_free_fall() -> None:
    x = make_state((0.0, 0.0, 0.0))
    idle = [0.0] * 13  # motors off: in the air this is free fall
    for sensors in ("ideal", "px4-typical"):
        tel = TelemetrySource(P, HOME, sensors=sensors, sensor_rng=np.random.default_rng(2))
        bias = tel.accel_bias
        ground = np.mean([tel.snapshot(1000 * k, x, idle, on_ground=True).acc for k in range(400)], axis=0)
        falling = np.mean([tel.snapshot(1000 * k, x, idle).acc for k in range(400)], axis=0)
        tol = 1e-12 if sensors == "ideal" else 0.05
        assert ground == pytest.approx((bias[0], -bias[1], -P.g - bias[2]), abs=tol)  # FLU bias -> FRD
        assert falling == pytest.approx((bias[0], -bias[1], -bias[2]), abs=tol)
