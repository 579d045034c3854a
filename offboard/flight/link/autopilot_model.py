"""What the flight side assumes of the autopilot's inner loops (flavour, attitude P gains, rate bandwidths, hover
throttle, ...): read from its parameters (:func:`autopilot_model_from_params`, over the link by
``offboard.flight.link.management``, in process from the emulator's parameter table by ``slung compare``) and used by
the command mappers (``offboard.flight.command_mapping``, ``offboard.flight.attitude_mapping``).

Here, below both, so that the link does not import the mapping above it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from estimators.model.vehicle import Vehicle
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


#: per flavour: the attitude P, rate P and rate I parameters (roll, pitch, yaw) and the hover throttle's
_PARAMS = {
    "px4": (
        ("MC_ROLL_P", "MC_PITCH_P", "MC_YAW_P"),
        ("MC_ROLLRATE_P", "MC_PITCHRATE_P", "MC_YAWRATE_P"),
        ("MC_ROLLRATE_I", "MC_PITCHRATE_I", "MC_YAWRATE_I"),
        "MPC_THR_HOVER",
    ),
    "ardupilot": (
        ("ATC_ANG_RLL_P", "ATC_ANG_PIT_P", "ATC_ANG_YAW_P"),
        ("ATC_RAT_RLL_P", "ATC_RAT_PIT_P", "ATC_RAT_YAW_P"),
        ("ATC_RAT_RLL_I", "ATC_RAT_PIT_I", "ATC_RAT_YAW_I"),
        "MOT_THST_HOVER",
    ),
}


def autopilot_model_from_params(
    flavour: str,
    get: Callable[[str], float | None],
    vehicle: Vehicle,
    unit_torque: tuple[float, float, float] | None = None,
    angle_boost_default: bool = True,
    warn: Callable[[str], None] | None = None,
) -> AutopilotModel:
    """The :class:`AutopilotModel` of an autopilot whose parameters ``get(name)`` reads (None: no answer); the
    defaults, each with a ``warn``, for those that do not answer.

    Rate-loop bandwidth per axis ``B = K_p tau_max / I`` (the rate P gain is in normalized torque per rad/s,
    normalized by ``unit_torque`` where PX4's allocator gives it, ``offboard.flight.px4_allocation``, else by the
    vehicle file's maximum torque per axis); rate I/P ratio per axis; hover throttle (:func:`choose_hover_throttle`);
    ArduPilot's ATC_ANGLE_BOOST."""
    say = warn if warn is not None else (lambda _msg: None)
    att, rate, rate_i, hover = _PARAMS[flavour]
    default = AutopilotModel(flavour=flavour)
    tmax = unit_torque or (vehicle.roll_pitch_torque_max, vehicle.roll_pitch_torque_max, vehicle.yaw_torque_max)
    kp = list(default.attitude_p)
    bw = list(default.rate_bandwidth)
    ki = list(default.rate_integral)
    for i in range(3):
        a, r, ri = get(att[i]), get(rate[i]), get(rate_i[i])
        if r is not None and ri is not None and r > 0 and math.isfinite(ri) and ri >= 0:
            ki[i] = ri / r
        if a is not None and math.isfinite(a) and a > 0:
            kp[i] = a
        else:
            say(f"{att[i]} not readable: assuming {kp[i]:g}")
        if r is not None and math.isfinite(r) and r > 0:
            bw[i] = r * tmax[i] / vehicle.inertia[i]
        else:
            say(f"{rate[i]} not readable: assuming a rate bandwidth of {bw[i]:g} 1/s")
    hover_norm, why = choose_hover_throttle(flavour, get(hover), vehicle)
    if why is not None:
        say(why)
    boost = angle_boost_default
    if flavour == "ardupilot":
        b = get("ATC_ANGLE_BOOST")
        boost = bool(b) if b is not None else angle_boost_default
    unit = None if unit_torque is None else (float(unit_torque[0]), float(unit_torque[1]), float(unit_torque[2]))
    return AutopilotModel(
        flavour,
        (kp[0], kp[1], kp[2]),
        (bw[0], bw[1], bw[2]),
        hover_norm,
        boost,
        (ki[0], ki[1], ki[2]),
        unit_torque=unit,
    )


def choose_hover_throttle(
    flavour: str, theirs: float | None, vehicle: Vehicle, learned: tuple[float, float] | None = None
) -> tuple[float | None, str | None]:
    """The hover throttle (0..1) to map thrust with, from the autopilot's parameter ``theirs`` (PX4 MPC_THR_HOVER,
    ArduPilot MOT_THST_HOVER; None when it did not answer), the vehicle file and the hover throttle ``learned`` in
    flight ((value, 1 sigma), trusted; ``offboard.flight.hover_thrust_learning``), and a warning when they disagree.

    A learned value flies: it is this vehicle with this load, measured. The warning then names which of the
    autopilot's parameter and the file's ``hover_throttle`` (both throttles, like the learned one) differ from it by
    more than 10 %; a file without one is not compared (its thrust fraction is not a throttle).

    Like is compared with like: the autopilot's hover *throttle* with the file's ``hover_throttle`` (a throttle, with
    this load). A file without one is not compared before the flight: its thrust fraction, total weight / max thrust,
    is the throttle only on a linear thrust curve (ArduPilot's MOT_THST_EXPO 0.65 makes the SITL quad's loaded 0.51 a
    thrust fraction of 0.348: the old warning compared 0.39 with 0.343 and fired on every flight); the value learned
    in flight is compared instead.

    Without a learned value, which one flies: the autopilot's, except on ArduPilot when the file gives a hover
    throttle more than 10 % away. ArduPilot learns MOT_THST_HOVER only while its own altitude controller flies
    (MOT_HOVER_LEARN), so on the ground, and after a take-off into attitude targets, it is the value of its last
    such flight, often without this load (the SITL quad's 0.39 bare against 0.51 loaded: the vehicle sagged 13 cm
    at the start, issue 38);
    PX4's MPC_THR_HOVER is what its own position controller flies with, so PX4's is kept."""
    mine = vehicle.hover_throttle
    name = "MPC_THR_HOVER" if flavour == "px4" else "MOT_THST_HOVER"
    if learned is not None and math.isfinite(learned[0]) and 0.0 < learned[0] < 1.0:
        h, sigma = learned
        off = [
            f"{what} {value:.3f} ({(value / h - 1.0) * 100.0:+.0f} %)"
            for what, value in ((name, theirs), ("the vehicle file's hover_throttle", mine))
            if value is not None and math.isfinite(value) and abs(value - h) > 0.1 * h
        ]
        if not off:
            return h, None
        return h, (
            f"hover throttle learned in flight {h:.3f} +- {sigma:.3f} differs by more than 10 % from "
            f"{' and '.join(off)}: flying with the learned one; check the vehicle file's load and hover_throttle"
        )
    if theirs is None or not (math.isfinite(theirs) and 0.0 < theirs < 1.0):
        return mine, None
    if mine is None:  # nothing to compare a throttle with before the flight: the learned value is compared in flight
        return theirs, None
    if abs(theirs - mine) <= 0.1 * mine:
        return theirs, None
    if flavour == "ardupilot":
        return mine, (
            f"{name} = {theirs:.3f} differs from the vehicle file's hover throttle {mine:.3f} by more than 10 %: "
            "flying with the file's (ArduPilot learns its own only under its altitude controller, perhaps without "
            "this load)"
        )
    return theirs, (
        f"{name} = {theirs:.3f} differs from the vehicle file's hover throttle {mine:.3f} by more than 10 %: flying "
        f"with the autopilot's; check the vehicle file"
    )


__all__ = ["AutopilotModel", "autopilot_model_from_params", "choose_hover_throttle"]
