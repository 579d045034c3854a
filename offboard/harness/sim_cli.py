"""``slung sim``: run a scenario in one process and write metrics, time series and figures.

Usage: ``slung sim (--scenario NAME | --trajectory FILE) [--switching sign|smooth] [--epsilon E] [--duration S]
[--seed N] [--sensors ideal|px4-typical|px4-fast] [--estimator truth|kf|kf-torque] [--no-load-sensor] [--vehicle FILE]
--out DIR`` (all options: ``docs/usage.md``).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

from estimators.errors import UserError
from estimators.model.vehicle import load_vehicle
from offboard.cli_args import (
    add_controller_arguments,
    add_controller_choice,
    add_feedforward_argument,
    add_no_figures_argument,
    add_seed_argument,
    chosen_controller,
    feedforward_tuning,
    positive_float,
)
from offboard.control import smc
from offboard.control.boundary_layers import FLIGHT_LAYER_ERRORS
from offboard.control.scenarios import SCENARIOS, make_scenario
from offboard.harness import sim as sim_mod
from offboard.logs.runlog import PlantSetup, Scenario
from offboard.outputs import prepare_output_dir
from offboard.report import metrics as metrics_mod
from sim_bridge.plant.sensors import PRESETS as SENSOR_PRESETS


def configure(p: argparse.ArgumentParser) -> None:
    """Arguments of ``slung sim``."""
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--scenario", metavar="NAME", help=f"scenario to run: {', '.join(SCENARIOS)}")
    g.add_argument(
        "--trajectory",
        metavar="FILE",
        help="trajectory file (TOML, docs/references.md): the vehicle starts at rest at its start, no disturbance",
    )
    add_controller_arguments(p)
    add_controller_choice(
        p,
        "smc, the paper's torque-level law as --switching / --epsilon / --layers / --motor-lag set it (any other "
        "as slung compare flies it)",
    )
    p.add_argument("--duration", type=positive_float, metavar="S", help="simulated time in s (default: the scenario's)")
    add_seed_argument(p)
    p.add_argument(
        "--sensors",
        choices=SENSOR_PRESETS,
        default=None,
        help="sensor models feeding the estimator (default: none, the controller sees the true state)",
    )
    p.add_argument(
        "--estimator",
        choices=("truth", "kf", "kf-torque"),
        default="truth",
        help="truth: the controller sees the true state; kf: the Kalman filter on the sensor data (fed by the "
        "measured attitude and accelerometer); kf-torque: the earlier filter that predicts from the commanded torques",
    )
    add_feedforward_argument(p)
    p.add_argument(
        "--no-load-sensor",
        action="store_true",
        help="no cable-angle sensor: the filter observes the swing through the accelerometer",
    )
    p.add_argument(
        "--control-rate",
        type=positive_float,
        default=1000.0,
        metavar="HZ",
        help="controller rate in Hz (default 1000; the plant steps at 1 kHz)",
    )
    p.add_argument(
        "--attitude-model",
        choices=("paper", "rigid"),
        default="paper",
        help="plant rotation: the paper's eq. (13) or the full rigid body (default: paper)",
    )
    p.add_argument(
        "--actuators",
        choices=("ideal", "mixer", "px4"),
        default="ideal",
        help="ideal: the commanded thrust and torques act as in the paper (default); mixer: through "
        "the vehicle's X mixer with motor limits and lag (roll / pitch priority); px4: through PX4's control "
        "allocator (sequential desaturation, airmode off) and motors, what --output actuator meets on PX4",
    )
    p.add_argument(
        "--layers",
        action="store_true",
        help="with --switching smooth: each loop's boundary layer scaled to its own sliding variable (the sliding "
        "variable of a 2 cm / 0.02 rad error), as slung fly's torque-level law flies by default, instead of --epsilon",
    )
    p.add_argument(
        "--motor-lag",
        action="store_true",
        help="the torque-level law leads over the vehicle's motor time constant (its model of the motors' lag), as "
        "slung fly's torque-level law flies by default; for --actuators mixer / px4, whose motors lag",
    )
    add_no_figures_argument(p)
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (created if needed)")


def run_cli(args: argparse.Namespace) -> dict[str, Any]:
    """Run ``slung sim`` and return its metrics (used by tests and the demo)."""
    from offboard.report import report

    out_dir = prepare_output_dir(args.out)
    vehicle = load_vehicle(args.vehicle)
    scenario = (
        make_scenario(args.scenario, duration=args.duration, seed=args.seed)
        if args.scenario
        else trajectory_scenario(args.trajectory, args.duration, args.seed)
    )
    plant_dt = 0.001
    n_sub = round(1.0 / (args.control_rate * plant_dt))
    if n_sub < 1 or abs(n_sub * plant_dt * args.control_rate - 1.0) > 1e-9:
        raise UserError(
            "--control-rate must divide the 1 kHz plant rate (e.g. 1000, 500, 250, 200, 100), "
            f"got {args.control_rate:g}"
        )
    if args.estimator in ("kf", "kf-torque") and args.sensors is None:
        args.sensors = "px4-typical"
    tuning = feedforward_tuning(args, args.estimator)
    config = sim_mod.SimConfig(
        plant_dt=plant_dt,
        control_rate=args.control_rate,
        attitude_model=args.attitude_model,
        sensors=args.sensors,
        estimator=args.estimator,
        load_sensor=not args.no_load_sensor,
        seed=args.seed,
        actuators=args.actuators,
    )
    if args.layers and args.switching != "smooth":
        raise UserError("--layers sets the boundary layers of --switching smooth: add --switching smooth")
    layer_errors = FLIGHT_LAYER_ERRORS if args.layers else None
    params = smc.ControllerParams.for_vehicle(
        vehicle,
        switching=args.switching,
        epsilon=args.epsilon,
        layer_errors=layer_errors,
        actuation_lag_s=vehicle.motor_time_constant if args.motor_lag else 0.0,
    )
    _print_feasibility(scenario, vehicle, params)
    name = chosen_controller(args) or "smc"
    controller = None
    if name != "smc" and (args.layers or args.motor_lag):
        raise UserError(f"--layers and --motor-lag configure the sliding-mode law smc: not with --controller {name}")
    if name != "smc":  # a controller of the registry, flown as slung compare flies it
        from offboard.harness.compare import controller_as_flown

        config, controller = controller_as_flown(name, vehicle, config, switching=args.switching, epsilon=args.epsilon)
    progress = _progress_printer() if sys.stderr.isatty() else None
    log = sim_mod.run(scenario, vehicle, params, config, progress=progress, tuning=tuning, controller=controller)
    m = metrics_mod.compute(log)
    m["config"]["controller"] = name
    m["config"]["external_feedforward"] = tuning is not None
    m["config"]["switching"] = args.switching
    m["config"]["epsilon"] = args.epsilon if args.switching == "smooth" and not args.layers else None
    m["config"]["layer_errors"] = list(layer_errors) if layer_errors else None
    m["config"]["actuation_lag_s"] = params.actuation_lag_s or None
    report.write_report(log, m, out_dir, figures=not args.no_figures, command="sim")
    print(f"scenario {scenario.name}: {scenario.description}; controller {name}")
    print(metrics_mod.format_table(m))
    print(f"report: {out_dir.resolve()}")
    return m


def trajectory_scenario(path: str, duration: float | None, seed: int) -> Scenario:
    """A trajectory file as a scenario: the vehicle at rest at the reference's start (position, height,
    heading), the load hanging still below it, no disturbance; ``duration`` defaults to the file's."""
    from offboard.control.trajectory_file import load_trajectory_file

    ref = load_trajectory_file(path)
    dur = duration or ref.duration
    if not math.isfinite(dur) or dur <= 0:
        raise UserError(f"{path}: the trajectory has no duration: give --duration")
    r0 = ref.sample(0.0)
    return Scenario(
        f"trajectory:{Path(path).name}",
        f"trajectory file {path}",
        dur,
        ref,
        setup=PlantSetup(position=(r0.fx[0], r0.fy[0], r0.z[0]), heading=r0.psi[0], seed=seed),
    )


def _print_feasibility(scenario: Scenario, vehicle: Any, params: smc.ControllerParams) -> None:
    """The pre-flight feasibility check's findings (``offboard.control.feasibility``), as warnings only: a simulation is
    where an infeasible reference may be explored."""
    from offboard.control.feasibility import FeasibilityLimits, check_reference

    res = check_reference(scenario.reference, scenario.duration, vehicle, FeasibilityLimits.from_config(params))
    for msg in res.messages:
        print(f"feasibility check: {msg}", file=sys.stderr)


def _progress_printer() -> Any:
    def show(fraction: float) -> None:
        width = 30
        done = int(fraction * width)
        sys.stderr.write(f"\r[{'#' * done}{'.' * (width - done)}] {100 * fraction:5.1f}%")
        sys.stderr.flush()
        if fraction >= 0.999:
            sys.stderr.write("\n")

    return show


def run(args: argparse.Namespace) -> int:
    """Entry point of ``slung sim``; 0 when the run completed with finite values, 1 otherwise."""
    m = run_cli(args)
    if sys.stderr.isatty():
        sys.stderr.write("\n")
    return 0 if (m["completed"] and m["all_finite"]) else 1
