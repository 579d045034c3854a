"""``slung fly``: fly a real or emulated vehicle over MAVLink with the Kalman filter and the sliding-mode controller.

Usage::

    slung fly --connect URL (--scenario NAME | --trajectory FILE) [--output attitude|actuator]
              [--mask attitude|attitude+rates|rates] [--rate HZ] [--vehicle FILE] [--backend pymavlink|mavsdk]
              [--lockstep] [--stale-limit S] [--swing-limit RAD] [--end hold|land] [--on-signal hold|land]
              --out DIR

Writes into DIR: ``flight.tlog`` (every packet in and out, QGC format, flushed as written),
``timeseries_live.csv`` (one row per tick, every estimator / controller / setpoint field at full precision, the
columns of ``offboard.loop.LIVE_COLUMNS``), ``events.json`` (every watchdog, fallback and management step with
its reason), ``metrics.json`` (the ``slung sim`` schema plus ``loop``, ``link``, ``flight`` blocks),
``timeseries.csv`` and figures (the ``slung sim`` report). Without a truth source (a real vehicle) the
tracking errors are those of the ESTIMATE: ``metrics.json`` says so in ``flight.truth_source``.
"""

from __future__ import annotations

import argparse
import io
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from estimators.cable import cable_from_planar, planar_swing
from estimators.errors import UserError
from estimators.flatness import flat_chain, flat_constants, world_tilt
from estimators.vehicle import Vehicle, load_vehicle
from offboard import metrics as metrics_mod
from offboard import smc
from offboard.cli_args import add_controller_arguments, positive_float
from offboard.command_mapping import AutopilotModel, CommandMapper, MappingConfig
from offboard.link.setpoints import MASKS
from offboard.loop import (
    DEFAULT_RATE_HZ,
    LIVE_COL,
    LIVE_COLUMNS,
    RATE_MAX_HZ,
    RATE_MIN_HZ,
    FlightLoop,
    FlightResult,
    LoopConfig,
    TruthProbe,
)
from offboard.outputs import prepare_output_dir, write_json_atomic, write_text_atomic
from offboard.runlog import COL, LOG_COLUMNS, Scenario, SimConfig, SimLog

#: the Kalman filter's fusion horizon behind its output, s (``estimators.factory.make_estimator``'s default: above
#: the 4-9 ms latency of PX4 / ArduPilot estimates and the emulator's px4-typical sensors)
ESTIMATOR_DELAY_S = 0.012


def configure(p: argparse.ArgumentParser) -> None:
    """Arguments of ``slung fly``."""
    p.add_argument("--connect", required=True, metavar="URL",
                   help="MAVLink connection: udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT, serial:/dev/X:BAUD")
    p.add_argument("--baud", type=int, default=None, help="serial baud rate (default 57600, or from the URL)")
    add_reference_arguments(p)
    add_flight_arguments(p)
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (created if needed)")


def add_reference_arguments(p: argparse.ArgumentParser) -> None:
    """--scenario / --trajectory / --duration."""
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--scenario", metavar="NAME", help="named scenario (paper, rest-to-rest, hover, circle)")
    g.add_argument("--trajectory", metavar="FILE", help="trajectory file (TOML, docs/references.md)")
    p.add_argument("--duration", type=positive_float, metavar="S", help="flight time under offboard control, s")


def add_flight_arguments(p: argparse.ArgumentParser, demo: bool = False) -> None:
    """Options shared by ``fly`` and ``demo``."""
    add_controller_arguments(p)
    p.add_argument("--output", choices=("attitude", "actuator"), default="attitude",
                   help="attitude: SET_ATTITUDE_TARGET (PX4 and ArduPilot); actuator: SET_ACTUATOR_CONTROL_TARGET "
                        "(PX4 <= v1.13, the emulator)")
    p.add_argument("--mask", choices=tuple(MASKS), default="attitude",
                   help="SET_ATTITUDE_TARGET fields: attitude (type_mask 7, default), attitude+rates (0), rates (128)")
    p.add_argument("--rate", type=positive_float, default=DEFAULT_RATE_HZ, metavar="HZ",
                   help=f"loop rate, {RATE_MIN_HZ:g}..{RATE_MAX_HZ:g} Hz (default {DEFAULT_RATE_HZ:g})")
    if not demo:
        p.add_argument("--backend", choices=("pymavlink", "mavsdk"), default="pymavlink",
                       help="MAVLink library for management (default pymavlink)")
        p.add_argument("--lockstep", action="store_true",
                       help="the bundled emulator's lockstep handshake (slung emulate --lockstep)")
        p.add_argument("--no-takeoff", action="store_true", help="the vehicle is already flying at the start")
    p.add_argument("--stale-limit", type=positive_float, default=0.1, metavar="S",
                   help="telemetry staleness watchdog, s (default 0.1)")
    p.add_argument("--swing-limit", type=positive_float, default=0.8, metavar="RAD",
                   help="abort to hold above this estimated swing angle, rad (default 0.8)")
    p.add_argument("--divergence-limit", type=positive_float, default=1.0, metavar="M",
                   help="estimator divergence watchdog: estimate vs autopilot position, m (default 1)")
    p.add_argument("--end", choices=("hold", "land"), default="hold", help="what to do at the end (default hold)")
    p.add_argument("--on-signal", choices=("hold", "land"), default="hold",
                   help="what Ctrl-C / SIGTERM does (default hold)")
    p.add_argument("--rt-priority", type=int, default=0, metavar="N",
                   help="run the loop with SCHED_FIFO real-time priority N (1..99; needs the right to; default off)")
    p.add_argument("--force", action="store_true",
                   help="fly a reference the pre-flight feasibility check finds beyond the vehicle's limits")
    p.add_argument("--no-figures", action="store_true", help="write metrics and time series only")


def set_realtime_priority(priority: int) -> str | None:
    """SCHED_FIFO at ``priority`` for this process (Linux); a warning text when it cannot be done, else None.
    The loop never busy-waits (it blocks in select), so a real-time priority does not starve the machine."""
    if priority <= 0:
        return None
    if not 1 <= priority <= 99:
        raise UserError(f"--rt-priority must be in 1..99, got {priority}")
    try:
        import os

        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (AttributeError, OSError) as exc:
        return f"could not set real-time priority {priority}: {exc}"
    return None


def make_reference(args: argparse.Namespace) -> tuple[Scenario, float]:
    """The scenario (or a trajectory wrapped as one) and the flight duration: the reference part only (plant-free,
    ``offboard.scenarios``); a live flight starts wherever the vehicle is."""
    from offboard.reference import load_trajectory_file
    from offboard.scenarios import make_scenario

    if getattr(args, "scenario", None):
        sc = make_scenario(args.scenario, duration=args.duration)
        return sc, sc.duration
    ref = load_trajectory_file(args.trajectory)
    dur = args.duration or getattr(ref, "duration", None)
    if dur is None or not math.isfinite(dur) or dur <= 0:
        raise UserError(f"{args.trajectory}: the trajectory has no duration: give --duration")
    sc = Scenario(f"trajectory:{Path(args.trajectory).name}", f"trajectory file {args.trajectory}", dur, ref)
    return sc, dur


def build_loop_config(args: argparse.Namespace, lockstep: bool, takeoff: bool = True,
                      inject: tuple[tuple[str, float, float], ...] = ()) -> LoopConfig:
    """LoopConfig from the options; UserError for values out of range."""
    cfg = LoopConfig(rate_hz=args.rate, lockstep=lockstep, stale_s=args.stale_limit, swing_limit_rad=args.swing_limit,
                     divergence_m=args.divergence_limit, end_action=args.end, signal_action=args.on_signal,
                     takeoff=takeoff, inject_nan=inject)
    try:
        cfg.validate()
    except ValueError as exc:
        raise UserError(str(exc)) from None
    return cfg


def fly(args: argparse.Namespace, *, lockstep: bool, takeoff: bool = True, truth_probe: TruthProbe | None = None,
        inject: tuple[tuple[str, float, float], ...] = (), backend: str = "pymavlink",
        quiet: bool = False, on_reference_start: Any = None) -> tuple[dict[str, Any], Path]:
    """Connect, fly, write the report folder; returns (metrics, folder). Used by ``fly``, ``demo`` and tests."""
    from estimators.factory import make_estimator
    from offboard.link.connection import MavConnection

    out_dir = prepare_output_dir(args.out)
    vehicle = load_vehicle(args.vehicle)
    scenario, duration = make_reference(args)
    cfg = build_loop_config(args, lockstep, takeoff, inject)
    params = smc.ControllerParams.for_vehicle(vehicle, switching=args.switching, epsilon=args.epsilon)
    mapper = CommandMapper(vehicle, MappingConfig(output=args.output, mask=args.mask), AutopilotModel())
    feasibility = check_feasibility(scenario, duration, vehicle, params, mapper, cfg, args, quiet)
    tlog_path = out_dir / "flight.tlog"
    manager: Any = None
    if backend == "mavsdk":
        from offboard.link.mavsdk_backend import MavsdkConnection, MavsdkManager

        conn: Any = MavsdkConnection(args.connect, baud=getattr(args, "baud", None), tlog_path=tlog_path)
        manager = MavsdkManager(conn)
    else:
        conn = MavConnection(args.connect, baud=getattr(args, "baud", None), tlog_path=tlog_path)
    wall0 = time.perf_counter()
    prio_warning = set_realtime_priority(getattr(args, "rt_priority", 0))
    try:
        info = conn.wait_heartbeat(timeout=15.0)
        if info.flavour == "ardupilot" and args.output == "actuator":
            raise UserError("ArduPilot has no actuator-control setpoint: use --output attitude")
        mapper.set_autopilot(AutopilotModel(flavour=info.flavour))
        load_sensor = True  # the filter always has the load-angle channel; without LOADANG it predicts the swing
        est = make_estimator("kf", vehicle, load_sensor=load_sensor, rate_hz=args.rate, delay_s=ESTIMATOR_DELAY_S)
        loop = FlightLoop(conn, vehicle, scenario.reference, duration, params, mapper, est, cfg, truth_probe,
                          manager=manager, estimator_factory=lambda: make_estimator(
                              "kf", vehicle, load_sensor=load_sensor, rate_hz=args.rate, delay_s=ESTIMATOR_DELAY_S),
                          on_reference_start=on_reference_start)
        if not quiet:
            print(f"slung fly: {info.flavour} (system {info.system}) on {args.connect}; {scenario.name}, "
                  f"{duration:g} s, {args.output} output at {args.rate:g} Hz"
                  + (" (lockstep)" if lockstep else ""), file=sys.stderr, flush=True)
        result = loop.run()
        if prio_warning:
            result.warnings.append(prio_warning)
        if not result.load_sensor:
            result.warnings.append("no load-angle telemetry: the filter estimated the swing from the IMU")
        link = {"received": conn.stats.received, "sent": conn.stats.sent, "bad_data": conn.stats.bad_data,
                "by_type": dict(conn.stats.by_type), "clock_source": conn.clock.source,
                "tlog_records": conn.tlog.records if conn.tlog is not None else 0, "backend": backend}
    finally:
        conn.close()
    wall = time.perf_counter() - wall0
    m = write_flight_outputs(out_dir, result, scenario, vehicle, args, cfg, info.flavour, wall, link,
                             loop_t0=loop.events, figures=not args.no_figures,
                             estimator_config={"load_sensor": load_sensor, "delay_s": ESTIMATOR_DELAY_S},
                             feasibility=feasibility)
    if not quiet:
        print(f"scenario {scenario.name}: ended by {result.ended_by}, vehicle {result.end_state}")
        if m.get("rms"):
            print(metrics_mod.format_table(m))
        lp = m["loop"]
        pace = (f"lockstep at {cfg.rate_hz:g} Hz of vehicle time ({(lp['rate_hz_achieved'] or 0) / cfg.rate_hz:.1f}x "
                f"real time)" if cfg.lockstep else f"{lp['rate_hz_achieved'] or 0:.1f} Hz")
        print(f"loop: {pace}, compute p50/p99 {lp['compute_us_p50'] or 0:.0f}/"
              f"{lp['compute_us_p99'] or 0:.0f} us, latency p50/p99 {lp['latency_us_p50'] or 0:.0f}/"
              f"{lp['latency_us_p99'] or 0:.0f} us, missed {lp['missed_deadlines']}")
        for w in result.warnings:
            print(f"warning: {w}")
        print(f"report: {out_dir.resolve()}")
    return m, out_dir


def check_feasibility(scenario: Scenario, duration: float, vehicle: Vehicle, params: smc.ControllerParams,
                      mapper: CommandMapper, cfg: LoopConfig, args: argparse.Namespace,
                      quiet: bool) -> dict[str, Any]:
    """The nominal pre-flight check of the reference (``offboard.feasibility``), before anything connects: a
    reference the vehicle cannot fly even in theory is a UserError unless ``--force``; warnings are printed.
    Returns the summary recorded in ``metrics.json`` (``feasibility``)."""
    from offboard.feasibility import FeasibilityLimits, check_reference

    limits = FeasibilityLimits.from_config(params, mapper.config, cfg.swing_limit_rad)
    res = check_reference(scenario.reference, duration, vehicle, limits)
    force = bool(getattr(args, "force", False))
    if not res.feasible and not force:
        raise UserError(f"{scenario.name}: {res.messages[0]} (nominal pre-flight check, docs/references.md; "
                        "--force flies it anyway)")
    if not quiet:
        for msg in res.messages:
            print(f"pre-flight check: {msg}", file=sys.stderr)
    return {"feasible": res.feasible, "forced": force and not res.feasible, "messages": list(res.messages),
            "peaks": {d.name: d.peak for d in res.demands}}


def to_sim_log(result: FlightResult, scenario: Scenario, vehicle: Vehicle, rate_hz: float, wall: float,
               load_sensor: bool) -> tuple[SimLog, str]:
    """The flight as a :class:`SimLog` (the ``slung sim`` columns) so that ``offboard.metrics`` and
    ``offboard.report`` apply unchanged. Truth columns come from the truth probe when there was one, else from
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
            x = list(r[L["truth_x0"]:L["truth_x0"] + 18])
            tens = r[L["truth_tension"]]
        else:
            e = r[L["est_fx0"]:L["est_alpha_y_rate"] + 1]
            ax, ay, axd, ayd = e[20], e[21], e[22], e[23]
            (r1, r2, r3), (d1, d2, d3) = cable_from_planar(ay, ax, ayd, axd)
            x = [e[0] - ell * ay, e[6] - ell * ax, e[12], e[1] - ell * ayd, e[7] - ell * axd, e[13],
                 e[14], e[15], e[16], e[17], e[18], e[19], r1, r2, r3, d1, d2, d3]
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
        row[37:46] = (*r[L["cmd_thrust"]:L["cmd_sigma_y"] + 1], r[L["cmd_saturated"]])
        row[COL["tension"]] = tens if math.isfinite(tens) else vehicle.mass_load * vehicle.gravity
        dist = r[L["truth_dist_fx"]:L["truth_dist_tpsi"] + 1]
        row[47:51] = dist if has_truth and np.all(np.isfinite(dist)) else 0.0
        row[51:54] = (x[0] + ell * r1, x[1] + ell * r2, x[2] + ell * r3)
        est = r[L["est_fx0"]:L["est_alpha_y_rate"] + 1]
        if has_truth:
            sa_y, sa_x, sa_yd, sa_xd = planar_swing(x[12], x[13], x[14], x[15], x[16], x[17])
            nx, ny, nxd, nyd = world_tilt(x[6], x[7], x[8], x[9], x[10], x[11])
            tfx = flat_chain(kc, x[0], x[3], sa_y, sa_yd, nx, nxd)
            tfy = flat_chain(kc, x[1], x[4], sa_x, sa_xd, ny, nyd)
            row[COL["est_alpha_x"]:COL["est_alpha_y_rate"] + 1] = (est[20] - sa_x, est[21] - sa_y,
                                                                   est[22] - sa_xd, est[23] - sa_yd)
            row[COL["est_Fx0"]:COL["est_Fx5"] + 1] = [est[i] - tfx[i] for i in range(6)]
            row[COL["est_Fy0"]:COL["est_Fy5"] + 1] = [est[6 + i] - tfy[i] for i in range(6)]
            row[COL["est_z"]] = est[12] - x[2]
            row[COL["est_psi"]] = math.remainder(est[16] - x[8], 2.0 * math.pi)
        else:
            row[COL["est_alpha_x"]:COL["est_psi"] + 1] = 0.0
    config = SimConfig(plant_dt=1.0 / rate_hz, control_rate=rate_hz, attitude_model="vehicle", sensors="mavlink",
                       estimator="kf", load_sensor=load_sensor)
    sc = Scenario(scenario.name, scenario.description, scenario.duration, scenario.reference,
                  scenario.initial_state, None, scenario.disturbance_start, scenario.arrival_time)
    return SimLog(d, sc, config, vehicle, wall, slack, min_tension, dict(result.estimator_stats)), source


def write_flight_outputs(out_dir: Path, result: FlightResult, scenario: Scenario, vehicle: Vehicle,
                         args: argparse.Namespace, cfg: LoopConfig, flavour: str, wall: float, link: dict[str, Any],
                         loop_t0: Any = None, figures: bool = True,
                         estimator_config: dict[str, Any] | None = None,
                         feasibility: dict[str, Any] | None = None) -> dict[str, Any]:
    """timeseries_live.csv, events.json, metrics.json, timeseries.csv and figures. ``estimator_config``: the
    ``load_sensor`` and ``delay_s`` the filter was built with (recorded in ``config`` for ``slung replay``)."""
    from offboard import report

    rows = np.asarray(result.rows, dtype=float).reshape(-1, len(LIVE_COLUMNS))
    buf = io.StringIO()
    np.savetxt(buf, rows, delimiter=",", header=",".join(LIVE_COLUMNS), comments="", fmt="%.17g")
    write_text_atomic(out_dir / "timeseries_live.csv", buf.getvalue())
    events = {
        "loop": [e.__dict__ for e in result.events],
        "mapping": [e.__dict__ for e in result.mapper_events[:1000]],
        "mapping_total": len(result.mapper_events),
        "management": [e.__dict__ for e in result.management_events],
        "warnings": list(result.warnings),
    }
    write_json_atomic(out_dir / "events.json", events)
    log, source = to_sim_log(result, scenario, vehicle, cfg.rate_hz, wall, result.load_sensor)
    t_ref0 = rows[0, LIVE_COL["t_vehicle"]] - rows[0, LIVE_COL["t_ref"]] if len(rows) else None
    if len(rows) >= 2:
        m = metrics_mod.compute(log)
        m["completed"] = result.ended_by == "completed" and m["completed"]
        sp = rows[:, LIVE_COL["sp0"]:LIVE_COL["sp0"] + (9 if args.output == "attitude" else 4)]
        m["all_finite"] = bool(np.all(np.isfinite(sp)) and np.all(np.isfinite(
            rows[:, LIVE_COL["est_fx0"]:LIVE_COL["est_alpha_y_rate"] + 1])))
    else:
        m = {"scenario": scenario.name, "duration_s": 0.0, "completed": False, "all_finite": True}
    m.setdefault("config", {})
    m["config"].update({
        "switching": args.switching, "epsilon": args.epsilon if args.switching == "smooth" else None,
        "output": args.output, "mask": args.mask, "flavour": flavour, "rate_hz": cfg.rate_hz,
        "lockstep": cfg.lockstep, "hover_thrust_norm": result.autopilot.get("hover_thrust_norm"),
        "autopilot": result.autopilot, "origin_xy": list(result.origin), "reference_start_s": t_ref0,
        "attitude_model": "vehicle", "actuators": "vehicle", "sensors": "mavlink", "estimator": "kf",
        "load_telemetry_seen": result.load_sensor, "vehicle": vehicle.name,
        "trajectory": str(Path(args.trajectory).resolve()) if getattr(args, "trajectory", None) else None,
    })
    if estimator_config is not None:  # what make_estimator was given (replay rebuilds the same filter)
        m["config"].update({"load_sensor": bool(estimator_config["load_sensor"]),
                            "estimator_load_sensor": bool(estimator_config["load_sensor"]),
                            "delay_s": float(estimator_config["delay_s"])})
    m["loop"] = {**result.stats.summary(cfg.rate_hz), "reference_start_s": t_ref0,
                 "stale_limit_s": cfg.stale_s, "swing_limit_rad": cfg.swing_limit_rad}
    m["link"] = link
    if feasibility is not None:
        m["feasibility"] = feasibility
    m["flight"] = {"ended_by": result.ended_by, "end_state": result.end_state, "truth_source": source,
                   "setpoint_fallbacks": len(result.mapper_events), "warnings": list(result.warnings),
                   "telemetry": result.telemetry_counts}
    if len(rows) >= 2:
        report.write_report(log, m, out_dir, figures=figures)
    else:
        write_json_atomic(out_dir / "metrics.json", m)
    return m


def check_rate(rate_hz: float) -> None:
    """UserError unless ``--rate`` is within the loop's documented limits."""
    if not (RATE_MIN_HZ <= rate_hz <= RATE_MAX_HZ):
        raise UserError(f"--rate must be within {RATE_MIN_HZ:g}..{RATE_MAX_HZ:g} Hz, got {rate_hz:g}")


def run(args: argparse.Namespace) -> int:
    """Entry point of ``slung fly``: 0 when the reference was flown to its end, 1 when a watchdog or a signal ended
    the flight early (the vehicle was left in hold / landing)."""
    check_rate(args.rate)
    m, _ = fly(args, lockstep=args.lockstep, takeoff=not args.no_takeoff, backend=args.backend)
    return 0 if m.get("flight", {}).get("ended_by") == "completed" else 1
