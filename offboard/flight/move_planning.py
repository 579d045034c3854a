"""``slung fly`` with a ``kind = "move"`` trajectory (``offboard.control.reference_move``): its corners planned
against the vehicle's pre-flight check before anything connects, or, when the asked arrival time cannot be flown,
a one-line refusal that says why and proposes the fastest feasible time."""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace

from estimators.errors import UserError
from estimators.model.vehicle import Vehicle
from offboard.control import smc
from offboard.flight.command_mapping import CommandMapper
from offboard.flight.loop import LoopConfig
from offboard.logs.runlog import Scenario


def plan_user_move(
    scenario: Scenario,
    vehicle: Vehicle,
    params: smc.ControllerParams,
    mapper: CommandMapper,
    cfg: LoopConfig,
    args: argparse.Namespace,
    quiet: bool,
) -> Scenario:
    """A ``kind = "move"`` trajectory without a fixed ramp: the corners the pre-flight check lets closest to the
    physical bound (``offboard.control.reference_move.plan_move``). When the asked arrival time cannot be flown, a
    UserError says why and proposes the fastest feasible one (``--force`` flies the asked time, smoothest corners).
    Anything else is returned unchanged."""
    from offboard.control.feasibility import FeasibilityLimits, check_reference
    from offboard.control.reference_move import RAMPS, MoveReference, peak_over_bound, plan_move

    ref = scenario.reference
    if not isinstance(ref, MoveReference) or ref.ramp_given:
        return scenario
    limits = FeasibilityLimits.from_config(params, mapper.config, cfg.swing_limit_rad)

    def feasible(r: MoveReference) -> str | None:
        res = check_reference(r, r.duration, vehicle, limits)
        return None if res.feasible else res.messages[0]

    spec = ref.spec
    plan = plan_move(spec, feasible)
    asked = f"{spec.distance:g} m in {spec.arrive_by:g} s"
    if plan.reference is not None:
        if not quiet:
            print(
                f"move: {asked}, corners {plan.ramp:g} of the move's time: peak acceleration "
                f"{plan.reference.peak_acceleration:.2f} m/s^2, {peak_over_bound(plan.ramp or RAMPS[-1]):.2f}x the "
                "physical bound's",
                file=sys.stderr,
            )
        return replace(scenario, reference=plan.reference)
    if getattr(args, "force", False):
        return scenario  # the asked time with the smoothest corners; check_feasibility says what is beyond
    if plan.fastest_s is None:
        raise UserError(f"{scenario.name}: {asked} cannot be flown ({plan.why}), nor any slower move up to 120 s")
    raise UserError(
        f"{scenario.name}: {asked} cannot be flown ({plan.why}); the fastest feasible arrival is "
        f"{plan.fastest_s:g} s (arrive_by = {plan.fastest_s:g}; --force flies the asked time anyway)"
    )


__all__ = ["plan_user_move"]
