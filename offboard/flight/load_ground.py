"""The load on the ground during offboard control: touch-down and lift-off as events.

A reference whose heights put the load below the take-off point is refused before the flight
(``offboard.control.feasibility``, ``load_height``); in flight the load may still touch down (a height error, a long
line's bounce, a landing) or lie on the ground and lift off. Nothing measures the load's height: it is the estimate's,
the vehicle's height above the take-off point less the line's vertical extent, ``z - z_ground - l cos|a|`` (m,
model frame, up). A touch-down is reported when it falls below 0, a lift-off when it rises above ``hysteresis_m``
again, so that a load skimming the ground is not reported at every tick.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from estimators.model.control_state import ControlState


@dataclass
class LoadGroundWatch:
    """Touch-down / lift-off of the load from the estimate (module docstring). cable_length: m; ground_z: the take-off
    point's local z (m, model frame, up); hysteresis_m: how far above the ground the load must rise again before a
    lift-off is reported (m)."""

    cable_length: float
    ground_z: float
    hysteresis_m: float = 0.1
    on_ground: bool = False
    touchdowns: int = 0

    def height(self, est: ControlState) -> float:
        """The load's estimated height above the take-off point, m."""
        swing = math.hypot(est.alpha_x, est.alpha_y)
        return est.z - self.ground_z - self.cable_length * math.cos(swing)

    def update(self, est: ControlState) -> tuple[str, str] | None:
        """``(kind, reason)`` of an event when the load touches down (``load_touchdown``) or lifts off
        (``load_liftoff``) at this estimate, else None. A non-finite estimate says nothing."""
        h = self.height(est)
        if not math.isfinite(h):
            return None
        if not self.on_ground and h < 0.0:
            self.on_ground = True
            self.touchdowns += 1
            return (
                "load_touchdown",
                f"the load's estimated height above the take-off point is {h:.2f} m: the load is on the ground with a "
                f"{self.cable_length:g} m line (the line slack, the swing estimate not valid); fly higher",
            )
        if self.on_ground and h > self.hysteresis_m:
            self.on_ground = False
            return "load_liftoff", f"the load lifted off: estimated {h:.2f} m above the take-off point"
        return None


__all__ = ["LoadGroundWatch"]
