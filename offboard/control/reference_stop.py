"""A smooth stop after a reference's end, so that a flight hands the autopilot a vehicle at rest.

A reference that is still moving at its end (the paper's figure-eight, a circle: endless patterns cut at the
scenario's duration) would otherwise be followed on after the end while the load settles, and handed over at
speed: the autopilot's hold then brakes the vehicle on its own, knowing nothing of the load (the circle's 0.63 m/s
end swung the load to 0.185 rad within 2 s of the hand-over, against 0.032-0.038 rad after this stop; `slung demo
--scenario circle --disturbance none`, 4 Dec 2026). Here each channel leaves the reference at its end ``t_end`` on
a polynomial of degree 12 that matches the reference's derivatives of orders 0..6 there (so no input of the law
jumps: it uses the reference's F^(6)) and comes to rest, derivatives 1..6 zero, ``stop_s`` later: its rate is the
smallest polynomial with those ends, and where the channel rests follows from it (about ``p0 + v0 stop_s / 2``).
The law keeps damping the swing during the stop. A reference at rest at its end is left as it is (no stop).

Units and frames as :mod:`offboard.control.reference` (world NWU, z up, m, rad, s).
"""

from __future__ import annotations

import math

import numpy as np

from offboard.control.reference import ORDERS, FlatSample, Reference

#: shortest stop (s)
STOP_MIN_S = 2.0
#: mean deceleration of the stop: horizontal and vertical speed (m/s^2), heading rate (rad/s^2)
STOP_MEAN_DECEL = 0.25
STOP_MEAN_YAW_DECEL = 0.25
#: largest horizontal F^(6) of the stop (m/s^6): the law's commanded F^(6) maps to the tilt's second derivative
#: through ``n'' = F^(6) / c`` (c about g), so 1 m/s^6 asks about 0.1 rad/s^2 of tilt acceleration, a few percent
#: of a small vehicle's torque; a 2 s stop from the paper scenario's 0.17 m/s asked 97 m/s^6, more than its limit
STOP_MAX_F6 = 1.0
#: longest stop (s)
STOP_MAX_S = 60.0
#: a derivative (of any order, in its SI unit) this small counts as zero: the reference is at rest
AT_REST = 1e-9

_DEGREE = 2 * ORDERS - 2  # 12: the rate's orders 0..5 at both ends, integrated
_FACT = [math.factorial(k) for k in range(_DEGREE + 1)]
_POWERS = np.arange(_DEGREE + 1)  # the exponents of x, made once (sample runs every tick of the stop)


def stop_duration(end: FlatSample) -> float:
    """How long the stop from the reference's state ``end`` takes (s): at least :data:`STOP_MIN_S`, long enough
    that the speed (horizontal, vertical) and the heading rate come down at their mean decelerations, and that the
    horizontal F^(6) stays within :data:`STOP_MAX_F6`, or the reference's own at its end if larger (at most
    :data:`STOP_MAX_S`); 0 for a reference at rest at its end (every derivative within :data:`AT_REST`), which
    needs no stop."""
    if all(abs(v) < AT_REST for ch in end for v in ch[1:]):
        return 0.0
    speed = math.hypot(end.fx[1], end.fy[1])
    t = max(STOP_MIN_S, speed / STOP_MEAN_DECEL, abs(end.z[1]) / STOP_MEAN_DECEL, abs(end.psi[1]) / STOP_MEAN_YAW_DECEL)
    x = np.linspace(0.0, 1.0, 201)
    # never more than the reference itself asked at its end (its own F^(6) is where the stop starts)
    bound = max(STOP_MAX_F6, 1.05 * max(abs(end.fx[6]), abs(end.fy[6])))
    for _ in range(20):
        f6 = max(
            float(np.max(np.abs(np.polynomial.polynomial.polyval(x, np.polynomial.polynomial.polyder(c, 6))))) / t**6
            for c in (_stop_polynomial(end.fx, t), _stop_polynomial(end.fy, t))
        )
        if f6 <= bound * 1.0001 or t >= STOP_MAX_S:
            break
        t = min(STOP_MAX_S, t * (f6 / bound) ** 0.2)  # F^(6) of the speed's part scales as 1 / t^5
    return t


def _stop_polynomial(d: tuple[float, ...], stop_s: float) -> np.ndarray:
    """Coefficients in ``x = (t - t_end) / stop_s`` (lowest first, degree 12) of the stop of one channel whose
    derivatives at the end are ``d`` (orders 0..6, per s^k). Its rate is the polynomial of degree 11 that matches
    the rate's orders 0..5 (the channel's 1..6) at ``x = 0`` and is zero with its orders 1..5 at ``x = 1``; the
    channel is its integral from ``d_0``, so where it comes to rest follows from the derivatives (no overshoot of
    a chosen end point: among such stops it has the smallest rate polynomial)."""
    n = ORDERS - 1  # 6 conditions at each end of the rate
    # rate in x: r(x) = stop_s * (channel rate), r^(k)(0) = d_{k+1} stop_s^(k+1)
    c = np.zeros(2 * n)
    for k in range(n):
        c[k] = d[k + 1] * stop_s ** (k + 1) / _FACT[k]
    a = np.zeros((n, n))
    b = np.zeros(n)
    for order in range(n):
        # d^order/dx^order of x^j at x = 1 is j! / (j - order)!
        b[order] = -sum(c[j] * _FACT[j] / _FACT[j - order] for j in range(order, n))
        for col, j in enumerate(range(n, 2 * n)):
            a[order, col] = _FACT[j] / _FACT[j - order]
    c[n:] = np.linalg.solve(a, b)
    return np.concatenate(([d[0]], np.polynomial.polynomial.polyint(c)[1:]))


class StoppingReference:
    """``reference`` up to ``t_end`` (s, the flight's reference duration), then the smooth stop (above) and rest.
    A :class:`~offboard.control.reference.Reference` itself; ``stop_s`` is the stop's length (s)."""

    def __init__(self, reference: Reference, t_end: float) -> None:
        if not math.isfinite(t_end):
            raise ValueError(f"the stop must start at a finite time, got {t_end!r}")
        self.reference = reference
        self.t_end = float(t_end)
        end = reference.sample(self.t_end)
        self.stop_s = stop_duration(end)
        if self.stop_s == 0.0:  # at rest at its end: the reference itself, unchanged
            return
        coeffs = [_stop_polynomial(ch, self.stop_s) for ch in end]
        # rows: channel-major, orders 0..6 of each, in per-second units; columns: powers x^0..x^12, so that one
        # product with the powers of x gives every derivative of every channel (a few microseconds a tick)
        rows = []
        for c in coeffs:
            for k in range(ORDERS):
                d = np.polynomial.polynomial.polyder(c, k) / self.stop_s**k if k else c
                rows.append(np.pad(d, (0, _DEGREE + 1 - len(d))))
        self._matrix = np.array(rows)
        self._rest = FlatSample(*(tuple([float(np.sum(c)), *(0.0,) * (ORDERS - 1)]) for c in coeffs))

    @property
    def duration(self) -> float:
        """The reference's own length (s); the stop follows it."""
        return self.reference.duration

    def sample(self, t: float) -> FlatSample:
        """The reference at ``t`` (s) up to its end, the stop after it, the rest point after the stop."""
        if not math.isfinite(t):
            raise ValueError(f"reference sampled at a non-finite time t = {t!r} s")
        if t <= self.t_end or self.stop_s == 0.0:
            return self.reference.sample(t)
        x = (t - self.t_end) / self.stop_s
        if x >= 1.0:
            return self._rest
        v = (self._matrix @ (x**_POWERS)).tolist()
        n = ORDERS
        return FlatSample(tuple(v[0:n]), tuple(v[n : 2 * n]), tuple(v[2 * n : 3 * n]), tuple(v[3 * n :]))
