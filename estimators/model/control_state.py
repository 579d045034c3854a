"""The state estimate the controller consumes: one typed record, produced by the true-state path of the
simulation, by the Kalman filters, and by replay. Model frame: world NWU (z up), ZYX Euler angles, SI.
"""

from __future__ import annotations

import math
from typing import NamedTuple


class ControlState(NamedTuple):
    """What the sliding-mode controller needs at one tick (model frame, SI units, radians).

    fx, fy: flat outputs of the two horizontal axes in the world frame and their derivatives, orders 0..5
        (m, m/s, m/s^2, m/s^3, m/s^4, m/s^5); ``estimators.model.flatness`` defines the chain.
    z, z_rate: vehicle height (m, up) and vertical velocity (m/s).
    phi, theta, psi: roll, pitch, yaw (rad); phi_rate, theta_rate, psi_rate: their time derivatives (rad/s).
    alpha_x, alpha_y: planar swing angles (rad, errata C5); alpha_x_rate, alpha_y_rate (rad/s).
    """

    fx: tuple[float, float, float, float, float, float]
    fy: tuple[float, float, float, float, float, float]
    z: float
    z_rate: float
    phi: float
    theta: float
    psi: float
    phi_rate: float
    theta_rate: float
    psi_rate: float
    alpha_x: float
    alpha_y: float
    alpha_x_rate: float
    alpha_y_rate: float

    def is_finite(self) -> bool:
        """True when every field is a finite number (the controller refuses anything else).

        One sum is checked instead of every field: a NaN or infinity anywhere makes the sum non-finite
        (a sum that overflows from huge finite values is refused too, which is the safe side).
        """
        return math.isfinite(sum(self.fx) + sum(self.fy) + sum(self[2:]))


#: names of the rigid body's 12 states, in the order the plant state (``sim_bridge.plant.dynamics``), the 16-state
#: linear model (``offboard.control.linear_model``) and the simulation log start with: position (m), velocity (m/s), ZYX
#: Euler angles (rad), their rates (rad/s); world NWU
RIGID_BODY_NAMES: tuple[str, ...] = (
    "x",
    "y",
    "z",
    "vx",
    "vy",
    "vz",
    "phi",
    "theta",
    "psi",
    "phi_rate",
    "theta_rate",
    "psi_rate",
)
#: the reduced 16-state (minimal coordinates: the cable as its planar swing angles, errata C5, rad and rad/s)
REDUCED_STATE_NAMES: tuple[str, ...] = (*RIGID_BODY_NAMES, "alpha_y", "alpha_x", "alpha_y_rate", "alpha_x_rate")
#: the plant's input: collective thrust (N) and body torques (N m, FLU)
INPUT_NAMES: tuple[str, ...] = ("thrust", "tau_phi", "tau_theta", "tau_psi")
