"""The replay of a log without a horizontal position (``slung replay``): what can be estimated is replayed instead
of refusing the log. A flight without GPS (PX4's STABILIZED flown by hand, ``vehicle_local_position`` with
``xy_valid`` 0) still has its attitude, its height (``z_valid``) and its IMU: the load identification
(``offboard.logs.replay_load``) runs on the IMU and attitude, the attitude and the height above the take-off are
written out per airborne segment. The flat outputs, the horizontal position and the swing estimate need the
position, so they are not. Model frame (world NWU z up, body FLU), SI units, radians, vehicle time.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from estimators.model.measurements import Attitude
from estimators.model.vehicle import Vehicle
from offboard.logs.log_inventory import Scan, flight_segments, records_by_epoch
from offboard.logs.replay_load import identify_from_log, load_block

#: the columns of a partial replay's timeseries.slts
PARTIAL_COLUMNS = ("t", "segment", "phi", "theta", "psi", "tilt", "p", "q", "r", "height", "height_rate")

#: what a partial replay cannot give, in words
NOT_ESTIMATED = (
    "no horizontal position in the log: the flat outputs, the horizontal position and velocity and the swing "
    "estimate are not replayed"
)


def partial_possible(inv: dict[str, Any], reasons: list[str]) -> bool:
    """Whether a log refused only for want of a local position can be replayed in part: it flew, and it has the
    attitude and an IMU."""
    return reasons == ["no local position"] and inv["has_imu"] and inv["measurements"]["Attitude"] > 0 and inv["flew"]


def _stats(v: np.ndarray) -> dict[str, float] | None:
    v = v[np.isfinite(v)]
    if not len(v):
        return None
    return {
        "max": float(np.max(v)),
        "min": float(np.min(v)),
        "rms": float(np.sqrt(np.mean(v * v))),
        "p95_abs": float(np.percentile(np.abs(v), 95)),
    }


def replay_partial(sc: Scan, inv: dict[str, Any], vehicle: Vehicle) -> tuple[np.ndarray, dict[str, Any]]:
    """The table (:data:`PARTIAL_COLUMNS`, one row per attitude sample within an airborne segment) and metrics.json
    of a partial replay. The height is the autopilot's, above the last height it reported before the segment's
    take-off (heights relative to take-off), NaN before its first height sample."""
    ap = inv["autopilot_sysid"]
    segments, _ = flight_segments(sc)
    heights = [e.payload for e in sc.events if e.kind == "height" and e.sysid == ap]
    ht = np.array([h[0] for h in heights]) if heights else np.zeros(0)
    hz = np.array([h[1] for h in heights]) if heights else np.zeros(0)
    hv = np.array([h[2] for h in heights]) if heights else np.zeros(0)
    rows: list[tuple[float, ...]] = []
    ground: dict[int, float] = {}
    for epoch, m in records_by_epoch(sc.events, ap):
        if not isinstance(m, Attitude):
            continue
        k = next((i for i, sg in enumerate(segments) if sg.holds(epoch, m.t)), None)
        if k is None:
            continue
        if k not in ground:
            j = int(np.searchsorted(ht, segments[k].t0)) - 1
            ground[k] = float(hz[j]) if j >= 0 else (float(hz[0]) if len(hz) else math.nan)
        j = int(np.searchsorted(ht, m.t, side="right")) - 1
        h = float(hz[j]) - ground[k] if j >= 0 else math.nan
        h_rate = float(hv[j]) if j >= 0 else math.nan
        tilt = math.acos(max(-1.0, min(1.0, math.cos(m.phi) * math.cos(m.theta))))
        rows.append((m.t, float(k), m.phi, m.theta, m.psi, tilt, m.p, m.q, m.r, h, h_rate))
    data = np.array(rows, dtype=float).reshape(-1, len(PARTIAL_COLUMNS))
    col = {c: data[:, i] for i, c in enumerate(PARTIAL_COLUMNS)}
    ident = identify_from_log(sc.events, ap, segments, vehicle)
    est: dict[str, Any] = {
        "partial": True,
        "what": (
            "the autopilot's attitude and its height above the take-off over the airborne segments; the load "
            "identification from the IMU and the attitude"
        ),
        "not_estimated": NOT_ESTIMATED,
        "ticks": len(data),
        "tick_source": "attitude samples",
        "vehicle_time_span_s": [float(data[0, 0]), float(data[-1, 0])] if len(data) else None,
        "segments": [sg.as_dict() for sg in segments],
        "height_m": _stats(col["height"]),
        "tilt_rad": _stats(col["tilt"]),
        "height_samples": int(np.sum(np.isfinite(col["height"]))),
    }
    metrics = {
        "log": inv,
        "replayed": True,
        "partial": True,
        "estimation": est,
        "load": load_block(ident, vehicle, inv["has_load_sensor"]),
    }
    return data, metrics


def partial_summary(metrics: dict[str, Any]) -> list[tuple[str, str]]:
    """The summary's rows for a partial replay."""
    est = metrics["estimation"]
    rows = [("replayed", f"in part: {est['what']}")]
    span = est.get("vehicle_time_span_s")
    if span:
        rows.append(("attitude", f"{est['ticks']} samples, t = {span[0]:.3f} .. {span[1]:.3f} s"))
    if est.get("tilt_rad"):
        rows.append(("tilt", f"max {est['tilt_rad']['max']:.3g} rad, p95 {est['tilt_rad']['p95_abs']:.3g} rad"))
    if est.get("height_m"):
        h = est["height_m"]
        rows.append(("height", f"{h['min']:.3g} .. {h['max']:.3g} m above the take-off"))
    rows.append(("not replayed", est["not_estimated"]))
    return rows


__all__ = ["NOT_ESTIMATED", "PARTIAL_COLUMNS", "partial_possible", "partial_summary", "replay_partial"]
