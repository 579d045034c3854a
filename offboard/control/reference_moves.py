"""A move as a user gives it: go D metres and arrive by T, the load at rest at both ends, on a profile whose peak
acceleration approaches the physical bound ``4 D / T^2``.

The reference is the LOAD's position (the flat output, ``docs/model.md`` §8), whose swing follows its acceleration:
``F'' = -g a`` (first order). No rest-to-rest move of D metres in T seconds has a peak acceleration below
``4 D / T^2`` (the bang-bang: full acceleration for T/2, full braking for T/2), so no swing below
``atan(4 D / (g T^2))``. This profile is that bang-bang with its corners rounded: the acceleration rises from 0 to
``A`` over a ramp of ``tau`` seconds with a smooth step, holds ``A``, crosses from ``A`` to ``-A`` over ``2 tau``
(one smooth step), holds ``-A`` and returns to 0 over ``tau``; with a speed limit the crossing is two ramps of
``tau`` (``A`` to 0, 0 to ``-A``) around a cruise at the limit. ``A`` is what makes the move exactly D long:
``A / (4 D / T^2)`` is 1 for ``tau = 0`` and grows with ``tau / T`` (:attr:`MoveProfile.peak_over_bound`: 1.11 at
``tau = T / 20``, 1.31 at ``T / 8``, 1.83 at ``T / 4``, the longest ramp).

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


def _position_piece(length: float, acc: tuple[float, ...], p0: float, v0: float) -> tuple[float, ...]:
    """Position polynomial in x = u / length on [0, 1] for the acceleration ``sum acc[j] x^j`` (m/s^2), starting at
    ``p0`` (m) with speed ``v0`` (m/s)."""
    L2 = length * length
    return (p0, v0 * length, *(L2 * c / ((j + 1) * (j + 2)) for j, c in enumerate(acc)))


def _end(poly: tuple[float, ...], length: float) -> tuple[float, float]:
    """(position, speed) at x = 1 of a position polynomial in x = u / length."""
    return sum(poly), sum(j * c for j, c in enumerate(poly)) / length


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


def _half_pieces(T: float, tau: float, cruise: float, order: int) -> list[tuple[float, tuple[float, ...]]]:
    """The first half's acceleration pieces for a unit peak acceleration: (length s, coefficients in x)."""
    s = _ramp(order)
    hold = 0.5 * T - 2.0 * tau - 0.5 * cruise
    if hold < -1e-12 * T:
        raise TrajectoryError(
            f"a move of {T:g} s has no room for ramps of {tau:g} s and a cruise of {cruise:g} s (needs "
            f"T >= 4 ramp + cruise)"
        )
    pieces: list[tuple[float, tuple[float, ...]]] = [(tau, s)]
    if hold > 0.0:
        pieces.append((hold, (1.0,)))
    if cruise > 0.0:
        # A -> 0 over tau, then the cruise's first half at zero acceleration
        pieces.append((tau, (1.0 - s[0], *(-c for c in s[1:]))))
        pieces.append((0.5 * cruise, (0.0,)))
    else:
        # the first half of one step from A to -A over 2 tau: 1 - 2 S(x / 2) on x in [0, 1]
        pieces.append((tau, (1.0 - 2.0 * s[0], *(-2.0 * c / 2.0**j for j, c in enumerate(s) if j > 0))))
    return [(L, a) for L, a in pieces if L > 0.0]


def _unit_half(
    T: float, tau: float, cruise: float, order: int
) -> tuple[list[tuple[float, float, tuple]], float, float]:
    """Position pieces of the first half for a unit peak acceleration: [(start s, length s, poly)], the position at
    T/2 (m) and the speed there (m/s)."""
    out = []
    p, v, t = 0.0, 0.0, 0.0
    for L, acc in _half_pieces(T, tau, cruise, order):
        poly = _position_piece(L, acc, p, v)
        out.append((t, L, poly))
        p, v = _end(poly, L)
        t += L
    return out, p, v


def move_profile(
    duration: float, ramp: float, cruise: float = 0.0, ramp_order: int = DEFAULT_RAMP_ORDER
) -> MoveProfile:
    """The :class:`MoveProfile` of a unit move in ``duration`` s with ``ramp`` s acceleration ramps and ``cruise`` s
    at constant speed in the middle (TrajectoryError if they do not fit: ``duration >= 4 ramp + cruise``)."""
    T = _positive("move time", duration)
    tau = _positive("ramp time", ramp)
    c = _finite("cruise time", cruise)
    if c < 0.0:
        raise TrajectoryError(f"cruise time must be >= 0 s, got {cruise!r}")
    _, half, speed = _unit_half(T, tau, c, ramp_order)
    A = 0.5 / half
    return MoveProfile(T, tau, c, ramp_order, A, A * speed)


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
        d = self.v1 - self.v0
        A = shape.peak_acceleration * d
        pieces, _, _ = _unit_half(shape.duration, shape.ramp, shape.cruise, shape.ramp_order)
        # (start, 1 / length, polynomial) per piece of the first half, scaled to this move
        self._pieces = tuple((t, 1.0 / L, PolynomialTaylor([A * c for c in poly])) for t, L, poly in pieces)
        self._d = d

    def _half(self, u: float, n: int) -> tuple[float, ...]:
        """Taylor coefficients (real time) of the displacement at u in [0, T/2]."""
        pieces = self._pieces
        i = len(pieces) - 1
        while i > 0 and u < pieces[i][0]:
            i -= 1
        t, inv, poly = pieces[i]
        return scaled(poly.taylor((u - t) * inv, n), inv)

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
        first = [self.t0 + t for t, _, _ in self._pieces]
        return tuple(
            sorted({*first, *(self.t0 + self.T - (b - self.t0) for b in first), self.t0 + 0.5 * self.T, self.end})
        )
