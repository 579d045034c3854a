"""Plan a move as a user gives it (go from A to B, arrive by T, or within an acceleration / speed limit), checked
before flight: the ramps of the smoothed bang-bang (``offboard.control.reference_moves``) as short as the vehicle
allows, and the fastest feasible time proposed when the asked one cannot be flown.

For a move time T the planner takes the shortest acceleration ramp ``tau`` (up to :data:`LONGEST_RAMP` T) whose
nominal demands,
mapped through the flatness chain by the pre-flight check (``offboard.control.feasibility``), keep

- the tilt rate within :data:`TILT_RATE_BUDGET` (rad/s): 80 % of the attitude-level law's tilt-rate clip
  (``smc_attitude.AttitudeParams.tilt_rate_max``, 2 rad/s), the rest left to its feedback, and the tilt
  acceleration within :data:`TILT_ACCEL_BUDGET` (what a first-order attitude loop can follow);
- the tilt within :data:`TILT_SHARE` of the check's tilt limit, the same share for the swing watchdog;
- every hard limit of the check (thrust, torques, motors, cable tension) met.

A shorter ramp is a peak acceleration nearer ``4 D / T^2`` (the profile's ``peak_over_bound``) but a sharper snap
``F^(4)`` and ``F^(5)``, i.e. more vehicle tilt beyond the swing (``n = F''/g + F^(4)/c``) and a faster tilt
(``n' = F'''/g + F^(5)/c``). When no ramp fits, the time cannot be flown and the planner searches the shortest
one that can (bisection on T, to :data:`TIME_RESOLUTION`). SI units, radians, world NWU; pure (no I/O).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from estimators.model.vehicle import Vehicle
from offboard.control.feasibility import WARN_FRACTION, FeasibilityLimits, check_reference
from offboard.control.nominal_demands import nominal_profile
from offboard.control.reference import Composite, Constant, TrajectoryError, _finite
from offboard.control.reference_moves import DEFAULT_RAMP_ORDER, Move, MoveProfile, move_profile
from offboard.control.smc_attitude import AttitudeParams
from offboard.control.smc_attitude_design import InnerLoop

#: the share of the tilt-rate clip, the tilt limit and the swing watchdog a move's nominal demands may take: the
#: pre-flight check's warning share, the rest left to the law's feedback
TILT_SHARE = WARN_FRACTION
#: the nominal tilt rate a move may ask, rad/s: that share of the attitude-level law's tilt-rate clip (2 rad/s)
TILT_RATE_BUDGET = TILT_SHARE * AttitudeParams.tilt_rate_max
#: the nominal tilt acceleration a move may ask, rad/s^2: the tilt-rate budget times the attitude loop's nominal
#: bandwidth (``InnerLoop.attitude_bandwidth``, 4 1/s): a first-order inner loop changes the tilt
#: rate by at most about that per second. Without it the shortest order-3 ramps asked 52 rad/s^2 and the
#: emulator's ArduPilot flavour saturated through the move (3 m in 4 s: 0.3 m overshoot; the waypoints 0.03 m)
TILT_ACCEL_BUDGET = TILT_RATE_BUDGET * InnerLoop.attitude_bandwidth
G = 9.80665  # m/s^2, for the printed swing only
#: the longest ramp the planner tries, a share of the move's time: beyond T / 4 the ramps overlap and the profile
#: turns from the rounded bang-bang (1.83x the bound at T / 4) towards one smooth lobe (2.90x at 0.45 T, 3.11x at
#: T / 2); the tilt rate falls with longer ramps up to about 0.45 T and rises again after (3 m in 3.5 s)
LONGEST_RAMP = 0.45
#: the planner's resolution on the move time, s
TIME_RESOLUTION = 0.02
#: samples per second of the planner's quick pass (the final check is the full one's grid)
QUICK_RATE_HZ = 100.0
#: the longest move the planner searches, s
LONGEST_MOVE_S = 120.0


@dataclass(frozen=True)
class MovePlan:
    """A planned move: the reference and what it asks.

    reference: the Composite (rest at ``start`` until ``t_start``, the move, rest at ``goal`` until ``duration``);
    profile: the shape (T, ramp, cruise); distance: |goal - start| (m); asked: the time asked, s (None: the fastest);
    peak_acceleration (m/s^2) and peak_speed (m/s) along the move; feasible: the asked time can be flown (False only
    when forced to fly an infeasible one); fastest: the shortest feasible time found, s (None when not searched);
    why: the first reason the asked time failed ('' if it did not).
    """

    reference: Composite
    profile: MoveProfile
    distance: float
    t_start: float
    asked: float | None
    peak_acceleration: float
    peak_speed: float
    feasible: bool
    fastest: float | None
    why: str

    @property
    def arrival(self) -> float:
        """The reference's arrival at the goal, s (reference time)."""
        return self.t_start + self.profile.duration

    @property
    def peak_over_bound(self) -> float:
        """The profile's peak acceleration over ``4 D / T^2``."""
        return self.profile.peak_over_bound

    def describe(self) -> str:
        """One line for the terminal."""
        T = self.profile.duration
        bound = 4.0 * self.distance / T**2
        return (
            f"move {self.distance:.3g} m in {T:.3g} s (ramps {self.profile.ramp:.2f} s"
            + (f", cruise {self.profile.cruise:.2f} s" if self.profile.cruise > 0 else "")
            + f"): peak acceleration {self.peak_acceleration:.3g} m/s^2 = {self.peak_over_bound:.2f} x 4D/T^2 "
            f"({bound:.3g}), the load's steady swing {math.degrees(math.atan(self.peak_acceleration / G)):.1f} deg "
            f"against the bound {math.degrees(math.atan(bound / G)):.1f}; peak speed {self.peak_speed:.3g} m/s"
        )


def _point(name: str, p: Sequence[float]) -> tuple[float, float, float]:
    if isinstance(p, (str, bytes)) or not hasattr(p, "__len__") or len(p) != 3:
        raise TrajectoryError(f"{name} must be (x, y, z) in m, got {p!r}")
    return (_finite(f"{name} x", p[0]), _finite(f"{name} y", p[1]), _finite(f"{name} z", p[2]))


def move_reference(
    start: Sequence[float], goal: Sequence[float], shape: MoveProfile, t_start: float, hold: float, psi: float = 0.0
) -> Composite:
    """Rest at ``start`` until ``t_start`` (s), move to ``goal`` (m, NWU, z the height) on ``shape`` along the
    straight line (every axis the same profile, scaled), rest ``hold`` s at the goal; heading ``psi`` (rad)."""
    a, b = _point("start", start), _point("goal", goal)
    chans = [Move(u, v, t_start, shape) if u != v else Constant(u) for u, v in zip(a, b)]
    return Composite(*chans, Constant(psi), duration=t_start + shape.duration + hold)


class _Trial:
    """Judges one (T, ramp) for the planner: quick nominal pass, then the full check on the chosen one."""

    def __init__(
        self,
        start: tuple[float, float, float],
        goal: tuple[float, float, float],
        vehicle: Vehicle,
        limits: FeasibilityLimits,
        max_accel: float,
        max_speed: float,
        order: int,
    ) -> None:
        self.start, self.goal, self.vehicle, self.limits = start, goal, vehicle, limits
        self.distance = math.dist(start, goal)
        self.max_accel, self.max_speed, self.order = max_accel, max_speed, order

    def shape(self, T: float, ramp: float) -> MoveProfile | None:
        """The profile for (T, ramp) within the speed limit (a cruise when needed), None if none fits."""
        prof = move_profile(T, ramp, 0.0, self.order)
        if prof.peak_speed * self.distance <= self.max_speed:
            return prof
        # cruise at the limit: the speed grows with a shorter cruise, so bisect the cruise time
        lo, hi = 0.0, T - 4.0 * ramp
        if hi <= 0.0:
            return None
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            if move_profile(T, ramp, mid, self.order).peak_speed * self.distance > self.max_speed:
                lo = mid
            else:
                hi = mid
        prof = move_profile(T, ramp, hi, self.order)
        return prof if prof.peak_speed * self.distance <= self.max_speed * (1 + 1e-6) else None

    def quick(self, shape: MoveProfile) -> str:
        """'' when the nominal demands of ``shape`` are within the planner's budgets, else the first reason (the
        acceleration limit apart: it falls as the ramps shorten, where the budgets rise)."""
        ref = move_reference(self.start, self.goal, shape, 0.0, 0.0)
        n = max(50, int(shape.duration * QUICK_RATE_HZ))
        ts = [shape.duration * i / n for i in range(n + 1)]
        p = nominal_profile(ref, ts, self.vehicle)
        lim = self.limits
        checks = (
            ("tilt rate", float(p["tilt_rate"].max()), TILT_RATE_BUDGET, "rad/s"),
            ("tilt acceleration", float(p["tilt_accel"].max()), TILT_ACCEL_BUDGET, "rad/s^2"),
            ("tilt", float(p["tilt"].max()), TILT_SHARE * lim.max_tilt, "rad"),
            ("swing", float(p["swing"].max()), TILT_SHARE * lim.swing_limit, "rad"),
        )
        for name, peak, budget, unit in checks:
            if not peak <= budget:
                return f"nominal {name} {peak:.3g} {unit} above the move's budget {budget:.3g} {unit}"
        if self.vehicle.mass_load > 0.0 and not float(p["tension"].min()) > 0.0:
            return f"the cable would go slack (nominal tension {float(p['tension'].min()):.3g} N)"
        return ""

    def full(self, shape: MoveProfile) -> str:
        """'' when the pre-flight check passes ``shape`` (hard limits), else its first violation."""
        ref = move_reference(self.start, self.goal, shape, 0.0, 0.0)
        res = check_reference(ref, shape.duration, self.vehicle, self.limits)
        return "" if res.feasible else res.messages[0].removeprefix("infeasible: ")

    def best(self, T: float) -> tuple[MoveProfile | None, str]:
        """The shortest ramp that passes for time T (bisection on the ramp; the demands fall as it grows), or
        (None, why the longest ramp fails)."""
        lo, hi = 0.01 * T, LONGEST_RAMP * T
        if self.shape(T, hi) is None:
            # a speed limit: a cruise fits only beside short enough ramps; the longest that leaves room for one
            if self.shape(T, lo) is None:
                return None, "no profile within the speed limit"
            a, b = lo, hi
            for _ in range(20):
                mid = 0.5 * (a + b)
                a, b = (mid, b) if self.shape(T, mid) is not None else (a, mid)
            hi = a
        longest = self.shape(T, hi)
        why = "no profile within the speed limit" if longest is None else self.quick(longest)
        if longest is None or why:
            return None, why
        cand = self.shape(T, lo)
        if cand is not None and not self.quick(cand):
            hi = lo
        else:
            for _ in range(10):
                mid = 0.5 * (lo + hi)
                s = self.shape(T, mid)
                if s is not None and not self.quick(s):
                    hi = mid
                else:
                    lo = mid
        shape = self.shape(T, hi)
        assert shape is not None
        if shape.peak_acceleration * self.distance > self.max_accel:
            return None, (
                f"peak acceleration {shape.peak_acceleration * self.distance:.3g} m/s^2 above the limit "
                f"{self.max_accel:g} m/s^2"
            )
        why = self.full(shape)
        return (shape, "") if not why else (None, why)


def plan_move(
    start: Sequence[float],
    goal: Sequence[float],
    vehicle: Vehicle,
    limits: FeasibilityLimits,
    *,
    arrive_by: float | None = None,
    max_accel: float | None = None,
    max_speed: float | None = None,
    t_start: float = 2.0,
    hold: float = 5.0,
    force: bool = False,
    ramp_order: int = DEFAULT_RAMP_ORDER,
) -> MovePlan:
    """Plan the move ``start`` -> ``goal`` (m, NWU, z the height above take-off) on ``vehicle``.

    arrive_by: the move's time, s (the load at the goal, at rest, ``arrive_by`` s after ``t_start``); None: the
    fastest the vehicle allows within ``max_accel`` (m/s^2) and ``max_speed`` (m/s). A time that cannot be flown
    raises :class:`TrajectoryError` naming the reason and the fastest feasible time, unless ``force`` (then the
    asked time is flown with the longest ramps, and ``feasible`` is False). ``t_start``: rest before, s;
    ``hold``: rest at the goal after, s.
    """
    a, b = _point("start", start), _point("goal", goal)
    D = math.dist(a, b)
    if not D > 0.0:
        raise TrajectoryError("the move's goal is its start: give a goal other than the start")
    t0 = _finite("t_start", t_start)
    hold_s = _finite("hold", hold)
    if t0 < 0.0 or hold_s < 0.0:
        raise TrajectoryError("the rests before and after the move must be >= 0 s")
    acc = math.inf if max_accel is None else _finite("max acceleration", max_accel)
    spd = math.inf if max_speed is None else _finite("max speed", max_speed)
    if not (acc > 0.0 and spd > 0.0):
        raise TrajectoryError("the acceleration and speed limits must be > 0")
    trial = _Trial(a, b, vehicle, limits, acc, spd, ramp_order)

    def done(shape: MoveProfile, feasible: bool, fastest: float | None, why: str) -> MovePlan:
        ref = move_reference(a, b, shape, t0, hold_s)
        return MovePlan(
            ref, shape, D, t0, arrive_by, shape.peak_acceleration * D, shape.peak_speed * D, feasible, fastest, why
        )

    if arrive_by is not None:
        T = _finite("arrival time", arrive_by)
        if not T > 0.0:
            raise TrajectoryError(f"the arrival time must be > 0 s, got {arrive_by!r}")
        shape, why = trial.best(T)
        if shape is not None:
            return done(shape, True, None, "")
    else:
        why = ""
    fastest = _fastest(trial, arrive_by)
    if arrive_by is None:
        if fastest is None:
            raise TrajectoryError(f"no move of {D:.3g} m within {LONGEST_MOVE_S:g} s passes the pre-flight check")
        shape, _ = trial.best(fastest)
        assert shape is not None
        return done(shape, True, fastest, "")
    if force:
        gentle = trial.shape(T, LONGEST_RAMP * T) or move_profile(T, LONGEST_RAMP * T, 0.0, ramp_order)
        return done(gentle, False, fastest, why)
    hint = (
        f"the fastest feasible is {fastest:.2f} s (--arrive-by {math.ceil(fastest * 100) / 100:g})"
        if fastest is not None
        else f"no time up to {LONGEST_MOVE_S:g} s passes"
    )
    raise TrajectoryError(f"a move of {D:.3g} m in {T:g} s cannot be flown: {why}; {hint} (--force flies it anyway)")


def _fastest(trial: _Trial, above: float | None) -> float | None:
    """The shortest feasible move time (s, to TIME_RESOLUTION), searched above ``above`` when given (known to
    fail); None when even LONGEST_MOVE_S fails."""
    lo = above if above is not None else 0.1
    hi = max(2.0 * lo, 1.0)
    while trial.best(hi)[0] is None:
        lo, hi = hi, 2.0 * hi
        if hi > LONGEST_MOVE_S:
            return None
    if above is None and trial.best(lo)[0] is not None:
        return lo
    while hi - lo > TIME_RESOLUTION:
        mid = 0.5 * (lo + hi)
        if trial.best(mid)[0] is None:
            lo = mid
        else:
            hi = mid
    # on the resolution's grid, if that passes too (the demands need not fall strictly with T), else the one found
    t = round(math.ceil(hi / TIME_RESOLUTION - 1e-9) * TIME_RESOLUTION, 6)
    return t if trial.best(t)[0] is not None else hi


__all__ = ["TILT_RATE_BUDGET", "MovePlan", "move_reference", "plan_move"]
