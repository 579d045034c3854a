"""The roll and pitch torques of a quadrotor X share its motors' margin (issue 10, docs/estimation.md section 0.3).

PX4's allocator (sequential desaturation, MC_AIRMODE 0: the thrust only lowered, then roll, then pitch) resolves a
pair the motors cannot give by cutting the roll torque first. The torque-level law clipped each axis alone, so it
asked for such pairs whenever both torques saturated or the height loop's sign switching took the thrust below
the margin; at 30 % packet loss the cut roll torque swung the load up in world y, the roll axis, in about one
hover in five (the same runs with the emulator's order mirrored, pitch first, swung up in x instead). The law of
a flight (``offboard.flight.flight_law.torque_law_params``) now asks only for what the motors give."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimators.model.control_state import ControlState
from estimators.model.vehicle import Vehicle
from offboard.control import smc
from offboard.flight.flight_law import torque_law_params
from sim_bridge.inner.px4_inner import Px4ActuatorPath

VEHICLE = Vehicle()


def _states(n: int, seed: int) -> list[ControlState]:
    """Estimates far from a hover reference at the origin, 1 m up, heading 0: saturated horizontal torques and a
    height error that sends the sign-switching thrust below and above hover."""
    rng = np.random.default_rng(seed)
    scales = np.array([0.3, 0.5, 1.0, 3.0, 10.0, 30.0])
    out = []
    for _ in range(n):
        fx, fy = rng.normal(size=6) * scales, rng.normal(size=6) * scales
        phi, theta = rng.normal(size=2) * 0.05
        out.append(
            ControlState(
                tuple(fx),  # type: ignore[arg-type]
                tuple(fy),  # type: ignore[arg-type]
                1.0 + rng.normal() * 0.05,
                rng.normal() * 0.2,
                phi,
                theta,
                0.0,
                rng.normal() * 0.3,
                rng.normal() * 0.3,
                0.0,
                rng.normal() * 0.1,
                rng.normal() * 0.1,
                rng.normal() * 0.3,
                rng.normal() * 0.3,
            )
        )
    return out


def _hover_ref() -> tuple[tuple[float, ...], ...]:
    z7 = (0.0,) * 7
    return z7, z7, (1.0, 0.0, 0.0), (0.0, 0.0, 0.0)


def _cut(params: smc.ControllerParams, states: list[ControlState]) -> tuple[np.ndarray, np.ndarray]:
    """Per state: the law's command through the emulator's PX4 allocator and motors (the path of ``--output
    actuator``, PX4's own allocator behind ``--output attitude``): (roll, pitch) torque the allocator could not
    give (N m, FRD), and the command's ``|tau_phi| / tp_max + |tau_theta| / tt_max``."""
    path = Px4ActuatorPath(VEHICLE, 0.004)
    rfx, rfy, rz, rpsi = _hover_ref()
    tp, tt, _ = params.torque_max
    cut, share = [], []
    for est in states:
        cmd, _ = smc.step(0.0, est, rfx, rfy, rz, rpsi, smc.ControllerMemory(), params)
        path.allocate(cmd.thrust, cmd.tau_phi, cmd.tau_theta, 0.0)  # no yaw: the heading is held
        un = path.alloc.unallocated
        cut.append((un[0] * path.unit_torque[0], un[1] * path.unit_torque[1]))
        share.append(abs(cmd.tau_phi) / tp + abs(cmd.tau_theta) / tt)
    return np.abs(np.array(cut)), np.array(share)


def test_px4_allocation_cuts_the_roll_torque_first() -> None:
    """The emulator's allocator as PX4's: both torques at the hover-margin limit (a corner of the per-axis box)
    at hover thrust; the roll torque is cut, the pitch torque delivered whole."""
    path = Px4ActuatorPath(VEHICLE, 0.004)
    tau = VEHICLE.roll_pitch_torque_max
    path.allocate(VEHICLE.hover_thrust, tau, tau, 0.0)
    roll_cut, pitch_cut, _ = (abs(u) * t for u, t in zip(path.alloc.unallocated, path.unit_torque, strict=True))
    assert roll_cut > 0.2 * tau and pitch_cut < 1e-9


def test_the_flight_law_asks_only_for_what_the_x_motors_give() -> None:
    states = _states(400, seed=10)
    paper = smc.ControllerParams.for_vehicle(VEHICLE)  # each axis clipped alone (the paper's ideal actuators)
    cut, _ = _cut(paper, states)
    roll_cut, pitch_cut = cut.mean(axis=0)  # N m, mean over the states
    assert roll_cut > 0.5 and roll_cut > 3.0 * pitch_cut  # the asymmetry: PX4 cuts roll first (0.70 / 0.20 N m)
    flight = torque_law_params(VEHICLE, "sign", 1.0)
    assert flight.shared_roll_pitch
    cut, share = _cut(flight, states)
    assert np.mean(share > 0.999) > 0.5  # the pairs were at the margin, not inside it
    assert cut.max() < 1e-6  # and the motors gave every one of them


def test_the_pair_keeps_its_direction_and_the_thrust_yields_the_margin() -> None:
    params = torque_law_params(VEHICLE, "sign", 1.0)
    rfx, rfy, rz, rpsi = _hover_ref()
    tp_max = params.torque_max[0]
    for est in _states(200, seed=11):
        cmd, _ = smc.step(0.0, est, rfx, rfy, rz, rpsi, smc.ControllerMemory(), params)
        box, _ = smc.step(
            0.0, est, rfx, rfy, rz, rpsi, smc.ControllerMemory(), smc.ControllerParams.for_vehicle(VEHICLE)
        )
        share = (abs(cmd.tau_phi) + abs(cmd.tau_theta)) / tp_max
        assert share <= 1.0 + 1e-12
        # the box's pair scaled as one: same signs, same ratio
        assert math.copysign(1.0, cmd.tau_phi) == math.copysign(1.0, box.tau_phi)
        assert cmd.tau_phi * box.tau_theta == pytest.approx(cmd.tau_theta * box.tau_phi, abs=1e-12)
        lo, hi = smc.shared_thrust_range(params, share)
        assert lo - 1e-9 <= cmd.thrust <= hi + 1e-9
        assert lo - 1e-9 <= VEHICLE.hover_thrust <= hi


@pytest.mark.parametrize("switching", ["sign", "layers"])
def test_compiled_law_limits_the_pair_as_the_scalar_one(switching: str) -> None:
    # "layers": the flight default, each loop's own boundary layer (docs/model.md C-12); on these states a compiled
    # law that used one epsilon instead differs from the scalar one in 19 of 50 (thrust by up to 0.17 N)
    from estimators.kernels import EST_SIZE
    from offboard.control.compiled import laws

    layered = switching == "layers"
    params = torque_law_params(VEHICLE, "smooth" if layered else "sign", 1.0, layered=layered)
    states = _states(50, seed=12)
    rfx, rfy, rz, rpsi = _hover_ref()
    code, c, K = laws.law_constants("smc", VEHICLE, params)
    pad = (0.0,) * 4  # the reference row carries orders 0..6 of z and psi too
    ref = np.array([*rfx, *rfy, *rz, *pad, *rpsi, *pad])
    u = np.zeros(4)
    for e in states:
        est = np.array([*e.fx, *e.fy, *e[2:]], dtype=float)
        assert est.shape == (EST_SIZE,)
        laws.law_step(code, c, K, laws.law_memory(code, c), 0.0, 0.0, est, ref, u)
        cmd, _ = smc.step(0.0, e, rfx, rfy, rz, rpsi, smc.ControllerMemory(), params)
        np.testing.assert_allclose(u, (cmd.thrust, cmd.tau_phi, cmd.tau_theta, cmd.tau_psi), rtol=1e-9, atol=1e-12)
