"""Setpoint messages sent to the autopilot: encoding and checking (no NaN or infinity ever leaves here).

Two outputs (``--output``):

``attitude`` -> SET_ATTITUDE_TARGET (#82)
    ``q``: attitude setpoint, rotation LOCAL_NED -> BODY_FRD (w, x, y, z), unit norm;
    ``body_roll_rate``, ``body_pitch_rate``, ``body_yaw_rate``: body rates, rad/s, FRD;
    ``thrust``: collective thrust normalized to 0..1 (PX4: ``thrust_body[2] = -thrust``; ArduPilot with
    GUID_OPTIONS bit 3: throttle, see ``offboard.flight.command_mapping``).
    ``type_mask`` (common.xml ATTITUDE_TARGET_TYPEMASK): bit 1 / 2 / 4 ignore roll / pitch / yaw rate,
    64 ignore thrust (never set here: PX4 and ArduPilot both need thrust), 128 ignore attitude. The masks
    used here are

    - :data:`MASK_ATTITUDE` = 7: attitude + thrust, rates ignored (what MAVSDK sends; PX4 and ArduPilot);
    - :data:`MASK_ATTITUDE_RATES` = 0: attitude + thrust with all three body rates as feed-forward
      (ArduPilot: ``input_quaternion(q, rates)``; PX4: attitude has priority, only the yaw rate is used);
    - :data:`MASK_RATES` = 128: body rates + thrust, attitude ignored.

``actuator`` -> SET_ACTUATOR_CONTROL_TARGET (#139), group 0 (PX4 up to v1.13, the bundled emulator)
    ``controls[0..2]``: roll, pitch, yaw torque normalized to -1..1 (FRD axes, fraction of the vehicle's
    maximum torque per axis); ``controls[3]``: thrust 0..1; ``controls[4..7]``: 0.

Times: SET_ATTITUDE_TARGET carries ``time_boot_ms`` and SET_ACTUATOR_CONTROL_TARGET ``time_usec``, both the
*sender's* time since it started (PX4 and ArduPilot ignore them); we send the controller's time base.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

MASK_ATTITUDE = 7
MASK_ATTITUDE_RATES = 0
MASK_RATES = 128
THROTTLE_IGNORE = 64
ATTITUDE_IGNORE = 128

MASKS: dict[str, int] = {"attitude": MASK_ATTITUDE, "attitude+rates": MASK_ATTITUDE_RATES, "rates": MASK_RATES}


class AttitudeTarget(NamedTuple):
    """What SET_ATTITUDE_TARGET carries, already in MAVLink's frames.

    q: (w, x, y, z) rotation LOCAL_NED -> BODY_FRD; roll_rate, pitch_rate, yaw_rate: rad/s, body FRD;
    thrust: 0..1; type_mask: see module docstring.
    """

    q: tuple[float, float, float, float]
    roll_rate: float
    pitch_rate: float
    yaw_rate: float
    thrust: float
    type_mask: int


class ActuatorTarget(NamedTuple):
    """What SET_ACTUATOR_CONTROL_TARGET group 0 carries: roll, pitch, yaw (-1..1, FRD) and thrust (0..1)."""

    roll: float
    pitch: float
    yaw: float
    thrust: float


Setpoint = AttitudeTarget | ActuatorTarget

#: SET_POSITION_TARGET_LOCAL_NED type_mask: position + yaw (velocity, acceleration and yaw rate ignored)
MASK_POSITION_YAW = 8 | 16 | 32 | 64 | 128 | 256 | 2048
MAV_FRAME_LOCAL_NED = 1


def encode_position(
    mav: Any,
    north: float,
    east: float,
    down: float,
    yaw: float,
    time_s: float,
    target_system: int,
    target_component: int,
) -> Any:
    """SET_POSITION_TARGET_LOCAL_NED (#84) holding a position (m, NED) and yaw (rad, NED), used only to bring
    the vehicle to the start of the reference; SetpointError for non-finite values."""
    if not all(math.isfinite(v) for v in (north, east, down, yaw)):
        raise SetpointError("non-finite position setpoint")
    return mav.set_position_target_local_ned_encode(
        int(max(time_s, 0.0) * 1000.0) & 0xFFFFFFFF,
        target_system,
        target_component,
        MAV_FRAME_LOCAL_NED,
        MASK_POSITION_YAW,
        north,
        east,
        down,
        0.0,
        0.0,
        0.0,
        0.0,
        0.0,
        0.0,
        yaw,
        0.0,
    )


class SetpointError(ValueError):
    """A setpoint with NaN / infinity or out-of-range values was about to be encoded."""


def check_attitude(sp: AttitudeTarget) -> None:
    """Raise :class:`SetpointError` unless every field is finite, q is unit (1e-3) and thrust in 0..1."""
    vals = (*sp.q, sp.roll_rate, sp.pitch_rate, sp.yaw_rate, sp.thrust)
    for v in vals:
        if not math.isfinite(v):
            raise SetpointError(f"non-finite value in attitude setpoint {sp!r}")
    n = math.sqrt(sp.q[0] ** 2 + sp.q[1] ** 2 + sp.q[2] ** 2 + sp.q[3] ** 2)
    if abs(n - 1.0) > 1e-3:
        raise SetpointError(f"attitude quaternion norm {n!r} is not 1")
    if not 0.0 <= sp.thrust <= 1.0:
        raise SetpointError(f"thrust {sp.thrust!r} outside 0..1")


def check_actuator(sp: ActuatorTarget) -> None:
    """Raise :class:`SetpointError` unless every field is finite, torques in -1..1 and thrust in 0..1."""
    for v in sp:
        if not math.isfinite(v):
            raise SetpointError(f"non-finite value in actuator setpoint {sp!r}")
    if not all(-1.0 <= v <= 1.0 for v in sp[:3]) or not 0.0 <= sp.thrust <= 1.0:
        raise SetpointError(f"actuator setpoint out of range {sp!r}")


def encode(mav: Any, sp: Setpoint, time_s: float, target_system: int, target_component: int) -> Any:
    """The pymavlink message for ``sp`` (not yet packed), after :func:`check_attitude` / :func:`check_actuator`.

    mav: a ``pymavlink`` ``MAVLink`` instance (``connection.mav``); time_s: sender time (s, >= 0).
    Raises :class:`SetpointError` for anything that must not reach the wire.
    """
    if not (math.isfinite(time_s) and time_s >= 0.0):
        time_s = 0.0
    if isinstance(sp, AttitudeTarget):
        check_attitude(sp)
        return mav.set_attitude_target_encode(
            int(time_s * 1000.0) & 0xFFFFFFFF,
            target_system,
            target_component,
            sp.type_mask,
            [float(v) for v in sp.q],
            sp.roll_rate,
            sp.pitch_rate,
            sp.yaw_rate,
            sp.thrust,
        )
    check_actuator(sp)
    return mav.set_actuator_control_target_encode(
        int(time_s * 1e6),
        0,
        target_system,
        target_component,
        [sp.roll, sp.pitch, sp.yaw, sp.thrust, 0.0, 0.0, 0.0, 0.0],
    )


def decode(msg: Any) -> Setpoint | None:
    """The setpoint carried by a received SET_ATTITUDE_TARGET / SET_ACTUATOR_CONTROL_TARGET (tests, replay)."""
    kind = msg.get_type()
    if kind == "SET_ATTITUDE_TARGET":
        q = msg.q
        return AttitudeTarget(
            (float(q[0]), float(q[1]), float(q[2]), float(q[3])),
            float(msg.body_roll_rate),
            float(msg.body_pitch_rate),
            float(msg.body_yaw_rate),
            float(msg.thrust),
            int(msg.type_mask),
        )
    if kind == "SET_ACTUATOR_CONTROL_TARGET" and msg.group_mlx == 0:
        c = msg.controls
        return ActuatorTarget(float(c[0]), float(c[1]), float(c[2]), float(c[3]))
    return None


__all__ = [
    "ATTITUDE_IGNORE",
    "MASKS",
    "MASK_ATTITUDE",
    "MASK_ATTITUDE_RATES",
    "MASK_POSITION_YAW",
    "MASK_RATES",
    "THROTTLE_IGNORE",
    "ActuatorTarget",
    "AttitudeTarget",
    "Setpoint",
    "SetpointError",
    "check_actuator",
    "check_attitude",
    "decode",
    "encode",
    "encode_position",
]
