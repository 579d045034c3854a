"""The take-off point as PX4 sets it: its home (HOME_POSITION), taken at arming.

Heights of a reference are above the take-off point. ``FlightLoop.fix_ground`` fixes it before the take-off from the
position samples on the ground, but PX4 sets its home at arming and EKF2's height moves at arming: in a second
flight after a landing slung hovered 0.26-0.34 m (truth) away from PX4's own hold at the same target (issue 38). So
on PX4, from the take-off on until the vehicle is in the air, a HOME_POSITION received while the heartbeat shows the
vehicle armed (PX4 sets home on the arming transition, before it reports it armed) gives the take-off point instead.
HOME_POSITION's x, y, z are the home in the local frame (NED, m), turned into the model frame in the one place
(``estimators.model.frames``). Only the first one received armed counts: PX4 SITL (SIH) went on moving its home by up
to 1.5 m every 2 s while slung hovered (its land detector, 7 Dec 2026, ``bench/px4_two_flights.py``), where the first
after arming was the ground EKF2 had at arming to 1 cm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from estimators.model.frames import ned_to_model_vector


@dataclass
class HomeAtArming:
    """Collects the home PX4 set at arming (module docstring). ``active``: between :meth:`start` (just before the
    take-off) and :meth:`stop` (the vehicle in the air, before control); ``z``: the first such home's local z,
    model frame (up), m, or None."""

    active: bool = False
    z: float | None = None

    def start(self) -> None:
        """From now on (the take-off), a home received armed is the take-off point."""
        self.active, self.z = True, None

    def stop(self) -> None:
        self.active = False

    def observe(self, msg: Any, armed: bool) -> float | None:
        """One HOME_POSITION; its local z (model frame, up, m) when it counts (active, armed, the first, finite),
        else None."""
        if not (self.active and armed) or self.z is not None:  # the first one only: PX4 SITL's home then wandered
            return None
        z = ned_to_model_vector(float(msg.x), float(msg.y), float(msg.z))[2]
        if not math.isfinite(z):
            return None
        self.z = z
        return z


__all__ = ["HomeAtArming"]
