"""The named options of the controller and the flight, each listed once: switching function, law, setpoint output,
autopilot flavour, end action. Their values are the strings the command line, the logs and ``metrics.json`` carry
(unchanged); the flight code keeps plain strings and checks them against these lists instead of tuples written
out by hand at every check and every ``choices=``.
"""

from __future__ import annotations

from enum import Enum


class Switching(str, Enum):
    """The sliding-mode laws' switching function: the paper's ``sign(.)`` or ``v / (|v| + eps)`` (eq. 92)."""

    SIGN = "sign"
    SMOOTH = "smooth"


class Law(str, Enum):
    """Which sliding-mode law flies: attitude level (``offboard.control.smc_attitude``) or torque level
    (``offboard.control.smc``)."""

    ATTITUDE = "attitude"
    TORQUE = "torque"


class Output(str, Enum):
    """What the flight sends: SET_ATTITUDE_TARGET, or (PX4) SET_ACTUATOR_CONTROL_TARGET."""

    ATTITUDE = "attitude"
    ACTUATOR = "actuator"


class Flavour(str, Enum):
    """The autopilot on the other end of the link."""

    PX4 = "px4"
    ARDUPILOT = "ardupilot"


class EndAction(str, Enum):
    """What the vehicle is told at the end of offboard control (or on a signal)."""

    HOLD = "hold"
    LAND = "land"


def values(option: type[Enum]) -> tuple[str, ...]:
    """The accepted strings of ``option``, in its order (for ``choices=`` and for checks)."""
    return tuple(m.value for m in option)


__all__ = ["EndAction", "Flavour", "Law", "Output", "Switching", "values"]
