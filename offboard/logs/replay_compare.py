"""What a replay finds (``offboard.logs.replay``): the recomputed setpoints and estimates against the logged ones,
the swing against the log's truth, the flight's timeline, and the replay's metrics (``metrics.json``).
Model frame, SI units, radians; angles between attitudes in rad.
"""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np

from offboard.logs.log_inventory import (
    Event,
)
from offboard.logs.replay_health import offset_swing, truth_swing
from offboard.logs.replay_records import EST_COLUMNS, SP_ACT, SP_ATT, LiveRun, ReplayConfig


def swing_vs_truth(
    events: list[Event], data: np.ndarray, cols: tuple[str, ...], ap: int, load_sysid: int | None
) -> tuple[dict[str, Any], np.ndarray]:
    """The swing estimate against the payload's truth: DataFlash SLUP (the payload's offset from the vehicle) where
    the log has it, else the payload system's GLOBAL_POSITION_INT against the vehicle's; per planar angle max / RMS
    / p99 of estimate minus truth over the ticks where both are known, and how many; and the truth per tick."""
    c = {n: i for i, n in enumerate(cols)}
    t = data[:, c["t"]].tolist()
    offsets = [(e.vt, e.payload) for e in events if e.kind == "payload" and e.sysid == ap]
    if offsets:
        ax_t, ay_t = offset_swing(t, offsets)
        source = "SLUP (the payload's offset from the vehicle, ArduPilot SITL), interpolated to the ticks"
    else:
        veh = [(e.vt, e.payload) for e in events if e.kind == "gpos" and e.sysid == ap]
        load = [(e.vt, e.payload) for e in events if e.kind == "gpos" and e.sysid == load_sysid]
        ax_t, ay_t = truth_swing(t, veh, load)
        source = f"GLOBAL_POSITION_INT of system {load_sysid} (payload) and of the vehicle"
    ax_t_a, ay_t_a = np.asarray(ax_t), np.asarray(ay_t)
    out: dict[str, Any] = {
        "source": source,
        "ticks": int(np.sum(np.isfinite(ax_t_a) & np.isfinite(data[:, c["alpha_x"]]))),
        "alpha_x": column_stats(data[:, c["alpha_x"]] - ax_t_a),
        "alpha_y": column_stats(data[:, c["alpha_y"]] - ay_t_a),
        "truth_swing_max_rad": float(np.nanmax(np.hypot(ax_t_a, ay_t_a))) if np.any(np.isfinite(ax_t_a)) else None,
    }
    return out, np.column_stack((ax_t_a, ay_t_a))


#: the most timeline entries kept in metrics.json (a log can change mode every second)
MAX_TIMELINE = 500


def timeline(events: list[Event], divergences: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The flight's modes, arming, landed state and the replay's divergences on the vehicle-time axis, in log order:
    ``{"t_s", "kind", "text"}`` (kinds ``mode``, ``armed``, ``landed``, ``divergence``)."""
    from offboard.logs.flight_modes import LANDED_STATE_NAMES

    out: list[dict[str, Any]] = []
    landed: int | None = None
    for e in events:
        if e.vt is None:
            continue
        if e.kind == "modename":
            out.append({"t_s": e.vt, "kind": "mode", "text": str(e.payload)})
        elif e.kind == "armed":
            out.append({"t_s": e.vt, "kind": "armed", "text": "armed" if e.payload else "disarmed"})
        elif e.kind == "landed" and e.payload != landed:  # EXTENDED_SYS_STATE repeats its state at a few Hz
            landed = int(e.payload)
            out.append({"t_s": e.vt, "kind": "landed", "text": LANDED_STATE_NAMES.get(landed, str(landed))})
        if len(out) >= MAX_TIMELINE:
            break
    out += [{"t_s": d["t_s"], "kind": "divergence", "text": d["reason"]} for d in divergences[:MAX_TIMELINE]]
    return out


def as_table(rows: list[tuple[float, ...]], width: int) -> np.ndarray:
    """The (len(rows), width) float array of equal-length rows (``np.fromiter`` over the chained rows: about half the
    cost of ``np.array(rows)``, same values)."""
    return np.fromiter(itertools.chain.from_iterable(rows), float, len(rows) * width).reshape(len(rows), width)


def quat_angles(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation angles (rad) between the rows of two (n, 4) arrays of unit quaternions, sign-insensitive:
    ``4 asin(|a - s b| / 2)`` with ``s = sign(a . b)``, well conditioned for small angles (``2 acos(|a . b|)``
    is not: float32 rounding alone would read as 5e-4 rad)."""
    s = np.where(np.sum(a * b, axis=1) >= 0.0, 1.0, -1.0)[:, None]
    d = np.sqrt(np.sum((a - s * b) ** 2, axis=1))
    return 4.0 * np.arcsin(np.minimum(1.0, 0.5 * d))


def compare_ticks(
    data: np.ndarray,
    cols: tuple[str, ...],
    output: str,
    controller_ran: bool,
    live: LiveRun | None,
    live_idx: np.ndarray,
    extra: dict[str, Any],
) -> None:
    """Recomputed vs logged setpoints, logged vs the autopilot's ATTITUDE_TARGET, and replay vs the live tick
    log, over all ticks at once; fills the ``live_*_diff`` columns and the comparison entries of ``extra``."""
    if len(data) == 0:
        return
    c = {n: i for i, n in enumerate(cols)}
    nsp = 8 if output == "attitude" else 4
    s0, l0 = (
        c["sp_" + (SP_ATT if output == "attitude" else SP_ACT)[0]],
        c["log_" + (SP_ATT if output == "attitude" else SP_ACT)[0]],
    )
    rec, logged = data[:, s0 : s0 + nsp], data[:, l0 : l0 + nsp]
    if controller_ran:
        extra["cmp_exact"] = np.all(rec.astype(np.float32) == logged, axis=1).tolist()
        if output == "attitude":
            extra["cmp_angle"] = quat_angles(rec[:, :4], logged[:, :4]).tolist()
            extra["cmp_fields"] = np.abs(rec[:, 4:] - logged[:, 4:]).tolist()
        else:
            extra["cmp_fields"] = np.abs(rec - logged).tolist()
    if output == "attitude":
        ap = data[:, c["ap_q_w"] : c["ap_q_w"] + 4]
        ok = np.all(np.isfinite(ap), axis=1)
        extra["ap_angle"] = quat_angles(ap[ok], logged[ok, :4]).tolist()
    if live is not None:
        # at the precision the tick log kept (float32 since the .slts format's second version: live_storage):
        # the replay's value rounded as the live run's was stored, then compared; 0: identical at that precision
        ok = live_idx >= 0
        e0 = c["Fx"]
        mine = data[ok, e0 : e0 + len(EST_COLUMNS)].astype(live.est_stored).astype(float)
        d_est = np.max(np.abs(mine - live.est[live_idx[ok]]), axis=1)
        data[ok, c["live_est_diff"]] = d_est
        extra["live_est"] = d_est.tolist()
        extra["live_compared_at"] = {"estimate": live.est_stored.name, "setpoint": live.sp_stored.name}
        if controller_ran:
            d_sp = np.max(np.abs(rec[ok].astype(live.sp_stored).astype(float) - live.sp[live_idx[ok], :nsp]), axis=1)
            data[ok, c["live_sp_diff"]] = d_sp
            extra["live_sp"] = d_sp.tolist()


def column_stats(x: np.ndarray) -> dict[str, float | None]:
    x = x[np.isfinite(x)]
    if len(x) == 0:
        return {"max": None, "rms": None, "p99": None}
    return {
        "max": float(np.max(np.abs(x))),
        "rms": float(np.sqrt(np.mean(x * x))),
        "p99": float(np.percentile(np.abs(x), 99)),
    }


def replay_metrics(
    data: np.ndarray,
    cols: tuple[str, ...],
    inv: dict[str, Any],
    estimator: Any,
    output: str,
    source: str,
    extra: dict[str, Any],
    config: ReplayConfig,
    rate: float,
    load_sensor: bool,
    masks: dict[str, int],
) -> dict[str, Any]:
    """The metrics.json dictionary of a replay (sections: log, estimation, tracking, setpoint_agreement,
    live_agreement, config)."""
    c = {n: i for i, n in enumerate(cols)}
    col = lambda n: data[:, c[n]]  # noqa: E731 - short accessor
    n = len(data)
    t = col("t") if n else np.zeros(0)
    e0 = c["Fx"]
    est: dict[str, Any] = {
        "ticks": n,
        "tick_source": source,
        "rate_hz": rate,
        "estimator": config.estimator,
        "load_sensor_used": load_sensor,
        "initialized_at_s": extra.get("t_init"),
        "filter_starts": extra.get("filter_starts", 1),
        "airborne_only": bool(extra.get("airborne_gating", False)),
        "vehicle_time_span_s": [float(t[0]), float(t[-1])] if n else None,
        "estimator_stats": estimator.stats(),
    }
    usable = np.all(np.isfinite(data[:, e0 : e0 + len(EST_COLUMNS)]), axis=1) if n else np.zeros(0, bool)
    # finite means usable: a diverged tick's estimate is recorded as NaN, so "all finite" is never said of it
    est["all_finite"] = bool(np.all(usable)) if n else False
    est["usable_ticks"] = int(np.sum(usable))
    est["diverged_ticks"] = int(extra.get("diverged_ticks", 0))
    est["divergences"] = extra.get("divergences", [])
    if "segments" in extra:
        est["segments"] = extra["segments"]
    if "sensor_noise" in extra:
        est["sensor_noise"] = extra["sensor_noise"]
    if n and np.any(usable):
        ax, ay = col("alpha_x"), col("alpha_y")
        alpha = np.sqrt(ax * ax + ay * ay)[usable]
        est["swing_max_rad"] = float(np.max(alpha))
        est["swing_rms_rad"] = float(np.sqrt(np.mean(alpha * alpha)))
        ell = config.vehicle.cable_length
        ok = np.isfinite(col("pos_x"))
        if np.any(ok):  # the vehicle position implied by the estimate (F - l alpha) vs the autopilot's latest
            dx = col("Fx") - ell * col("alpha_y") - col("pos_x")
            dy = col("Fy") - ell * col("alpha_x") - col("pos_y")
            est["position_vs_autopilot_m"] = column_stats(np.sqrt(dx * dx + dy * dy)[ok])
            est["height_vs_autopilot_m"] = column_stats((col("z") - col("pos_z"))[ok])
        if np.any(np.isfinite(col("meas_alpha_x"))):
            est["alpha_x_vs_sensor"] = column_stats(ax - col("meas_alpha_x"))
            est["alpha_y_vs_sensor"] = column_stats(ay - col("meas_alpha_y"))
    tracking: dict[str, Any] | None = None
    agreement: dict[str, Any] | None = None
    cmp_fields = extra.get("cmp_fields", [])
    cmp_angle = extra.get("cmp_angle", [])
    if extra.get("controller_ran") and n:
        tracking = {"note": "errors of the ESTIMATED flat outputs, height and heading against the reference"}
        for name, a, b in (("e_Fx", "Fx", "Fx_ref"), ("e_Fy", "Fy", "Fy_ref"), ("e_z", "z", "z_ref")):
            tracking[name] = column_stats(col(a) - col(b))
        tracking["e_psi"] = column_stats(np.remainder(col("psi") - col("psi_ref") + math.pi, 2 * math.pi) - math.pi)
        agreement = {
            "ticks_compared": len(cmp_fields),
            "mapper_fallbacks": extra["mapper"].fallbacks,
            "float32_identical": int(sum(extra.get("cmp_exact", []))),
        }
        if cmp_fields:
            f = np.asarray(cmp_fields)
            names = SP_ATT[4:] if output == "attitude" else SP_ACT
            for i, nm in enumerate(names):
                agreement[nm] = column_stats(f[:, i])
            if output == "attitude":
                agreement["attitude_angle_rad"] = column_stats(np.asarray(cmp_angle))
            agreement["max_abs_difference"] = max(float(np.max(f)), max(cmp_angle) if cmp_angle else 0.0)
    if extra.get("ap_angle"):
        agreement = agreement or {}
        agreement["logged_vs_autopilot_attitude_target_rad"] = column_stats(np.asarray(extra["ap_angle"]))
    live: dict[str, Any] | None = None
    if extra.get("live_est"):
        le = np.asarray(extra["live_est"])
        live = {
            "ticks": len(le),
            "estimate_max_abs_difference": float(np.max(le)),
            "estimate_identical": int(np.sum(le == 0.0)),
            # the precision of those comparisons: the tick log's (float64 whole, or float32 as the folder keeps it)
            "compared_at": extra.get("live_compared_at"),
        }
        if extra.get("live_sp"):
            ls = np.asarray(extra["live_sp"])
            live["setpoint_max_abs_difference"] = float(np.max(ls))
            live["setpoint_identical"] = int(np.sum(ls == 0.0))
    ref = config.reference
    notes = []
    if source != "grid" and not source.startswith("grid") and not extra.get("controller_ran"):
        notes.append(
            "the log holds an offboard flight but the reference it flew is unknown: only the estimator ran "
            "(give --scenario or --trajectory, or keep the run's metrics.json beside the tlog)"
        )
    est["notes"] = notes
    return {
        "log": inv,
        "estimation": est,
        "tracking": tracking,
        "setpoint_agreement": agreement,
        "live_agreement": live,
        "config": {
            "vehicle": config.vehicle.name,
            "from_s": config.t_from,
            "to_s": config.t_to,
            "output": output,
            "switching": config.switching,
            "law": config.law,
            # the controller replayed (smc / smc-attitude: the sliding-mode law of "law")
            "controller": config.controller or ("smc-attitude" if config.law == "attitude" else "smc"),
            "epsilon": config.epsilon,
            "layer_errors": None if config.layer_errors is None else list(config.layer_errors),
            "actuation_lag_s": config.actuation_lag_s,
            "delay_s": config.delay_s,
            "external_feedforward": config.external_feedforward,
            "reference": None if ref is None else {"scenario": ref.scenario, "origin": extra.get("origin")},
        },
    }
