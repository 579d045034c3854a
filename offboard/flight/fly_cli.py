"""``slung fly``: fly a real or emulated vehicle over MAVLink with the Kalman filter and the sliding-mode controller
(or another controller of the registry, ``--controller``).

Usage (the main options; ``slung fly --help`` and ``docs/usage-fly-demo.md`` list every one)::

    slung fly --connect URL (--scenario NAME | --trajectory FILE | --move X,Y,Z [--arrive-by S]) [--duration S]
              [--output attitude|actuator]
              [--mask attitude|attitude+rates|rates] [--rate HZ] [--vehicle FILE|NAME] [--law auto|attitude|torque]
              [--controller NAME]
              [--backend pymavlink|mavsdk] [--lockstep] [--no-takeoff] [--external-feedforward]
              [--stale-floor S] [--stale-ceiling S] [--stale-limit S] [--swing-limit RAD]
              [--settle S] [--settle-swing RAD]
              [--end hold|land] [--on-signal hold|land] [--rt-priority N] [--force] --out DIR

Writes into DIR: ``flight.tlog`` (every packet in and out, QGC format, flushed as written),
``timeseries_live.slts`` (one row per tick, every estimator / controller / setpoint field at full precision, the
columns of ``offboard.flight.loop.LIVE_COLUMNS``; written while the flight runs, a block every 0.5 s, in the format
of ``offboard.logs.timeseries_file``), ``events.json`` (every watchdog, fallback and management step with
its reason), ``metrics.json`` (the ``slung sim`` schema plus ``loop``, ``link``, ``flight`` blocks),
``timeseries.slts`` and figures (the ``slung sim`` report); ``slung export --csv DIR`` writes them as CSV.
Without a truth source (a real vehicle) the tracking errors are those of the ESTIMATE: ``metrics.json`` says so in
``flight.truth_source``.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path
from typing import Any

from estimators.errors import UserError
from estimators.model.vehicle import load_vehicle
from offboard.cli_args import feedforward_tuning, positive_int
from offboard.control.controllers.registry import drag_in_law
from offboard.flight.attitude_mapping import AttitudeLawMapper
from offboard.flight.command_mapping import CommandMapper, MappingConfig
from offboard.flight.flight_law import (
    attitude_law_params,
    check_feasibility,
    rebuild_for_vehicle,
    resolve_law,
    resolve_switching,
    torque_fallback,
)
from offboard.flight.flight_outputs import write_flight_outputs
from offboard.flight.fly_args import (
    add_flight_arguments,
    add_reference_arguments,
    add_signing_arguments,
    signing_config,
)
from offboard.flight.fly_controller import controller_from_args
from offboard.flight.latency import DEFAULT_LIMIT_S as DEFAULT_LATENCY_LIMIT_S
from offboard.flight.link.autopilot_model import AutopilotModel
from offboard.flight.loop import (
    RATE_MAX_HZ,
    RATE_MIN_HZ,
    FlightLoop,
    LoopConfig,
    TruthProbe,
)
from offboard.flight.loop_records import LIVE_COLUMNS
from offboard.flight.status import FlightStatus
from offboard.flight.supervisor import exit_code, tracking_limit_for
from offboard.logs.live_storage import live_storage
from offboard.logs.runlog import Scenario
from offboard.logs.timeseries_file import LIVE_LOG_NAME, TableStreamer
from offboard.outputs import prepare_output_dir, write_json_atomic

#: the Kalman filter's fusion horizon behind its output, s (``estimators.filters.factory.make_estimator``'s default:
#: above the 4-9 ms latency of PX4 / ArduPilot estimates and the emulator's px4-typical sensors)
ESTIMATOR_DELAY_S = 0.012


def configure(p: argparse.ArgumentParser) -> None:
    """Arguments of ``slung fly``."""
    p.add_argument(
        "--connect",
        required=True,
        metavar="URL",
        help="MAVLink connection: udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT, serial:/dev/X:BAUD",
    )
    p.add_argument("--baud", type=positive_int, default=None, help="serial baud rate (default 57600, or from the URL)")
    add_signing_arguments(p)
    add_reference_arguments(p)
    add_flight_arguments(p)
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (created if needed)")


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


def make_reference(args: argparse.Namespace, vehicle: Any = None, quiet: bool = False) -> tuple[Scenario, float]:
    """The scenario (or a trajectory or a ``--move`` planned on ``vehicle``, wrapped as one) and the flight
    duration: the reference part only (plant-free, ``offboard.control.scenarios``); a live flight starts wherever the
    vehicle is."""
    from offboard.control.scenarios import make_scenario
    from offboard.control.trajectory_file import load_trajectory_file
    from offboard.flight.fly_move import check_move_options, move_scenario

    check_move_options(args)
    if getattr(args, "move", None) is not None:
        return move_scenario(args, vehicle, quiet)
    if getattr(args, "scenario", None):
        sc = make_scenario(args.scenario, duration=args.duration)
        return sc, sc.duration
    ref = load_trajectory_file(args.trajectory)
    dur = args.duration or getattr(ref, "duration", None)
    if dur is None or not math.isfinite(dur) or dur <= 0:
        raise UserError(f"{args.trajectory}: the trajectory has no duration: give --duration")
    sc = Scenario(f"trajectory:{Path(args.trajectory).name}", f"trajectory file {args.trajectory}", dur, ref)
    return sc, dur


#: plausible bounds of a flown reference (heights relative to the take-off point, m; s); docs/usage-fly-demo.md
DURATION_RANGE_S = (0.5, 3600.0)
HEIGHT_RANGE_M = (0.3, 120.0)  # above the take-off point: clear of the ground with the load, below 120 m
HORIZONTAL_RANGE_M = 1000.0  # from the reference's start


def check_reference_bounds(scenario: Scenario, duration: float) -> None:
    """UserError (one line, with the limit) for a duration or a reference that leaves the plausible range: the
    load's height above the take-off point outside ``HEIGHT_RANGE_M`` or farther than ``HORIZONTAL_RANGE_M``
    from its start, anywhere on the flight (sampled every 0.1 s, at most 4000 samples, and at the end)."""
    lo, hi = DURATION_RANGE_S
    if not (math.isfinite(duration) and lo <= duration <= hi):
        raise UserError(f"{scenario.name}: duration {duration:g} s outside the plausible range {lo:g}..{hi:g} s")
    ref = scenario.reference
    s0 = ref.sample(0.0)
    x0, y0 = s0.fx[0], s0.fy[0]
    n = int(min(4000, max(10, duration / 0.1)))
    zlo, zhi = HEIGHT_RANGE_M
    for i in range(n + 1):
        t = duration * i / n
        s = ref.sample(t)
        z, dxy = s.z[0], math.hypot(s.fx[0] - x0, s.fy[0] - y0)
        if not (math.isfinite(z) and zlo <= z <= zhi):
            raise UserError(
                f"{scenario.name}: height {z:g} m above the take-off point at t = {t:g} s is outside the plausible "
                f"range {zlo:g}..{zhi:g} m"
            )
        if not (math.isfinite(dxy) and dxy <= HORIZONTAL_RANGE_M):
            raise UserError(
                f"{scenario.name}: {dxy:g} m from the start at t = {t:g} s, beyond the plausible "
                f"{HORIZONTAL_RANGE_M:g} m"
            )


def build_loop_config(
    args: argparse.Namespace,
    lockstep: bool,
    takeoff: bool = True,
    inject: tuple[tuple[str, float, float], ...] = (),
    cable_length: float = 1.0,
) -> LoopConfig:
    """LoopConfig from the options; UserError for values out of range. ``cable_length`` (m) scales the default
    tracking limit (:func:`~offboard.flight.supervisor.tracking_limit_for`)."""
    tracking = getattr(args, "tracking_limit", None)
    if tracking is None:
        tracking = tracking_limit_for(cable_length, args.swing_limit)
    cfg = LoopConfig(
        rate_hz=args.rate,
        lockstep=lockstep,
        stale_s=args.stale_limit if args.stale_limit is not None else args.stale_floor,
        stale_ceiling_s=args.stale_limit if args.stale_limit is not None else args.stale_ceiling,
        swing_limit_rad=args.swing_limit,
        settle_s=getattr(args, "settle", 5.0),
        settle_swing_rad=getattr(args, "settle_swing", 0.05),
        divergence_m=args.divergence_limit,
        tracking_limit_m=tracking,
        latency_limit_s=getattr(args, "latency_limit", DEFAULT_LATENCY_LIMIT_S),
        base_filter_delay_s=ESTIMATOR_DELAY_S,
        end_action=args.end,
        signal_action=args.on_signal,
        takeoff=takeoff,
        inject_nan=inject,
        telemetry_timeout_s=getattr(args, "telemetry_timeout", 10.0),
        start_timeout_s=getattr(args, "start_timeout", 10.0),
        learn_hover=not getattr(args, "no_hover_learning", False),
        identify_load_s=getattr(args, "identify_load", None) or 0.0,
    )
    try:
        cfg.validate()
    except ValueError as exc:
        raise UserError(str(exc)) from None
    return cfg


def fly(
    args: argparse.Namespace,
    *,
    lockstep: bool,
    takeoff: bool = True,
    truth_probe: TruthProbe | None = None,
    inject: tuple[tuple[str, float, float], ...] = (),
    backend: str = "pymavlink",
    quiet: bool = False,
    on_reference_start: Any = None,
    scenario: Scenario | None = None,
    controller: Any = None,
    on_log: Any = None,
) -> tuple[dict[str, Any], Path]:
    """Connect, fly, write the report folder; returns (metrics, folder). Used by ``fly``, ``demo`` and tests.
    ``scenario``: fly this reference instead of the one ``args`` names; ``controller``: this
    :class:`~offboard.control.controllers.protocol.Controller` instead of the sliding-mode law (its output mapped
    as the law's ``args.law`` says); ``on_log``: called with the flight's :class:`SimLog` (full rate)."""
    from estimators.filters.factory import make_estimator
    from offboard.flight.link.connection import MavConnection

    out_dir = prepare_output_dir(args.out)
    vehicle = load_vehicle(args.vehicle)
    scenario, duration = make_reference(args, vehicle, quiet) if scenario is None else (scenario, scenario.duration)
    check_reference_bounds(scenario, duration)
    line = vehicle.cable_length if vehicle.mass_load > 0.0 else 0.0  # no load: no swing to allow for
    cfg = build_loop_config(args, lockstep, takeoff, inject, line)
    if controller is None:  # --controller NAME: a registered controller, or the sliding-mode law's level
        controller = controller_from_args(args, vehicle)
    asked_law = getattr(args, "law", "auto")
    args.law = resolve_law(asked_law, args.output, vehicle)
    law = args.law
    if law == "attitude" and args.output == "actuator":
        raise UserError("--law attitude commands attitude and thrust: use --output attitude, or --law torque")
    # --law auto chose on PX4's default attitude loop: the torque-level law stands by for the autopilot's own
    fallback = torque_fallback(args, vehicle) if law == "attitude" and asked_law in (None, "auto") else None
    torque_params = resolve_switching(args, law, vehicle)
    args.shared_roll_pitch = torque_params.shared_roll_pitch and law == "torque"  # recorded for slung replay
    mapping = MappingConfig(output=args.output, mask=args.mask or default_mask(None))
    params: Any = torque_params
    if law == "attitude":
        params = attitude_law_params(vehicle, args, mapping)
        mapper: CommandMapper = AttitudeLawMapper(vehicle, mapping, AutopilotModel())
    else:
        mapper = CommandMapper(vehicle, mapping, AutopilotModel())
    # the nominal feasibility check is the torque-level one: thrust and torque the vehicle can give, for either law
    feasibility = check_feasibility(scenario, duration, vehicle, torque_params, mapper, cfg, args, quiet)
    tlog_path = out_dir / "flight.tlog"
    signing = signing_config(args)
    manager: Any = None
    if backend == "mavsdk":
        from offboard.flight.link.mavsdk_backend import MavsdkConnection, MavsdkManager

        conn: Any = MavsdkConnection(
            args.connect, baud=getattr(args, "baud", None), tlog_path=tlog_path, signing=signing
        )
        manager = MavsdkManager(conn)
    else:
        conn = MavConnection(args.connect, baud=getattr(args, "baud", None), tlog_path=tlog_path, signing=signing)
    wall0 = time.perf_counter()
    prio_warning = set_realtime_priority(getattr(args, "rt_priority", 0))
    status = None if quiet else FlightStatus()  # phases and a live status line on stderr (offboard.flight.status)
    live_stream: TableStreamer | None = None
    try:
        if status is not None:
            status.phase("connecting", f"waiting for the autopilot's heartbeat on {args.connect}")
        info = conn.wait_heartbeat(timeout=15.0)
        if info.flavour == "ardupilot" and args.output == "actuator":
            raise UserError("ArduPilot has no actuator-control setpoint: use --output attitude")
        mapper.set_autopilot(AutopilotModel(flavour=info.flavour))
        if args.mask is None:  # the flavour's own default, now that the heartbeat has told which autopilot it is
            args.mask = default_mask(info.flavour)
            mapper.set_mask(args.mask)
        load_sensor = True  # the filter always has the load-angle channel; without LOADANG it predicts the swing
        tuning = feedforward_tuning(args)  # --external-feedforward (None: the filter's defaults)
        est = make_estimator(
            "kf", vehicle, load_sensor=load_sensor, rate_hz=args.rate, delay_s=ESTIMATOR_DELAY_S, tuning=tuning
        )
        loop = FlightLoop(
            conn,
            vehicle,
            flown_reference(scenario.reference, duration, cfg.settle_s, args),
            duration,
            params,
            mapper,
            est,
            cfg,
            truth_probe,
            manager=manager,
            estimator_factory=lambda delay_s=ESTIMATOR_DELAY_S: make_estimator(
                "kf", vehicle, load_sensor=load_sensor, rate_hz=args.rate, delay_s=delay_s, tuning=tuning
            ),
            on_reference_start=on_reference_start,
            controller=controller,
            torque_fallback=fallback.params if fallback is not None else None,
            rebuild_for=lambda v, attitude: rebuild_for_vehicle(
                v, attitude, args, law, mapping, scenario, duration, mapper, cfg, load_sensor, tuning, quiet
            ),
        )
        if not quiet:
            print(
                f"slung fly: {info.flavour} (system {info.system}) on {args.connect}; {scenario.name}, "
                f"{duration:g} s, controller {loop.controller.name} ({law} level), {args.output} output at "
                f"{args.rate:g} Hz" + (" (lockstep)" if lockstep else ""),
                file=sys.stderr,
                flush=True,
            )
        if status is not None:
            status.attach(loop)
        # the tick log on disk while the loop runs (a block every 0.5 s): a killed flight leaves its ticks
        live_stream = TableStreamer(
            out_dir / LIVE_LOG_NAME, LIVE_COLUMNS, loop.rows, storage=live_storage(LIVE_COLUMNS)
        ).start()
        try:
            result = loop.run()
        except UserError as exc:  # refused or impossible before the flight: the folder still says what happened
            write_refusal_events(out_dir, loop, exc)
            raise
        if fallback is not None and loop.flew_torque_fallback:
            vars(args).update(fallback.record)  # metrics.json and slung replay: the law that flew
        args.controller_flown = loop.controller.name  # metrics.json and slung replay: the controller that flew
        if prio_warning:
            result.warnings.append(prio_warning)
        if not result.load_sensor:
            result.warnings.append("no load-angle telemetry: the filter estimated the swing from the IMU")
        if conn.tlog is not None and conn.tlog.failure is not None:
            result.warnings.append(conn.tlog.failure + " (the flight went on)")
        live_stream.close()
        if live_stream.failure is not None:
            result.warnings.append(live_stream.failure + " (the flight went on)")
        link = {
            "received": conn.stats.received,
            "sent": conn.stats.sent,
            "bad_data": conn.stats.bad_data,
            "by_type": dict(conn.stats.by_type),
            "clock_source": conn.clock.source,
            "tlog_records": conn.tlog.records if conn.tlog is not None else 0,
            "tlog_failure": conn.tlog.failure if conn.tlog is not None else None,
            "live_log_failure": live_stream.failure,
            "foreign_command_acks": conn.stats.foreign_acks,
            "foreign_datagrams": conn.stats.foreign_datagrams,
            "deferred_polls": conn.stats.deferred_polls,
            "backend": backend,
        }
    finally:
        if live_stream is not None:
            live_stream.close()
        if status is not None:
            status.close()
        conn.close()
    result.warnings.extend(conn.signing_warnings)
    link["signing"] = (
        None
        if signing is None
        else {
            "link_id": signing.link_id,
            "state": str(signing.state_path),
            "good_signatures": conn.mav.signing.goodsig_count,
            "bad_signatures": conn.mav.signing.badsig_count,
            "unsigned_refused": conn.stats.refused_unsigned,
        }
    )
    wall = time.perf_counter() - wall0
    m = write_flight_outputs(
        out_dir,
        result,
        scenario,
        loop.vehicle,  # the identified load's when the flight flew it (--identify-load)
        args,
        cfg,
        info.flavour,
        wall,
        link,
        loop_t0=loop.events,
        figures=not args.no_figures,
        estimator_config={
            "load_sensor": load_sensor,
            "delay_s": result.filter_delay_s or ESTIMATOR_DELAY_S,
            "external_feedforward": tuning is not None,
            "drag_feedforward": law == "attitude" and drag_in_law(tuning),
        },
        feasibility=feasibility,
        on_log=on_log,
    )
    if not quiet:
        print(f"scenario {scenario.name}: ended by {result.ended_by}, vehicle {result.end_state}")
        if m.get("rms"):
            from offboard.report import metrics as metrics_mod  # the report side, loaded after the flight

            print(metrics_mod.format_table(m))
        lp = m["loop"]
        pace = (
            f"lockstep at {cfg.rate_hz:g} Hz of vehicle time ({(lp['rate_hz_achieved'] or 0) / cfg.rate_hz:.1f}x "
            f"real time)"
            if cfg.lockstep
            else f"{lp['rate_hz_achieved'] or 0:.1f} Hz"
        )
        print(
            f"loop: {pace}, compute p50/p99 {lp['compute_us_p50'] or 0:.0f}/"
            f"{lp['compute_us_p99'] or 0:.0f} us, latency p50/p99 {lp['latency_us_p50'] or 0:.0f}/"
            f"{lp['latency_us_p99'] or 0:.0f} us, missed {lp['missed_deadlines']}"
        )
        for w in result.warnings:
            print(f"warning: {w}")
        print(f"report: {out_dir.resolve()}")
    return m, out_dir


def write_refusal_events(out_dir: Path, loop: FlightLoop, exc: UserError) -> None:
    """``events.json`` of a run that ended before the flight (an autopilot that refused to arm, to take off or to
    enter offboard control; telemetry that never came): what the loop and management did and saw, and the error
    (the same one line the command prints)."""
    write_json_atomic(
        out_dir / "events.json",
        {
            "loop": [e.__dict__ for e in loop.events],
            "management": [e.__dict__ for e in loop.mgr.events],
            "warnings": list(loop.mgr.warnings),
            "error": str(exc),
        },
    )


def flown_reference(reference: Any, duration: float, settle_s: float, args: argparse.Namespace) -> Any:
    """The reference the loop flies: ``reference`` up to ``duration`` (s), then, unless ``--settle 0`` hands over
    at once, its smooth stop to rest (``offboard.control.reference_stop``: a reference still moving at its end, the
    paper's figure-eight, would be handed to the autopilot's hold at speed). ``args.stop_after_s`` records where
    the stop starts, for ``slung replay`` (None: no stop)."""
    from offboard.control.reference_stop import StoppingReference

    if settle_s <= 0.0:
        args.stop_after_s = None
        return reference
    stopping = StoppingReference(reference, duration)
    args.stop_after_s = duration if stopping.stop_s > 0.0 else None
    return stopping if stopping.stop_s > 0.0 else reference


def default_mask(flavour: str | None) -> str:
    """The SET_ATTITUDE_TARGET mask a flight uses unless ``--mask`` says otherwise: ``attitude+rates`` on ArduPilot,
    which adds the body rates as feed-forward and shapes the attitude request (ATC_INPUT_TC), so that the
    mapping's look-ahead in the attitude alone is not cancelled; ``attitude`` elsewhere (PX4 ignores the rates
    with it, and its P loop is the one the look-ahead inverts)."""
    return "attitude+rates" if flavour == "ardupilot" else "attitude"


def check_rate(rate_hz: float) -> None:
    """UserError unless ``--rate`` is within the loop's documented limits."""
    if not (RATE_MIN_HZ <= rate_hz <= RATE_MAX_HZ):
        raise UserError(f"--rate must be within {RATE_MIN_HZ:g}..{RATE_MAX_HZ:g} Hz, got {rate_hz:g}")


def run(args: argparse.Namespace) -> int:
    """Entry point of ``slung fly``: the exit code of how the flight ended (``offboard.flight.supervisor.exit_code``):
    0 flown to the end; 1 a watchdog, a signal or an internal fault ended it (vehicle handed to hold / land);
    3 the vehicle left offboard control without being asked (pilot, ground station, failsafe); 4 it disarmed."""
    check_rate(args.rate)
    m, out_dir = fly(args, lockstep=args.lockstep, takeoff=not args.no_takeoff, backend=args.backend)
    code = exit_code(m.get("flight", {}).get("ended_by", "internal_error"))
    print(summary_line(m, out_dir, code), file=sys.stderr, flush=True)
    return code


def summary_line(m: dict[str, Any], out_dir: Path, code: int) -> str:
    """The one line ``slung fly`` always ends with on stderr: how the flight ended, its exit code, and whether
    every output was written (an output that failed is reported here, apart from the flight's result)."""
    fl = m.get("flight", {})
    failed = m.get("outputs", {}).get("failed", [])
    outputs = f"outputs incomplete: {'; '.join(failed)}" if failed else f"outputs in {out_dir}"
    return f"slung fly: {fl.get('ended_by', 'unknown')} (exit {code}), vehicle {fl.get('end_state', '?')}; {outputs}"
