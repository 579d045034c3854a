"""The sliding-mode controller: gains, signs, designed closed-loop poles, heading frame, safety."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import expm

from estimators.model.control_state import ControlState
from estimators.model.vehicle import Vehicle
from offboard.control import smc
from offboard.harness.sim import truth_control_state
from sim_bridge.plant import dynamics

VEHICLE = Vehicle()
ZERO7 = (0.0,) * 7


def hold(value: float) -> tuple[float, ...]:
    return (value, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


def test_gains_place_the_triple_pole_pair_of_the_paper() -> None:
    g = smc.Gains.from_poles()
    poly = np.poly1d([1.0, 2 * 0.9 * 6.0, 36.0]) ** 3
    assert np.allclose(list(reversed(g.K)), poly.coeffs[1:], rtol=1e-12)
    assert g.K[4] == pytest.approx(457.92)  # errata E14: the printed formula gives 166.32
    roots = np.roots([1.0, *reversed(g.K)])
    assert np.all(roots.real < -5.3) and np.all(roots.real > -5.5)
    assert (g.lambda0, g.lambda1, g.gamma0, g.gamma1) == pytest.approx((100.0, 18.0, 81.0, 16.2))
    printed_k4 = 2 * 0.9**2 * 36 + 3 * 36
    printed = np.roots([1.0, g.K[5], printed_k4, g.K[3], g.K[2], g.K[1], g.K[0]])
    assert np.max(printed.real) > 1.0  # the misprint would make the horizontal loop unstable


def _hover_state(**kw: float) -> ControlState:
    base = {
        "fx": (0.0,) * 6,
        "fy": (0.0,) * 6,
        "z": 1.0,
        "z_rate": 0.0,
        "phi": 0.0,
        "theta": 0.0,
        "psi": 0.0,
        "phi_rate": 0.0,
        "theta_rate": 0.0,
        "psi_rate": 0.0,
        "alpha_x": 0.0,
        "alpha_y": 0.0,
        "alpha_x_rate": 0.0,
        "alpha_y_rate": 0.0,
    }
    base.update(kw)
    return ControlState(**base)  # type: ignore[arg-type]


def test_hover_command_and_restoring_signs() -> None:
    params = smc.ControllerParams.for_vehicle(VEHICLE, switching="smooth")

    def at_hover_reference(**state: object) -> smc.Command:
        """The first command for the state ``_hover_state(**state)`` against a hover at 1 m."""
        est = _hover_state(**state)
        return smc.step(0.0, est, hold(0.0), hold(0.0), hold(1.0), ZERO7, smc.ControllerMemory(), params)[0]

    cmd = at_hover_reference()
    assert cmd.thrust == pytest.approx(VEHICLE.hover_thrust, rel=1e-12)
    assert (cmd.tau_phi, cmd.tau_theta, cmd.tau_psi) == pytest.approx((0.0, 0.0, 0.0), abs=1e-12)
    # errata E10: positive e_Fx -> tau_theta < 0 (tilt toward -x); positive e_Fy -> tau_phi > 0 (tilt toward -y)
    cx = at_hover_reference(fx=(0.05, 0, 0, 0, 0, 0))
    cy = at_hover_reference(fy=(0.05, 0, 0, 0, 0, 0))
    assert cx.tau_theta < 0.0 and abs(cx.tau_phi) < 1e-12
    assert cy.tau_phi > 0.0 and abs(cy.tau_theta) < 1e-12
    # too low -> more thrust; yaw left of the reference -> negative yaw torque
    cz = at_hover_reference(z=0.9)
    cp = at_hover_reference(psi=0.1)
    assert cz.thrust > VEHICLE.hover_thrust
    assert cp.tau_psi < 0.0


def test_matches_printed_law_74_at_zero_heading() -> None:
    """At psi = 0 the world-frame implementation is the printed (74) with its feed-forward (I_theta/g) F^(4)."""
    params = smc.ControllerParams.for_vehicle(VEHICLE, switching="smooth", epsilon=0.5)
    rng = np.random.default_rng(1)
    M, m, l, g = VEHICLE.mass_vehicle, VEHICLE.mass_load, VEHICLE.cable_length, VEHICLE.gravity
    I_theta = VEHICLE.inertia[1]
    K = params.gains.K
    for _ in range(20):
        fx = tuple(rng.normal(0, 0.01, 6).tolist())
        ref = tuple(rng.normal(0, 0.01, 7).tolist())
        mem = smc.ControllerMemory(int_fx=float(rng.normal(0, 1e-4)), t=0.0)
        cmd, _ = smc.step(0.0, _hover_state(fx=fx), ref, hold(0.0), hold(1.0), ZERO7, mem, params)
        e = [fx[i] - ref[i] for i in range(6)]
        sigma = e[5] + K[5] * e[4] + K[4] * e[3] + K[3] * e[2] + K[2] * e[1] + K[1] * e[0] + K[0] * mem.int_fx
        sw = sigma / (abs(sigma) + 0.5)
        brace = ref[6] - sum(K[i] * e[i] for i in range(6)) - params.gains.rho_F * sw
        printed = M * l * I_theta / (g**2 * (M + m)) * brace + I_theta / g * fx[4]
        expected = max(-params.torque_max[1], min(params.torque_max[1], printed))
        assert cmd.tau_theta == pytest.approx(expected, rel=1e-9, abs=1e-12)


def _closed_loop_error(psi0: float, offset: tuple[float, float], duration: float) -> tuple[np.ndarray, np.ndarray]:
    """Fly the nonlinear plant with rho = 0 from a small flat-output offset; return times and e_F (world)."""
    gains = smc.Gains.from_poles(rho_z=0.0, rho_psi=0.0, rho_F=0.0)
    params = smc.ControllerParams(vehicle=VEHICLE, gains=gains, switching="smooth")
    p = dynamics.plant_params(VEHICLE)
    x = dynamics.make_state(position=(offset[0], offset[1], 1.0), euler=(0.0, 0.0, psi0))
    from estimators.model.flatness import flat_constants

    k = flat_constants(VEHICLE)
    mem = smc.ControllerMemory()
    ts, es = [], []
    h = 1e-3
    for i in range(round(duration / h)):
        t = i * h
        s = truth_control_state(x, k)
        cmd, mem = smc.step(t, s, hold(0.0), hold(0.0), hold(1.0), hold(psi0), mem, params)
        ts.append(t)
        es.append((s.fx[0], s.fy[0]))
        x = dynamics.rk4_step(x, dynamics.make_input(cmd.thrust, cmd[1:4]), p, h)
    return np.array(ts), np.array(es)


def test_tracking_error_decays_at_the_designed_poles() -> None:
    """With rho = 0 and a small offset the horizontal error obeys q3(p) e = 0 (companion matrix of (80))."""
    K = smc.Gains.from_poles().K
    A = np.zeros((6, 6))
    A[:5, 1:] = np.eye(5)
    A[5, :] = [-k for k in K]
    e0 = np.array([1e-3, 0, 0, 0, 0, 0])  # vehicle displaced 1 mm, everything else at rest
    _, e = _closed_loop_error(0.0, (1e-3, 0.0), 2.0)
    for tk in (0.25, 0.5, 1.0, 1.5):
        predicted = (expm(A * tk) @ e0)[0]
        i = round(tk / 1e-3)
        assert e[i, 0] == pytest.approx(predicted, abs=2e-3 * 1e-3), tk
    assert abs(e[-1, 0]) < 0.02 * 1e-3  # and it has decayed


def test_heading_aligned_frame_gives_the_same_response_at_any_heading() -> None:
    """The same offset, expressed in a frame rotated by the heading, decays identically."""
    psi = 0.7
    c, s = math.cos(psi), math.sin(psi)
    _, e0 = _closed_loop_error(0.0, (1e-3, 0.5e-3), 1.5)
    _, e1 = _closed_loop_error(psi, (1e-3 * c - 0.5e-3 * s, 1e-3 * s + 0.5e-3 * c), 1.5)
    rotated = np.stack([c * e0[:, 0] - s * e0[:, 1], s * e0[:, 0] + c * e0[:, 1]], axis=1)
    assert np.max(np.abs(e1 - rotated)) < 1e-8


def test_non_finite_inputs_give_the_hover_command_never_nan() -> None:
    params = smc.ControllerParams.for_vehicle(VEHICLE)
    mem = smc.ControllerMemory(int_z=0.1, t=0.0)
    for bad in (math.nan, math.inf, -math.inf):
        cmd, mem2 = smc.step(0.01, _hover_state(alpha_x=bad), hold(0.0), hold(0.0), hold(1.0), ZERO7, mem, params)
        assert not cmd.valid
        assert all(math.isfinite(v) for v in cmd[:8])
        assert cmd.thrust == pytest.approx(VEHICLE.hover_thrust)
        assert mem2 == mem
        cmd, _ = smc.step(0.01, _hover_state(), (bad, *ZERO7[1:]), hold(0.0), hold(1.0), ZERO7, mem, params)
        assert not cmd.valid and all(math.isfinite(v) for v in cmd[:8])


def test_commands_are_saturated_to_the_vehicle_limits() -> None:
    params = smc.ControllerParams.for_vehicle(VEHICLE)
    cmd, _ = smc.step(
        0.0,
        _hover_state(fx=(50.0, 0, 0, 0, 0, 0), fy=(-50.0, 0, 0, 0, 0, 0), z=-100.0, psi=2.0),
        hold(0.0),
        hold(0.0),
        hold(1.0),
        ZERO7,
        smc.ControllerMemory(),
        params,
    )
    assert cmd.saturated
    assert 0.0 <= cmd.thrust <= VEHICLE.thrust_max
    assert cmd.thrust == pytest.approx(VEHICLE.thrust_max)
    assert abs(cmd.tau_theta) == pytest.approx(VEHICLE.roll_pitch_torque_max)
    assert abs(cmd.tau_phi) == pytest.approx(VEHICLE.roll_pitch_torque_max)
    assert abs(cmd.tau_psi) <= VEHICLE.yaw_torque_max + 1e-12


def test_step_is_pure() -> None:
    params = smc.ControllerParams.for_vehicle(VEHICLE)
    state = _hover_state(fx=(1e-3, 2e-3, 3e-3, 1e-3, 2e-3, 0.0), alpha_x=-0.005, alpha_y=0.01, theta=0.005)
    mem = smc.ControllerMemory(0.01, 0.0, 0.001, -0.002, 1.0)
    a = smc.step(1.001, state, hold(0.0), hold(0.0), hold(1.0), ZERO7, mem, params)
    b = smc.step(1.001, state, hold(0.0), hold(0.0), hold(1.0), ZERO7, mem, params)
    assert a == b
    assert not a[0].saturated
    assert a[1].int_fx == pytest.approx(0.001 + 1e-3 * 0.001)  # integral advanced by the elapsed time
    assert a[1].int_fy == pytest.approx(-0.002)  # zero error in y: unchanged


def test_integrals_are_held_while_the_command_is_clipped() -> None:
    """Anti-windup (docs/model.md C-10): a clipped loop does not integrate its error."""
    params = smc.ControllerParams.for_vehicle(VEHICLE)
    mem = smc.ControllerMemory(0.01, 0.02, 0.001, -0.002, 1.0)
    big_yaw = _hover_state(psi=1.0)  # far beyond the yaw authority
    cmd, new = smc.step(1.01, big_yaw, hold(0.0), hold(0.0), hold(1.0), ZERO7, mem, params)
    assert cmd.saturated and abs(cmd.tau_psi) == pytest.approx(VEHICLE.yaw_torque_max)
    assert new.int_psi == mem.int_psi
    assert new.int_fx == mem.int_fx and new.int_z == pytest.approx(mem.int_z)
    small_yaw = _hover_state(psi=1e-4)
    cmd, new = smc.step(1.01, small_yaw, hold(0.0), hold(0.0), hold(1.0), ZERO7, mem, params)
    assert not cmd.saturated and new.int_psi == pytest.approx(0.02 + 1e-4 * 0.01)
    big_x = _hover_state(fx=(5.0, 0, 0, 0, 0, 0))
    cmd, new = smc.step(1.01, big_x, hold(0.0), hold(0.0), hold(1.0), ZERO7, mem, params)
    assert cmd.saturated and (new.int_fx, new.int_fy) == (mem.int_fx, mem.int_fy)
