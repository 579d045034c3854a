"""``slung replay FILE [--vehicle FILE] [--from T] [--to T] [--out DIR]``: replay a flight log (telemetry ``.tlog``,
PX4 ULog ``.ulg``, ArduPilot DataFlash ``.bin``) through the live loop's estimator and controller
(``offboard.logs.replay``), print what the log holds and write a report.

Exit codes: 0 replayed; 2 bad input (missing, empty or unreadable file, bad options); 3 the log was read but cannot
be replayed (never armed, never off the ground, fixed wing, no position, no attitude, ...), after writing
``metrics.json`` with the reasons (``docs/replay.md``).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

from estimators.errors import UserError
from estimators.model.vehicle import Vehicle, VehicleFileError, load_vehicle, vehicle_from_toml
from offboard.cli_args import (
    OWN_LAWS,
    add_controller_choice,
    add_no_figures_argument,
    add_vehicle_argument,
    chosen_controller,
    finite_float,
)
from offboard.control.options import Switching, values
from offboard.logs.timeseries_file import LIVE_LOG_NAME, table_path, write_table

EXIT_NOT_REPLAYABLE = 3


_time = finite_float  # a time in seconds: any finite number


def _rate(text: str) -> float:
    v = _time(text)
    if not 1.0 <= v <= 5000.0:
        raise argparse.ArgumentTypeError(f"expected a rate between 1 and 5000 Hz, got {text!r}")
    return v


def configure(p: argparse.ArgumentParser) -> None:
    """Arguments of ``slung replay``."""
    p.add_argument(
        "tlog",
        metavar="FILE",
        help="flight log: telemetry (.tlog), PX4 ULog (.ulg) or ArduPilot DataFlash (.bin)",
    )
    add_vehicle_argument(p, "the vehicle the run recorded in the metrics.json beside the log, else the paper's Table 1")
    p.add_argument(
        "--from",
        dest="t_from",
        type=_time,
        metavar="T",
        help="start of the replayed window, vehicle time since boot (s)",
    )
    p.add_argument(
        "--to", dest="t_to", type=_time, metavar="T", help="end of the replayed window, vehicle time since boot (s)"
    )
    p.add_argument("--out", metavar="DIR", help="report folder (default: FILE-replay beside the log)")
    p.add_argument(
        "--rate",
        type=_rate,
        default=250.0,
        metavar="HZ",
        help="estimator tick rate where the log holds no setpoints (default 250; at most the log's fastest "
        "attitude / IMU rate)",
    )
    p.add_argument(
        "--no-load-sensor",
        action="store_true",
        help="ignore the log's cable-angle sensor (estimate the swing from the accelerometer)",
    )
    p.add_argument(
        "--scenario",
        metavar="NAME",
        help="reference the logged flight used (default: from the run's metrics.json beside the log)",
    )
    p.add_argument("--trajectory", metavar="FILE", help="trajectory file the logged flight used (TOML)")
    p.add_argument(
        "--reference-start",
        type=_time,
        metavar="T",
        help="vehicle time (s) at which the reference began (default: where the loop started)",
    )
    p.add_argument(
        "--no-live-log",
        action="store_true",
        help="ignore the live run's tick log (timeseries_live.slts) beside the log (replay from the tlog alone)",
    )
    p.add_argument(
        "--switching",
        choices=values(Switching),
        default=None,
        help="controller switching function (default: the run's, else smooth)",
    )
    add_controller_choice(
        p,
        "the run's (its metrics.json), else the sliding-mode law; smc: the torque-level law, smc-attitude: the "
        "attitude-level one",
    )
    p.add_argument(
        "--estimate-only",
        action="store_true",
        help="run only the estimator, on the --rate grid over the whole log (also outside offboard flight)",
    )
    add_no_figures_argument(p)


def run_metadata(tlog: Path) -> dict[str, Any]:
    """The live run's settings from ``metrics.json`` beside the tlog (written by ``slung fly`` / ``slung demo``),
    or {} when there is none, it cannot be read, or it is a replay's own metrics."""
    path = tlog.parent / "metrics.json"
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    if not isinstance(data, dict) or "replayed" in data or "scenario" not in data:
        return {}
    return data


def recorded_vehicle(cfg: dict[str, Any]) -> Vehicle:
    """The vehicle a live run recorded (``vehicle_toml`` of its ``metrics.json`` config), else the paper's; a
    recorded one that no longer reads is a UserError (``--vehicle`` then says which to use)."""
    text = cfg.get("vehicle_toml")
    if not isinstance(text, str):
        return Vehicle()
    try:
        return vehicle_from_toml(text, source="recorded in the run's metrics.json")
    except VehicleFileError as exc:
        raise UserError(f"{exc}: give --vehicle FILE") from None


def build_config(args: argparse.Namespace, meta: dict[str, Any], live: Any = None) -> Any:
    """The :class:`offboard.logs.replay.ReplayConfig` from the options, completed by the live run's metadata
    (``metrics.json`` of ``slung fly`` / ``slung demo``: scenario, switching, epsilon, output, mask, autopilot
    model, reference origin, rate) and its tick log ``live`` when present."""
    from offboard.logs.replay import ReferenceSpec, ReplayConfig

    cfg = meta.get("config", {}) if isinstance(meta.get("config"), dict) else {}
    vehicle = load_vehicle(args.vehicle) if args.vehicle is not None else recorded_vehicle(cfg)
    scenario = args.scenario or meta.get("scenario")
    reference = None
    if scenario is not None:
        scenario = str(scenario)
        if scenario.startswith("trajectory:") and not args.trajectory:
            scenario = None  # a trajectory file was flown: the one the run recorded, if it is still there
    flown_file = cfg.get("trajectory") if not args.scenario and not args.trajectory else None
    if args.trajectory:
        reference = ReferenceSpec("trajectory", trajectory=str(args.trajectory))
    elif isinstance(flown_file, str) and Path(flown_file).is_file():
        reference = ReferenceSpec("trajectory", trajectory=flown_file)
    elif scenario is not None:
        from offboard.control.scenarios import SCENARIOS

        if scenario not in SCENARIOS:
            raise UserError(f"unknown scenario {scenario!r} (known: {', '.join(SCENARIOS)})")
        reference = ReferenceSpec(scenario)
    if reference is not None:
        origin = cfg.get("origin_xy") if not args.scenario and not args.trajectory else None
        ground_z = cfg.get("ground_z") if not args.scenario and not args.trajectory else None
        # the live loop's smooth stop after the reference's end (offboard.control.reference_stop)
        stop = cfg.get("stop_after_s") if not args.scenario and not args.trajectory else None
        start = args.reference_start  # else the tick plan's own controller time (the loop's t - t0)
        reference = ReferenceSpec(
            reference.scenario,
            float(start) if start is not None else math.nan,
            tuple(origin) if isinstance(origin, list) and len(origin) == 2 else None,
            reference.trajectory,
            float(ground_z) if isinstance(ground_z, (int, float)) and math.isfinite(ground_z) else 0.0,
            float(stop) if isinstance(stop, (int, float)) and math.isfinite(stop) else None,
        )
    if args.t_from is not None and args.t_to is not None and args.t_to <= args.t_from:
        raise UserError(f"--to ({args.t_to:g} s) must be after --from ({args.t_from:g} s)")
    switching = args.switching or cfg.get("switching") or "smooth"
    epsilon = cfg.get("epsilon") or 1.0
    autopilot = cfg.get("autopilot") if isinstance(cfg.get("autopilot"), dict) else None
    load_sensor: bool | None = None
    if args.no_load_sensor:
        load_sensor = False
    elif meta:  # the filter the live run was built with (older runs recorded only estimator_load_sensor)
        load_sensor = bool(cfg.get("load_sensor", cfg.get("estimator_load_sensor", True)))
    rate = float(cfg.get("rate_hz") or args.rate) if meta else args.rate
    delay = cfg.get("delay_s")
    extra = {"delay_s": float(delay)} if isinstance(delay, (int, float)) and delay >= 0 else {}
    scale = cfg.get("gain_scale")
    # the live run's delay schedule (offboard.control.delay_margin)
    if isinstance(scale, (int, float)) and 0.0 < scale <= 1.0:
        extra["gain_scale"] = float(scale)
    # the live run's roll / pitch limit (runs recorded before it existed clipped each axis alone)
    if cfg.get("shared_roll_pitch") is True:
        extra["shared_roll_pitch"] = True
    # the live run's filter fed the external acceleration forward (--external-feedforward)
    if cfg.get("external_feedforward") is True:
        extra["external_feedforward"] = True
    # whether the live run's attitude-level law modelled the vehicle's drag (runs recorded before it: not)
    if meta:
        extra["drag_feedforward"] = cfg.get("drag_feedforward") is True
    # the live run's per-loop boundary layers (runs recorded before them used epsilon for all loops)
    layers = cfg.get("layer_errors")
    if switching == "smooth" and isinstance(layers, list) and len(layers) == 3:
        extra["layer_errors"] = tuple(float(e) for e in layers)
    # the live run's model of the motors' lag (runs recorded before it flew the paper's law, lag 0)
    lag = cfg.get("actuation_lag_s")
    if isinstance(lag, (int, float)) and math.isfinite(lag) and lag > 0.0:
        extra["actuation_lag_s"] = float(lag)
    # the controller: --controller, else the run's; smc / smc-attitude are the sliding-mode law at either level
    controller = chosen_controller(args) or cfg.get("controller")
    law = "attitude" if cfg.get("law") == "attitude" else "torque"
    if controller in OWN_LAWS:
        law = "attitude" if controller == "smc-attitude" else "torque"
        controller = None
    elif controller is not None and not isinstance(controller, str):
        controller = None  # not a name: the run's metrics.json was edited
    elif controller is not None:
        from offboard.control.controllers import registry

        if controller not in registry.CONTROLLERS:
            raise UserError(
                f"the run flew controller {controller!r}, not known here (known: {', '.join(registry.CONTROLLERS)}): "
                "give --controller"
            )
    return ReplayConfig(
        vehicle=vehicle,
        t_from=args.t_from,
        t_to=args.t_to,
        rate_hz=rate,
        load_sensor=load_sensor,
        **extra,
        reference=reference,
        switching=switching,
        epsilon=float(epsilon),
        law=law,
        controller=controller,
        output=cfg.get("output"),
        mask=cfg.get("mask"),
        autopilot=autopilot,
        live=live,
        estimate_only=args.estimate_only,
    )


def _progress_bar() -> Any:
    state = {"last": -1}

    def show(fraction: float) -> None:
        pct = int(100 * fraction)
        if pct == state["last"]:
            return
        state["last"] = pct
        width = 30
        done = int(fraction * width)
        sys.stderr.write(f"\rreplay [{'#' * done}{'.' * (width - done)}] {pct:3d}%")
        if fraction >= 1.0:
            sys.stderr.write("\n")
        sys.stderr.flush()

    return show


def run_replay(args: argparse.Namespace) -> tuple[int, dict[str, Any], Path]:
    """Do the work of ``slung replay``; returns (exit code, metrics, report folder). Used by tests."""
    from offboard.logs import replay as rp
    from offboard.logs.log_formats import log_format_of, scan_dataflash, scan_ulog
    from offboard.logs.replay_partial import PARTIAL_COLUMNS, partial_possible, replay_partial
    from offboard.logs.tlog import TlogReader
    from offboard.outputs import prepare_output_dir, write_json_atomic
    from offboard.report.replay_report import format_summary, write_outputs

    path = Path(args.tlog)
    if not path.exists():
        raise UserError(f"{path}: no such file")
    if path.is_file() and path.stat().st_size == 0:
        raise UserError(f"{path} is empty: not a tlog")
    tty = sys.stderr.isatty()
    wall0 = time.perf_counter()
    fmt = log_format_of(path)
    bar = _progress_bar() if tty and path.stat().st_size > 2_000_000 else None
    rstats: dict[str, Any] | None
    if fmt == "tlog":
        reader = TlogReader.from_path(path)
        if bar is not None:
            reader.progress = lambda f: bar(0.5 * f)
        sc = rp.scan(reader)
        rstats = reader.stats.as_dict()
        if rstats["packets"] == 0:
            raise UserError(
                f"{path} is not a tlog: no MAVLink packet with a valid checksum behind an 8-byte timestamp "
                f"in {rstats['bytes_total']} bytes"
            )
    else:  # an on-board log: the same records from the autopilot's own log (offboard.logs.log_formats)
        sc = scan_ulog(path) if fmt == "ulog" else scan_dataflash(path)
        rstats = None
        if not sc.events:
            raise UserError(f"{path}: a {fmt} log with no attitude, position or IMU record in it")
    meta = run_metadata(path)
    live = None
    live_path = table_path(path.parent, "timeseries_live") or path.parent / LIVE_LOG_NAME
    if meta and not args.no_live_log:
        live = rp.load_live_table(live_path)
    config = build_config(args, meta, live)
    out_dir = prepare_output_dir(args.out or path.with_name(path.stem + "-replay"))
    inv = rp.inventory(sc)
    ok, reasons = rp.replayable(inv)
    print(f"log: {path} ({path.stat().st_size} bytes, {fmt})")
    if not ok and partial_possible(inv, reasons):  # no horizontal position: replay what can be estimated
        data, metrics = replay_partial(sc, inv, config.vehicle)
        metrics["reader"] = rstats
        metrics["speed"] = {"wall_s": time.perf_counter() - wall0}
        write_json_atomic(out_dir / "metrics.json", metrics)
        write_table(out_dir / "timeseries.slts", PARTIAL_COLUMNS, data)
        print(format_summary(metrics, rstats))
        print(f"report: {out_dir.resolve()}")
        return 0, metrics, out_dir
    if not ok:
        metrics = {"log": inv, "reader": rstats, "replayed": False, "reasons": reasons}
        write_json_atomic(out_dir / "metrics.json", metrics)
        print(format_summary(metrics, rstats))
        print(f"not replayed: {'; '.join(reasons)}")
        print(f"report: {out_dir.resolve()}")
        return EXIT_NOT_REPLAYABLE, metrics, out_dir
    try:
        result = rp.replay(sc, inv, config, progress=(lambda f: bar(0.5 + 0.5 * f)) if bar else None)
    except rp.LiveLogMismatchError as exc:
        raise UserError(f"{live_path}: {exc} (use --no-live-log)") from None
    wall = time.perf_counter() - wall0
    result.metrics["reader"] = rstats
    if len(result.data) == 0:  # nothing was flown that the estimator could run on: say why, never "0 ticks"
        why = next((s for s in inv["missing"] if s.startswith("no flight")), None) or (
            "no controller tick and no airborne span with attitude and position to start the estimator from"
        )
        metrics = {**result.metrics, "replayed": False, "reasons": [why]}
        write_json_atomic(out_dir / "metrics.json", metrics)
        print(format_summary(inv_only(metrics), rstats))
        print(f"not replayed: {why}")
        print(f"report: {out_dir.resolve()}")
        return EXIT_NOT_REPLAYABLE, metrics, out_dir
    result.metrics["replayed"] = True
    if "load" not in result.metrics and meta:  # slung's own run: the load its law and filter flew
        from offboard.logs.replay_load import live_run_load

        cfg = meta.get("config") if isinstance(meta.get("config"), dict) else {}
        result.metrics["load"] = live_run_load(config.vehicle, cfg.get("load_identification"))
    span = result.metrics["estimation"].get("vehicle_time_span_s")
    log_s = (span[1] - span[0]) if span else 0.0
    result.metrics["speed"] = {"wall_s": wall, "log_s": log_s, "x_realtime": log_s / wall if wall > 0 else None}
    # the cable the replay's filter used (the identified one, where the load identification found a load)
    cable = ((result.metrics.get("load") or {}).get("estimator_load") or {}).get(
        "cable_m"
    ) or config.vehicle.cable_length
    write_outputs(result, out_dir, figures=not args.no_figures, log_name=path.name, cable_length=cable)
    if not args.no_figures and len(result.data) > 1:
        from offboard.report.replay_report_html import write_replay_html

        title = f"slung replay: {path.name}, {config.vehicle.name} vehicle, kf estimator, {result.output} setpoints"
        write_replay_html(result, out_dir, title, cable)
    print(format_summary(result.metrics, rstats))
    print(f"replayed {log_s:.1f} s of flight in {wall:.2f} s ({log_s / max(wall, 1e-9):.0f}x real time)")
    print(f"report: {out_dir.resolve()}")
    return 0, result.metrics, out_dir


def inv_only(metrics: dict[str, Any]) -> dict[str, Any]:
    """``metrics`` without its estimation sections (for the summary of a log that was not replayed)."""
    return {"log": metrics["log"]}


def run(args: argparse.Namespace) -> int:
    """Entry point of ``slung replay`` (exit codes in the module docstring)."""
    code, _, _ = run_replay(args)
    return code
