"""PX4's hover thrust estimator as the emulator's PX4 flavour runs it: the filter itself is
``estimators.identification.hover_thrust`` (shared with ``slung fly``, which learns the hover throttle in flight);
here are what PX4's module and position controller add around it.

Real PX4 does not fly its position-controlled modes on MPC_THR_HOVER alone: the filter learns the normalized thrust
that holds a hover from the measured vertical acceleration and the position controller's vertical thrust, and once
that estimate is trusted the position controller flies with it (MPC_USE_HTE, on by default), moving its velocity
integrator so that the thrust does not jump. A vehicle whose MPC_THR_HOVER is wrong (a payload added, a vehicle
file written for another autopilot) therefore overshoots its first climb and then holds height as if the parameter
were right. Without this model the emulator kept the wrong belief for the whole flight. It runs while armed, in the
air (above 1 m once since the last landing) and under PX4's position controller; disarming resets it to
MPC_THR_HOVER.
"""

from __future__ import annotations

from estimators.identification.hover_thrust import HTE_DEFAULTS, HoverThrustEstimator

#: height (m) above which the vehicle counts as in the air (PX4: distance to the ground above 1 m)
IN_AIR_HEIGHT_M = 1.0


def integrator_after_hover_change(int_z: float, acc_up: float, gravity: float, old: float, new: float) -> float:
    """PX4's position controller on a new hover thrust: the vertical velocity integrator moved so that the thrust
    ``(g + a) h / g`` does not jump, ``a`` the current vertical acceleration setpoint (m/s^2, up) of which the
    integrator is a part."""
    a_new = (gravity + acc_up) * old / new - gravity
    return int_z + a_new - acc_up


__all__ = ["HTE_DEFAULTS", "IN_AIR_HEIGHT_M", "HoverThrustEstimator", "integrator_after_hover_change"]
