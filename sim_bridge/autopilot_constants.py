"""Constants and small helpers shared by the parts of the emulated autopilot (``sim_bridge.autopilot*``)."""

from __future__ import annotations

import math

# MAV_RESULT
ACCEPTED, TEMPORARILY_REJECTED, DENIED, UNSUPPORTED, FAILED = 0, 1, 2, 3, 4
# MAV_SEVERITY
EMERGENCY, ALERT, CRITICAL, ERROR, WARNING, NOTICE, INFO = 0, 1, 2, 3, 4, 5, 6

PX4_FORCE = 21196  # MAVLink spec force value (arm/disarm); ArduPilot uses it for force-disarm
AP_FORCE_ARM = 2989  # ArduPilot's force-arm magic

SETPOINT_MSGS = frozenset({"SET_ATTITUDE_TARGET", "SET_POSITION_TARGET_LOCAL_NED", "SET_ACTUATOR_CONTROL_TARGET"})
SETPOINT_IDS = frozenset({82, 84, 139})

#: PX4 COM_OBL_RC_ACT -> mode name (6 Terminate and 7 Disarm are handled separately)
PX4_OBL_ACTIONS = {0: "POSCTL", 1: "ALTCTL", 2: "STABILIZED", 3: "AUTO.RTL", 4: "AUTO.LAND", 5: "AUTO.LOITER"}

#: the emulated rotors' thrust curve (thrust fraction (1 - e) u + e u^2 of the actuator u): ArduPilot's default
#: MOT_THST_EXPO, so the default linearization is exact and a changed parameter mis-linearizes as on a real vehicle
AP_PHYSICAL_THRUST_EXPO = 0.65

LOAD_COMPID = 35  # MAV_COMP_ID_USER11, as ArduPilot's slung-payload SITL


def all_finite(*vals: float) -> bool:
    """True if every value is finite."""
    return all(math.isfinite(v) for v in vals)


def ap_stream_groups() -> dict[str, list[str]]:
    """ArduPilot's SR0_* parameter -> the streams of its group (``sim_bridge.modes.flavors.AP_GROUPS``)."""
    from sim_bridge.modes.flavors import AP_GROUPS

    return AP_GROUPS
