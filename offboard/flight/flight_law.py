"""Which sliding-mode law a flight flies, and with what: ``--law auto`` resolved for the vehicle and output, the
switching (``--switching`` / ``--epsilon``) resolved per law, the torque-level law's flight parameters (X-frame
shared roll / pitch limit, per-loop boundary layers, the motors' lag designed in) and the attitude-level law's
gain overrides from the vehicle file. What is resolved is written back into ``args`` so that ``metrics.json``
records it and ``slung replay`` rebuilds the same law. The nominal feasibility check of the reference for the
vehicle (:func:`check_feasibility`), and the law and filter rebuilt for the load identified in flight
(:func:`rebuild_for_vehicle`)."""

from __future__ import annotations

import argparse
import copy
import sys
from dataclasses import dataclass
from typing import Any

from estimators.errors import UserError
from estimators.model.vehicle import Vehicle
from offboard.cli_args import feedforward_tuning
from offboard.control import smc, smc_attitude
from offboard.control.boundary_layers import FLIGHT_LAYER_ERRORS
from offboard.control.controllers.registry import drag_in_law
from offboard.flight.command_mapping import CommandMapper, MappingConfig
from offboard.flight.loop_records import LoopConfig
from offboard.logs.runlog import Scenario


def resolve_switching(args: argparse.Namespace, law: str, vehicle: Vehicle) -> smc.ControllerParams:
    """``--switching`` / ``--epsilon`` for the flight's law, written back into ``args`` (recorded for replay, with
    ``args.layer_errors``), and the torque-level law's parameters. Default: smooth switching for both laws; the
    torque-level law's with each loop's own boundary layer (``boundary_layers.error_boundary_layers``) unless
    ``--epsilon`` gives the paper's one width for all. The paper's sign(.) chattered the roll / pitch torque on the
    filter's noise, into the torque limits under the paper's disturbances, and swung the load up in 4 of 14 seeds
    of ``slung demo`` (1 of 14 with the layers; docs/model.md C-12)."""
    if getattr(args, "switching", None) is None:
        args.switching = "smooth"
    layered = args.switching == "smooth" and getattr(args, "epsilon", None) is None and law == "torque"
    args.layer_errors = list(FLIGHT_LAYER_ERRORS) if layered else None
    if getattr(args, "epsilon", None) is None:
        args.epsilon = 1.0
    params = torque_law_params(vehicle, args.switching, args.epsilon, layered, motor_lag=law == "torque")
    args.actuation_lag_s = params.actuation_lag_s if law == "torque" else None
    return params


def torque_law_params(
    vehicle: Vehicle, switching: str, epsilon: float, layered: bool = False, *, motor_lag: bool = False
) -> smc.ControllerParams:
    """The torque-level law a flight uses: the paper's, with the vehicle's limits, and on an X frame the roll and
    pitch torques limited together (``shared_roll_pitch``): every motor takes part in both, so a pair at the corner
    of the per-axis box is one the motors cannot give, and PX4's allocator (sequential desaturation, roll before
    pitch) then cut the roll torque alone; at 30 % packet loss that swung the load up in world y, the roll axis, in
    12-16 of 64 hovers (3-4 with this limit; docs/estimation.md section 0.3). ``layered``: each loop's own
    boundary layer (``boundary_layers.FLIGHT_LAYER_ERRORS``) instead of ``epsilon`` for the smooth switching.

    ``motor_lag`` (a flight's default): the law leads over the vehicle's ``motor_time_constant_s``, the lag through
    which the flight's filter is given the torque (``ActuatorLag``); docs/model.md C-13."""
    return smc.ControllerParams.for_vehicle(
        vehicle,
        switching=switching,
        epsilon=epsilon,
        shared_roll_pitch=vehicle.frame == "x",
        layer_errors=FLIGHT_LAYER_ERRORS if layered else None,
        actuation_lag_s=vehicle.motor_time_constant if motor_lag else 0.0,
    )


def resolve_law(law: str | None, output: str, vehicle: Vehicle) -> str:
    """``--law auto`` -> ``attitude`` or ``torque`` (see the option's help); the others as given."""
    if law not in (None, "auto"):
        return law
    if output != "attitude":
        return "torque"
    if smc_attitude.robust_gains_exist(vehicle, smc_attitude.InnerLoop()):
        return "attitude"
    # a load swinging faster than the autopilot's attitude loop (docs/model.md §12.5); the start line names the law
    return "torque"


#: the ``args`` fields :func:`resolve_switching` and ``fly`` record for ``slung replay``, per law
RECORDED_LAW_FIELDS = ("law", "switching", "epsilon", "layer_errors", "actuation_lag_s", "shared_roll_pitch")


@dataclass(frozen=True)
class TorqueFallback:
    """What ``--law auto`` flies instead of the attitude-level law it chose on PX4's default attitude loop (the
    only loop known before the connection) if the autopilot's own loop, read before the take-off, leaves that law
    no robust gains: the torque-level law's flight parameters, and the ``args`` fields to record then
    (``RECORDED_LAW_FIELDS``, so that ``metrics.json`` and ``slung replay`` name the law that flew)."""

    params: smc.ControllerParams
    record: dict[str, Any]


def torque_fallback(args: argparse.Namespace, vehicle: Vehicle) -> TorqueFallback:
    """The torque-level law as ``fly`` would resolve it for ``--law torque`` with the same options (``args`` is
    left as it is)."""
    alt = copy.copy(args)
    alt.law = "torque"
    params = resolve_switching(alt, "torque", vehicle)
    alt.shared_roll_pitch = params.shared_roll_pitch
    return TorqueFallback(params, {name: getattr(alt, name, None) for name in RECORDED_LAW_FIELDS})


def vehicle_gain_overrides(vehicle: Vehicle) -> dict[str, float]:
    """The attitude-level law's gains set in the vehicle file's ``[gains]`` table (UserError for an unknown name)."""
    known = smc_attitude.GAIN_NAMES
    for name, _ in vehicle.gains:
        if name not in known:
            raise UserError(f"vehicle file: unknown gain {name!r} in [gains] (known: {', '.join(known)})")
    return dict(vehicle.gains)


def attitude_law_params(
    vehicle: Vehicle, args: argparse.Namespace, mapping: MappingConfig
) -> smc_attitude.AttitudeParams:
    """The attitude-level law's parameters for ``vehicle`` as ``slung fly`` flies it: the file's ``[gains]``, the
    command line's switching and feed-forward, the mapping's tilt limit (rad)."""
    return smc_attitude.AttitudeParams.for_vehicle(
        vehicle,
        overrides=vehicle_gain_overrides(vehicle),
        switching=args.switching,
        tilt_max=mapping.max_tilt,
        drag_feedforward=drag_in_law(feedforward_tuning(args)),
    )


def rebuild_for_vehicle(
    vehicle: Vehicle,
    attitude: bool,
    args: argparse.Namespace,
    law: str,
    mapping: MappingConfig,
    scenario: Scenario,
    duration: float,
    mapper: CommandMapper,
    cfg: LoopConfig,
    load_sensor: bool,
    tuning: Any,
    quiet: bool,
) -> tuple[Any, Any]:
    """The law's parameters (attitude level when ``attitude``, else torque level) and the filter's factory for
    ``vehicle`` (the load identified in flight), built as :func:`fly` builds them for the vehicle file, after the
    nominal feasibility check for it (a UserError when the reference is beyond it, unless ``--force``: the flight
    then ends in the autopilot's hold). ``args``' recorded switching and layers are the flown vehicle's."""
    from estimators.filters.factory import make_estimator

    torque_params = resolve_switching(args, law, vehicle)
    args.feasibility_identified = check_feasibility(
        scenario, duration, vehicle, torque_params, mapper, cfg, args, quiet
    )
    params: Any = torque_params
    if attitude:
        params = attitude_law_params(vehicle, args, mapping)

    def factory(delay_s: float = cfg.base_filter_delay_s) -> Any:
        return make_estimator("kf", vehicle, load_sensor=load_sensor, rate_hz=args.rate, delay_s=delay_s, tuning=tuning)

    return params, factory


def check_feasibility(
    scenario: Scenario,
    duration: float,
    vehicle: Vehicle,
    params: smc.ControllerParams,
    mapper: CommandMapper,
    cfg: LoopConfig,
    args: argparse.Namespace,
    quiet: bool,
) -> dict[str, Any]:
    """The nominal pre-flight check of the reference (``offboard.control.feasibility``), before anything connects: a
    reference the vehicle cannot fly even in theory is a UserError unless ``--force``; warnings are printed.
    Returns the summary recorded in ``metrics.json`` (``feasibility``)."""
    from offboard.control.feasibility import FeasibilityLimits, check_reference

    limits = FeasibilityLimits.from_config(params, mapper.config, cfg.swing_limit_rad)
    res = check_reference(scenario.reference, duration, vehicle, limits)
    force = bool(getattr(args, "force", False))
    if not res.feasible and not force:
        raise UserError(
            f"{scenario.name}: {res.messages[0]} (nominal pre-flight check, docs/references.md; "
            "--force flies it anyway)"
        )
    if not quiet:
        for d in res.violations:  # only here with --force
            print(f"pre-flight check: beyond the vehicle's limits (flown anyway, --force): {d.why}", file=sys.stderr)
        for d in res.warnings:  # flyable, with an action the user can take (the text says which)
            print(f"pre-flight check, note: {d.why}", file=sys.stderr)
    return {
        "feasible": res.feasible,
        "forced": force and not res.feasible,
        "messages": list(res.messages),
        "peaks": {d.name: d.peak for d in res.demands},
    }
