"""What a tlog holds: pass 1 of ``slung replay`` (see ``offboard.logs.replay``).

:func:`scan` reads ``(logger_time_s, message)`` pairs (``offboard.logs.tlog``) once: every packet is counted per system
and message type; HEARTBEATs give the autopilot's system id, flavour (PX4 / ArduPilot / other), vehicle type and flight
mode; telemetry of every system is decoded into the estimator's measurement records by the live link's own decoder
(``offboard.flight.link.telemetry.TelemetryDecoder``: model frame, times from the vehicle's ``time_boot_ms`` /
``time_usec``, never the logger's clock); setpoints sent to the autopilot (SET_ATTITUDE_TARGET,
SET_ACTUATOR_CONTROL_TARGET), the autopilot's ATTITUDE_TARGET, SYSTEM_TIME and EXTENDED_SYS_STATE are kept in
log order beside them as :class:`Event` records. ``offboard.logs.log_summary`` turns that into the ``log``
block of metrics.json (``inventory``) and says whether the estimator can run (``replayable``).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as dialect

from estimators.model.measurements import Attitude, Measurement, PositionVelocity
from offboard.flight.link.setpoints import decode as decode_setpoint
from offboard.flight.link.telemetry import IMU_RANK, TelemetryDecoder
from offboard.logs.flight_modes import (
    LANDED_STATE_AIRBORNE,
    is_armed,
    is_offboard_mode,
    mode_name,
)

# ---------------------------------------------------------------------------------------------------------------
# MAVLink enums used by the inventory (common.xml)

MAV_AUTOPILOT_NAMES = {0: "generic", 3: "ardupilot", 8: "invalid", 12: "px4"}
MAV_TYPE_NAMES = {
    0: "generic",
    1: "fixed wing",
    2: "quadrotor",
    3: "coaxial",
    4: "helicopter",
    6: "ground control station",
    10: "ground rover",
    11: "surface boat",
    12: "submarine",
    13: "hexarotor",
    14: "octorotor",
    15: "tricopter",
    18: "onboard controller",
    19: "VTOL tailsitter duo",
    20: "VTOL tailsitter quad",
    21: "VTOL tiltrotor",
    22: "VTOL fixed rotor",
    23: "VTOL tailsitter",
    26: "gimbal",
    27: "ADS-B",
    29: "dodecarotor",
}
MULTIROTOR_TYPES = frozenset({2, 3, 4, 13, 14, 15, 29})
FIXED_WING_TYPES = frozenset({1, 16, 19, 20, 21, 22, 23, 24, 25})
#: types that are never the vehicle itself (ground stations, companions, gimbals, cameras, ...)
NON_VEHICLE_TYPES = frozenset({6, 18, 26, 27, 30, 31})
SETPOINT_TYPES = ("SET_ATTITUDE_TARGET", "SET_ACTUATOR_CONTROL_TARGET")
#: a vehicle clock (ATTITUDE time_boot_ms) going back by more than this (s) is a discontinuity: a reboot when it
#: falls to less than :data:`REBOOT_FRACTION` of where it was (a new boot counts from 0), else a clock step
REBOOT_JUMP_S = 1.0
REBOOT_FRACTION = 0.5
#: without EXTENDED_SYS_STATE, an armed vehicle is taken as off the ground this high (m) above where it armed
AIRBORNE_HEIGHT_M = 0.5
#: airborne spans shorter than this (s) are not replayed (a hop, a bounce, a glitch of the landed state)
MIN_SEGMENT_S = 1.0
#: every message the live decoder turns into a measurement (every IMU message it ranks, ``IMU_RANK``)
TELEMETRY_TYPES = frozenset(
    {
        "ATTITUDE",
        "ATTITUDE_QUATERNION",
        "LOCAL_POSITION_NED",
        "ODOMETRY",
        "DEBUG_VECT",
        "ESTIMATOR_STATUS",
        "GPS_RAW_INT",
        *IMU_RANK,
    }
)


#: what each log format calls the records behind the inventory's sentences
SOURCE_NAMES: dict[str, dict[str, str]] = {
    "tlog": {
        "armed": "HEARTBEAT armed flag",
        "landed": "EXTENDED_SYS_STATE",
        "position": "LOCAL_POSITION_NED / ODOMETRY",
        "attitude": "ATTITUDE",
    },
    "ulog": {
        "armed": "vehicle_status.arming_state",
        "landed": "vehicle_land_detected",
        "position": "vehicle_local_position with xy_valid",
        "attitude": "vehicle_attitude",
    },
    "dataflash": {
        "armed": "EV armed / disarmed or ARM",
        "landed": "EV land complete / not landed",
        "position": "XKF1 / NKF1 / EKF1",
        "attitude": "ATT",
    },
}


def clock_jump(t_new: float, t_old: float) -> str | None:
    """How a vehicle clock moved from ``t_old`` to ``t_new`` (s): None (forward, or back by less than
    :data:`REBOOT_JUMP_S`), ``"reboot"`` (back to a small fraction of where it was: a new boot counts from 0) or
    ``"step"`` (back by more than the tolerance but not to a new boot: a time source switch, not a reboot)."""
    if not t_new < t_old - REBOOT_JUMP_S:
        return None
    return "reboot" if t_new < REBOOT_FRACTION * t_old else "step"


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
    the vehicle's ``time_boot_ms``, the lockstep emulator's tick marker), "landed" (EXTENDED_SYS_STATE's
    MAV_LANDED_STATE), "armed" (the HEARTBEAT's armed flag changed: bool), "modename" (the flight mode changed:
    its name), "gpos" (GLOBAL_POSITION_INT of any system: latitude, longitude in degrees, altitude m AMSL; a
    payload reporting as its own system gives the swing's truth), "height" (a ULog's height alone, without a
    horizontal position: (t, z m up, vz m/s up)).
    Events without a time field of their own (HEARTBEAT) carry the sender's latest vehicle time.

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
    log_format: str = "tlog"  # "tlog", "ulog", "dataflash"
    notes: list[str] = field(default_factory=list)  # what the format reader could not map, in plain words
    sources: dict[str, str] = field(default_factory=dict)  # where a record came from when a log has a choice


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
    last_vt: dict[int, float] = {}  # newest own time field per system (s), for events that carry none
    last_armed: bool | None = None
    last_name: str | None = None
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
        if vt is not None and vt > 0.0:  # stamped 0: no time (GPS without a fix, HOME_POSITION, ...)
            last_vt[sid] = vt
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
                    hvt = last_vt.get(sid)
                    off = is_offboard_mode(msg.autopilot, msg.custom_mode, msg.base_mode, msg.type)
                    hb_offboard += off
                    if off != last_off:
                        mode_changes.append((lt, off))
                        events.append(Event("mode", sid, hvt, lt, off))
                        last_off = off
                    armed = is_armed(msg.base_mode)
                    if armed != last_armed:
                        events.append(Event("armed", sid, hvt, lt, armed))
                        last_armed = armed
                    name = mode_name(msg.autopilot, msg.type, msg.base_mode, msg.custom_mode)
                    if name != last_name:
                        events.append(Event("modename", sid, hvt, lt, name))
                        last_name = name
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
        elif kind == "GLOBAL_POSITION_INT" and vt is not None:  # the vehicle's, and a payload system's (truth)
            events.append(Event("gpos", sid, vt, lt, (msg.lat * 1e-7, msg.lon * 1e-7, msg.alt * 1e-3)))
        elif kind == "EXTENDED_SYS_STATE":
            events.append(Event("landed", sid, last_vt.get(sid), lt, int(msg.landed_state)))
    if ap_sysid is None:
        ap_sysid = telemetry_sysid
    return Scan(systems, events, {}, ap_sysid, ap_kind, mav_type, hb_offboard, hb_total, mode_changes, sp_targets)


@dataclass(frozen=True)
class Segment:
    """One airborne span of the log: vehicle time ``t0`` .. ``t1`` (s since boot) within clock epoch ``epoch`` (0 for
    the first boot; each reboot or clock step starts a new one, since vehicle time repeats across them)."""

    epoch: int
    t0: float
    t1: float

    def as_dict(self) -> dict[str, Any]:
        return {"epoch": self.epoch, "from_s": self.t0, "to_s": self.t1, "duration_s": self.t1 - self.t0}

    def holds(self, epoch: int, t: float) -> bool:
        """Whether vehicle time ``t`` (s) of clock epoch ``epoch`` falls within the segment (both ends included)."""
        return self.epoch == epoch and self.t0 <= t <= self.t1


def records_by_epoch(events: Iterable[Event], ap: int | None) -> Iterator[tuple[int, Measurement]]:
    """The measurement records of system ``ap`` in log order, each with its clock epoch: a new epoch at each clock
    jump (:func:`clock_jump`) between consecutive attitude samples, the epochs :class:`Segment` counts."""
    epoch, t_att = 0, -math.inf
    for e in events:
        if e.kind != "m" or e.sysid != ap:
            continue
        m = e.payload
        if isinstance(m, Attitude):
            if clock_jump(m.t, t_att) is not None:
                epoch += 1
            t_att = m.t
        yield epoch, m


def flight_segments(sc: Scan) -> tuple[list[Segment], dict[str, Any]]:
    """The airborne segments of the autopilot's stream and the facts behind them.

    Airborne = armed (HEARTBEAT; a log without the autopilot's HEARTBEAT counts as armed throughout, with a note)
    and off the ground: EXTENDED_SYS_STATE in air or landing when the log has it, else higher than
    :data:`AIRBORNE_HEIGHT_M` above the height at which the vehicle armed (the local origin when the log starts
    armed). Times are the vehicle's own (attitude and position samples); spans shorter than
    :data:`MIN_SEGMENT_S` are dropped. Facts: ``armed_s`` (vehicle time armed), ``armed_known``,
    ``landed_state_known``, ``max_height_above_arming_m``, ``reboots``, ``clock_steps``."""
    ap = sc.autopilot_sysid
    has_landed = any(e.kind == "landed" and e.sysid == ap for e in sc.events)
    armed_known = any(e.kind == "armed" and e.sysid == ap for e in sc.events)
    armed = not armed_known
    landed: int | None = None
    z_ref = 0.0
    z_now: float | None = None
    epoch = 0
    t_last = -math.inf
    t_att = -math.inf
    reboots = steps = 0
    armed_s = 0.0
    max_h = -math.inf
    segs: list[Segment] = []
    open_t0: float | None = None
    open_t1 = -math.inf

    def close() -> None:
        nonlocal open_t0
        if open_t0 is not None and open_t1 - open_t0 >= MIN_SEGMENT_S:
            segs.append(Segment(epoch, open_t0, open_t1))
        open_t0 = None

    for e in sc.events:
        if e.sysid != ap:
            continue
        kind = e.kind
        if kind == "armed":
            armed = bool(e.payload)
            if armed and z_now is not None:
                z_ref = z_now
            continue
        if kind == "landed":
            landed = int(e.payload)
            continue
        if kind != "m":
            continue
        m = e.payload
        if isinstance(m, Attitude):
            jump = clock_jump(m.t, t_att)
            t_att = m.t
            if jump is not None:
                close()
                epoch += 1
                reboots += jump == "reboot"
                steps += jump == "step"
                t_last = -math.inf
        elif isinstance(m, PositionVelocity):
            z_now = m.z
        else:
            continue
        if m.t < t_last - REBOOT_JUMP_S:
            continue  # a late sample of another stream across a discontinuity
        if armed and m.t > t_last > -math.inf:
            armed_s += m.t - t_last
        if z_now is not None and armed:
            max_h = max(max_h, z_now - z_ref)
        t_last = max(t_last, m.t)
        if has_landed:
            up = armed and landed in LANDED_STATE_AIRBORNE
        else:
            up = armed and z_now is not None and z_now - z_ref > AIRBORNE_HEIGHT_M
        if up:
            if open_t0 is None:
                open_t0 = m.t
            open_t1 = m.t
        else:
            close()
    close()
    facts = {
        "armed_known": armed_known,
        "landed_state_known": has_landed,
        "armed_s": armed_s,
        "max_height_above_arming_m": max_h if math.isfinite(max_h) else None,
        "reboots": reboots,
        "clock_steps": steps,
    }
    return segs, facts


__all__ = [
    "AIRBORNE_HEIGHT_M",
    "MAV_AUTOPILOT_NAMES",
    "MAV_TYPE_NAMES",
    "REBOOT_JUMP_S",
    "TELEMETRY_TYPES",
    "Event",
    "Scan",
    "Segment",
    "SystemInfo",
    "clock_jump",
    "flight_segments",
    "is_offboard_mode",
    "records_by_epoch",
    "scan",
    "type_name",
    "vehicle_time_of",
]
