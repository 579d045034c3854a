"""What a tlog holds: pass 1 of ``slung replay`` (see ``offboard.replay``).

:func:`scan` reads ``(logger_time_s, message)`` pairs (``offboard.tlog``) once: every packet is counted per system and
message type; HEARTBEATs give the autopilot's system id, flavour (PX4 / ArduPilot / other), vehicle type and flight
mode; telemetry of every system is decoded into the estimator's measurement records by the live link's own decoder
(``offboard.link.telemetry.TelemetryDecoder``: model frame, times from the vehicle's ``time_boot_ms`` /
``time_usec``, never the logger's clock); setpoints sent to the autopilot (SET_ATTITUDE_TARGET,
SET_ACTUATOR_CONTROL_TARGET), the autopilot's ATTITUDE_TARGET, SYSTEM_TIME and EXTENDED_SYS_STATE are kept in
log order beside them as :class:`Event` records. :func:`inventory` turns that into the ``log`` block of
metrics.json, with one sentence per thing that is missing; :func:`replayable` says whether the estimator can run.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as dialect

from estimators.measurements import Attitude
from offboard.link.setpoints import decode as decode_setpoint
from offboard.link.telemetry import LOAD_ANGLE_NAME, TelemetryDecoder

# ---------------------------------------------------------------------------------------------------------------
# MAVLink enums used by the inventory (common.xml)

MAV_AUTOPILOT_NAMES = {0: "generic", 3: "ardupilot", 8: "invalid", 12: "px4"}
MAV_TYPE_NAMES = {
    0: "generic", 1: "fixed wing", 2: "quadrotor", 3: "coaxial", 4: "helicopter", 6: "ground control station",
    10: "ground rover", 11: "surface boat", 12: "submarine", 13: "hexarotor", 14: "octorotor", 15: "tricopter",
    18: "onboard controller", 19: "VTOL tailsitter duo", 20: "VTOL tailsitter quad", 21: "VTOL tiltrotor",
    22: "VTOL fixed rotor", 23: "VTOL tailsitter", 26: "gimbal", 27: "ADS-B", 29: "dodecarotor",
}
MULTIROTOR_TYPES = frozenset({2, 3, 4, 13, 14, 15, 29})
FIXED_WING_TYPES = frozenset({1, 16, 19, 20, 21, 22, 23, 24, 25})
#: types that are never the vehicle itself (ground stations, companions, gimbals, cameras, ...)
NON_VEHICLE_TYPES = frozenset({6, 18, 26, 27, 30, 31})
PX4_MAIN_MODE_OFFBOARD = 6
ARDUPILOT_COPTER_GUIDED = (4, 20)  # GUIDED, GUIDED_NOGPS
SETPOINT_TYPES = ("SET_ATTITUDE_TARGET", "SET_ACTUATOR_CONTROL_TARGET")
#: a vehicle clock (ATTITUDE time_boot_ms) going back by more than this (s) is a reboot
REBOOT_JUMP_S = 1.0
TELEMETRY_TYPES = frozenset({"ATTITUDE", "ATTITUDE_QUATERNION", "LOCAL_POSITION_NED", "ODOMETRY", "HIGHRES_IMU",
                             "SCALED_IMU", "DEBUG_VECT"})


def type_name(mav_type: int) -> str:
    """Readable MAV_TYPE name (``"quadrotor"``, ``"fixed wing"``, else pymavlink's enum name)."""
    if mav_type in MAV_TYPE_NAMES:
        return MAV_TYPE_NAMES[mav_type]
    entry = dialect.enums.get("MAV_TYPE", {}).get(mav_type)
    return entry.name.removeprefix("MAV_TYPE_").lower().replace("_", " ") if entry is not None else f"type {mav_type}"


def vehicle_time_of(msg: Any) -> float | None:
    """The vehicle's own time of a message (s since its boot) from ``time_usec`` or ``time_boot_ms``, else None."""
    d = msg.__dict__
    if "time_usec" in d:
        return d["time_usec"] * 1e-6
    if "time_boot_ms" in d:
        return d["time_boot_ms"] * 1e-3
    return None


def is_offboard_mode(autopilot: int, custom_mode: int, base_mode: int) -> bool:
    """Whether a HEARTBEAT reports the mode in which a companion computer flies: PX4 OFFBOARD (custom main mode 6),
    ArduPilot GUIDED / GUIDED_NOGPS (custom modes 4, 20); needs MAV_MODE_FLAG_CUSTOM_MODE_ENABLED (1)."""
    if not base_mode & 1:
        return False
    if autopilot == 12:
        return (custom_mode >> 16) & 0xFF == PX4_MAIN_MODE_OFFBOARD
    if autopilot == 3:
        return custom_mode in ARDUPILOT_COPTER_GUIDED
    return False


# ---------------------------------------------------------------------------------------------------------------
# pass 1: read and inventory


@dataclass
class SystemInfo:
    """One MAVLink source (system id, component id) seen in the log. Rates (metrics.json ``rates_hz``) are per
    message type: (count - 1) / the span of its own time field (sender time; messages without one have none)."""

    sysid: int
    compid: int
    messages: dict[str, int] = field(default_factory=dict)
    heartbeat: tuple[int, int] | None = None  # (MAV_TYPE, MAV_AUTOPILOT) of its last HEARTBEAT
    vt_first: float = math.inf  # vehicle time span of its timed messages, s
    vt_last: float = -math.inf
    lt_first: float = math.inf  # logger time span, s since the epoch
    lt_last: float = -math.inf
    spans: dict[str, list[float]] = field(default_factory=dict)  # message type -> [first, last] own time, s

    @property
    def count(self) -> int:
        return sum(self.messages.values())


@dataclass(slots=True)
class Event:
    """One entry of the replay stream, in log order. kind: "m" (measurement), "sp" (setpoint sent to the
    autopilot), "at" (the autopilot's ATTITUDE_TARGET), "mode" (offboard flag changed), "clock" (SYSTEM_TIME:
    the vehicle's ``time_boot_ms``, the lockstep emulator's tick marker).

    sysid: sender; vt: vehicle/sender time field (s) or None; lt: logger time (s); payload: the record."""

    kind: str
    sysid: int
    vt: float | None
    lt: float
    payload: Any


@dataclass
class Scan:
    """Result of pass 1: systems, events, reader counters, autopilot identity and mode history."""

    systems: dict[tuple[int, int], SystemInfo]
    events: list[Event]
    reader_stats: dict[str, Any]
    autopilot_sysid: int | None
    autopilot: int | None
    mav_type: int | None
    offboard_heartbeats: int
    heartbeats: int
    mode_changes: list[tuple[float, bool]]  # (logger time, offboard?) whenever the autopilot's mode flag changes
    setpoint_targets: dict[str, int]


def scan(messages: Iterable[tuple[float, Any]]) -> Scan:
    """Pass 1 over ``(logger_time_s, message)`` pairs (see module docstring)."""
    systems: dict[tuple[int, int], SystemInfo] = {}
    events: list[Event] = []
    decoder = TelemetryDecoder(system=None, use_attitude_quaternion=False, use_odometry=False)
    ap_sysid: int | None = None
    ap_kind: int | None = None
    mav_type: int | None = None
    telemetry_sysid: int | None = None
    hb_total = 0
    hb_offboard = 0
    last_off: bool | None = None
    mode_changes: list[tuple[float, bool]] = []
    sp_targets: dict[str, int] = {}
    has_attitude: dict[int, bool] = {}
    for lt, msg in messages:
        kind = msg.get_type()
        sid, cid = msg.get_srcSystem(), msg.get_srcComponent()
        info = systems.get((sid, cid))
        if info is None:
            info = systems[(sid, cid)] = SystemInfo(sid, cid)
        info.messages[kind] = info.messages.get(kind, 0) + 1
        if lt < info.lt_first:
            info.lt_first = lt
        if lt > info.lt_last:
            info.lt_last = lt
        vt = vehicle_time_of(msg)
        if vt is not None:
            if vt < info.vt_first:
                info.vt_first = vt
            if vt > info.vt_last:
                info.vt_last = vt
            sp_ = info.spans.get(kind)
            if sp_ is None:
                info.spans[kind] = [vt, vt]
            elif vt > sp_[1]:
                sp_[1] = vt
        if kind == "HEARTBEAT":
            info.heartbeat = (msg.type, msg.autopilot)
            if msg.autopilot != 8 and msg.type not in NON_VEHICLE_TYPES:
                if ap_sysid is None:
                    ap_sysid, ap_kind, mav_type = sid, msg.autopilot, msg.type
                if sid == ap_sysid:
                    hb_total += 1
                    off = is_offboard_mode(msg.autopilot, msg.custom_mode, msg.base_mode)
                    hb_offboard += off
                    if off != last_off:
                        mode_changes.append((lt, off))
                        events.append(Event("mode", sid, None, lt, off))
                        last_off = off
            continue
        if kind in TELEMETRY_TYPES:
            if kind == "ATTITUDE":
                has_attitude[sid] = True
                if telemetry_sysid is None:
                    telemetry_sysid = sid
            m = decoder.decode(msg)
            if m is not None:
                events.append(Event("m", sid, m.t, lt, m))
            continue
        if kind in SETPOINT_TYPES:
            sp = decode_setpoint(msg)
            if sp is not None:
                tgt = msg.target_system
                sp_targets[kind] = sp_targets.get(kind, 0) + 1
                events.append(Event("sp", tgt, vt, lt, (sp, msg)))
            continue
        if kind == "ATTITUDE_TARGET":
            events.append(Event("at", sid, vt, lt, (tuple(float(v) for v in msg.q), float(msg.thrust))))
        elif kind == "SYSTEM_TIME":
            events.append(Event("clock", sid, vt, lt, msg.time_boot_ms * 1e-3))
        elif kind == "EXTENDED_SYS_STATE":
            events.append(Event("landed", sid, vt, lt, int(msg.landed_state)))
    if ap_sysid is None:
        ap_sysid = telemetry_sysid
    return Scan(systems, events, {}, ap_sysid, ap_kind, mav_type, hb_offboard, hb_total, mode_changes, sp_targets)


def inventory(sc: Scan) -> dict[str, Any]:
    """What was found in the log (the ``log`` block of metrics.json) and what is missing for the replay."""
    ap = sc.autopilot_sysid
    msg_counts: dict[str, int] = {}
    systems = []
    for (sid, cid), info in sorted(sc.systems.items()):
        for k, v in info.messages.items():
            if sid == ap:
                msg_counts[k] = msg_counts.get(k, 0) + v
        span = info.vt_last - info.vt_first if info.vt_last > info.vt_first else None
        lspan = info.lt_last - info.lt_first if info.lt_last > info.lt_first else None
        hb = info.heartbeat
        systems.append({
            "sysid": sid, "compid": cid, "messages": info.count,
            "type": None if hb is None else type_name(hb[0]),
            "autopilot": None if hb is None else MAV_AUTOPILOT_NAMES.get(hb[1], f"autopilot {hb[1]}"),
            "logger_span_s": lspan, "vehicle_time_span_s": span,
            "rates_hz": {k: (v - 1) / (info.spans[k][1] - info.spans[k][0]) for k, v in sorted(info.messages.items())
                         if v > 1 and k in info.spans and info.spans[k][1] > info.spans[k][0]},
        })
    by_kind = {k: 0 for k in ("PositionVelocity", "Attitude", "Imu", "LoadAngle")}
    load_system = False
    resets = 0
    t_att = -math.inf
    for e in sc.events:
        if e.kind == "m" and e.sysid == ap:
            by_kind[type(e.payload).__name__] += 1
            if isinstance(e.payload, Attitude):
                if e.payload.t < t_att - REBOOT_JUMP_S:
                    resets += 1
                t_att = e.payload.t
    for (sid, _), info in sc.systems.items():
        hb = info.heartbeat
        if sid != ap and "GLOBAL_POSITION_INT" in info.messages and (hb is None or hb[0] not in NON_VEHICLE_TYPES):
            load_system = True  # e.g. ArduPilot's slung-payload SITL: the load as its own system
    sp_to_ap = sum(1 for e in sc.events if e.kind == "sp" and (e.sysid == ap or e.sysid == 0))
    mt = sc.mav_type
    vehicle_class = ("unknown" if mt is None else "multirotor" if mt in MULTIROTOR_TYPES
                     else "fixed wing" if mt in FIXED_WING_TYPES else "other")
    missing: list[str] = []
    if ap is None:
        missing.append("no autopilot found: no HEARTBEAT from a vehicle and no ATTITUDE telemetry")
    if sc.heartbeats == 0 and ap is not None:
        missing.append("no HEARTBEAT from the autopilot: flavour, vehicle type and flight mode unknown "
                       f"(system {ap} assumed from its ATTITUDE telemetry)")
    if vehicle_class == "fixed wing":
        missing.append(f"vehicle type is {type_name(mt)} (fixed wing): the slung-load model, "
                       "estimator and controller are for multirotors; not replayed")
    elif vehicle_class == "other":
        missing.append(f"vehicle type is {type_name(mt)}: not a multirotor; not replayed")
    if resets:
        missing.append(f"the vehicle's clock went back {resets} time(s) (reboots): each boot is replayed with a "
                       "fresh estimator; --from / --to select by vehicle time, which repeats across boots")
    if by_kind["Attitude"] == 0:
        missing.append("no ATTITUDE telemetry from the autopilot: the estimator cannot run")
    if by_kind["PositionVelocity"] == 0:
        missing.append("no local position (LOCAL_POSITION_NED / ODOMETRY): the vehicle's position and velocity, "
                       "hence the flat outputs, cannot be estimated; not replayed")
    if by_kind["LoadAngle"] == 0:
        if by_kind["Imu"] == 0:
            missing.append("no cable-angle sensor and no IMU telemetry: the swing is unobservable")
        else:
            missing.append(f"no cable-angle sensor (DEBUG_VECT {LOAD_ANGLE_NAME!r}): the swing is estimated from "
                           "the accelerometer only; whether a load is attached at all cannot be told from the log")
    return {
        "systems": systems,
        "autopilot_sysid": ap,
        "autopilot": None if sc.autopilot is None else MAV_AUTOPILOT_NAMES.get(sc.autopilot, f"{sc.autopilot}"),
        "vehicle_type": None if mt is None else type_name(mt),
        "vehicle_class": vehicle_class,
        "message_counts": dict(sorted(msg_counts.items())),
        "measurements": by_kind,
        "has_load_sensor": by_kind["LoadAngle"] > 0,
        "has_load_system": load_system,
        "has_local_position": by_kind["PositionVelocity"] > 0,
        "has_imu": by_kind["Imu"] > 0,
        "heartbeats": sc.heartbeats,
        "boots": resets + 1,
        "offboard_heartbeats": sc.offboard_heartbeats,
        "setpoints_to_autopilot": sp_to_ap,
        "setpoint_messages": dict(sc.setpoint_targets),
        "has_offboard_segment": sp_to_ap > 0 or sc.offboard_heartbeats > 0,
        "missing": missing,
    }


def replayable(inv: dict[str, Any]) -> tuple[bool, list[str]]:
    """Whether the estimator can run on the log, and the reasons when it cannot."""
    reasons = []
    if inv["autopilot_sysid"] is None:
        reasons.append("no autopilot telemetry")
    if inv["vehicle_class"] in ("fixed wing", "other"):
        reasons.append(f"vehicle type {inv['vehicle_type']} is not a multirotor")
    if not inv["measurements"]["Attitude"]:
        reasons.append("no ATTITUDE telemetry")
    if not inv["has_local_position"]:
        reasons.append("no local position")
    if not inv["has_load_sensor"] and not inv["has_imu"]:
        reasons.append("neither a cable-angle sensor nor an IMU")
    return not reasons, reasons


__all__ = [
    "MAV_AUTOPILOT_NAMES", "MAV_TYPE_NAMES", "REBOOT_JUMP_S", "Event", "Scan", "SystemInfo", "inventory",
    "is_offboard_mode", "replayable", "scan", "type_name", "vehicle_time_of",
]
