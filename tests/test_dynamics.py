"""Physics and numerics of the plant (sim_bridge/plant/dynamics.py) against first principles and the paper.

Figures quoted in comments were measured on this model (Table 1 vehicle) when the tests were written.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from estimators.model.cable import cable_from_planar, cable_from_spherical, swing_angles
from estimators.model.vehicle import Vehicle
from offboard.control.linear_model import STATE_NAMES, linear_model
from sim_bridge.plant.angle_form import (
    angle_accelerations_from_sphere,
    angle_derivative,
    angle_to_sphere_state,
    sphere_to_angle_state,
)
from sim_bridge.plant.dynamics import (
    derivative,
    energy,
    hover_input,
    make_input,
    make_state,
    plant_params,
    rk4_step,
    tension,
    thrust_direction,
)
from sim_bridge.plant.linearize import (
    full_to_reduced,
    hover_point,
    jacobian,
    reduced_derivative,
    reduced_to_full,
)

VEHICLE = Vehicle()
MODELS = ("paper", "rigid")


def _swinging_state() -> list[float]:
    """A state with everything moving: tilt, rates, a 0.5 rad swing with azimuthal rate."""
    r, rd = cable_from_spherical(0.5, 0.3, 1.2, 2.0)
    return make_state((0.1, -0.2, 1.0), (0.3, -0.1, 0.2), (0.1, -0.15, 0.4), (0.5, -0.3, 0.8), r, rd)


def _run_rk4(x: list[float], u: list[float], p, h: float, n: int) -> list[float]:
    for _ in range(n):
        x = rk4_step(x, u, p, h)
    return x


# 1. Energy -------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("model", MODELS)
def test_energy_conserved_in_free_motion(model: str) -> None:
    """u = 0, tau = 0, no external forces: E is constant (measured drift 6e-12 J over 10 s at h = 1 ms)."""
    p = plant_params(VEHICLE, model)
    x = _swinging_state()
    u = make_input(0.0)
    e0 = energy(x, p)
    worst = 0.0
    for _ in range(10):  # 10 s in 1 s chunks
        x = _run_rk4(x, u, p, 1e-3, 1000)
        worst = max(worst, abs(energy(x, p) - e0))
    # Free fall: the energy is dominated by the potential term, which changes by ~ M_t g * 490 m; the total must not.
    assert abs(x[2] - 1.0) > 100.0  # the system really fell
    assert worst < 1e-9  # J; the kinetic energy at the end is ~3e3 J


@pytest.mark.parametrize("model", MODELS)
def test_work_energy_balance_with_constant_thrust(model: str) -> None:
    """dE/dt = u (n . xi') + tau . eta' (E5): with constant u and tau = 0, E - int u (n . xi') dt is constant.

    The power integral is integrated with the same RK4 stages as the state (augmented system).
    Measured: 5e-11 J while the thrust does ~100 J of work.
    """
    p = plant_params(VEHICLE, model)
    thrust = 1.1 * (p.M + p.m) * p.g
    u = make_input(thrust)

    def aug(y: np.ndarray) -> np.ndarray:
        d = derivative(0.0, y[:18], u, p)
        n = thrust_direction(y[6], y[7], y[8])
        power = thrust * (n[0] * y[3] + n[1] * y[4] + n[2] * y[5])
        return np.array([*d, power])

    y = np.array([*_swinging_state(), 0.0])
    h = 1e-3
    e0 = energy(list(y[:18]), p)
    worst = 0.0
    for _ in range(3000):
        k1 = aug(y)
        k2 = aug(y + 0.5 * h * k1)
        k3 = aug(y + 0.5 * h * k2)
        k4 = aug(y + h * k3)
        y = y + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        worst = max(worst, abs(energy(list(y[:18]), p) - y[18] - e0))
    assert abs(y[18]) > 1.0  # the thrust did real work (J)
    assert worst < 1e-9


# 2. Sphere form == the paper's angle form -------------------------------------------------------------------
def _paper_input(t: float, p) -> list[float]:
    mt = p.M + p.m
    torque = (0.01 * math.sin(2 * t), 0.01 * math.cos(t), 0.005 * math.sin(t))
    return make_input(mt * p.g * (1.0 + 0.1 * math.sin(t)), torque)


def test_sphere_form_matches_printed_angle_form_along_a_trajectory() -> None:
    """Integrate (15)-(24) (with E1, E2) and the sphere form side by side, DOP853 rtol 1e-11, 4 s."""
    p = plant_params(VEHICLE, "paper")
    xa0 = [0.0, 0.0, 1.0, 0.2, -0.1, 0.0, 0.05, -0.04, 0.1, 0.0, 0.0, 0.0, 0.5, 0.3, 1.0, 6.0]
    x0 = angle_to_sphere_state(xa0)
    ts = np.linspace(0.0, 4.0, 81)
    sa, ss = (
        solve_ivp(
            lambda t, y, f=f: f(t, y, _paper_input(t, p), p),
            (0, 4),
            y0,
            method="DOP853",
            rtol=1e-11,
            atol=1e-12,
            t_eval=ts,
        )
        for f, y0 in ((angle_derivative, xa0), (derivative, x0))
    )
    assert sa.success and ss.success
    alphas = sa.y[12]
    assert alphas.min() > 0.15 and alphas.max() > 0.6  # away from the singularity, and a real swing
    betas = np.unwrap(sa.y[13])
    worst_xi = worst_ang = worst_rate = 0.0
    for k in range(len(ts)):
        x = ss.y[:, k]
        worst_xi = max(worst_xi, np.abs(x[:6] - sa.y[:6, k]).max())
        s = swing_angles(*x[12:18])
        dbeta = (s.beta - betas[k] + math.pi) % (2 * math.pi) - math.pi
        worst_ang = max(worst_ang, abs(s.alpha - alphas[k]), abs(dbeta))
        worst_rate = max(worst_rate, abs(s.alpha_rate - sa.y[14, k]), abs(s.beta_rate - sa.y[15, k]))
    # measured: 1.5e-11 (xi, xi'), 4e-11 (alpha, beta), 1e-9 (alpha', beta'); alpha in [0.23, 0.76] rad
    assert worst_xi < 1e-8
    assert worst_ang < 1e-8
    assert worst_rate < 1e-7


def test_sphere_derivative_equals_angle_derivative_at_random_states() -> None:
    """derivative() agrees with the printed (12)-(24) pointwise, including alpha'' and beta''."""
    p = plant_params(VEHICLE, "paper")
    rng = np.random.default_rng(20260522)
    for _ in range(200):
        xa = list(rng.normal(scale=0.6, size=16))
        xa[12] = rng.uniform(0.1, 1.4)
        xa[13] = rng.uniform(-math.pi, math.pi)
        u = make_input(rng.uniform(0.0, 15.0), rng.normal(scale=0.05, size=3))
        x = angle_to_sphere_state(xa)
        d = derivative(0.0, x, u, p)
        da = angle_derivative(0.0, xa, u, p)
        np.testing.assert_allclose(d[:12], da[:12], rtol=0, atol=1e-12)
        add, bdd = angle_accelerations_from_sphere(x, d)
        assert abs(add - da[14]) < 1e-11
        assert abs(bdd - da[15]) < 1e-10 / math.sin(xa[12])
        # round trip of the state maps
        np.testing.assert_allclose(sphere_to_angle_state(x), xa, atol=1e-12)


def test_printed_r_with_plus_cos_alpha_is_wrong() -> None:
    """E1: with the printed r3 = +C_a, the load would sit above the vehicle at alpha = 0, and the potential
    m g (z + l r3) would not be (5)'s ``- m g l C_a``. Our plant: hover with the load straight below."""
    p = plant_params(VEHICLE)
    x = make_state(position=(0, 0, 2.0))
    e = energy(x, p)
    # (5): V = (M + m) g z - m g l C_a at alpha = 0
    assert e == pytest.approx((p.M + p.m) * p.g * 2.0 - p.m * p.g * p.l, abs=1e-12)


# 3. Jacobian == corrected tangent linearization ----------------------------------------------------------
def test_state_names_describe_the_reduced_coordinates() -> None:
    """The linear model's state names (one list, ``estimators.model.control_state``) name what ``full_to_reduced`` puts
    in each place, for the rigid body and the swing angles alike."""
    r, rd = cable_from_planar(0.05, -0.02, 0.3, -0.1)
    z = full_to_reduced(make_state((1.0, 2.0, 3.0), (4.0, 5.0, 6.0), (0.1, 0.2, 0.3), (0.4, 0.5, 0.6), r, rd))
    named = dict(zip(STATE_NAMES, z, strict=True))
    assert [named[n] for n in ("x", "y", "z", "vx", "vy", "vz")] == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
    assert [named[n] for n in ("phi", "theta", "psi", "phi_rate", "theta_rate", "psi_rate")] == [
        0.1,
        0.2,
        0.3,
        0.4,
        0.5,
        0.6,
    ]
    swing = [named[n] for n in ("alpha_y", "alpha_x", "alpha_y_rate", "alpha_x_rate")]
    assert swing == pytest.approx([0.05, -0.02, 0.3, -0.1], abs=1e-12)


def test_reduced_coordinates_round_trip_and_derivative() -> None:
    """reduced <-> full maps invert each other; reduced_derivative equals the derivative of full_to_reduced
    along the plant's flow (central differences, step 1e-6), so the Jacobian is taken of the right function."""
    p = plant_params(VEHICLE, "rigid")
    rng = np.random.default_rng(3)
    for _ in range(50):
        z = rng.normal(scale=0.4, size=16)
        x = reduced_to_full(z)
        np.testing.assert_allclose(full_to_reduced(x), z, atol=1e-13)
        v = [rng.uniform(3.0, 10.0), *rng.normal(scale=0.05, size=3)]
        xd = np.array(derivative(0.0, x, make_input(v[0], v[1:]), p))
        eps = 1e-6
        fd = (
            np.array(full_to_reduced(list(np.array(x) + eps * xd)))
            - np.array(full_to_reduced(list(np.array(x) - eps * xd)))
        ) / (2 * eps)
        np.testing.assert_allclose(reduced_derivative(z, v, p), fd, atol=1e-7)


@pytest.mark.parametrize("model", MODELS)
@pytest.mark.parametrize("psibar", [0.0, 0.7, -2.3, math.pi / 2])
def test_numerical_jacobian_equals_corrected_linearization(model: str, psibar: float) -> None:
    """Central-difference Jacobian (reduced coordinates) == (25)-(32) with E6, E7, heading psibar (measured 8e-12)."""
    p = plant_params(VEHICLE, model)
    z0, v0 = hover_point(p, psibar)
    A, B = jacobian(p, z0, v0)
    lin = linear_model(VEHICLE, psibar)
    np.testing.assert_allclose(A, lin.A, rtol=0, atol=1e-7)
    np.testing.assert_allclose(B, lin.B, rtol=0, atol=1e-7)


def test_printed_xz_linearization_disagrees_with_the_plant() -> None:
    """E6/E7 are real: the printed x'' = ((M+m) g theta - m g l alpha)/M does not match the Jacobian."""
    p = plant_params(VEHICLE)
    A, _ = jacobian(p, *hover_point(p))
    printed_dxdd_dalpha = -p.m * p.g * p.l / p.M
    assert abs(A[3, 12] - printed_dxdd_dalpha) > 1.0
    assert A[3, 12] == pytest.approx(p.m * p.g / p.M, abs=1e-7)
    w2 = (p.M + p.m) * p.g / (p.M * p.l)
    # (28) prints alpha_y'' = w2 (theta - alpha): the alpha coefficient is right, the theta one has the wrong sign
    assert A[14, 12] == pytest.approx(-w2, abs=1e-6)
    assert A[14, 7] == pytest.approx(-w2, abs=1e-6)


# 4. Hover -------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("model", MODELS)
@pytest.mark.parametrize("psi", [0.0, 1.1])
def test_hover_is_an_equilibrium(model: str, psi: float) -> None:
    p = plant_params(VEHICLE, model)
    x = make_state(position=(1.0, -2.0, 5.0), euler=(0.0, 0.0, psi))
    u = hover_input(p)
    d = derivative(0.0, x, u, p)
    assert max(abs(v) for v in d) < 1e-14
    assert tension(x, u, p) == pytest.approx(p.m * p.g, rel=1e-15)
    # and it stays there
    y = _run_rk4(x, u, p, 1e-2, 100)
    assert max(abs(a - b) for a, b in zip(x, y)) < 1e-12


# 5. Tension -----------------------------------------------------------------------------------------------
def test_tension_matches_load_acceleration() -> None:
    """m (a_load + g e3) = -T r + F_L and M (a_vehicle + g e3) = u n + F_Q + T r at random states."""
    p = plant_params(VEHICLE, "rigid")
    rng = np.random.default_rng(7)
    for _ in range(100):
        r = rng.normal(size=3)
        r /= np.linalg.norm(r)
        x = make_state(
            rng.normal(size=3),
            rng.normal(size=3),
            rng.normal(scale=0.3, size=3),
            rng.normal(size=3),
            r,
            rng.normal(scale=2.0, size=3),
        )
        fq, fl = rng.normal(size=3), rng.normal(scale=0.3, size=3)
        u = make_input(rng.uniform(0, 15), rng.normal(scale=0.1, size=3), fq, fl)
        d = np.array(derivative(0.0, x, u, p))
        T = tension(x, u, p)
        a_load = d[3:6] + p.l * d[15:18]
        g3 = np.array([0.0, 0.0, p.g])
        rv = np.array(x[12:15])
        np.testing.assert_allclose(p.m * (a_load + g3), -T * rv + fl, atol=1e-11)
        n = np.array(thrust_direction(*x[6:9]))
        np.testing.assert_allclose(p.M * (d[3:6] + g3), u[0] * n + fq + T * rv, atol=1e-11)
        # without external load force: |T| = m |a_load + g e3|
        u0 = make_input(u[0], u[1:4], fq)
        d0 = np.array(derivative(0.0, x, u0, p))
        assert abs(tension(x, u0, p)) == pytest.approx(
            p.m * np.linalg.norm(d0[3:6] + p.l * d0[15:18] + g3), rel=1e-10, abs=1e-12
        )


def test_tension_is_signed_and_detects_a_slack_cable() -> None:
    """tension() returns the signed constraint force of the rigid (bilateral) cable, never clamped.

    - free fall, u = 0, r' = 0: T = 0 (vehicle and load fall together, the cable carries nothing);
    - u = 0, load whirling (|r'| large): T = m M l |r'|^2 / M_t > 0 (centripetal; the cable is taut);
    - thrust pointing toward the load (vehicle upside down above a hanging load, or load above an upright
      vehicle): T = -m u / M_t < 0, the vehicle out-accelerates the free-falling load: slack cable.
    """
    p = plant_params(VEHICLE)
    mt = p.M + p.m
    x = make_state()
    assert tension(x, make_input(0.0), p) == 0.0
    x = make_state(cable=(1.0, 0.0, 0.0), cable_rate=(0.0, 10.0, 0.0))
    assert tension(x, make_input(0.0), p) == pytest.approx(p.m * p.M * p.l * 100.0 / mt, rel=1e-14)
    u = make_input(5.0)
    assert tension(make_state(euler=(math.pi, 0.0, 0.0)), u, p) == pytest.approx(-p.m * 5.0 / mt, rel=1e-12)
    assert tension(make_state(cable=(0.0, 0.0, 1.0)), u, p) == pytest.approx(-p.m * 5.0 / mt, rel=1e-12)
    # load above an upright vehicle but spun fast enough: taut again (sign flips at M l |r'|^2 = u)
    x = make_state(cable=(0.0, 0.0, 1.0), cable_rate=(math.sqrt(5.0 / (p.M * p.l)) * 1.01, 0.0, 0.0))
    assert tension(x, u, p) > 0.0


# 6. Invariants --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("model", MODELS)
def test_cable_invariants_after_many_steps(model: str) -> None:
    p = plant_params(VEHICLE, model)
    x = _swinging_state()
    u = make_input(8.0, (0.001, -0.002, 0.001))
    worst_norm = worst_dot = 0.0
    for _ in range(20):
        x = _run_rk4(x, u, p, 5e-3, 100)
        worst_norm = max(worst_norm, abs(math.sqrt(sum(c * c for c in x[12:15])) - 1.0))
        worst_dot = max(worst_dot, abs(sum(a * b for a, b in zip(x[12:15], x[15:18]))))
    assert worst_norm < 1e-14
    assert worst_dot < 1e-13


# 7. RK4 order ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("model", MODELS)
def test_rk4_is_fourth_order(model: str) -> None:
    """Halving h divides the error at t = 1 s by ~16 (measured ratios 16.3-16.4, h = 40, 20, 10 ms)."""
    p = plant_params(VEHICLE, model)
    x0 = _swinging_state()
    u = make_input(7.5, (0.002, -0.001, 0.0005))
    ref = solve_ivp(lambda t, y: derivative(t, y, u, p), (0, 1.0), x0, method="DOP853", rtol=1e-13, atol=1e-13)
    xr = ref.y[:, -1]
    errs = []
    for n in (25, 50, 100):
        x = _run_rk4(x0, u, p, 1.0 / n, n)
        errs.append(np.abs(np.array(x) - xr).max())
    assert errs[0] > 1e-7  # the error is measurable, not round-off
    for a, b in itertools.pairwise(errs):
        assert 13.0 < a / b < 19.0


def test_rigid_body_conserves_world_angular_momentum() -> None:
    """attitude_model="rigid", tau = 0, asymmetric inertia: the world-frame angular momentum R I w is constant.

    Energy alone cannot catch a wrong sign of the gyroscopic term (w . (w x I w) = 0 either way); this can.
    Measured: 2e-12 (rigid); the paper's (13) on the same state drifts by 0.11 kg m^2/s.
    """
    v = Vehicle(inertia=(0.01, 0.02, 0.035))
    p = plant_params(v, "rigid")
    x = make_state(euler=(0.2, -0.3, 0.5), euler_rate=(3.0, -2.0, 4.0))
    u = make_input(0.0)

    def world_momentum(s: list[float]) -> np.ndarray:
        f, t, ps = s[6:9]
        df, dt, dp = s[9:12]
        w = np.array(
            [
                df - math.sin(t) * dp,
                math.cos(f) * dt + math.sin(f) * math.cos(t) * dp,
                -math.sin(f) * dt + math.cos(f) * math.cos(t) * dp,
            ]
        )
        n = np.array(thrust_direction(f, t, ps))
        cp, sp = math.cos(ps), math.sin(ps)
        ct, st = math.cos(t), math.sin(t)
        ex = np.array([cp * ct, sp * ct, -st])  # body x axis in the world (first column of R)
        ey = np.cross(n, ex)
        R = np.column_stack([ex, ey, n])
        return R @ (np.array(v.inertia) * w)

    l0 = world_momentum(x)
    worst = 0.0
    for _ in range(10):
        x = _run_rk4(x, u, p, 1e-3, 100)
        worst = max(worst, np.abs(world_momentum(x) - l0).max())
    assert np.abs(np.array(x[9:12]) - [3.0, -2.0, 4.0]).max() > 0.1  # the Euler rates really changed
    assert worst < 1e-9
