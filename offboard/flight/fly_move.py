"""``slung fly --move X,Y,Z``: a move as a user gives it (the goal, and ``--arrive-by`` / ``--max-accel`` /
``--max-speed``), planned before anything connects (``offboard.control.move_planning``) against the same limits as
the pre-flight check, and written into the run folder as an explicit trajectory file (``move.toml``, kind ``move``),
which the flight then flies and ``slung replay`` reads back. Positions in m (x north, y west of where control
starts, z above the take-off point), times in s.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from estimators.errors import UserError
from estimators.model.vehicle import Vehicle
from offboard.control.feasibility import FeasibilityLimits
from offboard.control.move_planning import MovePlan, plan_move
from offboard.flight.command_mapping import MappingConfig
from offboard.flight.flight_law import torque_law_params
from offboard.logs.runlog import Scenario
from offboard.outputs import write_text_atomic

#: the rest at the start before the move, s (the bench's and the tests' moves too)
REST_BEFORE_S = 2.0
#: the rest at the goal after the move when --duration does not say, s
REST_AFTER_S = 5.0
MOVE_FILE = "move.toml"


def parse_goal(text: str) -> tuple[float, float, float]:
    """``"3,0,2"`` -> (3.0, 0.0, 2.0); UserError (one line) for anything else."""
    try:
        vals = tuple(float(v) for v in text.split(","))
    except ValueError:
        vals = ()
    if len(vals) != 3 or not all(math.isfinite(v) for v in vals):
        raise UserError(f"--move: expected X,Y,Z in metres (e.g. 3,0,2), got {text!r}")
    return vals  # type: ignore[return-value]


def check_move_options(args: argparse.Namespace) -> None:
    """--arrive-by / --max-accel / --max-speed belong to --move: a UserError when given without it."""
    if getattr(args, "move", None) is None:
        for opt in ("arrive_by", "max_accel", "max_speed"):
            if getattr(args, opt, None) is not None:
                raise UserError(f"--{opt.replace('_', '-')} applies to --move only")


def move_limits(vehicle: Vehicle, args: argparse.Namespace) -> FeasibilityLimits:
    """The pre-flight check's limits as ``slung fly`` builds them before the connection (the torque-level law's
    thrust and torque, the default mapping's tilt and rate clips, ``--swing-limit``)."""
    params = torque_law_params(vehicle, "smooth", 1.0)
    mapping = MappingConfig(output=getattr(args, "output", "attitude"), mask=getattr(args, "mask", None) or "attitude")
    return FeasibilityLimits.from_config(params, mapping, getattr(args, "swing_limit", 0.8))


def move_file_text(plan: MovePlan, start: tuple[float, ...], goal: tuple[float, ...], hold: float) -> str:
    """The plan as a trajectory file (kind ``move``, every number written in full)."""
    p = plan.profile
    return (
        f'# slung fly --move: {plan.describe()}\nkind = "move"\n'
        f"from = [{start[0]!r}, {start[1]!r}, {start[2]!r}]\nto = [{goal[0]!r}, {goal[1]!r}, {goal[2]!r}]\n"
        f"time = {p.duration!r}\nramp = {p.ramp!r}\ncruise = {p.cruise!r}\nramp_order = {p.ramp_order}\n"
        f"t_start = {plan.t_start!r}\nhold = {hold!r}\n"
    )


def move_scenario(args: argparse.Namespace, vehicle: Vehicle, quiet: bool = False) -> tuple[Scenario, float]:
    """Plan ``--move`` on ``vehicle``, write ``move.toml`` into ``args.out`` (and point ``args.trajectory`` at it, so
    that the run records it for replay), and return the scenario and the flight's duration (s): ``--duration`` if
    given (at least the move's end), else the rest before, the move and :data:`REST_AFTER_S`."""
    goal = parse_goal(args.move)
    start = (0.0, 0.0, goal[2])
    plan = plan_move(
        start,
        goal,
        vehicle,
        move_limits(vehicle, args),
        arrive_by=args.arrive_by,
        max_accel=args.max_accel,
        max_speed=args.max_speed,
        t_start=REST_BEFORE_S,
        hold=REST_AFTER_S,
        force=bool(getattr(args, "force", False)),
    )
    end = plan.arrival
    duration = args.duration if args.duration is not None else end + REST_AFTER_S
    if duration < end:
        raise UserError(f"--duration {duration:g} s ends before the move arrives ({end:.2f} s): give at least that")
    if not quiet:
        print(f"slung fly: {plan.describe()}", file=sys.stderr)
        if not plan.feasible:
            print(f"slung fly: flown anyway (--force): {plan.why}", file=sys.stderr)
    path = Path(args.out) / MOVE_FILE
    write_text_atomic(path, move_file_text(plan, start, goal, duration - end))
    args.trajectory = str(path)
    name = f"trajectory:{MOVE_FILE}"
    desc = f"move to {args.move} (x north, y west, z height; m) in {plan.profile.duration:.3g} s"
    return Scenario(name, desc, duration, plan.reference.replace(duration=duration)), duration


__all__ = ["move_scenario", "parse_goal"]
