"""A toy controller kept outside the product, the module of docs/architecture.md's walk-through "a new controller":
a PD on the vehicle's position (the load's position less the swing's offset) with a term that follows the load's
swing, to an attitude setpoint and thrust. ``tests/test_toy_controller.py`` registers it with one line
(``registry.register(NAME, make_toy)``) and flies it through every command.

Model frame (world NWU z up, body FLU), SI, rad. Its attitude setpoint and the torques that would fly it come from
the stock cascade's attitude and rate loops (``AttitudeThrustLoop``, reused, not copied): in ``slung sim`` /
``compare`` / ``sweep`` the setpoint flies through PX4's attitude loops as the attitude-level law does
(``compare.controller_as_flown``), over MAVLink through the autopilot's (``--output attitude``).
"""

from __future__ import annotations

import math

from estimators.model.control_state import ControlState
from estimators.model.vehicle import Vehicle
from offboard.control.controllers.cascade import AttitudeThrustLoop, CascadeGains, vehicle_position
from offboard.control.smc import Ref
from offboard.control.smc_attitude import AttitudeCommand

#: the registry name the tests give it
NAME = "toy-pd"
#: position P (1/s^2) and D (1/s) gains, horizontal and vertical, and the swing-following gain (1/s): a slow,
#: well-damped loop (natural frequency 1 rad/s horizontally, far below the load's swing)
KP_XY, KD_XY = 1.0, 1.8
KP_Z, KD_Z = 2.0, 2.8
K_SWING = 1.5


class ToyPd:
    """``toy-pd``: PD on the vehicle's position plus swing following, to an attitude setpoint and thrust."""

    name = NAME
    #: it commands an attitude and a thrust (``protocol.level_of``): its steps return an ``AttitudeCommand``
    level = "attitude"

    def __init__(self, vehicle: Vehicle) -> None:
        self.l = vehicle.cable_length
        self.hover = vehicle.hover_thrust
        self.inner = AttitudeThrustLoop(vehicle, CascadeGains())

    def reset(self) -> None:
        self.inner.reset()

    def step(self, t: float, est: ControlState, ref_fx: Ref, ref_fy: Ref, ref_z: Ref, ref_psi: Ref) -> AttitudeCommand:
        refs = (*ref_fx[:3], *ref_fy[:3], *ref_z[:3], *ref_psi[:2])
        if not est.is_finite() or not all(math.isfinite(r) for r in refs):  # never a non-finite setpoint
            psi = ref_psi[0] if math.isfinite(ref_psi[0]) else 0.0
            return AttitudeCommand(self.hover, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, False, False, 0.0, 0.0, psi, 0, 0, 0)
        x, y, vx, vy = vehicle_position(est, self.l)
        # the load is l * alpha ahead of the vehicle: moving with its swing rate damps the swing
        ax = ref_fx[2] + KP_XY * (ref_fx[0] - x) + KD_XY * (ref_fx[1] - vx) + K_SWING * self.l * est.alpha_y_rate
        ay = ref_fy[2] + KP_XY * (ref_fy[0] - y) + KD_XY * (ref_fy[1] - vy) + K_SWING * self.l * est.alpha_x_rate
        az = ref_z[2] + KP_Z * (ref_z[0] - est.z) + KD_Z * (ref_z[1] - est.z_rate)
        thrust, tau_phi, tau_theta, tau_psi, sat, tilted = self.inner(t, est, ax, ay, az, ref_psi)
        phi, theta, psi = self.inner.attitude_sp or (0.0, 0.0, ref_psi[0])
        return AttitudeCommand(
            thrust, tau_phi, tau_theta, tau_psi, 0.0, 0.0, 0.0, 0.0, sat or tilted, True, phi, theta, psi, 0.0, 0.0,
            ref_psi[1],
        )  # fmt: skip

    def memory_fields(self) -> tuple[float, float, float, float]:
        return math.nan, math.nan, math.nan, math.nan  # no integrators


def make_toy(vehicle: Vehicle, **_: object) -> ToyPd:
    """The registry's factory: a fresh ``toy-pd`` for the nominal ``vehicle`` (the sliding-mode laws' options that
    the registry passes every factory are not its own: ``**_``)."""
    return ToyPd(vehicle)
