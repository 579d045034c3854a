"""A move as a user gives it: go D metres and arrive by T, the load at rest at both ends, on a profile whose peak
acceleration approaches the physical bound ``4 D / T^2``.

The reference is the LOAD's position (the flat output, ``docs/model.md`` §8), whose swing follows its acceleration:
``F'' = -g a`` (first order). No rest-to-rest move of D metres in T seconds has a peak acceleration below
``4 D / T^2`` (the bang-bang: full acceleration for T/2, full braking for T/2), so no swing below
``atan(4 D / (g T^2))``. This profile is that bang-bang with its corners rounded: the acceleration is a sum of
smooth steps, up from 0 to ``A`` over a ramp of ``tau`` seconds, down to ``-A`` over ``2 tau`` centred on T/2, back to
0 over ``tau`` at the end; with a speed limit the crossing is two ramps of ``tau`` (``A`` to 0, 0 to ``-A``) around
a cruise at the limit. ``A`` is what makes the move exactly D long: ``A / (4 D / T^2)`` is 1 for ``tau = 0`` and
grows with ``tau / T`` (:attr:`MoveProfile.peak_over_bound`: 1.11 at ``tau = T / 20``, 1.31 at ``T / 8``, 1.83 at
``T / 4``). Longer ramps overlap: the profile turns into one smooth lobe per half (2.90x at ``0.45 T``, 3.11x at
``T / 2``, against 3.77x for the degree-15 step of ``rest_to_rest``), which asks less tilt rate of a short move.

The ramps are smooth steps of order ``ramp_order`` (derivatives 1..N zero at both ends): the acceleration is C^N,
the position C^(N+2). The flat chain asks for the position's derivatives up to order 5 and 6: the attitude-level
law's feed-forward is ``F*^(5)`` (the tilt rate), the torque-level law's ``F*^(6)`` (the tilt acceleration, a
torque). Order 4 (degree 9) is the least that keeps both continuous (position C^6). Order 3 (position C^5) has a
smaller third derivative (52.5 against 78.8 per unit step and time; 176 for the degree-15 step of the other
references) but steps ``F^(6)`` at the ramps' ends: 3 m in 4 s on its shortest ramps asked a tilt acceleration of
52 rad/s^2 there, and the emulator's ArduPilot flavour saturated through the move. The ramps' length is chosen in
``offboard.control.move_planning`` from the vehicle's tilt rate and tilt acceleration.

Frames and units: one scalar channel (m or rad), time in s. The profile is odd about its midpoint: built on its
first half as polynomials in each piece's normalized time and mirrored, ``p(t) = D - p(T - t)``, so the end is
exactly ``D`` with every derivative zero. Design: ``docs/references.md``, "Moves".
"""

from __future__ import annotations

from dataclasses import dataclass

from offboard.control.jet import Jet, PolynomialTaylor
from offboard.control.reference import ORDERS, Scalar, TrajectoryError, _finite, _positive
from offboard.control.smooth_step import mirrored, scaled, step_coefficients

#: the acceleration ramps' smooth-step order (derivatives 1..4 vanish at the ramp's ends): position C^6, the least
#: that keeps both laws' feed-forward (F^(5), F^(6)) continuous; see the module docstring
DEFAULT_RAMP_ORDER = 4


def _ramp(order: int) -> tuple[float, ...]:
    """Monomial coefficients of the order-``order`` smooth step on [0, 1]."""
    if isinstance(order, bool) or not isinstance(order, int) or not 2 <= order <= 7:
        raise TrajectoryError(f"ramp_order must be a whole number in 2..7, got {order!r}")
    return tuple(float(c) for c in step_coefficients(order))


@dataclass(frozen=True)
class MoveProfile:
    """The shape of one rest-to-rest move along one axis, for a unit distance and its real duration.

    duration: T, s; ramp: tau, s; cruise: the time at constant speed in the middle, s (0: none); ramp_order: the
    ramps' smooth-step order. peak_acceleration, peak_speed: for a 1 m move, m/s^2 and m/s (scale by D).
    """

    duration: float
    ramp: float
    cruise: float
    ramp_order: int
    peak_acceleration: float
    peak_speed: float

    @property
    def peak_over_bound(self) -> float:
        """Peak acceleration / ``4 D / T^2`` (dimensionless, >= 1): how far the profile is from the bang-bang."""
        return self.peak_acceleration * self.duration**2 / 4.0


def _terms(T: float, tau: float, cruise: float) -> tuple[tuple[float, float, float], ...]:
    """The acceleration as a sum of smooth steps, for a unit ``A``: (start s, length s, height) per step. Without a
    cruise: up over ``tau``, down by 2 over ``2 tau`` centred on T/2, up over ``tau`` at the end; with one: up, down,
    (cruise), down, up, each over ``tau``. Without a cruise the steps may overlap (ramps longer than T/4): the sum
    stays smooth and rest to rest, its peak then below ``A``."""
    if cruise == 0.0:
        if tau > 0.5 * T * (1 + 1e-12):
            raise TrajectoryError(f"a move of {T:g} s has no room for ramps of {tau:g} s (at most T / 2)")
        return ((0.0, tau, 1.0), (0.5 * T - tau, 2.0 * tau, -2.0), (T - tau, tau, 1.0))
    if cruise > (T - 4.0 * tau) * (1 + 1e-12):  # with a cruise the ramps do not overlap
        raise TrajectoryError(
            f"a move of {T:g} s has no room for ramps of {tau:g} s and a cruise of {cruise:g} s (needs "
            f"T >= 4 ramp + cruise)"
        )
    down = 0.5 * T - 0.5 * cruise - tau  # the first ramp down ends where the cruise begins
    return ((0.0, tau, 1.0), (down, tau, -1.0), (0.5 * T + 0.5 * cruise, tau, -1.0), (T - tau, tau, 1.0))


class _Ramps:
    """The unit move's position as the double integral of :func:`_terms`: each step ``h S((u - s) / L)`` adds
    ``h L^2 J((u - s) / L)``, ``J`` the step's double integral from rest (``J(x) = J(1) + J'(1) (x - 1) + (x - 1)^2
    / 2`` past its end)."""

    def __init__(self, T: float, tau: float, cruise: float, order: int) -> None:
        step = _ramp(order)
        jc = (0.0, 0.0, *(c / ((j + 1) * (j + 2)) for j, c in enumerate(step)))
        self.J = PolynomialTaylor(jc)
        self.S = PolynomialTaylor(step)
        self.J1 = sum(jc)  # J(1)
        self.dJ1 = sum(j * c for j, c in enumerate(jc))  # J'(1)
        self.terms = _terms(T, tau, cruise)

    def series(self, u: float, n: int) -> list[float]:
        """Taylor coefficients (real time, unit A) of the position at ``u`` (s)."""
        out = [0.0] * n
        for s, L, h in self.terms:
            x = (u - s) / L
            if x <= 0.0:
                continue
            if x < 1.0:
                c = self.J.taylor(x, n)
            else:
                y = x - 1.0
                c = (self.J1 + self.dJ1 * y + 0.5 * y * y, self.dJ1 + y, 0.5, *(0.0,) * max(0, n - 3))[:n]
            k = h * L * L
            for i, v in enumerate(scaled(c, 1.0 / L)):
                out[i] += k * v
        return out

    def acceleration(self, u: float) -> float:
        """The unit acceleration at ``u`` (s)."""
        return sum(h * self.S.taylor(min(max((u - s) / L, 0.0), 1.0), 1)[0] for s, L, h in self.terms)


def move_profile(
    duration: float, ramp: float, cruise: float = 0.0, ramp_order: int = DEFAULT_RAMP_ORDER
) -> MoveProfile:
    """The :class:`MoveProfile` of a unit move in ``duration`` s with ``ramp`` s acceleration ramps and ``cruise`` s
    at constant speed in the middle (TrajectoryError if they do not fit: ``ramp <= duration / 2`` without a cruise,
    ``4 ramp + cruise <= duration`` with one). The peak acceleration is exact where the ramps do not overlap, sampled
    (1000 points a half, within 1e-5) where they do."""
    T = _positive("move time", duration)
    tau = _positive("ramp time", ramp)
    c = _finite("cruise time", cruise)
    if c < 0.0:
        raise TrajectoryError(f"cruise time must be >= 0 s, got {cruise!r}")
    r = _Ramps(T, tau, c, ramp_order)
    half = r.series(0.5 * T, 2)
    A = 0.5 / half[0]
    peak = 1.0  # ramps that do not overlap reach A and hold it (or touch at T / 4)
    if c == 0.0 and tau > 0.25 * T:
        peak = max(abs(r.acceleration(0.5 * T * i / 1000)) for i in range(1001))
    return MoveProfile(T, tau, c, ramp_order, A * peak, A * half[1])


class Move(Scalar):
    """One channel's rest-to-rest move from ``start`` to ``end`` (m or rad), beginning at ``t_start`` (s), on the
    profile ``shape`` (a :class:`MoveProfile`, whose duration it takes). Held before and after; derivatives
    1..``ramp_order + 2`` are zero at both ends. Peak acceleration ``shape.peak_acceleration * |end - start|``."""

    def __init__(self, start: float, end: float, t_start: float, shape: MoveProfile) -> None:
        self.v0 = _finite("start value", start)
        self.v1 = _finite("end value", end)
        self.t0 = _finite("t_start", t_start)
        self.shape = shape
        self.T = shape.duration
        self._ramps = _Ramps(shape.duration, shape.ramp, shape.cruise, shape.ramp_order)
        # the unit profile scaled to this move: half the distance at T/2
        self._k = 0.5 * (self.v1 - self.v0) / self._ramps.series(0.5 * self.T, 1)[0]

    def _half(self, u: float, n: int) -> tuple[float, ...]:
        """Taylor coefficients (real time) of the displacement at u in [0, T/2]."""
        k = self._k
        return tuple(k * v for v in self._ramps.series(u, n))

    def jet(self, t: float, n: int = ORDERS) -> Jet:
        u = t - self.t0
        if u <= 0.0:
            return Jet.constant(self.v0, n)
        if u >= self.T:
            return Jet.constant(self.v1, n)
        if u <= 0.5 * self.T:
            c = self._half(u, n)
            return Jet._raw((self.v0 + c[0], *c[1:]))
        # p(u) = d - p(T - u): the series at T - u mirrored and negated
        c = mirrored(self._half(self.T - u, n))
        return Jet._raw((self.v1 - c[0], *(-x for x in c[1:])))

    @property
    def end(self) -> float:
        return self.t0 + self.T

    @property
    def breakpoints(self) -> tuple[float, ...]:
        ends = {b for s, L, _ in self._ramps.terms for b in (s, s + L)}
        return tuple(sorted(self.t0 + b for b in ends | {0.5 * self.T}))
