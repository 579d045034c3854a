"""The torque-level law's per-loop boundary layers (``boundary_layers.error_boundary_layers``, docs/model.md
C-12): each loop's smooth switching width is the value its own sliding variable takes for a small tracking error,
it follows a gain scaling, each loop gets its own width (not another loop's), and flights use it by default (the
compiled law: tests/test_roll_pitch_margin.py; the record for replay: tests/test_replay.py)."""

from __future__ import annotations

import argparse
import math
from dataclasses import replace

import numpy as np
import pytest

from estimators.model.control_state import ControlState
from estimators.model.vehicle import Vehicle
from offboard.control import smc
from offboard.control.boundary_layers import FLIGHT_LAYER_ERRORS, error_boundary_layers
from offboard.flight.fly_args import add_flight_arguments

VEHICLE = Vehicle()
ZERO7 = (0.0,) * 7


def _state(rng: np.random.Generator) -> ControlState:
    """A state near hover at 1 m with small errors in every loop (inside and outside the layers)."""
    fx = tuple(float(v) for v in rng.normal(0.0, [0.02, 0.05, 0.2, 1.0, 5.0, 20.0]))
    fy = tuple(float(v) for v in rng.normal(0.0, [0.02, 0.05, 0.2, 1.0, 5.0, 20.0]))
    ax, ay, axr, ayr, phi, th, pr, tr = (float(v) for v in rng.normal(0.0, 0.02, 8))
    return ControlState(
        fx=fx,
        fy=fy,
        z=1.0 + float(rng.normal(0.0, 0.02)),
        z_rate=float(rng.normal(0.0, 0.05)),
        phi=phi,
        theta=th,
        psi=float(rng.normal(0.0, 0.02)),
        phi_rate=pr,
        theta_rate=tr,
        psi_rate=float(rng.normal(0.0, 0.05)),
        alpha_x=ax,
        alpha_y=ay,
        alpha_x_rate=axr,
        alpha_y_rate=ayr,
    )


def _ref() -> tuple[tuple[float, ...], ...]:
    return ZERO7, ZERO7, (1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0), ZERO7


def test_each_layer_is_its_surface_s_value_for_the_given_error_and_follows_a_gain_scaling() -> None:
    g = smc.Gains.from_poles()
    ez, epsi, ef = error_boundary_layers(g, (0.02, 0.03, 0.04))
    # the error terms of the surfaces: s_z = e' + lambda1 e + ..., s_psi = e' + gamma1 e + ...,
    # sigma = e^(5) + ... + K1 e + K0 int e (smc.step)
    assert (ez, epsi, ef) == pytest.approx((g.lambda1 * 0.02, g.gamma1 * 0.03, g.K[1] * 0.04), rel=1e-15)
    assert ef > 500.0 * ez  # why one epsilon cannot serve all loops: the horizontal variable is ~1000x larger
    p = smc.ControllerParams.for_vehicle(VEHICLE, switching="smooth", layer_errors=(0.02, 0.03, 0.04))
    assert p.layers() == pytest.approx((ez, epsi, ef), rel=1e-15)
    scaled = replace(p, gains=p.gains.scaled(0.5))  # what the live loop does for a slow link
    lz, lpsi, lf = scaled.layers()
    assert (lz, lpsi) == pytest.approx((0.5 * ez, 0.5 * epsi), rel=1e-12)
    assert lf == pytest.approx(0.5**5 * ef, rel=1e-12)
    # without layer errors: the paper's one epsilon for all loops
    assert smc.ControllerParams.for_vehicle(VEHICLE, switching="smooth", epsilon=2.5).layers() == (2.5, 2.5, 2.5)
    for bad in ((0.02, 0.0, 0.02), (0.02, math.nan, 0.02), (0.02, 0.02)):
        with pytest.raises(ValueError):
            smc.ControllerParams.for_vehicle(VEHICLE, switching="smooth", layer_errors=bad)


def test_each_loop_switches_with_its_own_layer() -> None:
    """With layers (a, b, c) the height command is the uniform-epsilon law's at epsilon a, the yaw torque at b, the
    roll / pitch torques at c: each loop reads its own width, none another's."""
    layered = smc.ControllerParams.for_vehicle(VEHICLE, switching="smooth", layer_errors=(0.02, 0.02, 0.02))
    a, b, c = layered.layers()
    uniform = {e: smc.ControllerParams.for_vehicle(VEHICLE, switching="smooth", epsilon=e) for e in (a, b, c)}
    rng = np.random.default_rng(3)
    rfx, rfy, rz, rpsi = _ref()
    differs = 0
    for _ in range(50):
        est = _state(rng)
        mem = smc.ControllerMemory()
        cmd, _ = smc.step(0.0, est, rfx, rfy, rz, rpsi, mem, layered)
        at = {e: smc.step(0.0, est, rfx, rfy, rz, rpsi, mem, p)[0] for e, p in uniform.items()}
        assert cmd.thrust == pytest.approx(at[a].thrust, rel=1e-12, abs=1e-12)
        assert cmd.tau_psi == pytest.approx(at[b].tau_psi, rel=1e-12, abs=1e-12)
        assert (cmd.tau_phi, cmd.tau_theta) == pytest.approx((at[c].tau_phi, at[c].tau_theta), rel=1e-12, abs=1e-12)
        differs += abs(at[a].tau_phi - at[c].tau_phi) > 1e-6  # the widths matter: the wrong one is another law
    assert differs > 10  # (where both clip the pair to the same limit they agree)


def test_inside_its_layer_the_horizontal_switching_is_linear_not_a_jump() -> None:
    """The point of the layer: an error of a few millimetres (the filter's noise) moves the roll / pitch torque in
    proportion, where the paper's sign(.) (or epsilon = 1) flips it by the whole switching amplitude."""
    layered = smc.ControllerParams.for_vehicle(VEHICLE, switching="smooth", layer_errors=FLIGHT_LAYER_ERRORS)
    sign = smc.ControllerParams.for_vehicle(VEHICLE, switching="sign")
    rfx, rfy, rz, rpsi = _ref()
    base = _state(np.random.default_rng(0))._replace(fx=(0.0,) * 6, fy=(0.0,) * 6, alpha_x=0.0, alpha_y=0.0)
    base = base._replace(alpha_x_rate=0.0, alpha_y_rate=0.0, phi=0.0, theta=0.0, phi_rate=0.0, theta_rate=0.0)

    def jump(p: smc.ControllerParams) -> float:
        """tau_theta at +1 mm minus at -1 mm of x error."""
        t = [
            smc.step(0.0, base._replace(fx=(d, 0.0, 0.0, 0.0, 0.0, 0.0)), rfx, rfy, rz, rpsi, smc.ControllerMemory(), p)
            for d in (1e-3, -1e-3)
        ]
        return abs(t[0][0].tau_theta - t[1][0].tau_theta)

    linear_part = jump(replace(layered, layer_errors=(1e6, 1e6, 1e6)))  # the switching term all but off
    # in the layer the switching term adds rho / eps_F * K1 e = 1.19 * 41990 e to the linear K0 e = 46656 e of the
    # commanded F^(6): about twice the linear response, in proportion
    assert 1.5 * linear_part < jump(layered) < 2.5 * linear_part
    assert jump(sign) > 10.0 * jump(layered)  # sign(.): +-rho_F = 1000 m/s^6 for any error, about 21 times that


def test_flights_default_to_the_layers_and_an_epsilon_restores_the_paper_s_one_width() -> None:
    from offboard.flight import flight_law

    p = argparse.ArgumentParser()
    add_flight_arguments(p)
    args = p.parse_args([])
    assert args.switching is None and args.epsilon is None  # resolved in fly(), per law
    # the resolution fly() does (its first lines), without flying
    resolved = flight_law.resolve_switching(args, "torque", VEHICLE)
    assert (args.switching, args.layer_errors, resolved.layer_errors) == (
        "smooth",
        list(FLIGHT_LAYER_ERRORS),
        FLIGHT_LAYER_ERRORS,
    )
    args = p.parse_args(["--epsilon", "1"])
    resolved = flight_law.resolve_switching(args, "torque", VEHICLE)
    assert (args.switching, args.layer_errors, resolved.layer_errors, resolved.epsilon) == ("smooth", None, None, 1.0)
    args = p.parse_args(["--switching", "sign"])
    resolved = flight_law.resolve_switching(args, "torque", VEHICLE)
    assert (resolved.switching, resolved.layer_errors) == ("sign", None)
    # whatever the switching, the flight's torque-level law leads over the vehicle's motor lag (docs/model.md C-13),
    # recorded for replay; the attitude-level law records none (its inner loop is the autopilot's)
    assert resolved.actuation_lag_s == args.actuation_lag_s == VEHICLE.motor_time_constant > 0.0
    flight_law.resolve_switching(args := p.parse_args([]), "attitude", VEHICLE)
    assert args.actuation_lag_s is None


def test_the_layers_fly_the_paper_seed_that_the_sign_law_swings_up() -> None:
    """The paper scenario, seed 9, through the emulator's X mixer with the filter on px4-fast sensors at 250 Hz (the
    demo's loop in process): with the paper's sign(.) the roll / pitch chatter meets the disturbance's 1.9 Hz power
    and the load swings up; with each loop's own layer it is flown within the paper's Table 2."""
    from offboard.control.scenarios import make_scenario
    from offboard.harness import sim as sim_mod
    from offboard.report import metrics as metrics_mod

    scenario = make_scenario("paper", duration=50.0, seed=9)
    config = sim_mod.SimConfig(
        control_rate=250.0, attitude_model="rigid", sensors="px4-fast", estimator="kf", seed=9, actuators="mixer"
    )
    alpha = {}
    for name, params in (
        ("sign", smc.ControllerParams.for_vehicle(VEHICLE, switching="sign")),
        ("layers", smc.ControllerParams.for_vehicle(VEHICLE, switching="smooth", layer_errors=FLIGHT_LAYER_ERRORS)),
    ):
        alpha[name] = metrics_mod.compute(sim_mod.run(scenario, VEHICLE, params, config))["rms"]["alpha"]
    assert alpha["sign"] > 0.3, alpha  # measured 0.93 rad: swung up
    assert alpha["layers"] < 0.05, alpha  # measured 0.028 rad (Table 2: 0.11)
