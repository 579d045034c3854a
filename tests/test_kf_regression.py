"""The optimized Kalman filter computes what the original one computed.

``tests/kf_reference.py`` is a frozen copy of the filter before its hot paths were optimized. Both run on the
same seeded stream (10 s of the real plant and ``px4-typical`` sensors, open loop around hover with a 10 degree
initial swing), tampered with the faults the filter must survive (NaN fields, wild outliers, extra delays that
make records late or out of order, a silent position stream that comes back offset so that its gate has to
reopen, non-finite commands), at several control rates and in both modes. Every tick's estimate, the covariance
and the NEES now and then, and every counter must agree to 1e-9 (relative).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest
from kf_reference import ReferenceKalmanEstimator

from estimators.filters.kf import KalmanEstimator
from estimators.model.cable import cable_from_planar
from estimators.model.control_state import ControlState
from estimators.model.flatness import flat_constants, truth_control_state
from estimators.model.measurements import Attitude, Imu, LoadAngle, Measurement, PositionVelocity
from estimators.model.vehicle import Vehicle
from sim_bridge.plant import dynamics
from sim_bridge.plant.sensors import SensorSuite

V = Vehicle()
K = flat_constants(V)
SECONDS = 10.0
PLANT_DT = 0.001


def _truth(x: list[float]) -> ControlState:
    return truth_control_state(x, K)


def _command(t: float) -> tuple[float, tuple[float, float, float]]:
    """Open-loop command (N, N m): hover thrust and sinusoidal torques, with a few non-finite commands."""
    if 3.0 <= t < 3.02:
        return math.nan, (0.0, 0.0, 0.0)
    return (
        V.hover_thrust + 0.4 * math.sin(2.0 * t),
        (0.004 * math.sin(3.0 * t), 0.004 * math.cos(2.5 * t), 0.002 * math.sin(t)),
    )


@dataclass
class Stream:
    deliveries: list[tuple[float, Measurement]]  # (delivery time s, record), in delivery order
    truth: list[ControlState]  # plant state every PLANT_DT


def _tamper(m: Measurement, rng: np.random.Generator) -> tuple[float, Measurement]:
    """Extra delivery delay (s) and the possibly corrupted record."""
    u = rng.uniform()
    delay = 0.0
    if u < 0.02:  # a NaN field
        i = int(rng.integers(1, len(m)))
        m = m._replace(**{m._fields[i]: math.nan})
    elif u < 0.03:  # a wild outlier
        i = int(rng.integers(1, len(m)))
        m = m._replace(**{m._fields[i]: m[i] + float(rng.choice((-1.0, 1.0))) * 5.0})
    elif u < 0.10:  # late: some within the fusion horizon (out of order), some beyond it (dropped)
        delay = float(rng.uniform(0.001, 0.03))
    if isinstance(m, PositionVelocity) and m.t >= 6.0:  # the position stream comes back offset
        m = m._replace(x=m.x + 0.4, y=m.y - 0.3, z=m.z + 0.3)
    return delay, m


@pytest.fixture(scope="module")
def stream() -> Stream:
    rng = np.random.default_rng(2026)
    p = dynamics.plant_params(V)
    r, rd = cable_from_planar(0.17, -0.09)
    x = dynamics.make_state(position=(0.0, 0.0, 1.0), euler=(0.0, 0.0, 0.4), cable=r, cable_rate=rd)
    sensors = SensorSuite("px4-typical", V, rng, load_sensor=True)
    deliveries: list[tuple[float, Measurement]] = []
    truth = [_truth(x)]
    n = round(SECONDS / PLANT_DT)
    u = dynamics.make_input(V.hover_thrust)
    for i in range(n):
        t = i * PLANT_DT
        if i % 2 == 0:  # the plant's input changes at 500 Hz
            thrust, tau = _command(t)
            u = dynamics.make_input(thrust if math.isfinite(thrust) else V.hover_thrust, tau)
        x = dynamics.rk4_step(x, u, p, PLANT_DT)
        truth.append(_truth(x))
        for m in sensors.sample(t + PLANT_DT, x, u):
            if isinstance(m, PositionVelocity) and 5.0 <= m.t < 6.0:
                continue  # silent
            delay, m = _tamper(m, rng)
            deliveries.append((t + PLANT_DT + delay, m))
    deliveries.sort(key=lambda d: d[0])
    return Stream(deliveries, truth)


def _values(e: ControlState) -> list[float]:
    return [
        *e.fx,
        *e.fy,
        e.z,
        e.z_rate,
        e.phi,
        e.theta,
        e.psi,
        e.phi_rate,
        e.theta_rate,
        e.psi_rate,
        e.alpha_x,
        e.alpha_y,
        e.alpha_x_rate,
        e.alpha_y_rate,
    ]


@pytest.mark.parametrize(("rate", "load_sensor"), [(250.0, True), (250.0, False), (100.0, False), (500.0, True)])
def test_optimized_filter_matches_the_frozen_reference(stream: Stream, rate: float, load_sensor: bool) -> None:
    start = stream.truth[0]
    guess = start._replace(alpha_x=start.alpha_x + 0.1)  # a wrong swing: the filter has to converge
    filters = [cls(V, load_sensor=load_sensor, rate_hz=rate) for cls in (KalmanEstimator, ReferenceKalmanEstimator)]
    for f in filters:
        f.initialize(0.0, guess)
    deliveries = stream.deliveries
    j = 0
    n_ticks = round(SECONDS * rate)
    checked = 0
    for i in range(n_ticks):
        t = i / rate
        k = j
        while k < len(deliveries) and deliveries[k][0] <= t:
            k += 1
        batch = [m for _, m in deliveries[j:k]]
        j = k
        res = []
        for f in filters:
            for m in batch:
                f.push(m)
            res.append(_values(f.estimate(t)))
            f.push_command(t, *_command(t))
        np.testing.assert_allclose(res[0], res[1], rtol=1e-9, atol=1e-12, err_msg=f"estimate at t={t}")
        if i % 97 == 0:
            tr = stream.truth[min(round(t / PLANT_DT), len(stream.truth) - 1)]
            c0, c1 = (f.covariance() for f in filters)
            np.testing.assert_allclose(c0, c1, rtol=1e-9, atol=1e-15, err_msg=f"covariance at t={t}")
            n0, n1 = (f.nees(t, tr) for f in filters)
            assert n0 == pytest.approx(n1, rel=1e-9)
            checked += 1
    s0, s1 = (f.stats() for f in filters)
    assert s0 == s1
    assert checked > 5
    # the stream really exercised the robustness paths being compared
    assert s0["nan_rejected"] > 20 and s0["late_dropped"] > 5 and s0["out_of_order"] > 20
    assert s0["gated_outliers"] > 10 and s0["gate_reopened"] >= 1 and s0["commands_rejected"] >= 1
    assert s0["accepted"] > 0.8 * sum(1 for _, m in deliveries if isinstance(m, Attitude | Imu))
    if load_sensor:
        assert s0["gated_load"] > 0 and any(isinstance(m, LoadAngle) for _, m in deliveries)
