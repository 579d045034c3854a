"""What a log holds, in words (``slung replay``): :func:`inventory` turns a :class:`~offboard.logs.log_inventory.Scan`
into the ``log`` block of metrics.json (systems, autopilot, streams and their rates, airborne segments), with one
sentence per thing that is missing; :func:`replayable` says whether the estimator can run, and why not.
"""

from __future__ import annotations

from typing import Any

from offboard.flight.link.telemetry import LOAD_ANGLE_NAME
from offboard.logs.flight_modes import (
    MAV_AUTOPILOT_ARDUPILOT,
    ardupilot_family,
)
from offboard.logs.log_inventory import (
    AIRBORNE_HEIGHT_M,
    FIXED_WING_TYPES,
    MAV_AUTOPILOT_NAMES,
    MULTIROTOR_TYPES,
    NON_VEHICLE_TYPES,
    SOURCE_NAMES,
    Scan,
    flight_segments,
    type_name,
)


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
        systems.append(
            {
                "sysid": sid,
                "compid": cid,
                "messages": info.count,
                "type": None if hb is None else type_name(hb[0]),
                "autopilot": None if hb is None else MAV_AUTOPILOT_NAMES.get(hb[1], f"autopilot {hb[1]}"),
                "logger_span_s": lspan,
                "vehicle_time_span_s": span,
                "rates_hz": {
                    k: (v - 1) / (info.spans[k][1] - info.spans[k][0])
                    for k, v in sorted(info.messages.items())
                    if v > 1 and k in info.spans and info.spans[k][1] > info.spans[k][0]
                },
            }
        )
    by_kind = {k: 0 for k in ("PositionVelocity", "Attitude", "Imu", "LoadAngle", "ReportedAccuracy")}
    load_system = False
    load_sysid: int | None = None
    for e in sc.events:
        if e.kind == "m" and e.sysid == ap:
            by_kind[type(e.payload).__name__] += 1
    segments, facts = flight_segments(sc)
    resets, steps = facts["reboots"], facts["clock_steps"]
    modes = [e.payload for e in sc.events if e.kind == "modename" and e.sysid == ap]
    for (sid, _), info in sc.systems.items():
        hb = info.heartbeat
        if sid != ap and "GLOBAL_POSITION_INT" in info.messages and (hb is None or hb[0] not in NON_VEHICLE_TYPES):
            load_system = True  # e.g. ArduPilot's slung-payload SITL: the load as its own system
            load_sysid = sid
    sp_to_ap = sum(1 for e in sc.events if e.kind == "sp" and (e.sysid == ap or e.sysid == 0))
    mt = sc.mav_type
    vehicle_class = (
        "unknown"
        if mt is None
        else "multirotor"
        if mt in MULTIROTOR_TYPES
        else "fixed wing"
        if mt in FIXED_WING_TYPES
        else "other"
    )
    missing: list[str] = []
    names = SOURCE_NAMES.get(sc.log_format, SOURCE_NAMES["tlog"])
    if ap is None:
        missing.append("no autopilot found: no HEARTBEAT from a vehicle and no ATTITUDE telemetry")
    if sc.heartbeats == 0 and ap is not None:
        missing.append(
            "no HEARTBEAT from the autopilot: flavour, vehicle type and flight mode unknown "
            f"(system {ap} assumed from its ATTITUDE telemetry)"
        )
    if vehicle_class == "fixed wing":
        missing.append(
            f"vehicle type is {type_name(mt)}{'' if type_name(mt) == 'fixed wing' else ' (fixed wing)'}: the "
            "slung-load model, "
            "estimator and controller are for multirotors; not replayed"
        )
    elif vehicle_class == "other":
        missing.append(f"vehicle type is {type_name(mt)}: not a multirotor; not replayed")
    if resets:
        missing.append(
            f"the vehicle's clock went back {resets} time(s) (reboots): each boot is replayed with a "
            "fresh estimator; --from / --to select by vehicle time, which repeats across boots"
        )
    if steps:
        missing.append(
            f"the vehicle's clock stepped back {steps} time(s) without a reboot (a time source switch): the "
            "estimator restarts there, since vehicle time repeats across the step"
        )
    if ap is not None and not facts["armed_known"]:
        missing.append(f"no {names['armed']} from the autopilot: the vehicle is taken as armed throughout")
    if ap is not None and not facts["landed_state_known"]:
        missing.append(
            f"no {names['landed']}: the vehicle is taken as off the ground while armed and more than "
            f"{AIRBORNE_HEIGHT_M:g} m above the height at which it armed"
        )
    if ap is not None and not segments:
        missing.append(why_no_flight(facts, sc.log_format))
    if by_kind["Attitude"] == 0:
        missing.append(f"no attitude ({names['attitude']}) from the autopilot: the estimator cannot run")
    if by_kind["PositionVelocity"] == 0:
        missing.append(
            f"no local position ({names['position']}): the vehicle's position and velocity, "
            "hence the flat outputs, cannot be estimated; with an IMU, only the attitude, the height and the load "
            "identification are replayed"
        )
    if by_kind["LoadAngle"] == 0:
        if by_kind["Imu"] == 0:
            missing.append("no cable-angle sensor and no IMU telemetry: the swing is unobservable")
        else:
            missing.append(
                f"no cable-angle sensor (DEBUG_VECT {LOAD_ANGLE_NAME!r}): the swing is estimated from "
                "the accelerometer only; whether a load is attached at all is identified from the IMU and "
                "attitude (metrics.json 'load')"
            )
    return {
        "systems": systems,
        "autopilot_sysid": ap,
        "autopilot": None if sc.autopilot is None else MAV_AUTOPILOT_NAMES.get(sc.autopilot, f"{sc.autopilot}"),
        "vehicle_type": None if mt is None else type_name(mt),
        "vehicle_class": vehicle_class,
        "ardupilot_firmware": (
            ardupilot_family(mt) if sc.autopilot == MAV_AUTOPILOT_ARDUPILOT and mt is not None else None
        ),
        "message_counts": dict(sorted(msg_counts.items())),
        "measurements": by_kind,
        "has_load_sensor": by_kind["LoadAngle"] > 0,
        "has_load_system": load_system,
        "load_sysid": load_sysid,
        "payload_truth": (
            "SLUP" if any(e.kind == "payload" for e in sc.events) else "GLOBAL_POSITION_INT" if load_system else None
        ),
        "sources": dict(sc.sources),
        "has_local_position": by_kind["PositionVelocity"] > 0,
        "has_imu": by_kind["Imu"] > 0,
        "heartbeats": sc.heartbeats,
        "boots": resets + 1,
        "clock_steps": steps,
        "log_format": sc.log_format,
        "flight_modes": sorted(set(modes), key=modes.index),
        "armed_s": facts["armed_s"],
        "airborne_segments": [sg.as_dict() for sg in segments],
        "flew": bool(segments),
        "offboard_heartbeats": sc.offboard_heartbeats,
        "setpoints_to_autopilot": sp_to_ap,
        "setpoint_messages": dict(sc.setpoint_targets),
        "has_offboard_segment": sp_to_ap > 0 or sc.offboard_heartbeats > 0,
        "missing": [*sc.notes, *missing],
    }


def why_no_flight(facts: dict[str, Any], log_format: str = "tlog") -> str:
    """The plain-words reason a log holds no airborne segment (``facts`` of :func:`flight_segments`)."""
    names = SOURCE_NAMES.get(log_format, SOURCE_NAMES["tlog"])
    if facts["armed_s"] <= 0.0:
        return f"no flight: the vehicle was never armed in this log ({names['armed']} clear throughout)"
    if facts["landed_state_known"]:
        return (
            f"no flight: armed for {facts['armed_s']:.1f} s but never off the ground "
            f"({names['landed']} on the ground throughout)"
        )
    h = facts["max_height_above_arming_m"]
    rose = "" if h is None else f", at most {h:.2f} m above where it armed"
    return f"no flight: armed for {facts['armed_s']:.1f} s but never off the ground{rose}"


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
    if inv["autopilot_sysid"] is not None and not inv["flew"] and not inv["setpoints_to_autopilot"]:
        reasons.append(next(s for s in inv["missing"] if s.startswith("no flight")))
    return not reasons, reasons


__all__ = ["inventory", "replayable", "why_no_flight"]
