"""``slung compare --scenario NAME [--controllers a,b,...] --out DIR``: the controllers side by side on the same
runs (``offboard.harness.compare``); docs/compare.md."""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from pathlib import Path
from typing import Any

from estimators.errors import UserError
from estimators.model.vehicle import load_vehicle
from offboard.cli_args import add_seed_argument, add_vehicle_argument
from offboard.control.controllers import registry
from offboard.control.options import Switching, values
from offboard.harness import compare, compare_mavlink
from offboard.harness.demo_cli import add_flavor_argument
from offboard.logs.runlog import SimConfig
from offboard.outputs import prepare_output_dir, write_atomic
from sim_bridge.plant.sensors import PRESETS as SENSOR_PRESETS


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--scenario", required=True, metavar="NAME", help=f"scenario: {', '.join(compare.COMPARE_SCENARIOS)}"
    )
    p.add_argument(
        "--controllers",
        metavar="LIST",
        help=f"comma-separated controllers (default: all: {', '.join(registry.CONTROLLERS)})",
    )
    add_vehicle_argument(p)
    p.add_argument(
        "--estimator",
        choices=("truth", "kf"),
        default="kf",
        help="kf (default): the Kalman filter on simulated sensors; truth: every controller sees the true state",
    )
    p.add_argument(
        "--sensors", choices=SENSOR_PRESETS, default="px4-typical", help="sensor models for kf (default px4-typical)"
    )
    p.add_argument("--no-load-sensor", action="store_true", help="no cable-angle sensor (swing from the accelerometer)")
    p.add_argument("--switching", choices=values(Switching), default="sign", help="switching of the smc law")
    add_seed_argument(p)
    p.add_argument(
        "--mavlink",
        action="store_true",
        help="fly each controller over MAVLink against the bundled emulator (lockstep, Kalman filter on its "
        "telemetry) instead of simulating it; rest-to-rest and paper only; each flight's folder under DIR/mavlink",
    )
    add_flavor_argument(p, "with --mavlink: the autopilot the emulator imitates")
    p.add_argument("--no-figures", action="store_true", help="write no PNG figures and no report.html")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")


def designs_missing(names: list[str], vehicle: Any, flavour: str = "px4") -> dict[str, str]:
    """The controllers of ``names`` that have no design for ``vehicle`` behind the emulator's ``flavour`` loops (the
    ones they fly through, in process and over MAVLink), with why (``registry.not_designed_for``), each said on
    stderr: they are flown all the same (the comparison shows what they do), and their rows say it."""
    from offboard.harness.emulated_autopilot import emulated_inner_loop

    inner = emulated_inner_loop(vehicle, flavour)
    missing = {}
    for name in names:
        reason = registry.not_designed_for(name, vehicle, inner)
        if reason is not None:
            missing[name] = reason
            print(f"compare: warning: {name}: {reason}", file=sys.stderr)
    return missing


def run(args: argparse.Namespace) -> int:
    the_cases = compare.cases(args.scenario)
    vehicle = load_vehicle(args.vehicle)
    compare.require_load(vehicle)
    if args.mavlink:
        compare_mavlink.check_scenario(args.scenario)
        if args.estimator != "kf" or args.no_load_sensor:
            raise UserError("--mavlink flies with the Kalman filter on the emulator's telemetry, cable angle included")
    names = registry.parse_list(args.controllers)
    no_design = designs_missing(names, vehicle, args.flavor if args.mavlink else "px4")
    feasibility = compare.reference_feasibility(the_cases, vehicle)
    for label, res in feasibility.items():
        for msg in res.messages:  # warnings only, as slung sim gives them: compare is where such a move is explored
            print(f"compare: feasibility check of {label} ({vehicle.name}): {msg}", file=sys.stderr)
    out = prepare_output_dir(args.out)
    config = SimConfig(
        estimator=args.estimator,
        sensors=args.sensors if args.estimator == "kf" else None,
        load_sensor=not args.no_load_sensor,
        seed=args.seed,
    )
    by_case: dict[str, list[compare.CaseResult]] = {}
    total = len(the_cases) * len(names)
    done = 0
    # one line rewritten in place on a terminal; a line per run through a pipe or over MAVLink, whose flights log
    # their own warnings to stderr and would otherwise land in the middle of the progress line
    in_place = sys.stderr.isatty() and not args.mavlink
    for case in the_cases:
        results = []
        for name in names:
            progress = f"  running {case.label}: {name:<15} ({done + 1}/{total})"
            print("\r" + progress if in_place else progress, end="" if in_place else "\n", file=sys.stderr, flush=True)
            if args.mavlink:
                flight = compare_mavlink.demo_args(
                    case,
                    args.scenario,
                    out / "mavlink" / f"{case.scenario.name}-{name}",
                    flavor=args.flavor,
                    sensors=args.sensors,
                    seed=args.seed,
                    vehicle=args.vehicle,
                )
                results.append(compare_mavlink.run_case(case, name, vehicle, flight, switching=args.switching))
            else:
                results.append(compare.run_case(case, name, vehicle, config, switching=args.switching))
            if name in no_design:
                results[-1].figures["not_designed_for_vehicle"] = no_design[name]
            done += 1
        by_case[case.label] = results
    if in_place:
        print("\r" + " " * 70 + "\r", end="", file=sys.stderr, flush=True)
    for results in by_case.values():
        print(compare.format_table(results))
        print()
    main = by_case[the_cases[0].label]
    summary = {r.controller: r.figures for r in main}
    _write_json(out / "compare.json", summary)
    _write_json(
        out / "compare_cases.json",
        {
            "scenario": args.scenario,
            "config": {
                "estimator": args.estimator,
                "sensors": config.sensors,
                "load_sensor": config.load_sensor,
                "mavlink": bool(args.mavlink),
                "flavor": args.flavor if args.mavlink else None,
            },
            "cases": {label: {r.controller: r.figures for r in rs} for label, rs in by_case.items()},
            # controllers flown on a vehicle they have no design for, and why (registry.not_designed_for)
            "not_designed_for_vehicle": no_design,
            # each case's reference against the vehicle's limits before any flight (compare.reference_feasibility)
            "reference_feasibility": {
                label: {"feasible": res.feasible, "messages": list(res.messages)} for label, res in feasibility.items()
            },
        },
    )
    rows = [r for rs in by_case.values() for r in compare.series_rows(rs)]
    write_atomic(out / "compare_series.csv", lambda p: _write_csv(p, rows))
    if not args.no_figures:
        from offboard.report.compare_report import write_figures

        write_figures(out, by_case)
    print(f"compare: {out}")
    return 0


def finite_or_null(obj: Any) -> Any:
    """``obj`` with every non-finite float (a diverged run's effort or error) replaced by None: strict JSON (``null``)
    instead of the ``Infinity`` / ``NaN`` that JSON does not have; the table printed beside it shows ``inf``."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: finite_or_null(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_or_null(v) for v in obj]
    return obj


def _write_json(path: Path, obj: Any) -> None:
    text = json.dumps(finite_or_null(obj), indent=2, sort_keys=False, allow_nan=False)
    write_atomic(path, lambda p: p.write_text(text + "\n", encoding="utf-8"))


def _write_csv(path: Path, rows: list[list[Any]]) -> None:
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["case", "controller", *compare.SERIES_COLUMNS])
        w.writerows(rows)
