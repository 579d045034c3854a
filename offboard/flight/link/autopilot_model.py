"""What the flight side assumes of the autopilot's inner loops (flavour, attitude P gains, rate bandwidths, hover
throttle, ...): read from its parameters by ``offboard.flight.link.management`` and used by the command mappers
(``offboard.flight.command_mapping``, ``offboard.flight.attitude_mapping``).

Here, below both, so that the link does not import the mapping above it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from offboard.control.options import Flavour, values


@dataclass(frozen=True)
class AutopilotModel:
    """What the mapping assumes of the autopilot (see module docstring).

    flavour: ``"px4"`` or ``"ardupilot"``; attitude_p: attitude P gains (rad/s per rad, roll, pitch, yaw);
    rate_bandwidth: closed-loop rate bandwidth per axis (1/s); hover_thrust_norm: the autopilot's hover throttle
    (0..1) or None for the vehicle file's; angle_boost: ArduPilot ATC_ANGLE_BOOST enabled; rate_integral: the rate
    loop's integral-to-proportional gain ratio per axis (1/s; PX4 MC_ROLLRATE_I / MC_ROLLRATE_P, defaults
    0.2 / 0.15, 0.2 / 0.15, 0.1 / 0.2); integral_limit: the rate integrator's limit as a fraction of the axis'
    maximum torque (PX4 MC_RR_INT_LIM 0.3); unit_torque: the physical torque (N m, roll, pitch, yaw) of a unit
    normalized torque through the autopilot's allocator (PX4: from CA_ROTOR*, ``offboard.flight.px4_allocation``), or
    None for the vehicle file's X-mixer maxima (``Vehicle.roll_pitch_torque_max``, ``Vehicle.yaw_torque_max``).
    """

    flavour: str = "px4"
    attitude_p: tuple[float, float, float] = (6.5, 6.5, 2.8)
    rate_bandwidth: tuple[float, float, float] = (18.0, 18.0, 5.0)
    hover_thrust_norm: float | None = None
    angle_boost: bool = True
    rate_integral: tuple[float, float, float] = (1.33, 1.33, 0.5)
    integral_limit: float = 0.3
    unit_torque: tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        if self.flavour not in values(Flavour):
            raise ValueError(f"flavour must be 'px4' or 'ardupilot', got {self.flavour!r}")
        if not all(math.isfinite(v) and v > 0 for v in (*self.attitude_p, *self.rate_bandwidth)):
            raise ValueError("attitude_p and rate_bandwidth must be finite and > 0")
        h = self.hover_thrust_norm
        if h is not None and not (math.isfinite(h) and 0.0 < h < 1.0):
            raise ValueError(f"hover_thrust_norm must be in (0, 1), got {h!r}")


__all__ = ["AutopilotModel"]
