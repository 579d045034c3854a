"""The :class:`Controller` protocol: what every control law offers the one controller tick (``offboard.control.tick``).

A controller turns the estimate (``estimators.model.control_state.ControlState``, model frame: world NWU z up, body FLU,
SI, rad) and the reference (flat outputs ``F_x``, ``F_y`` and their derivatives of orders 0..6 in m ... m/s^6,
height z and heading psi with derivatives of orders 0..2) into a collective thrust (N) and body torques (N m),
saturated within the vehicle's limits and never NaN: an :class:`offboard.control.smc.Command`. Its memory (integrals,
filter states, a shaper's queue) lives inside the object; :meth:`Controller.reset` clears it before a flight.

The sliding-mode law (``offboard.control.controllers.sliding_mode``) is the first implementation; the baselines of
``slung compare`` (``offboard.control.controllers.cascade``, ``.lqr``, ``.shaping``, ``.swing_feedback``) are the
others.
"""

from __future__ import annotations

from typing import Protocol

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
