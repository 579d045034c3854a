"""What ``slung fly`` writes after a flight (``offboard.flight.fly_cli``): the live tick log (``timeseries_live.slts``,
streamed during the flight and rewritten whole here), ``events.json``, and the flight turned into the ``slung sim``
run log (:class:`~offboard.logs.runlog.SimLog`) so that ``metrics.json``, ``timeseries.slts``, the figures and
``report.html`` are the simulation's. The report side (``offboard.report``) is imported inside the functions, after
the flight. Model frame, SI units, radians."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np

from estimators.model.cable import cable_from_planar, planar_swing, swing_amplitude
from estimators.model.flatness import flat_chain, flat_constants, world_tilt
from estimators.model.vehicle import Vehicle, vehicle_to_toml
from offboard.flight.loop import (
    LIVE_COL,
    LIVE_COLUMNS,
    FlightResult,
    LoopConfig,
)
from offboard.flight.supervisor import exit_code
from offboard.logs.estimate_columns import SIGMA_COLUMNS
from offboard.logs.live_storage import live_storage
from offboard.logs.runlog import COL, LOG_COLUMNS, Scenario, SimConfig, SimLog
from offboard.logs.timeseries_file import LIVE_LOG_NAME, write_table
from offboard.outputs import OutputFailures, write_json_atomic

#: rate of a flight's ``timeseries.slts`` (the ``slung sim`` columns, Hz): an overview for tools that read runs of
#: both kinds; the flight's full record is its tick log (``timeseries_live.slts``, every tick), from which these
#: columns are computed. At ``slung sim``'s 100 Hz it was the second largest file of a 10-minute flight (36 MB).
FLIGHT_TIMESERIES_RATE_HZ = 10.0


def settle_summary(rows: np.ndarray, result: FlightResult, vehicle: Vehicle) -> dict[str, Any]:
    """What the loop flew after the reference's end while the load settled (``LoopConfig.settle_s``): how long (s),
    the load's estimated swing amplitude (rad, ``offboard.flight.loop.FlightLoop.swing_amplitude``) at the
    reference's end and at the hand-over, and whether the time-out ended it."""
    w2 = vehicle.gravity / vehicle.cable_length
    L = LIVE_COL

    def amplitude(r: np.ndarray) -> float:
        ax, ay = float(r[L["est_alpha_x"]]), float(r[L["est_alpha_y"]])
        return swing_amplitude(ax, ay, float(r[L["est_alpha_x_rate"]]), float(r[L["est_alpha_y_rate"]]), w2)

    t_ref = rows[:, L["t_ref"]] if len(rows) else np.zeros(0)
    end = result.reference_duration_s
    inside = np.flatnonzero(t_ref <= end + 1e-9)
    after = len(rows) - len(inside)
    return {
        "flown_s": float(t_ref[-1] - end) if after else 0.0,
        "ticks": int(after),
        "swing_at_end_rad": amplitude(rows[inside[-1]]) if len(inside) else None,
        "swing_at_handover_rad": amplitude(rows[-1]) if len(rows) else None,
        "timed_out": any(e.kind == "settle_timeout" for e in result.events),
    }


def to_sim_log(
    result: FlightResult, scenario: Scenario, vehicle: Vehicle, rate_hz: float, wall: float, load_sensor: bool
) -> tuple[SimLog, str]:
    """The flight as a :class:`SimLog` (the ``slung sim`` columns) so that ``offboard.report.metrics`` and
    ``offboard.report.report`` apply unchanged. Truth columns come from the truth probe when there was one, else from
    the estimate (returned ``truth_source``)."""
    rows = np.asarray(result.rows, dtype=float).reshape(-1, len(LIVE_COLUMNS))
    n = rows.shape[0]
    d = np.full((n, len(LOG_COLUMNS)), np.nan)
    has_truth = n > 0 and bool(np.all(np.isfinite(rows[:, LIVE_COL["truth_x0"]])))
    source = "emulator truth" if has_truth else "estimate"
    ell = vehicle.cable_length
    L = LIVE_COL
    min_tension = math.inf
    slack = 0
    kc = flat_constants(vehicle)
    for k in range(n):
        r = rows[k]
        if has_truth:
            x = list(r[L["truth_x0"] : L["truth_x0"] + 18])
            tens = r[L["truth_tension"]]
        else:
            e = r[L["est_fx0"] : L["est_alpha_y_rate"] + 1]
            ax, ay, axd, ayd = e[20], e[21], e[22], e[23]
            (r1, r2, r3), (d1, d2, d3) = cable_from_planar(ay, ax, ayd, axd)
            x = [
                e[0] - ell * ay,
                e[6] - ell * ax,
                e[12],
                e[1] - ell * ayd,
                e[7] - ell * axd,
                e[13],
                e[14],
                e[15],
                e[16],
                e[17],
                e[18],
                e[19],
                r1,
                r2,
                r3,
                d1,
                d2,
                d3,
            ]
            tens = math.nan
        if math.isfinite(tens):
            min_tension = min(min_tension, tens)
            slack += tens <= 0.0
        row = d[k]
        r1, r2, r3 = x[12], x[13], x[14]
        h = math.hypot(r1, r2)
        alpha = math.atan2(h, -r3)
        beta = math.atan2(r2, r1) if h > 1e-12 else 0.0
        ay_t, ax_t = math.atan2(r1, -r3), math.atan2(r2, -r3)
        Fx, Fy = x[0] + ell * ay_t, x[1] + ell * ax_t
        t = r[L["t_ref"]]
        rfx0, rfy0, rz0, rpsi0 = r[L["ref_fx0"]], r[L["ref_fy0"]], r[L["ref_z0"]], r[L["ref_psi0"]]
        row[COL["t"]] = t
        row[1:19] = x
        row[19:25] = (alpha, beta, ax_t, ay_t, Fx, Fy)
        row[25:33] = (rfx0, rfy0, rz0, rpsi0, r[L["ref_fx1"]], r[L["ref_fy1"]], r[L["ref_z1"]], r[L["ref_psi1"]])
        row[33:37] = (Fx - rfx0, Fy - rfy0, x[2] - rz0, math.remainder(x[8] - rpsi0, 2.0 * math.pi))
        row[37:46] = (*r[L["cmd_thrust"] : L["cmd_sigma_y"] + 1], r[L["cmd_saturated"]])
        row[COL["tension"]] = tens if math.isfinite(tens) else vehicle.mass_load * vehicle.gravity
        dist = r[L["truth_dist_fx"] : L["truth_dist_tpsi"] + 1]
        row[47:51] = dist if has_truth and np.all(np.isfinite(dist)) else 0.0
        row[51:54] = (x[0] + ell * r1, x[1] + ell * r2, x[2] + ell * r3)
        est = r[L["est_fx0"] : L["est_alpha_y_rate"] + 1]
        if has_truth:
            sa_y, sa_x, sa_yd, sa_xd = planar_swing(x[12], x[13], x[14], x[15], x[16], x[17])
            nx, ny, nxd, nyd = world_tilt(x[6], x[7], x[8], x[9], x[10], x[11])
            tfx = flat_chain(kc, x[0], x[3], sa_y, sa_yd, nx, nxd)
            tfy = flat_chain(kc, x[1], x[4], sa_x, sa_xd, ny, nyd)
            row[COL["est_alpha_x"] : COL["est_alpha_y_rate"] + 1] = (
                est[20] - sa_x,
                est[21] - sa_y,
                est[22] - sa_xd,
                est[23] - sa_yd,
            )
            row[COL["est_Fx0"] : COL["est_Fx5"] + 1] = [est[i] - tfx[i] for i in range(6)]
            row[COL["est_Fy0"] : COL["est_Fy5"] + 1] = [est[6 + i] - tfy[i] for i in range(6)]
            row[COL["est_z"]] = est[12] - x[2]
            row[COL["est_psi"]] = math.remainder(est[16] - x[8], 2.0 * math.pi)
        else:
            row[COL["est_alpha_x"] : COL["est_psi"] + 1] = 0.0
    n_sd = len(SIGMA_COLUMNS)  # the filter's standard deviations, as logged
    d[:, COL[SIGMA_COLUMNS[0]] : COL[SIGMA_COLUMNS[0]] + n_sd] = rows[
        :, L[SIGMA_COLUMNS[0]] : L[SIGMA_COLUMNS[0]] + n_sd
    ]
    config = SimConfig(
        plant_dt=1.0 / rate_hz,
        control_rate=rate_hz,
        attitude_model="vehicle",
        sensors="mavlink",
        estimator="kf",
        load_sensor=load_sensor,
    )
    sc = Scenario(
        scenario.name,
        scenario.description,
        scenario.duration,
        scenario.reference,
        scenario.initial_state,
        None,
        scenario.disturbance_start,
        scenario.arrival_time,
    )
    return SimLog(d, sc, config, vehicle, wall, slack, min_tension, dict(result.estimator_stats)), source


def write_flight_outputs(
    out_dir: Path,
    result: FlightResult,
    scenario: Scenario,
    vehicle: Vehicle,
    args: argparse.Namespace,
    cfg: LoopConfig,
    flavour: str,
    wall: float,
    link: dict[str, Any],
    loop_t0: Any = None,
    figures: bool = True,
    estimator_config: dict[str, Any] | None = None,
    feasibility: dict[str, Any] | None = None,
    on_log: Any = None,
) -> dict[str, Any]:
    """events.json, metrics.json, timeseries.slts and figures, then timeseries_live.slts rewritten whole: the small
    files first, so that a full disk leaves the flight's result and events behind. An output that cannot be written is
    warned about as it stops and listed in ``metrics.json``'s ``outputs.failed`` (rewritten once at the end if
    anything failed, if it can be), never raised: the flight's result is the flight's. ``estimator_config``: the
    ``load_sensor`` and ``delay_s`` the filter was built with (recorded in ``config`` for ``slung replay``)."""
    from offboard.report import report

    rows = np.asarray(result.rows, dtype=float).reshape(-1, len(LIVE_COLUMNS))
    outputs = OutputFailures()
    events = {
        "loop": [e.__dict__ for e in result.events],
        "mapping": [e.__dict__ for e in result.mapper_events[:1000]],
        "mapping_total": len(result.mapper_events),
        "management": [e.__dict__ for e in result.management_events],
        "warnings": list(result.warnings),
    }
    outputs.attempt("events.json", lambda: write_json_atomic(out_dir / "events.json", events))
    # the metrics are the reference's: the ticks flown after its end while the load settled are reported apart
    t_ref = rows[:, LIVE_COL["t_ref"]]
    in_ref = t_ref <= result.reference_duration_s + 1e-9
    flown = result if bool(np.all(in_ref)) else dataclasses.replace(result, rows=rows[in_ref].tolist())
    log, source = to_sim_log(flown, scenario, vehicle, cfg.rate_hz, wall, result.load_sensor)
    if on_log is not None:
        on_log(log)
    t_ref0 = rows[0, LIVE_COL["t_vehicle"]] - rows[0, LIVE_COL["t_ref"]] if len(rows) else None
    if len(rows) >= 2:
        from offboard.report import metrics as metrics_mod  # the report side, loaded after the flight

        m = metrics_mod.compute(log)
        m["completed"] = result.ended_by == "completed" and m["completed"]
        sp = rows[:, LIVE_COL["sp0"] : LIVE_COL["sp0"] + (9 if args.output == "attitude" else 4)]
        m["all_finite"] = bool(
            np.all(np.isfinite(sp))
            and np.all(np.isfinite(rows[:, LIVE_COL["est_fx0"] : LIVE_COL["est_alpha_y_rate"] + 1]))
        )
        if source == "estimate":  # no truth: no error to hold against the filter's band
            m.get("estimation", {}).pop("within_2sigma", None)
    else:
        m = {"scenario": scenario.name, "duration_s": 0.0, "completed": False, "all_finite": True}
    m["settle"] = settle_summary(rows, result, vehicle)
    m.setdefault("config", {})
    m["config"].update(
        {
            # the controller that flew (its registry name; smc / smc-attitude: the sliding-mode law of "law")
            "controller": getattr(args, "controller_flown", None),
            "law": getattr(args, "law", None),
            "switching": args.switching,
            "epsilon": (
                args.epsilon
                if args.switching == "smooth"
                and getattr(args, "law", None) == "torque"
                and not getattr(args, "layer_errors", None)
                else None
            ),
            # where the reference's smooth stop to rest began (offboard.control.reference_stop; replay applies it)
            "stop_after_s": getattr(args, "stop_after_s", None),
            # the torque-level law's per-loop boundary layers (smc.error_boundary_layers; replay applies them)
            "layer_errors": getattr(args, "layer_errors", None) if getattr(args, "law", None) == "torque" else None,
            # the torque-level law's model of the motors' lag, s (smc actuation_lag_s; replay applies it)
            # (None with the attitude-level law: resolve_switching)
            "actuation_lag_s": getattr(args, "actuation_lag_s", None),
            # the torque-level law's pole scale for the measured loop delay (offboard.control.delay_margin; replay
            # applies it)
            "gain_scale": result.gain_scale,
            # the torque-level law's roll / pitch pair limited to the X frame's shared motor margin (smc; replay
            # applies it)
            "shared_roll_pitch": bool(getattr(args, "shared_roll_pitch", False)),
            "output": args.output,
            "mask": args.mask,
            "flavour": flavour,
            "rate_hz": cfg.rate_hz,
            "lockstep": cfg.lockstep,
            "hover_thrust_norm": result.autopilot.get("hover_thrust_norm"),
            "autopilot": result.autopilot,
            # the hover throttle learned in flight: prior, estimate, 1 sigma, trusted (hover_thrust_learning)
            "hover_thrust_learning": result.hover_learning,
            # the load identified in flight: prior, identified, 1 sigma, used (load_identification)
            "load_identification": result.load_identification,
            "origin_xy": list(result.origin),
            "ground_z": result.ground_z,
            "reference_start_s": t_ref0,
            "attitude_model": "vehicle",
            "actuators": "vehicle",
            "sensors": "mavlink",
            "estimator": "kf",
            "load_telemetry_seen": result.load_sensor,
            "vehicle": vehicle.name,
            # the whole vehicle the law and filter were built on: slung replay rebuilds it without --vehicle
            "vehicle_toml": vehicle_to_toml(vehicle),
            "trajectory": str(Path(args.trajectory).resolve()) if getattr(args, "trajectory", None) else None,
        }
    )
    if estimator_config is not None:  # what make_estimator was given (replay rebuilds the same filter)
        m["config"].update(
            {
                "load_sensor": bool(estimator_config["load_sensor"]),
                "estimator_load_sensor": bool(estimator_config["load_sensor"]),
                "delay_s": float(estimator_config["delay_s"]),
                "external_feedforward": bool(estimator_config.get("external_feedforward", False)),
                # the attitude-level law modelled the vehicle's drag (AttitudeParams.drag_feedforward)
                "drag_feedforward": bool(estimator_config.get("drag_feedforward", False)),
            }
        )
    m["loop"] = {
        **result.stats.summary(cfg.rate_hz),
        "reference_start_s": t_ref0,
        "stale_limit_s": result.staleness.get("limit_s", cfg.stale_s),
        "staleness": result.staleness,
        "swing_limit_rad": cfg.swing_limit_rad,
    }
    m["link"] = link
    if feasibility is not None:
        m["feasibility"] = feasibility
    m["flight"] = {
        "ended_by": result.ended_by,
        "end_state": result.end_state,
        "truth_source": source,
        "setpoint_fallbacks": len(result.mapper_events),
        "warnings": list(result.warnings),
        "telemetry": result.telemetry_counts,
        "supervision": result.supervision,
        "latency": result.latency,
        "exit_code": exit_code(result.ended_by),
    }
    m["outputs"] = {"failed": [f for f in (link.get("tlog_failure"), link.get("live_log_failure")) if f]}
    outputs.attempt("metrics.json", lambda: write_json_atomic(out_dir / "metrics.json", m))
    storage = live_storage(LIVE_COLUMNS)
    if len(rows) >= 2:  # then timeseries.slts and the figures (the report writes metrics.json again, the same)
        outputs.attempt(
            "timeseries.slts or the report's figures",
            lambda: report.write_report(
                log,
                m,
                out_dir,
                figures=figures,
                command=getattr(args, "command", None) or "fly",
                live=rows[in_ref],  # the same ticks as the log (the settle after the end is not drawn)
                live_col=LIVE_COL,
                events=events,
                timeseries_rate_hz=FLIGHT_TIMESERIES_RATE_HZ,
            ),
        )

    # the streamed tick log (offboard.flight.fly_cli) rewritten whole, last: complete, and ~17 % smaller in larger
    # blocks; if it cannot be, the streamed one written during the flight stays
    outputs.attempt(LIVE_LOG_NAME, lambda: write_table(out_dir / LIVE_LOG_NAME, LIVE_COLUMNS, rows, storage=storage))
    m["outputs"]["failed"] += outputs.failed
    if outputs.failed:  # say so in metrics.json too, if it can still be written (a small file: it often can)
        with contextlib.suppress(OSError):
            write_json_atomic(out_dir / "metrics.json", m)
    return m
