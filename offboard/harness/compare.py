"""``slung compare``: every controller on the same plant, sensors, filter, references and disturbances.

Scenarios (``COMPARE_SCENARIOS``), each one or more cases:

- ``rest-to-rest``: 3 m along x at 2 m height, starting at 1 s, with move times 2.5 s (the named scenario of
  ``slung sim``), 4 s and 6 s (degree-15 steps, ``offboard.control.reference_patterns.rest_to_rest``), then 14 s
  of hover;
- ``paper``: the paper's 50 s scenario (figure-eight, heading manoeuvre, disturbances from 25 s);
- ``hover``: hold at 1 m, the load released at a 0.2 rad swing; 12 s;
- ``gust``: hover at 2 m, a 1 - cos gust of 1 s from t = 1 s pushing the vehicle (1.0 N) and the load (0.3 N)
  along x; 14 s.

Figures of a case (:func:`case_figures`, SI, rad): ``peak_swing_rad`` (largest swing ``alpha`` while the reference
moves; over the whole run where it does not move), ``residual_swing_rad`` (largest swing from 2 s to 12 s after
arrival), ``settle_s`` (time after arrival until the swing stays below 1 deg for good; None if it never does
before the end), ``tracking_rms_m`` (RMS of the load's 3D flat-output tracking error ``(e_Fx, e_Fy, e_z)`` over
the run), ``tracking_max_m``, ``overshoot_m`` (how far the load passes the end point along the move, after
arrival; for cases without a move the largest horizontal error after arrival), ``effort_torque_rms_nm`` (RMS of
the torque command's norm), ``effort_thrust_rms_n`` (RMS of the thrust's deviation from hover),
``saturation_s`` (time with a command clipped), ``slack_steps``; for moves ``lower_bound_rad = atan(a_max / g)``
with the reference's largest acceleration (the swing a perfectly tracked load must reach, the flat output's
``F'' = -g a``) and ``bang_bang_bound_rad = atan(4 D / (T^2 g))`` (the least peak acceleration of any
rest-to-rest move of length D in time T).

Outputs (``DIR``): ``compare.json`` (``{controller: {figure: value}}`` of the scenario's main case),
``compare_cases.json`` (every case), ``compare_series.csv`` (per case and controller the time series the
figures are made of: the hook ``report.html`` renders), side-by-side PNG figures and ``report.html``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from estimators.errors import UserError
from estimators.model.vehicle import Vehicle
from offboard.control import reference_patterns as patterns
from offboard.control import smc
from offboard.control.controllers import registry
from offboard.control.controllers.protocol import Controller, level_of
from offboard.control.scenarios import make_scenario
from offboard.logs.runlog import COL, PlantSetup, Scenario, SimConfig, SimLog

SWING_SETTLED_RAD = math.radians(1.0)
RESIDUAL_WINDOW_S = (2.0, 12.0)
REST_TO_REST_MOVE_TIMES_S = (2.5, 4.0, 6.0)
REST_TO_REST_DISTANCE_M = 3.0


@dataclass(frozen=True)
class Case:
    """One run of a compare scenario: its label, the scenario and the move it makes (for the bounds)."""

    label: str
    scenario: Scenario
    move_start: float | None = None
    move_time: float | None = None
    move_distance: float | None = None


def _rest_to_rest(move_time: float) -> Case:
    t0 = 1.0
    arrival = t0 + move_time
    duration = arrival + RESIDUAL_WINDOW_S[1] + 2.0
    move = patterns.rest_to_rest(
        (0.0, 0.0, 2.0, 0.0), (REST_TO_REST_DISTANCE_M, 0.0, 2.0, 0.0), t_start=t0, move_time=move_time
    )
    sc = Scenario(
        name=f"rest-to-rest-{move_time:g}s",
        description=f"{REST_TO_REST_DISTANCE_M:g} m along x in {move_time:g} s at 2 m height from t = 1 s, then hover",
        duration=duration,
        reference=move.replace(duration=duration),
        arrival_time=arrival,
        setup=PlantSetup(position=(0.0, 0.0, 2.0)),
    )
    return Case(f"move {move_time:g} s", sc, t0, move_time, REST_TO_REST_DISTANCE_M)


@dataclass(frozen=True)
class Gust:
    """A 1 - cos gust (N, world x) on the vehicle and the load from ``start`` for ``length`` s."""

    start: float = 1.0
    length: float = 1.0
    vehicle_n: float = 1.0
    load_n: float = 0.3

    def __call__(self, t: float) -> tuple[float, ...]:
        s = (t - self.start) / self.length
        if not 0.0 <= s <= 1.0:
            return (0.0,) * 9
        w = 0.5 * (1.0 - math.cos(2.0 * math.pi * s))
        return (self.vehicle_n * w, 0.0, 0.0, self.load_n * w, 0.0, 0.0, 0.0, 0.0, 0.0)


def _gust() -> Case:
    g = Gust()
    arrival = g.start + g.length
    duration = arrival + RESIDUAL_WINDOW_S[1] + 1.0
    sc = Scenario(
        name="gust",
        description="hover at 2 m; a 1 - cos gust of 1 s from t = 1 s: 1.0 N on the vehicle, 0.3 N on the load, +x",
        duration=duration,
        reference=patterns.hover(0.0, 0.0, 2.0).replace(duration=duration),
        arrival_time=arrival,
        setup=PlantSetup(position=(0.0, 0.0, 2.0)),
    )
    return Case("gust", _with_disturbance(sc, g))


def _with_disturbance(sc: Scenario, dist: Callable[[float], tuple[float, ...]]) -> Scenario:
    from dataclasses import replace

    return replace(sc, disturbance=dist)


def _hover() -> Case:
    sc = make_scenario("hover", duration=RESIDUAL_WINDOW_S[1] + 0.5)
    return Case("hover", sc)


def _paper() -> Case:
    return Case("paper", make_scenario("paper"))


#: scenario name -> its cases (the first is the main case, written to compare.json)
COMPARE_SCENARIOS: dict[str, Callable[[], list[Case]]] = {
    "rest-to-rest": lambda: [_rest_to_rest(t) for t in REST_TO_REST_MOVE_TIMES_S],
    "paper": lambda: [_paper()],
    "hover": lambda: [_hover()],
    "gust": lambda: [_gust()],
}


def cases(name: str) -> list[Case]:
    """The cases of compare scenario ``name``; UserError for an unknown one."""
    make = COMPARE_SCENARIOS.get(name)
    if make is None:
        raise UserError(f"unknown compare scenario {name!r} (known: {', '.join(COMPARE_SCENARIOS)})")
    return make()


def smc_feasibility(reference: Any, duration: float, vehicle: Any) -> Any:
    """The pre-flight feasibility check (``offboard.control.feasibility.check_reference``, as ``slung sim`` and
    ``slung fly`` run it) of ``reference`` over ``duration`` s for ``vehicle`` and the ``smc`` row's limits: what a
    fixed move asks of a vehicle before anything is flown (compare's cases, a sweep file's move)."""
    from offboard.control.feasibility import FeasibilityLimits, check_reference

    return check_reference(reference, duration, vehicle, FeasibilityLimits.from_config(registry.smc_params(vehicle)))


def reference_feasibility(the_cases: list[Case], vehicle: Any) -> dict[str, Any]:
    """:func:`smc_feasibility` of each case's reference: ``{case label: FeasibilityResult}``. A fixed move may ask
    more than another vehicle can give (3 m in 2.5 s is a 0.74 rad swing and a slack cable on ArduPilot SITL's quad
    with its 1 m cable): every row then fails for the move's sake, which the table alone would not say."""
    return {case.label: smc_feasibility(case.scenario.reference, case.scenario.duration, vehicle) for case in the_cases}


def require_load(vehicle: Any, where: str = "") -> None:
    """UserError unless ``vehicle`` carries a load: compare and sweep judge the load's swing and tracking, which
    a vehicle without one does not have (its plant would swing a massless pendulum)."""
    if not vehicle.mass_load > 0.0:
        raise UserError(
            f"{where}vehicle {vehicle.name!r} carries no load ([load] mass_kg = 0): compare and sweep judge the "
            "load's swing and tracking; give a vehicle file with a load"
        )


def case_figures(case: Case, log: SimLog) -> dict[str, Any]:
    """The figures of one run (see the module docstring)."""
    d = log.data
    t = d[:, COL["t"]]
    alpha = d[:, COL["alpha"]]
    e = d[:, [COL["e_Fx"], COL["e_Fy"], COL["e_z"]]]
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    sc = case.scenario
    ta = sc.arrival_time
    if ta is not None and not np.any(t >= ta):  # a run that ended before arrival (a flight's watchdog)
        ta = None
    out: dict[str, Any] = {}
    if case.move_start is not None and ta is not None:
        moving = (t >= case.move_start) & (t <= ta)
        out["peak_swing_rad"] = float(alpha[moving].max())
    else:
        out["peak_swing_rad"] = float(alpha.max())
    if ta is not None:
        win = (t >= ta + RESIDUAL_WINDOW_S[0]) & (t <= ta + RESIDUAL_WINDOW_S[1])
        out["residual_swing_rad"] = float(alpha[win].max()) if win.any() else None
        after = t >= ta
        above = np.nonzero(after & (alpha >= SWING_SETTLED_RAD))[0]
        if len(above) == 0:
            out["settle_s"] = 0.0
        elif above[-1] == len(t) - 1:
            out["settle_s"] = None  # still swinging at the end
        else:
            out["settle_s"] = float(t[above[-1] + 1] - ta)
    else:
        out["residual_swing_rad"] = None
        out["settle_s"] = None
    norm = np.sqrt((e * e).sum(axis=1))
    out["tracking_rms_m"] = float(np.sqrt(np.mean(norm * norm)))
    out["tracking_max_m"] = float(norm.max())
    if ta is not None:
        after = t >= ta
        if case.move_distance is not None:
            fx = d[:, COL["Fx"]]
            out["overshoot_m"] = float(max(0.0, (fx[after] - case.move_distance).max()))
        else:
            out["overshoot_m"] = float(np.hypot(e[after, 0], e[after, 1]).max())
    else:
        out["overshoot_m"] = None
    tau = d[:, [COL["tau_phi"], COL["tau_theta"], COL["tau_psi"]]]
    out["effort_torque_rms_nm"] = float(np.sqrt(np.mean((tau * tau).sum(axis=1))))
    out["effort_thrust_rms_n"] = float(np.sqrt(np.mean((d[:, COL["u"]] - log.vehicle.hover_thrust) ** 2)))
    out["saturation_s"] = float(np.nansum(d[:, COL["saturated"]]) * dt)
    out["slack_steps"] = int(log.slack_steps)
    out["completed"] = bool(len(t) and t[-1] >= sc.duration - 1e-6 and np.isfinite(d[:, 1:19]).all())
    if case.move_time is not None and case.move_distance is not None:
        a_max = reference_peak_acceleration(sc)
        g = log.vehicle.gravity
        out["lower_bound_rad"] = math.atan(a_max / g)
        out["bang_bang_bound_rad"] = math.atan(4.0 * case.move_distance / (case.move_time**2 * g))
        out["peak_over_bound"] = out["peak_swing_rad"] / out["lower_bound_rad"]
    return out


def reference_peak_acceleration(sc: Scenario, step: float = 1e-3) -> float:
    """The largest horizontal acceleration of the scenario's flat-output reference (m/s^2), sampled every ``step``."""
    best = 0.0
    for tk in np.arange(0.0, sc.duration, step):
        s = sc.reference.sample(float(tk))
        best = max(best, math.hypot(s.fx[2], s.fy[2]))
    return best


@dataclass
class CaseResult:
    """One controller on one case: its figures and its log."""

    controller: str
    case: Case
    figures: dict[str, Any]
    log: SimLog


def run_case(
    case: Case,
    controller: str,
    vehicle: Vehicle,
    config: SimConfig,
    switching: str = "sign",
    epsilon: float = 1.0,
) -> CaseResult:
    """Fly ``case`` in simulation with the named controller (fresh), the true plant ``vehicle`` and ``config``."""
    from offboard.harness import sim

    params = smc.ControllerParams.for_vehicle(vehicle, switching=switching, epsilon=epsilon)
    config, law = controller_as_flown(controller, vehicle, config, switching=switching, epsilon=epsilon)
    tuning = registry.filter_tuning(controller, config.estimator)
    # with motors in the loop the filter is given the command through their lag, as the live loop gives it
    lag = config.actuators == "px4-attitude"
    log = sim.run(case.scenario, vehicle, params, config, controller=law, tuning=tuning, command_lag=lag)
    return CaseResult(controller, case, case_figures(case, log), log)


def controller_as_flown(
    controller: str, nominal: Vehicle, config: SimConfig, switching: str = "sign", epsilon: float = 1.0
) -> tuple[SimConfig, Controller]:
    """The named controller, fresh, for the ``nominal`` vehicle, and the simulation's config it flies in.

    The attitude-level law (``smc-attitude``) commands an attitude and a thrust: it is flown through PX4's attitude
    P, rate PID, allocator and motors (``sim_bridge.inner.px4_attitude_path``, actuators ``px4-attitude``) in
    place of the config's motors (ideal or the mixer), as ``slung fly`` flies it through an autopilot, and designed
    as ``slung fly`` designs it for those loops: for what it would read from their parameters
    (``emulated_autopilot``), within the tilt its mapping clips to (the path clips the same). Any other
    attitude-level controller (``protocol.level_of``) flies through the same loops; the others keep the config."""
    inner = tilt_max = None
    if controller == "smc-attitude" and config.actuators in ("ideal", "mixer"):
        from offboard.flight.command_mapping import MappingConfig
        from offboard.harness.emulated_autopilot import emulated_inner_loop

        config = replace(config, actuators="px4-attitude")
        inner, tilt_max = emulated_inner_loop(nominal, "px4"), MappingConfig().max_tilt
    # the vehicle's drag in the attitude-level law's model, unless its filter's estimate carries it (fed forward)
    drag_ff = registry.drag_in_law(registry.filter_tuning(controller, config.estimator))
    law = registry.make(
        controller,
        nominal,
        switching=switching,
        epsilon=epsilon,
        inner=inner,
        tilt_max=tilt_max,
        drag_feedforward=drag_ff,
    )
    if level_of(law) == "attitude" and config.actuators in ("ideal", "mixer"):  # any attitude-level controller
        config = replace(config, actuators="px4-attitude")
    return config, law


#: columns of the table printed and their format
TABLE_COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("peak_swing_rad", "peak rad", "{:.3f}"),
    ("residual_swing_rad", "resid rad", "{:.4f}"),
    ("settle_s", "settle s", "{:.2f}"),
    ("tracking_rms_m", "track rms m", "{:.4f}"),
    ("overshoot_m", "overshoot m", "{:.3f}"),
    ("effort_torque_rms_nm", "tau rms Nm", "{:.3f}"),
    ("saturation_s", "sat s", "{:.2f}"),
)


def format_table(results: list[CaseResult]) -> str:
    """The comparison table of one case, one row per controller; the physical bounds beside the peak swing."""
    if not results:
        return ""
    case = results[0].case
    lines = [f"{case.label}: {case.scenario.description}"]
    f0 = results[0].figures
    if "lower_bound_rad" in f0:
        lines.append(
            f"  lower bound on the peak swing: atan(a_max/g) = {f0['lower_bound_rad']:.3f} rad for this reference "
            f"(any rest-to-rest of this length and time: {f0['bang_bang_bound_rad']:.3f} rad)"
        )
    head = f"  {'controller':<15}" + "".join(f"{h:>13}" for _, h, _ in TABLE_COLUMNS)
    if "lower_bound_rad" in f0:
        head += f"{'peak/bound':>12}"
    lines.append(head)
    for r in results:
        row = f"  {r.controller:<15}"
        for key, _, fmt in TABLE_COLUMNS:
            v = r.figures.get(key)
            row += f"{'-' if v is None else fmt.format(v):>13}"
        if "lower_bound_rad" in f0:
            row += f"{r.figures['peak_over_bound']:>12.2f}"
        if not r.figures["completed"]:
            row += f"  ({r.figures.get('ended_by', 'diverged')})"  # a flight: how it ended
        if r.figures.get("not_designed_for_vehicle"):
            row += "  (not designed for this vehicle)"
        lines.append(row)
    return "\n".join(lines)


SERIES_COLUMNS: tuple[str, ...] = ("t", "alpha", "e_Fx", "e_Fy", "e_z", "Fx", "Fy", "u", "tau_phi", "tau_theta")


def series_rows(results: list[CaseResult], every: int = 10) -> list[list[Any]]:
    """Rows of ``compare_series.csv``: case, controller, then :data:`SERIES_COLUMNS` every ``every`` ticks."""
    rows: list[list[Any]] = []
    idx = [COL[c] for c in SERIES_COLUMNS]
    for r in results:
        for row in r.log.data[::every, idx]:
            rows.append([r.case.label, r.controller, *(float(v) for v in row)])
    return rows
