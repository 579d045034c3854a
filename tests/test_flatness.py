"""estimators/model/flatness.py against the corrected linear model (offboard/control/linear_model.py): the flat-output
chain of errata E9 holds along the linear dynamics, the torque first appears in F^(6), and the world-frame chain
holds at any heading."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from estimators.model.flatness import flat_chain, flat_constants, planar_state, world_tilt
from estimators.model.vehicle import Vehicle
from offboard.control.linear_model import linear_model, xz_model, yz_model

VEHICLES = (
    Vehicle(),
    Vehicle(mass_vehicle=1.2, mass_load=0.3, cable_length=1.0, inertia=(0.02, 0.03, 0.05), motor_thrust_max=8.0),
)


def _plane_chain(k, s: np.ndarray, tilt_sign: float) -> np.ndarray:
    """Chain of one plane from [p, p', angle, angle', a, a']; the tilt is +theta (X-Z) or -phi (Y-Z) at psi = 0."""
    return np.array(flat_chain(k, s[0], s[1], s[4], s[5], tilt_sign * s[2], tilt_sign * s[3]))


@pytest.mark.parametrize("vehicle", VEHICLES)
def test_flat_chain_and_planar_state_are_inverse(vehicle: Vehicle) -> None:
    k = flat_constants(vehicle)
    rng = np.random.default_rng(5)
    for _ in range(100):
        st = tuple(rng.normal(size=6))
        np.testing.assert_allclose(planar_state(k, flat_chain(k, *st)), st, rtol=1e-12, atol=1e-12)
        ch = tuple(rng.normal(size=6) * [1, 1, 10, 10, 1e3, 1e3])
        np.testing.assert_allclose(flat_chain(k, *planar_state(k, ch)), ch, rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("vehicle", VEHICLES)
@pytest.mark.parametrize("plane", ["xz", "yz"])
def test_chain_along_the_linear_model(vehicle: Vehicle, plane: str) -> None:
    """d/dt F^(j) = F^(j+1) for j < 5 with no input, and F^(6) = +-(c/I) tau - (M_t g/(M l)) F^(4) (E9).

    X-Z: F'' = -g alpha_y, F^(4) = c (theta + alpha_y), F^(6) = (c/I_theta) tau_theta - w2 F^(4);
    Y-Z: F'' = -g alpha_x, F^(4) = c (alpha_x - phi), F^(6) = -(c/I_phi) tau_phi - w2 F^(4).
    """
    k = flat_constants(vehicle)
    lin = xz_model(vehicle) if plane == "xz" else yz_model(vehicle)
    sign = 1.0 if plane == "xz" else -1.0
    inertia = vehicle.inertia[1] if plane == "xz" else vehicle.inertia[0]
    rng = np.random.default_rng(6)
    for _ in range(50):
        s = rng.normal(size=6)
        tau = rng.normal()
        sd = lin.A @ s + lin.B[:, 0] * tau
        F = _plane_chain(k, s, sign)
        dF = _plane_chain(k, s + sd, sign) - F  # the chain is linear in the state
        scale = np.abs(F).max() + np.abs(dF).max()
        np.testing.assert_allclose(dF[:5], F[1:], atol=1e-12 * scale)
        assert dF[5] == pytest.approx(sign * k.c / inertia * tau - k.omega2 * F[4], abs=1e-12 * scale)
        assert F[2] == pytest.approx(-k.g * s[4])
        assert F[4] == pytest.approx(k.c * (s[4] + sign * s[2]))


@pytest.mark.parametrize("plane", ["xz", "yz"])
def test_torque_first_appears_in_sixth_derivative(plane: str) -> None:
    """Relative degree 6: F', ..., F^(5) do not depend on the torque; F^(6) does (so F is a flat output)."""
    vehicle = Vehicle()
    k = flat_constants(vehicle)
    lin = xz_model(vehicle) if plane == "xz" else yz_model(vehicle)
    sign = 1.0 if plane == "xz" else -1.0
    # chain as a matrix C (rows F^(j), j = 0..5) acting on the state
    C = np.column_stack([_plane_chain(k, e, sign) for e in np.eye(6)])
    CB = C @ lin.B[:, 0]
    np.testing.assert_allclose(CB[:5], 0.0, atol=1e-12)
    assert abs(CB[5]) > 1.0
    # the chain is a state transformation (invertible), so states are functions of F, ..., F^(5)
    assert abs(np.linalg.det(C)) > 1e-6


def test_printed_xz_sign_is_not_a_flat_chain() -> None:
    """Negative control (E7): with the printed F = x - l alpha_y (alpha_y from its atan2 definition), F'' is
    not -g alpha_y or +g alpha_y: it depends on theta, so torque enters before the 6th derivative."""
    vehicle = Vehicle()
    lin = xz_model(vehicle)
    c_wrong = np.array([1.0, 0.0, 0.0, 0.0, -vehicle.cable_length, 0.0])  # x - l alpha_y
    second = c_wrong @ lin.A @ lin.A
    assert abs(second[2]) > 1.0  # theta coefficient of F''
    fourth_b = c_wrong @ np.linalg.matrix_power(lin.A, 3) @ lin.B[:, 0]
    assert abs(fourth_b) > 1.0  # tau appears in F^(4)


@pytest.mark.parametrize("psibar", [0.0, 0.7, -2.0])
def test_world_frame_chain_at_any_heading(psibar: float) -> None:
    """At heading psibar, flat_chain with world_tilt still gives d/dt F^(j) = F^(j+1) and
    F_x^(6) = c (C tau_theta/I_theta + S tau_phi/I_phi) - w2 F_x^(4),
    F_y^(6) = c (S tau_theta/I_theta - C tau_phi/I_phi) - w2 F_y^(4), on the full 16-state linear model."""
    vehicle = Vehicle(inertia=(0.08, 0.1, 0.12))
    k = flat_constants(vehicle)
    lin = linear_model(vehicle, psibar)
    i_phi, i_theta, _ = vehicle.inertia
    cp, sp = math.cos(psibar), math.sin(psibar)

    def chains(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        nx, ny, nxd, nyd = world_tilt(z[6], z[7], psibar + z[8], z[9], z[10], z[11])
        return (
            np.array(flat_chain(k, z[0], z[3], z[12], z[14], nx, nxd)),
            np.array(flat_chain(k, z[1], z[4], z[13], z[15], ny, nyd)),
        )

    rng = np.random.default_rng(8)
    for _ in range(50):
        z = rng.normal(size=16)
        z[8] = z[11] = 0.0  # heading held at psibar (tau_psi = 0)
        v = np.array([rng.normal(), rng.normal(), rng.normal(), 0.0])
        zd = lin.A @ z + lin.B @ v
        (fx, fy), (fx2, fy2) = chains(z), chains(z + zd)
        dfx, dfy = fx2 - fx, fy2 - fy
        scale = 1e-12 * (np.abs(fx).max() + np.abs(fy).max() + np.abs(dfx).max() + np.abs(dfy).max())
        np.testing.assert_allclose(dfx[:5], fx[1:], atol=scale)
        np.testing.assert_allclose(dfy[:5], fy[1:], atol=scale)
        ax, ay = v[2] / i_theta, v[1] / i_phi
        assert dfx[5] == pytest.approx(k.c * (cp * ax + sp * ay) - k.omega2 * fx[4], abs=scale)
        assert dfy[5] == pytest.approx(k.c * (sp * ax - cp * ay) - k.omega2 * fy[4], abs=scale)


def test_chain_along_a_propagated_trajectory() -> None:
    """Integrate the X-Z linear model with tau(t) = 0.02 sin(3 t) and check F^(j+1)(t) against the time
    derivative of F^(j)(t) (central differences of the propagated states) and F^(6) from (42)."""
    vehicle = Vehicle()
    k = flat_constants(vehicle)
    lin = xz_model(vehicle)

    def tau(t: float) -> float:
        return 0.02 * math.sin(3.0 * t)

    s0 = [0.1, 0.0, 0.02, 0.0, -0.05, 0.1]
    h = 1e-4
    ts = np.array([0.5, 1.0, 1.5])
    t_eval = np.sort(np.concatenate([ts - h, ts, ts + h]))
    sol = solve_ivp(
        lambda t, s: lin.A @ s + lin.B[:, 0] * tau(t),
        (0.0, 2.0),
        s0,
        method="DOP853",
        rtol=1e-12,
        atol=1e-14,
        t_eval=t_eval,
    )
    assert sol.success
    for i in range(3):
        fm, f0, fp = (_plane_chain(k, sol.y[:, 3 * i + j], 1.0) for j in range(3))
        d = (fp - fm) / (2 * h)
        scale = np.abs(f0).max() + 1.0
        np.testing.assert_allclose(d[:5], f0[1:], atol=1e-6 * scale)
        f6 = k.c / vehicle.inertia[1] * tau(ts[i]) - k.omega2 * f0[4]
        assert d[5] == pytest.approx(f6, abs=1e-6 * (abs(f6) + scale))
