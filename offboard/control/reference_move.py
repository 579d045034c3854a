"""A move as a user thinks of it: go ``D`` metres and arrive by ``T`` seconds, the load at rest at both ends, on a
reference whose swing approaches the physical bound (issue 37).

The bound. ``F`` (the flat output) is the load's position, so the swing follows the load's acceleration: a steady
``F''`` gives the swing ``atan(F'' / g)``. No rest-to-rest move of ``D`` in ``T`` has a peak acceleration below
``4 D / T^2`` (bang-bang: accelerate for ``T / 2``, brake for ``T / 2``), hence no peak swing below
``atan(4 D / (g T^2))``. The polynomial references ask for far more: the degree-15 position step 15.1 D / T^2
(3.8x the bound's acceleration), the velocity step 12.6 (3.1x).

The profile. The load's acceleration is bang-bang with its corners rounded by the degree-15 smooth step
(``offboard.control.smooth_step``): it rises from 0 to ``A`` over ``r T``, holds, turns from ``A`` to ``-A`` over
``2 r T`` centred on ``T / 2``, holds, and returns to 0 over the last ``r T``; odd about ``T / 2``, so the velocity
is back to zero at ``T``. Each corner is a smooth step in the acceleration (:class:`AccelerationStep`, its double
integral in the position, exact to the 8th derivative), so the flat chain's derivatives are as smooth as the
polynomial steps'. ``A = D / (k(r) T^2)``; the peak acceleration in units of the bound's ``4 D / T^2`` is
``1 / (4 k(r))``: 1.11 at ``r`` = 0.05, 1.24 at 0.1, 1.39 at 0.15, 1.58 at 0.2, 1.81 at 0.25 (no hold).

The ramp ``r`` sets how fast the vehicle must move under the load at the corners (its lead ``l F'' / g`` turns
over in ``2 r T``: tilt, tilt rate and torque through ``F^(4)..F^(6)``). The smallest ramp the pre-flight check
accepts is taken (:func:`plan_move`); when none is feasible at the asked ``T``, the fastest feasible ``T`` is found
and proposed.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from fractions import Fraction

from offboard.control.jet import Jet, PolynomialTaylor
from offboard.control.reference import Composite, Constant, Scalar, TrajectoryError, _finite, _positive
from offboard.control.smooth_step import STEP_ORDER, _antiderivative, _step_coefficients, mirrored, scaled

_J_EXACT = _antiderivative(_antiderivative(_step_coefficients(STEP_ORDER)))
#: J(x), the double integral of the smooth step S: the position of a unit acceleration step over unit time
STEP_DOUBLE_INTEGRAL = PolynomialTaylor([float(c) for c in _J_EXACT])
_J_HALF = float(sum(c * Fraction(1, 2) ** k for k, c in enumerate(_J_EXACT)))
_J_ONE = float(sum(_J_EXACT))  # = 2 J(1/2) + 1/8
#: the ramps tried, shortest (closest to the bound) first: a fraction of the move's time for each corner
RAMPS = (0.05, 0.075, 0.1, 0.125, 0.15, 0.2, 0.25)


class AccelerationStep(Scalar):
    """The position (m) whose acceleration rises from 0 to 1 m/s^2 over ``[t0, t0 + tau]`` with the smooth step and
    stays at 1: 0 before, ``tau^2 J((t - t0) / tau)`` during, ``tau^2 J(1) + tau / 2 (t - t1) + (t - t1)^2 / 2``
    after (``t1 = t0 + tau``). Not constant after its end: only sums whose accelerations cancel are moves."""

    def __init__(self, t0: float, tau: float) -> None:
        self.t0 = _finite("t0", t0)
        self.tau = _positive("tau", tau)
        self._inv = 1.0 / self.tau

    def jet(self, t: float, n: int = 7) -> Jet:
        tau = self.tau
        x = (t - self.t0) * self._inv
        if x <= 0.0:
            return Jet.constant(0.0, n)
        if x >= 1.0:
            s = t - self.t0 - tau
            c = (tau * tau * _J_ONE + 0.5 * tau * s + 0.5 * s * s, 0.5 * tau + s, 0.5)
            return Jet._raw(tuple(c[k] if k < 3 else 0.0 for k in range(n)))
        if x <= 0.5:
            series = STEP_DOUBLE_INTEGRAL.taylor(x, n)
        else:  # J(x) = 2 J(1/2) + (x - 1/2)^2 / 2 - J(1 - x): no cancellation near 1
            m = mirrored(STEP_DOUBLE_INTEGRAL.taylor(1.0 - x, n))
            h = x - 0.5
            quad = (2.0 * _J_HALF + 0.5 * h * h, h, 0.5)
            series = tuple((quad[k] if k < 3 else 0.0) - m[k] for k in range(n))
        c = scaled(series, self._inv)
        return Jet._raw(tuple(tau * tau * v for v in c))

    @property
    def end(self) -> float:
        return math.inf

    @property
    def breakpoints(self) -> tuple[float, ...]:
        return (self.t0, self.t0 + self.tau)


class RoundedBangBang(Scalar):
    """0 until ``t_start``, then ``distance`` (m) reached at ``t_start + duration`` (s) on the rounded bang-bang
    acceleration with corner ramps ``ramp * duration`` (module docstring); held after."""

    def __init__(self, distance: float, t_start: float, duration: float, ramp: float) -> None:
        self.distance = _finite("distance", distance)
        self.t_start = _finite("t_start", t_start)
        self.duration = _positive("duration", duration)
        if not (0.0 < ramp <= 0.25):
            raise TrajectoryError(f"ramp must be in (0, 0.25] of the move's time, got {ramp!r}")
        self.ramp = ramp
        T, rT = self.duration, ramp * self.duration
        self._parts = (
            (1.0, AccelerationStep(self.t_start, rT)),
            (-2.0, AccelerationStep(self.t_start + 0.5 * T - rT, 2.0 * rT)),
            (1.0, AccelerationStep(self.t_start + T - rT, rT)),
        )
        self.peak_acceleration = self.distance / (T * T * unit_distance(ramp))
        self._end = self.t_start + T

    def jet(self, t: float, n: int = 7) -> Jet:
        if t >= self._end:
            return Jet.constant(self.distance, n)
        acc = [0.0] * n
        for k, part in self._parts:
            for i, v in enumerate(part.jet(t, n).c):
                acc[i] += k * v
        return Jet._raw(tuple(self.peak_acceleration * v for v in acc))

    @property
    def end(self) -> float:
        return self._end

    @property
    def breakpoints(self) -> tuple[float, ...]:
        return tuple(sorted({b for _, p in self._parts for b in p.breakpoints}))


def unit_distance(ramp: float) -> float:
    """``k(r)``: the distance of a unit-peak-acceleration move of unit time with corner ramps ``r`` (dimensionless;
    1/4 for the sharp bang-bang)."""
    r = ramp
    # accelerations: +S over [0, r], -2 S over [1/2 - r, 1/2 + r], +S over [1 - r, 1]; positions at t = 1
    return _after(1.0, 0.0, r) - 2.0 * _after(1.0, 0.5 - r, 2.0 * r) + _after(1.0, 1.0 - r, r)


def _after(t: float, t0: float, tau: float) -> float:
    s = t - t0 - tau
    return tau * tau * _J_ONE + 0.5 * tau * s + 0.5 * s * s


def peak_over_bound(ramp: float) -> float:
    """The profile's peak acceleration in units of the bound's ``4 D / T^2``."""
    return 1.0 / (4.0 * unit_distance(ramp))


@dataclass(frozen=True)
class MoveSpec:
    """A move as asked: from (``x``, ``y``) (m, model frame NWU) ``distance`` m towards ``direction`` (rad from x,
    towards y), arriving ``arrive_by`` s after ``t_start`` (s of rest first), then ``hold`` s at the goal, at height
    ``z`` (m) and heading ``psi`` (rad)."""

    distance: float
    arrive_by: float
    direction: float = 0.0
    x: float = 0.0
    y: float = 0.0
    z: float = 2.0
    psi: float = 0.0
    t_start: float = 2.0
    hold: float = 15.0

    def reference(self, ramp: float, arrive_by: float | None = None) -> MoveReference:
        """The move on the rounded bang-bang profile with corner ramps ``ramp`` (a fraction of the move's time),
        arriving ``arrive_by`` s after its start (default the asked time)."""
        T = self.arrive_by if arrive_by is None else arrive_by
        return MoveReference(self, ramp, T)


class MoveReference(Composite):
    """A :class:`MoveSpec` flown with corner ramps ``ramp`` and arrival time ``arrive_by`` (s); ``ramp_given``: the
    user chose the ramp (else ``slung fly`` plans it against the vehicle, :func:`plan_move`)."""

    def __init__(self, spec: MoveSpec, ramp: float, arrive_by: float, ramp_given: bool = False) -> None:
        s = RoundedBangBang(spec.distance, spec.t_start, arrive_by, ramp)
        c, d = math.cos(spec.direction), math.sin(spec.direction)
        super().__init__(
            fx=spec.x + c * s,
            fy=spec.y + d * s,
            z=Constant(spec.z),
            psi=Constant(spec.psi),
            duration=spec.t_start + arrive_by + spec.hold,
        )
        self.spec, self.ramp, self.arrive_by, self.ramp_given = spec, ramp, arrive_by, ramp_given
        self.peak_acceleration = s.peak_acceleration


@dataclass(frozen=True)
class MovePlan:
    """What :func:`plan_move` chose: the reference to fly (None when the asked time cannot be flown), its ramp, and
    the fastest feasible arrival time with its ramp (None when even the slowest tried is infeasible)."""

    reference: MoveReference | None
    ramp: float | None
    fastest_s: float | None
    fastest_ramp: float | None
    why: str


def plan_move(
    spec: MoveSpec, feasible: Callable[[MoveReference], str | None], t_max: float = 120.0, tol_s: float = 0.05
) -> MovePlan:
    """The move with the shortest feasible ramp at the asked time; if none, the fastest feasible arrival time (to
    ``tol_s``, searched with the smoothest corners) and the shortest ramp feasible at it. ``feasible(reference)`` is
    the pre-flight check: None when it passes, else why not. It is shown the move with a short hold after it (the
    hold asks nothing of the vehicle, and the check's cost grows with the reference's length)."""
    probe = replace(spec, hold=min(spec.hold, 0.5))

    def shortest(T: float) -> tuple[float | None, str]:
        why = ""
        for r in RAMPS:
            res = feasible(probe.reference(r, T))
            if res is None:
                return r, ""
            why = res  # the smoothest corners' reason, the last tried: the closest to feasible
        return None, why

    r, why = shortest(spec.arrive_by)
    if r is not None:
        return MovePlan(spec.reference(r), r, spec.arrive_by, r, "")

    def smooth_ok(T: float) -> bool:
        return feasible(probe.reference(RAMPS[-1], T)) is None

    lo = hi = spec.arrive_by
    while True:  # a feasible time, growing by half each try
        hi = min(hi * 1.5, t_max)
        if smooth_ok(hi):
            break
        if hi >= t_max:
            return MovePlan(None, None, None, None, why)
        lo = hi
    while hi - lo > tol_s:
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if smooth_ok(mid) else (mid, hi)
    rounded = math.ceil(hi / tol_s - 1e-9) * tol_s  # a round figure on the feasible side, when it is feasible
    for T in (rounded, hi):
        r, _ = shortest(T)
        if r is not None:
            return MovePlan(None, None, T, r, why)
    return MovePlan(None, None, hi, RAMPS[-1], why)


__all__ = [
    "RAMPS",
    "AccelerationStep",
    "MovePlan",
    "MoveReference",
    "MoveSpec",
    "RoundedBangBang",
    "peak_over_bound",
    "plan_move",
    "unit_distance",
]
