"""Flight modes, armed and landed state as the autopilots report them (HEARTBEAT, EXTENDED_SYS_STATE), per vehicle.

ArduPilot numbers its modes per vehicle (Copter's 4 is GUIDED, Plane's 4 is ACRO and its 20 is QLAND); the tables
are pymavlink's (``mavutil.mode_mapping_bynumber``, keyed by MAV_TYPE: Copter for multirotors and helicopters,
Plane for fixed wing and VTOL types (QuadPlane), Rover for rovers and boats, Sub for submarines). PX4 packs its
mode into ``custom_mode`` as main mode (bits 16-23) and sub mode (bits 24-31), named by
``mavutil.interpret_px4_mode``. The mode in which a companion computer flies the vehicle is OFFBOARD on PX4 and
GUIDED (Copter also GUIDED_NOGPS) on ArduPilot.

Armed: HEARTBEAT ``base_mode`` bit MAV_MODE_FLAG_SAFETY_ARMED (128). Landed: EXTENDED_SYS_STATE ``landed_state``
(MAV_LANDED_STATE: 0 undefined, 1 on ground, 2 in air, 3 taking off, 4 landing).
"""

from __future__ import annotations

from pymavlink import mavutil

MAV_AUTOPILOT_ARDUPILOT = 3
MAV_AUTOPILOT_PX4 = 12
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MAV_MODE_FLAG_SAFETY_ARMED = 128
PX4_MAIN_MODE_OFFBOARD = 6
#: the ArduPilot modes (by name, any vehicle) in which a companion computer's setpoints are flown
ARDUPILOT_OFFBOARD_MODES = frozenset({"GUIDED", "GUIDED_NOGPS"})
#: EXTENDED_SYS_STATE landed states that mean off the ground (in air, landing); taking off (3) still touches it
LANDED_STATE_AIRBORNE = frozenset({2, 4})
LANDED_STATE_NAMES = {0: "undefined", 1: "on ground", 2: "in air", 3: "taking off", 4: "landing"}


def ardupilot_family(mav_type: int) -> str:
    """Which ArduPilot firmware reports this MAV_TYPE: ``copter``, ``plane``, ``rover``, ``sub``, ``tracker`` or
    ``unknown``."""
    table = mavutil.mode_mapping_bynumber(mav_type)
    if table is None:
        return "unknown"
    for family, ref in (
        ("copter", mavutil.mode_mapping_acm),
        ("plane", mavutil.mode_mapping_apm),
        ("rover", mavutil.mode_mapping_rover),
        ("sub", mavutil.mode_mapping_sub),
        ("tracker", mavutil.mode_mapping_tracker),
    ):
        if table is ref:
            return family
    return "unknown"


def mode_name(autopilot: int, mav_type: int, base_mode: int, custom_mode: int) -> str:
    """The readable flight mode of a HEARTBEAT (``"GUIDED"``, ``"QLAND"``, ``"OFFBOARD"``, ``"AUTO.LOITER"`` style
    names from pymavlink), or ``"mode N"`` when the tables do not know it."""
    if not base_mode & MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
        return f"base mode {base_mode}"
    if autopilot == MAV_AUTOPILOT_PX4:
        return str(mavutil.interpret_px4_mode(base_mode, custom_mode))
    if autopilot == MAV_AUTOPILOT_ARDUPILOT:
        table = mavutil.mode_mapping_bynumber(mav_type) or {}
        return str(table.get(custom_mode, f"mode {custom_mode}"))
    return f"mode {custom_mode}"


def is_offboard_mode(autopilot: int, custom_mode: int, base_mode: int, mav_type: int = 2) -> bool:
    """Whether a HEARTBEAT reports the mode in which a companion computer flies: PX4 OFFBOARD (custom main mode 6),
    ArduPilot GUIDED (and Copter's GUIDED_NOGPS) in the vehicle's own numbering; needs
    MAV_MODE_FLAG_CUSTOM_MODE_ENABLED. ``mav_type`` selects ArduPilot's table (default: a quadrotor)."""
    if not base_mode & MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
        return False
    if autopilot == MAV_AUTOPILOT_PX4:
        return (custom_mode >> 16) & 0xFF == PX4_MAIN_MODE_OFFBOARD
    if autopilot == MAV_AUTOPILOT_ARDUPILOT:
        return mode_name(autopilot, mav_type, base_mode, custom_mode) in ARDUPILOT_OFFBOARD_MODES
    return False


def is_armed(base_mode: int) -> bool:
    """HEARTBEAT ``base_mode`` armed flag."""
    return bool(base_mode & MAV_MODE_FLAG_SAFETY_ARMED)


__all__ = [
    "ARDUPILOT_OFFBOARD_MODES",
    "LANDED_STATE_AIRBORNE",
    "LANDED_STATE_NAMES",
    "ardupilot_family",
    "is_armed",
    "is_offboard_mode",
    "mode_name",
]
