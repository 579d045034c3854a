"""Named scenarios: reference + duration, and the plant's start and disturbances as plain numbers. Rationale in
``docs/scenarios.md``.

Plant-free: ``slung fly`` and ``slung replay`` take the reference part (name, description, duration, reference,
arrival and disturbance times) from here without loading the simulator (``sim_bridge``). The simulation part
(initial plant state, disturbances) is only described here (``offboard.logs.runlog.PlantSetup``); the simulation
harness builds it (``offboard.harness.sim.plant_scenario``, called by ``offboard.harness.sim.run``).

- ``paper``: the paper's simulation study (Section 4) as far as its text and figures pin it down: Table 1
  vehicle, 50 s (Table 2's ISE/RMS^2 ratios), hover at 1 m with the load at rest, a smooth climb to 2 m
  during the first 5 s, a heading reference moving during the first 3 s (Fig. 6), from 5 s a figure-eight of
  1.5 m by 0.75 m with a 20 s period entered smoothly from rest (Fig. 5), and from 25 s bounded, band-limited,
  seeded random disturbances (Fig. 7): forces on the vehicle up to 0.5 N on x, y, z and a yaw torque.
- ``rest-to-rest``: an aggressive 3 m move in 2.5 s at 2 m height, then hover: residual swing and settling.
- ``hover``: hold at 1 m with an initial 0.2 rad swing: the swing damping on its own.
- ``circle``: a 1 m radius circle, 10 s period, at 2 m; heading held.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from estimators.errors import UserError
from estimators.model.cable import cable_from_spherical
from offboard.control import reference as ref
from offboard.control import reference_patterns as patterns
from offboard.logs.runlog import PlantSetup, Scenario

PAPER_DURATION_S = 50.0
PAPER_DISTURBANCE_START_S = 25.0
PAPER_HEADING_RAD = 0.5  # final heading of the first-3-s heading manoeuvre (Fig. 6 shows motion; no value given)


def paper(duration: float | None = None, seed: int = 0) -> Scenario:
    """The paper's simulation study (see module docstring)."""
    T = PAPER_DURATION_S if duration is None else duration
    eight = patterns.figure_eight((0.0, 0.0), 1.5, 0.75, 20.0, 2.0, t_start=5.0, ramp_time=5.0)
    reference = eight.replace(
        z=ref.SmoothStep(1.0, 2.0, 0.0, 5.0),
        psi=ref.SmoothStep(0.0, PAPER_HEADING_RAD, 0.0, 3.0),
        duration=T,
    )
    return Scenario(
        name="paper",
        description="Table 1 vehicle: climb 1->2 m (0-5 s), heading 0->0.5 rad (0-3 s), figure-eight 1.5 m x 0.75 m "
        "period 20 s from 5 s, random bounded disturbances from 25 s",
        duration=T,
        reference=reference,
        disturbance_start=PAPER_DISTURBANCE_START_S,
        setup=PlantSetup(position=(0.0, 0.0, 1.0), disturbance="paper", seed=seed),
    )


def rest_to_rest(duration: float | None = None, seed: int = 0) -> Scenario:
    """3 m along x in 2.5 s at 2 m height, starting at 1 s, then hover until 10 s."""
    T = 10.0 if duration is None else duration
    move = patterns.rest_to_rest((0.0, 0.0, 2.0, 0.0), (3.0, 0.0, 2.0, 0.0), t_start=1.0, move_time=2.5)
    return Scenario(
        name="rest-to-rest",
        description="3 m along x in 2.5 s at 2 m height (from t = 1 s), then hover",
        duration=T,
        reference=move.replace(duration=T),
        arrival_time=3.5,
        setup=PlantSetup(position=(0.0, 0.0, 2.0), seed=seed),
    )


def hover(duration: float | None = None, seed: int = 0) -> Scenario:
    """Hold position at 1 m starting with a 0.2 rad swing (beta = 0.5 rad) and a small swing rate."""
    T = 10.0 if duration is None else duration
    r, rd = cable_from_spherical(0.2, 0.5, 0.0, 0.3)
    return Scenario(
        name="hover",
        description="hold at 1 m, load released at 0.2 rad swing",
        duration=T,
        reference=patterns.hover(0.0, 0.0, 1.0).replace(duration=T),
        arrival_time=0.0,
        setup=PlantSetup(position=(0.0, 0.0, 1.0), cable=r, cable_rate=rd, seed=seed),
    )


def circle(duration: float | None = None, seed: int = 0) -> Scenario:
    """1 m radius circle of the load, 10 s period at 2 m height, entered smoothly from rest."""
    T = 30.0 if duration is None else duration
    c = patterns.circle((0.0, 0.0), 1.0, 10.0, 2.0, t_start=1.0, ramp_time=4.0)
    return Scenario(
        name="circle",
        description="load circle of 1 m radius, period 10 s, at 2 m",
        duration=T,
        reference=c.replace(duration=T),
        setup=PlantSetup(position=(1.0, 0.0, 2.0), seed=seed),
    )


SCENARIOS: dict[str, Callable[..., Scenario]] = {
    "paper": paper,
    "rest-to-rest": rest_to_rest,
    "hover": hover,
    "circle": circle,
}


def make_scenario(name: str, duration: float | None = None, seed: int = 0) -> Scenario:
    """Build a scenario by name; UserError for an unknown name or a bad duration. ``seed``: of the simulated
    disturbances (recorded in ``setup``; a live flight ignores it). Plant-free: ``offboard.harness.sim.run`` builds the
    plant's side."""
    factory = SCENARIOS.get(name)
    if factory is None:
        raise UserError(f"unknown scenario {name!r} (known: {', '.join(SCENARIOS)})")
    if duration is not None and not (math.isfinite(duration) and duration > 0.0):
        raise UserError(f"duration must be a finite number of seconds > 0, got {duration!r}")
    return factory(duration=duration, seed=seed)
