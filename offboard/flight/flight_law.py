"""Which sliding-mode law a flight flies, and with what: ``--law auto`` resolved for the vehicle and output, the
switching (``--switching`` / ``--epsilon``) resolved per law, the torque-level law's flight parameters (X-frame
shared roll / pitch limit, per-loop boundary layers, the motors' lag designed in) and the attitude-level law's
gain overrides from the vehicle file. What is resolved is written back into ``args`` so that ``metrics.json``
records it and ``slung replay`` rebuilds the same law."""

from __future__ import annotations

import argparse
import copy
from dataclasses import dataclass
from typing import Any

from estimators.errors import UserError
from estimators.model.vehicle import Vehicle
from offboard.control import smc, smc_attitude
from offboard.control.boundary_layers import FLIGHT_LAYER_ERRORS


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
