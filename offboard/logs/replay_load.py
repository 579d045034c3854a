"""Is a load attached in this log, and what is it? The airborne segments' IMU, attitude and (where the log has it)
velocity records handed to ``estimators.identification.load_id`` (``slung replay``'s ``load`` block of
metrics.json). Model frame, SI units, radians; vehicle time.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from estimators.identification.load_id import LoadIdentification, identify_load, resample
from estimators.model.measurements import Attitude, Imu, PositionVelocity
from estimators.model.vehicle import Vehicle
from offboard.logs.log_inventory import Event, Segment, records_by_epoch

#: time dropped at each end of an airborne segment (s): take-off and touch-down are not a hanging load's motion
EDGE_S = 2.0


def segment_stretches(events: list[Event], ap: int | None, segments: list[Segment]) -> list[tuple[Any, ...]]:
    """Per airborne segment: (t_imu, f_body, t_att, euler, t_vel, v_world) arrays of the autopilot's records
    (``t_vel`` / ``v_world`` None when the segment has no position record), ``EDGE_S`` trimmed at both ends."""
    per: list[dict[str, list[Any]]] = [{"imu": [], "att": [], "pv": []} for _ in segments]
    for epoch, m in records_by_epoch(events, ap):
        for i, sg in enumerate(segments):
            if sg.epoch == epoch and sg.t0 + EDGE_S <= m.t <= sg.t1 - EDGE_S:
                if isinstance(m, Imu):
                    per[i]["imu"].append(m)
                elif isinstance(m, Attitude):
                    per[i]["att"].append(m)
                elif isinstance(m, PositionVelocity):
                    per[i]["pv"].append(m)
                break
    out = []
    for p in per:
        if len(p["imu"]) < 4 or len(p["att"]) < 4:
            continue
        imu = sorted(p["imu"], key=lambda r: r.t)
        att = sorted(p["att"], key=lambda r: r.t)
        pv = sorted(p["pv"], key=lambda r: r.t)
        t_imu = np.array([r.t for r in imu])
        keep = np.concatenate([[True], np.diff(t_imu) > 0])  # strictly increasing for the interpolation
        t_att = np.array([r.t for r in att])
        keep_a = np.concatenate([[True], np.diff(t_att) > 0])
        f_body = np.array([(r.ax, r.ay, r.az) for r in imu])[keep]
        euler = np.array([(r.phi, r.theta, r.psi) for r in att])[keep_a]
        t_vel = v_world = None
        if len(pv) > 1:
            t_vel = np.array([r.t for r in pv])
            keep_v = np.concatenate([[True], np.diff(t_vel) > 0])
            t_vel = t_vel[keep_v]
            v_world = np.array([(r.vx, r.vy, r.vz) for r in pv])[keep_v]
        out.append((t_imu[keep], f_body, t_att[keep_a], euler, t_vel, v_world))
    return out


def identify_from_log(
    events: list[Event], ap: int | None, segments: list[Segment], vehicle: Vehicle
) -> LoadIdentification | None:
    """The load identified over the log's airborne segments (None when no segment has enough IMU and attitude)."""
    sig = resample(segment_stretches(events, ap, segments))
    if sig is None:
        return None
    return identify_load(sig, vehicle.mass_vehicle, vehicle.gravity)


def load_block(ident: LoadIdentification | None, vehicle: Vehicle, has_sensor: bool) -> dict[str, Any]:
    """metrics.json's ``load``: the decision, the identified values with their uncertainty, the vehicle file's
    values as the prior."""
    prior = {"mass_kg": vehicle.mass_load, "cable_m": vehicle.cable_length}
    if ident is None:
        return {
            "attached": None,
            "mass_kg": None,
            "cable_m": None,
            "uncertainty": None,
            "prior": prior,
            "reason": "too little airborne IMU and attitude data to tell",
        }
    return {**ident.as_dict(), "prior": prior, "cable_angle_sensor": has_sensor}


def live_run_load(vehicle: Vehicle, identification: Any) -> dict[str, Any]:
    """metrics.json's ``load`` for the replay of a run of slung's own (its tick log replayed bit for bit): the load
    the live run's law and filter were built on, as the run recorded it (``vehicle``: the vehicle file's load, or
    the one identified in flight, ``identification``: the run's ``config.load_identification``), not identified
    again from the log: the replay rebuilds the live run's filter, and a second identification would make it another
    pendulum than the one that flew."""
    attached = vehicle.mass_load > 0.0
    block: dict[str, Any] = {
        "attached": attached,
        "mass_kg": vehicle.mass_load if attached else None,
        "cable_m": vehicle.cable_length if attached else None,
        "uncertainty": None,
        "source": "the vehicle file the run recorded",
        "prior": {"mass_kg": vehicle.mass_load, "cable_m": vehicle.cable_length},
    }
    if isinstance(identification, dict):
        block["in_flight_identification"] = identification
        if isinstance(identification.get("prior"), dict):
            block["prior"] = identification["prior"]
        if identification.get("used"):
            block["uncertainty"] = identification.get("uncertainty")
            block["source"] = "identified in flight (slung fly --identify-load)"
    block["reason"] = block["source"]
    block["estimator_load"] = {"mass_kg": vehicle.mass_load, "cable_m": vehicle.cable_length}
    return block


__all__ = ["EDGE_S", "identify_from_log", "live_run_load", "load_block", "segment_stretches"]
