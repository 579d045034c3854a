"""The emulator's PX4 flavour learns the hover thrust as PX4 does (``sim_bridge.inner.px4_hover_thrust``) and holds
height with PX4's vertical velocity integrator: a wrong MPC_THR_HOVER no longer leaves the vehicle short of its
take-off height or flying on the wrong belief. Real PX4 SITL with the same wrong parameter
(``bench/px4_hover_thrust.py``, docs/emulator.md) learned 0.490 on SIH's body, whose physical value is 0.490."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimators.model.vehicle import load_vehicle
from sim_bridge.inner.airframe import px4_vertical_integral
from sim_bridge.inner.px4_hover_thrust import HoverThrustEstimator, integrator_after_hover_change

G = 9.80665


def _fly(h: HoverThrustEstimator, true_hover: float, seconds: float, rng: np.random.Generator) -> list[bool]:
    """Fusions at 100 Hz of a hover at thrusts around ``true_hover`` with 0.5 m/s^2 of accelerometer noise."""
    valid = []
    for _ in range(int(seconds * 100)):
        thrust = true_hover * (1.0 + 0.05 * rng.standard_normal())
        h.update(0.01, G * thrust / true_hover - G + 0.5 * rng.standard_normal(), thrust, 0.0, 0.0)
        valid.append(h.valid)
    return valid


def test_the_estimate_learns_the_hover_thrust_and_is_trusted_only_when_settled() -> None:
    rng = np.random.default_rng(0)
    h = HoverThrustEstimator(G, 0.35)
    valid = _fly(h, 0.49, 10.0, rng)
    assert h.h == pytest.approx(0.49, abs=0.01)
    first = valid.index(True)
    assert 2.0 <= first * 0.01 < 8.0  # 2 s of a settled estimate before it is trusted (PX4's hysteresis)
    assert all(valid[first:])
    # a spike of 30 m/s^2 is refused by the gate and leaves the estimate where it was
    before = h.h
    h.update(0.01, 30.0, 0.49, 0.0, 0.0)
    assert h.h == before and h.test_ratio > 1.0
    # the estimate stays within MPC_THR_HOVER +- HTE_THR_RANGE however far off the truth is
    far = HoverThrustEstimator(G, 0.3)
    _fly(far, 0.8, 10.0, rng)
    assert far.h == pytest.approx(0.5, abs=1e-9)
    # disarming: back to the parameter, not trusted
    h.reset(0.35)
    assert h.h == 0.35 and not h.valid


def test_a_new_hover_thrust_moves_the_integrator_so_the_thrust_does_not_jump() -> None:
    acc, old, new, int_z = 1.3, 0.35, 0.49, 0.8
    moved = integrator_after_hover_change(int_z, acc, G, old, new)
    assert (G + acc + moved - int_z) * new == pytest.approx((G + acc) * old)


def test_pxs_vertical_integrator_works_far_from_the_setpoint_and_stops_at_saturation() -> None:
    assert px4_vertical_integral(0.0, 2.0, 1.0, 3.0, G, 0.1) == pytest.approx(0.2)  # 1 m/s off: integrates
    assert px4_vertical_integral(0.5, 2.0, 1.0, G, G, 0.1) == 0.5  # thrust at its top, climbing wanted: holds
    assert px4_vertical_integral(0.5, 2.0, -1.0, G, G, 0.1) == pytest.approx(0.3)  # unwinds the other way
    assert px4_vertical_integral(-0.5, 2.0, -1.0, -0.8 * G, G, 0.1) == -0.5  # at the bottom, descending: holds
    assert px4_vertical_integral(G - 0.01, 2.0, 1.0, 3.0, G, 0.1) == G  # kept within +-g


def _take_off(hover_param: float, use_hte: bool) -> tuple[float, float, object]:
    """The emulator's PX4 flavour (in this process: the link is opened, nobody listens) on SIH's vehicle file with
    MPC_THR_HOVER ``hover_param``: PX4's take-off to 2.5 m, 25 s; (height at the end, largest height, autopilot)."""
    from sim_bridge.autopilot import Autopilot
    from sim_bridge.emulator import Emulator
    from sim_bridge.protocol.link import Link, LinkFaults

    v = load_vehicle("px4-sih")
    link = Link(["udpin:127.0.0.1:0"], LinkFaults())
    try:
        ap = Autopilot("px4", v, link)
        for name, value in (("MPC_THR_HOVER", hover_param), ("MPC_USE_HTE", int(use_hte))):
            assert ap.set_param(name, value) is None
        em = Emulator(ap, link, v)
        em.step(2000)
        assert ap._arm(0.0) == 0 and ap.request_mode(ap.fl.by_name["AUTO.TAKEOFF"]) == 0
        top = 0.0
        for _ in range(250):
            em.step(100)
            top = max(top, em.x[2])
        return em.x[2], top, ap
    finally:
        link.close()


def test_a_wrong_hover_thrust_parameter_is_learned_in_flight() -> None:
    """MPC_THR_HOVER 0.35 on a vehicle that needs 0.49: the take-off reaches its 2.5 m (it stalled at 1.52 m with
    the emulator's former integrator) and the position controller ends up flying the learned 0.49; with
    MPC_USE_HTE 0 the belief stays the parameter and the integrator carries the difference."""
    physical = load_vehicle("px4-sih").hover_thrust_normalized
    z, top, ap = _take_off(0.35, True)
    assert abs(z - 2.5) < 0.1 and top < 2.5 + 0.3, (z, top)
    assert ap.hover_norm == pytest.approx(physical, abs=0.01) and ap.px4_hover.valid  # type: ignore[attr-defined]
    z, _, ap = _take_off(0.35, False)
    assert abs(z - 2.5) < 0.2, z
    assert ap.hover_norm == 0.35  # type: ignore[attr-defined]
    assert ap.pos.int_z > 0.5 * G * (physical / 0.35 - 1.0)  # type: ignore[attr-defined]
    assert math.isfinite(ap.px4_hover.h)  # type: ignore[attr-defined]
