"""The :class:`Controller` protocol: what every control law offers the one controller tick (``offboard.control.tick``).

A controller turns the estimate (``estimators.model.control_state.ControlState``, model frame: world NWU z up, body FLU,
SI, rad) and the reference (flat outputs ``F_x``, ``F_y`` and their derivatives of orders 0..6 in m ... m/s^6,
height z and heading psi with derivatives of orders 0..2) into a collective thrust (N) and body torques (N m),
saturated within the vehicle's limits and never NaN: an :class:`offboard.control.smc.Command`. Its memory (integrals,
filter states, a shaper's queue) lives inside the object; :meth:`Controller.reset` clears it before a flight.

A controller may say what level it commands at (its ``level`` attribute, :func:`level_of`; ``"torque"`` when it
has none): ``"torque"``, a :class:`~offboard.control.smc.Command` of thrust and body torques (the torque-level
``smc``, ``lqr``); ``"attitude"``, an :class:`~offboard.control.smc_attitude.AttitudeCommand`, the torques its model
expects the autopilot's loops to give plus the attitude setpoint (``smc-attitude``); ``"position"``, a ``Command``
from its own attitude and rate loops, whose attitude setpoint of the last step is its ``attitude_sp`` attribute
(roll, pitch, heading, rad; the stock cascade and the baselines built on it). Over MAVLink
(:func:`offboard.control.controllers.flight_output.as_flown`) a torque-level controller's torques are mapped to the
chosen setpoint, an attitude- or position-level one sends its attitude setpoint (``--output attitude`` only).

The sliding-mode law (``offboard.control.controllers.sliding_mode``) is the first implementation; the baselines of
``slung compare`` (``offboard.control.controllers.cascade``, ``.lqr``, ``.shaping``, ``.swing_feedback``) are the
others. A new one is a module and one line in ``offboard.control.controllers.registry`` (docs/architecture.md).
"""

from __future__ import annotations

from typing import Any, Protocol

from estimators.model.control_state import ControlState
from offboard.control.smc import Command, Ref


class Controller(Protocol):
    """A control law behind the one controller tick (see the module docstring for units and frames)."""

    #: short name, as in ``slung compare --controllers`` (``smc``, ``cascade``, ...)
    name: str

    def reset(self) -> None:
        """Forget all memory (integrals, filter states): the state before the first tick of a flight."""
        ...

    def step(self, t: float, est: ControlState, ref_fx: Ref, ref_fy: Ref, ref_z: Ref, ref_psi: Ref) -> Command:
        """One tick at time ``t`` (s, the reference's clock): the saturated, finite command."""
        ...

    def memory_fields(self) -> tuple[float, float, float, float]:
        """Four numbers of the controller's memory for the flight log (the sliding-mode law's error integrals
        int_z, int_psi, int_fx, int_fy; a baseline's own integrators, NaN where it has none)."""
        ...


#: the levels a controller commands at (see the module docstring)
LEVELS = ("torque", "attitude", "position")


def level_of(controller: Any) -> str:
    """The level ``controller`` commands at (its ``level`` attribute; ``"torque"`` without one); ValueError for a
    level not in :data:`LEVELS`."""
    level = getattr(controller, "level", "torque")
    if level not in LEVELS:
        raise ValueError(f"controller {getattr(controller, 'name', controller)!r}: unknown level {level!r}")
    return str(level)
