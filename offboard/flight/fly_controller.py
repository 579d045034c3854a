"""The controller ``slung fly`` flies, from ``--controller`` (and ``--law``): the sliding-mode law by default, or
another controller of the registry as it flies over ``--output``."""

from __future__ import annotations

import argparse
from typing import Any

from estimators.errors import UserError
from offboard.cli_args import chosen_controller, feedforward_tuning
from offboard.control.controllers.registry import drag_in_law


def controller_from_args(args: argparse.Namespace, vehicle: Any) -> Any:
    """The controller ``--controller`` names for the flight (None: the sliding-mode law ``--law`` picks, the
    default; ``smc-attitude`` sets ``--law attitude``), as it flies over ``--output``
    (``offboard.control.controllers.flight_output.as_flown``; ``args.law`` set to the level that maps its commands).
    UserError for an unknown name, a controller that cannot fly ``--output``, or one given with a ``--law`` that
    is not its own."""
    name = chosen_controller(args)
    asked_law = getattr(args, "law", "auto")
    if name in (None, "smc"):
        return None
    if name == "smc-attitude":
        if asked_law == "torque":
            raise UserError("--controller smc-attitude is the attitude-level law: not with --law torque")
        args.law = "attitude"
        return None
    if asked_law not in (None, "auto"):
        raise UserError(f"--law picks the sliding-mode law's level: not with --controller {name}")
    from offboard.control.controllers.flight_output import registered_as_flown

    flown, args.law = registered_as_flown(
        name,
        vehicle,
        args.output,
        switching=getattr(args, "switching", None) or "smooth",
        epsilon=getattr(args, "epsilon", None) or 1.0,
        drag_feedforward=drag_in_law(feedforward_tuning(args)),
    )
    return flown


__all__ = ["controller_from_args"]
