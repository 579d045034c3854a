"""``slung compare --mavlink``: each controller flown over MAVLink against the bundled emulator in lockstep, on the
same cases as in simulation, measured by the same figures (``offboard.harness.compare.case_figures``).

Each run is a ``slung demo`` flight (``offboard.harness.demo_cli.run_demo``: the emulator in a thread of this
process, real UDP on 127.0.0.1, the Kalman filter on the emulator's telemetry, lockstep) whose reference is the
case's: take-off, approach to the reference's start, the case flown under offboard control, hand-over. The
sliding-mode laws fly as ``slung fly`` flies them (``smc``: ``--law torque``; ``smc-attitude``: ``--law
attitude``, gains following the autopilot's loops). The position-level baselines (``cascade``, ``zv``, ``zvd``,
``swing-feedback``) send what a stock autopilot's position controller hands its attitude controller: the attitude
setpoint and the collective thrust of their own position / velocity loops, the autopilot's attitude and rate loops
doing the rest; ``lqr``, a torque-level law, is mapped to attitude setpoints as the torque-level ``smc``; any other
controller by the level it commands at, as ``slung fly --controller`` flies it
(``offboard.control.controllers.flight_output``). The figures are computed on the emulator's true plant state,
in the case's own coordinates (the flight's reference is shifted to where the vehicle was at the start of control;
the shift is taken out again).

Cases the emulator cannot reproduce are refused: the released swing of ``hover`` (the vehicle takes off with the
load hanging) and the ``gust`` (the emulator knows the paper's disturbances only).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from estimators.errors import UserError
from estimators.model.vehicle import Vehicle
from offboard.control.controllers import registry
from offboard.control.controllers.flight_output import as_flown
from offboard.harness import compare
from offboard.logs.runlog import COL, SimLog

#: the compare scenarios a MAVLink run can fly, and the emulator's disturbance for each
MAVLINK_SCENARIOS: dict[str, str] = {"rest-to-rest": "none", "paper": "paper"}
#: the horizontal position columns of a flight's log, shifted back by the flight's origin
_HORIZONTAL = (("x", "y"), ("load_x", "load_y"), ("Fx", "Fy"), ("Fx_ref", "Fy_ref"))


def check_scenario(name: str) -> None:
    """UserError when compare scenario ``name`` cannot be flown against the emulator."""
    if name not in MAVLINK_SCENARIOS:
        raise UserError(
            f"--mavlink flies {', '.join(MAVLINK_SCENARIOS)} only: the emulator cannot start {name!r} as the "
            "simulation does (a released swing, a gust of its own)"
        )


def demo_args(
    case: compare.Case, scenario_name: str, out: Path, *, flavor: str, sensors: str, seed: int, vehicle: str | None
) -> argparse.Namespace:
    """The ``slung demo`` options of one MAVLink run of ``case`` (lockstep, no figures, the case's duration)."""
    from offboard.harness.demo_cli import configure

    p = argparse.ArgumentParser()
    configure(p)
    argv = [
        "--flavor",
        flavor,
        "--duration",
        repr(case.scenario.duration),
        "--sensors",
        sensors,
        "--seed",
        str(seed),
        "--disturbance",
        MAVLINK_SCENARIOS[scenario_name],
        "--no-figures",
        "--out",
        str(out),
    ]
    if vehicle:
        argv += ["--vehicle", vehicle]
    return p.parse_args(argv)


def run_case(
    case: compare.Case,
    controller: str,
    vehicle: Vehicle,
    args: argparse.Namespace,
    *,
    switching: str = "sign",
    epsilon: float = 1.0,
) -> compare.CaseResult:
    """Fly ``case`` with ``controller`` against the emulator; ``args``: the demo options (:func:`demo_args`).
    The flight's report folder is ``args.out``."""
    from offboard.harness.demo_cli import run_demo

    # the filter tuning the row flies with in simulation (the sliding-mode rows feed the filter's external
    # acceleration forward, and the attitude-level law then leaves the drag to it): the same over the wire
    args.external_feedforward = registry.filter_tuning(controller, "kf") is not None
    law = None
    if controller == "smc":
        args.law, args.switching, args.epsilon = "torque", switching, epsilon
    elif controller == "smc-attitude":
        args.law = "attitude"  # its own default switching (smooth), as slung fly --law attitude
    else:
        law, args.law = as_flown(registry.make(controller, vehicle), args.output)
    logs: list[SimLog] = []
    m, _, _ = run_demo(args, quiet=True, scenario=case.scenario, controller=law, on_log=logs.append)
    if not logs:
        raise RuntimeError(f"{controller} on {case.label}: the flight logged no tick ({m['flight']['ended_by']})")
    log = logs[0]
    ox, oy = m["config"]["origin_xy"]
    for cx, cy in _HORIZONTAL:  # back into the case's coordinates (the reference was shifted to the vehicle)
        log.data[:, COL[cx]] -= ox
        log.data[:, COL[cy]] -= oy
    figures = compare.case_figures(case, log)
    figures["completed"] = bool(m["flight"]["ended_by"] == "completed" and m.get("all_finite", False))
    figures["ended_by"] = m["flight"]["ended_by"]
    return compare.CaseResult(controller, case, figures, log)


__all__ = ["MAVLINK_SCENARIOS", "check_scenario", "demo_args", "run_case"]
