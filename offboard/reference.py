"""Smooth references for the flat outputs (F_x, F_y, z, psi) with exact derivatives of orders 0..6.

Frames and units: world NWU, z up. ``F_x, F_y`` are the LOAD's horizontal position to first order (m), ``z`` is the
height (m), ``psi`` the heading (rad). Time ``t`` in seconds. Each channel is a scalar trajectory (:class:`Scalar`)
that returns a :class:`~offboard.jet.Jet` (truncated Taylor series), so derivatives are exact up to rounding,
never differenced. Every transition is at least C^7: the building block is the degree-15 smooth step whose
derivatives 1..7 vanish at both ends, and phase-driven patterns (circle, figure-eight) ramp their angular rate with
that step, which makes the position C^8 at the ramp ends.

Design and file format: ``docs/references.md``.
"""

from __future__ import annotations

import itertools
import math
import numbers
from collections.abc import Callable, Sequence
from fractions import Fraction
from math import comb
from pathlib import Path
from typing import NamedTuple, Protocol

from estimators.errors import UserError
from offboard.jet import FACTORIALS, Jet, PolynomialTaylor

try:
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10
    import tomli as tomllib

ORDERS = 7  # derivative orders 0..6 in a FlatSample


class TrajectoryError(UserError, ValueError):
    """A reference was asked for with invalid arguments (one-line message naming the value)."""


class FlatSample(NamedTuple):
    """Flat outputs and their derivatives at one instant (each a 7-tuple, orders 0..6)."""

    fx: tuple[float, ...]  # F_x (m), m/s, ..., m/s^6; world NWU, load horizontal position to first order
    fy: tuple[float, ...]  # F_y, same units
    z: tuple[float, ...]  # height (m, up) and its derivatives
    psi: tuple[float, ...]  # heading (rad) and its derivatives (rad/s^k)


class Reference(Protocol):
    """What the controller needs: flat outputs with derivatives at any finite time, and a natural length."""

    def sample(self, t: float) -> FlatSample: ...

    @property
    def duration(self) -> float: ...


# --------------------------------------------------------------------------------------------------------------
# polynomials of the smooth step (exact rational coefficients, converted once)
# --------------------------------------------------------------------------------------------------------------
STEP_ORDER = 7  # derivatives 1..7 vanish at both ends -> degree 2*7+1 = 15


def _step_coefficients(order: int) -> list[Fraction]:
    """Monomial coefficients of S(x) = x^(N+1) sum_k C(N+k, k) C(2N+1, N-k) (-x)^k (the order-N smooth step)."""
    n = order
    coef = [Fraction(0)] * (2 * n + 2)
    for k in range(n + 1):
        coef[n + 1 + k] += Fraction(comb(n + k, k) * comb(2 * n + 1, n - k) * (-1) ** k)
    return coef


def _antiderivative(coef: Sequence[Fraction]) -> list[Fraction]:
    return [Fraction(0)] + [c / (j + 1) for j, c in enumerate(coef)]


def _hermite_velocity_basis(order: int) -> tuple[list[Fraction], list[Fraction]]:
    """Degree-(2N+1) polynomials h0, h1 on [0, 1]: h0'(0) = 1, h1'(1) = 1, every other value and derivative 0..N
    at both ends zero. With the smooth step S they span the Hermite interpolants with given end slopes."""
    deg = 2 * order + 1
    out = []
    for at_one in (False, True):
        # unknowns a_0..a_deg; conditions: p^(k)(0) = target0_k, p^(k)(1) = target1_k for k = 0..order
        rows: list[list[Fraction]] = []
        rhs: list[Fraction] = []
        for k in range(order + 1):
            rows.append([Fraction(math.factorial(k)) if j == k else Fraction(0) for j in range(deg + 1)])
            rhs.append(Fraction(1 if (k == 1 and not at_one) else 0))
        for k in range(order + 1):
            rows.append([Fraction(math.perm(j, k)) for j in range(deg + 1)])
            rhs.append(Fraction(1 if (k == 1 and at_one) else 0))
        out.append(_solve_exact(rows, rhs))
    return out[0], out[1]


def _solve_exact(a: list[list[Fraction]], b: list[Fraction]) -> list[Fraction]:
    n = len(b)
    m = [[*row, b[i]] for i, row in enumerate(a)]
    for col in range(n):
        piv = next(r for r in range(col, n) if m[r][col] != 0)
        m[col], m[piv] = m[piv], m[col]
        p = m[col][col]
        m[col] = [x / p for x in m[col]]
        for r in range(n):
            if r != col and m[r][col] != 0:
                f = m[r][col]
                m[r] = [x - f * y for x, y in zip(m[r], m[col])]
    return [m[i][n] for i in range(n)]


_STEP = PolynomialTaylor([float(c) for c in _step_coefficients(STEP_ORDER)])
_STEP_INTEGRAL = PolynomialTaylor([float(c) for c in _antiderivative(_step_coefficients(STEP_ORDER))])  # 1/2 at 1
_H0_EXACT, _H1_EXACT = _hermite_velocity_basis(STEP_ORDER)
_H0 = PolynomialTaylor([float(c) for c in _H0_EXACT])
_H1 = PolynomialTaylor([float(c) for c in _H1_EXACT])


def _mirrored(c: tuple[float, ...]) -> tuple[float, ...]:
    """Series of g(1 - x) at x from the series of g at 1 - x: coefficient k times (-1)^k."""
    return tuple(-v if k & 1 else v for k, v in enumerate(c))


def _step_series(x: float, n: int) -> tuple[float, ...]:
    """Series of the smooth step S at x in (0, 1); for x > 1/2 via S(x) = 1 - S(1 - x) (no cancellation near 1)."""
    if x <= 0.5:
        return _STEP.taylor(x, n)
    c = _mirrored(_STEP.taylor(1.0 - x, n))
    return (1.0 - c[0], *(-v for v in c[1:]))


def _step_integral_series(x: float, n: int) -> tuple[float, ...]:
    """Series of I(x) = integral_0^x S; for x > 1/2 via I(x) = x - 1/2 + I(1 - x)."""
    if x <= 0.5:
        return _STEP_INTEGRAL.taylor(x, n)
    c = list(_mirrored(_STEP_INTEGRAL.taylor(1.0 - x, n)))
    c[0] += x - 0.5
    if n > 1:
        c[1] += 1.0
    return tuple(c)


def smooth_step_value(x: float) -> float:
    """The degree-15 smooth step on [0, 1] (0 below, 1 above); derivatives 1..7 vanish at 0 and 1."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    return _step_series(x, 1)[0]


def _scaled(c: tuple[float, ...], inv_t: float) -> tuple[float, ...]:
    """Series in tau = (t - t0) / T  ->  series in t (coefficient k times T^-k)."""
    out = []
    f = 1.0
    for x in c:
        out.append(x * f)
        f *= inv_t
    return tuple(out)


# --------------------------------------------------------------------------------------------------------------
# argument checks
# --------------------------------------------------------------------------------------------------------------
def _finite(name: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TrajectoryError(f"{name} must be a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise TrajectoryError(f"{name} must be finite, got {value!r}")
    return v


def _positive(name: str, value: object) -> float:
    v = _finite(name, value)
    if v <= 0.0:
        raise TrajectoryError(f"{name} must be > 0 s, got {value!r}")
    return v


def _non_negative(name: str, value: object) -> float:
    v = _finite(name, value)
    if v < 0.0:
        raise TrajectoryError(f"{name} must be >= 0, got {value!r}")
    return v


# --------------------------------------------------------------------------------------------------------------
# scalar trajectories
# --------------------------------------------------------------------------------------------------------------
class Scalar:
    """A scalar function of time with exact derivatives.

    Subclasses implement :meth:`jet` (``n`` Taylor coefficients at ``t``, for any finite ``t``), :attr:`end` (the
    time after which the value is constant; ``inf`` for endless motions) and :attr:`breakpoints` (times where
    pieces meet, for tests). ``+``, ``-``, ``*`` by a number and :meth:`shifted` build new scalars.
    """

    def jet(self, t: float, n: int = ORDERS) -> Jet:
        raise NotImplementedError

    @property
    def end(self) -> float:
        return -math.inf

    @property
    def breakpoints(self) -> tuple[float, ...]:
        return ()

    def derivatives(self, t: float, n: int = ORDERS) -> tuple[float, ...]:
        """``(f, f', ..., f^(n-1))`` at ``t``."""
        return self.jet(t, n).derivatives()

    def __add__(self, other: Scalar | float) -> Scalar:
        return Sum(self, as_scalar(other))

    def __radd__(self, other: Scalar | float) -> Scalar:
        return Sum(as_scalar(other), self)

    def __sub__(self, other: Scalar | float) -> Scalar:
        return Sum(self, Scaled(as_scalar(other), -1.0))

    def __rsub__(self, other: float) -> Scalar:
        return Sum(as_scalar(other), Scaled(self, -1.0))

    def __neg__(self) -> Scalar:
        return Scaled(self, -1.0)

    def __mul__(self, k: float) -> Scalar:
        return Scaled(self, _finite("scale factor", k))

    __rmul__ = __mul__

    def shifted(self, dt: float) -> Scalar:
        """The same trajectory ``dt`` seconds later: ``g(t) = f(t - dt)``."""
        return Shifted(self, dt)


def as_scalar(x: Scalar | float) -> Scalar:
    """A :class:`Scalar` unchanged, a number as :class:`Constant`."""
    if isinstance(x, Scalar):
        return x
    return Constant(x)


class Constant(Scalar):
    """A constant value (any unit)."""

    def __init__(self, value: float) -> None:
        self.value = _finite("constant value", value)

    def jet(self, t: float, n: int = ORDERS) -> Jet:
        return Jet.constant(self.value, n)


class SmoothStep(Scalar):
    """From ``start_value`` to ``end_value`` during ``[t_start, t_start + duration]`` (s) with the degree-15 step.

    Held at ``start_value`` before and at ``end_value`` after; derivatives 1..7 are zero at both ends (C^7).
    """

    def __init__(self, start_value: float, end_value: float, t_start: float, duration: float) -> None:
        self.v0 = _finite("start value", start_value)
        self.v1 = _finite("end value", end_value)
        self.t0 = _finite("t_start", t_start)
        self.T = _positive("duration", duration)
        self._inv = 1.0 / self.T
        self._d = self.v1 - self.v0

    def jet(self, t: float, n: int = ORDERS) -> Jet:
        x = (t - self.t0) * self._inv
        if x <= 0.0:
            return Jet.constant(self.v0, n)
        if x >= 1.0:
            return Jet.constant(self.v1, n)
        c = _scaled(_step_series(x, n), self._inv)
        d = self._d
        return Jet._raw((self.v0 + d * c[0], *(d * v for v in c[1:])))

    @property
    def end(self) -> float:
        return self.t0 + self.T

    @property
    def breakpoints(self) -> tuple[float, ...]:
        return (self.t0, self.t0 + self.T)


class Sum(Scalar):
    """Sum of scalar trajectories (e.g. several smooth steps one after another)."""

    def __init__(self, *terms: Scalar | float) -> None:
        self.terms = tuple(as_scalar(x) for x in terms)

    def jet(self, t: float, n: int = ORDERS) -> Jet:
        acc = [0.0] * n
        for term in self.terms:
            for k, v in enumerate(term.jet(t, n).c):
                acc[k] += v
        return Jet._raw(tuple(acc))

    @property
    def end(self) -> float:
        return max((x.end for x in self.terms), default=-math.inf)

    @property
    def breakpoints(self) -> tuple[float, ...]:
        return tuple(sorted({b for x in self.terms for b in x.breakpoints}))


class Scaled(Scalar):
    """``k * f(t)`` for a number ``k``."""

    def __init__(self, inner: Scalar, k: float) -> None:
        self.inner = inner
        self.k = _finite("scale factor", k)

    def jet(self, t: float, n: int = ORDERS) -> Jet:
        return self.inner.jet(t, n) * self.k

    @property
    def end(self) -> float:
        return self.inner.end

    @property
    def breakpoints(self) -> tuple[float, ...]:
        return self.inner.breakpoints


class Shifted(Scalar):
    """``f(t - dt)``: the same trajectory ``dt`` seconds later."""

    def __init__(self, inner: Scalar, dt: float) -> None:
        self.inner = inner
        self.dt = _finite("time shift", dt)

    def jet(self, t: float, n: int = ORDERS) -> Jet:
        return self.inner.jet(t - self.dt, n)

    @property
    def end(self) -> float:
        return self.inner.end + self.dt

    @property
    def breakpoints(self) -> tuple[float, ...]:
        return tuple(b + self.dt for b in self.inner.breakpoints)


class Mapped(Scalar):
    """``func(a(t), b(t), ...)`` for a function of jets built from jet arithmetic (``+ - *``, ``sin``, ``cos``).

    Example: ``Mapped(lambda a, p: a * p.sin(), amplitude, phase)``. ``func`` must be smooth; the result is exact.
    """

    def __init__(self, func: Callable[..., Jet], *args: Scalar | float) -> None:
        self.func = func
        self.args = tuple(as_scalar(a) for a in args)

    def jet(self, t: float, n: int = ORDERS) -> Jet:
        return self.func(*(a.jet(t, n) for a in self.args))

    @property
    def end(self) -> float:
        return max((a.end for a in self.args), default=-math.inf)

    @property
    def breakpoints(self) -> tuple[float, ...]:
        return tuple(sorted({b for a in self.args for b in a.breakpoints}))


class Phase(Scalar):
    """Angle (rad) advancing at ``rate`` (rad/s) after a smooth ramp-in, optionally ramping out again.

    The angular rate is ``rate * S((t - t_start) / ramp_time)`` with the degree-15 step S, so the phase and
    everything built from it starts at rest with derivatives 1..8 zero. With ``cruise_time`` given, after the
    cruise the rate ramps back to zero over another ``ramp_time`` and the phase is held. Total advance with
    a ramp-out: ``rate * (ramp_time + cruise_time)``. Caches ``sin``/``cos`` of multiples for the last ``t``.
    """

    def __init__(
        self, rate: float, t_start: float, ramp_time: float, cruise_time: float | None = None, phase0: float = 0.0
    ) -> None:
        self.rate = _finite("angular rate", rate)
        self.t0 = _finite("t_start", t_start)
        self.Tr = _positive("ramp_time", ramp_time)
        self.Tc = None if cruise_time is None else _non_negative("cruise time", cruise_time)
        self.phase0 = _finite("initial phase", phase0)
        self._inv = 1.0 / self.Tr
        self._half = 0.5 * self.rate * self.Tr  # phase gained during one ramp
        # (t, n, phase jet, {multiple: (sin, cos)}) of the last sincos call
        self._entry: tuple[float, int, Jet, dict[float, tuple[Jet, Jet]]] = (math.nan, 0, Jet.constant(0.0, 1), {})

    def jet(self, t: float, n: int = ORDERS) -> Jet:
        s = t - self.t0
        w, Tr = self.rate, self.Tr
        if s <= 0.0:
            return Jet.constant(self.phase0, n)
        if s < Tr:
            c = _scaled(_step_integral_series(s * self._inv, n), self._inv)
            k = w * Tr
            return Jet._raw((self.phase0 + k * c[0], *(k * v for v in c[1:])))
        s -= Tr
        if self.Tc is None or s <= self.Tc:
            return Jet._raw((self.phase0 + self._half + w * s, w) + (0.0,) * (n - 2)) if n > 1 else Jet._raw(
                (self.phase0 + self._half + w * s,)
            )
        base = self.phase0 + self._half + w * self.Tc
        s -= self.Tc
        if s >= Tr:
            return Jet.constant(base + self._half, n)
        c = _scaled(_step_integral_series(s * self._inv, n), self._inv)
        k = w * Tr
        lin = (base + w * s, w) + (0.0,) * (n - 2)
        return Jet._raw(tuple(a - k * b for a, b in zip(lin, c)))

    def sincos(self, t: float, n: int, multiple: float = 1.0) -> tuple[Jet, Jet]:
        """(sin, cos) of ``multiple * phase(t)``, cached for the last (t, n).

        The cache is one tuple replaced in a single assignment, so a concurrent caller can at worst recompute,
        never read another instant's values.
        """
        entry = self._entry
        if entry[0] != t or entry[1] != n:
            entry = (t, n, self.jet(t, n), {})
            self._entry = entry
        cache = entry[3]
        hit = cache.get(multiple)
        if hit is None:
            ph = entry[2]
            if not any(ph.c[1:]):  # held (before the start or after the ramp-out): constants, no series work
                a = multiple * ph.c[0]
                hit = (Jet.constant(math.sin(a), n), Jet.constant(math.cos(a), n))
            else:
                hit = (ph * multiple).sincos() if multiple != 1.0 else ph.sincos()
            cache[multiple] = hit
        return hit

    @property
    def end(self) -> float:
        return math.inf if self.Tc is None else self.t0 + 2.0 * self.Tr + self.Tc

    @property
    def breakpoints(self) -> tuple[float, ...]:
        b = (self.t0, self.t0 + self.Tr)
        if self.Tc is not None:
            b += (self.t0 + self.Tr + self.Tc, self.t0 + 2.0 * self.Tr + self.Tc)
        return b


class PhaseSine(Scalar):
    """``offset + amplitude * sin(multiple * phase(t))`` (or ``cos`` with ``cosine=True``)."""

    def __init__(
        self, phase: Phase, amplitude: float, multiple: float = 1.0, cosine: bool = False, offset: float = 0.0
    ) -> None:
        self.phase = phase
        self.amplitude = _finite("amplitude", amplitude)
        self.multiple = _finite("phase multiple", multiple)
        self.cosine = bool(cosine)
        self.offset = _finite("offset", offset)

    def jet(self, t: float, n: int = ORDERS) -> Jet:
        s, c = self.phase.sincos(t, n, self.multiple)
        a = self.amplitude
        src = c.c if self.cosine else s.c
        return Jet._raw((self.offset + a * src[0], *(a * v for v in src[1:])))

    @property
    def end(self) -> float:
        return self.phase.end

    @property
    def breakpoints(self) -> tuple[float, ...]:
        return self.phase.breakpoints


class HermiteSpline(Scalar):
    """Piecewise degree-15 polynomial through ``values`` at ``times`` with the given ``slopes`` (unit/s).

    At every knot the value and slope are as given and derivatives 2..7 are zero, so the curve is C^7. Before
    the first and after the last knot the end values are held (C^7 there too when the end slopes are zero).
    """

    def __init__(self, times: Sequence[float], values: Sequence[float], slopes: Sequence[float]) -> None:
        if not (len(times) == len(values) == len(slopes)) or len(times) < 2:
            raise TrajectoryError("a Hermite spline needs at least 2 knots with one value and slope each")
        self.times = tuple(_finite("knot time", x) for x in times)
        self.values = tuple(_finite("knot value", x) for x in values)
        self.slopes = tuple(_finite("knot slope", x) for x in slopes)
        for a, b in itertools.pairwise(self.times):
            if not b > a:
                raise TrajectoryError(f"knot times must increase, got {a!r} then {b!r}")
        # one polynomial per half segment, precomputed: in x = (t - t_i) / T on [0, 1/2] and in y = 1 - x on
        # [0, 1/2] (the mirror keeps the variable small, so no cancellation near the right end)
        sc, h0c, h1c = _STEP.coefficients, _H0.coefficients, _H1.coefficients
        self._pieces: list[tuple[float, float, PolynomialTaylor, PolynomialTaylor]] = []
        for i in range(len(self.times) - 1):
            T = self.times[i + 1] - self.times[i]
            dp = self.values[i + 1] - self.values[i]
            m0 = self.slopes[i] * T
            m1 = self.slopes[i + 1] * T
            # p(x) = p0 + dp S(x) + m0 h0(x) + m1 h1(x)
            left = [dp * a + m0 * b + m1 * d for a, b, d in zip(sc, h0c, h1c)]
            left[0] += self.values[i]
            # with S(x) = 1 - S(y), h0(x) = -h1(y), h1(x) = -h0(y):  p = p1 - dp S(y) - m0 h1(y) - m1 h0(y)
            right = [-(dp * a + m0 * d + m1 * b) for a, b, d in zip(sc, h0c, h1c)]
            right[0] += self.values[i + 1]
            self._pieces.append((self.times[i], 1.0 / T, PolynomialTaylor(left), PolynomialTaylor(right)))

    def jet(self, t: float, n: int = ORDERS) -> Jet:
        ts = self.times
        if t <= ts[0]:
            return Jet.constant(self.values[0], n)
        if t >= ts[-1]:
            return Jet.constant(self.values[-1], n)
        lo, hi = 0, len(ts) - 1
        while hi - lo > 1:
            mid = (lo + hi) // 2
            if ts[mid] <= t:
                lo = mid
            else:
                hi = mid
        t0, inv, left, right = self._pieces[lo]
        x = (t - t0) * inv
        if x <= 0.5:
            return Jet._raw(_scaled(left.taylor(x, n), inv))
        return Jet._raw(_scaled(_mirrored(right.taylor(1.0 - x, n)), inv))

    @property
    def end(self) -> float:
        return self.times[-1]

    @property
    def breakpoints(self) -> tuple[float, ...]:
        return self.times


# --------------------------------------------------------------------------------------------------------------
# references
# --------------------------------------------------------------------------------------------------------------
class Composite:
    """A :class:`Reference` from one scalar trajectory (or number) per flat output.

    ``fx, fy`` (m, world NWU, load position to first order), ``z`` (m, up), ``psi`` (rad). ``duration`` (s)
    defaults to the latest end of a finite channel motion (0 if every channel is constant). Use
    :meth:`replace` to override channels, e.g. ``figure_eight(...).replace(z=SmoothStep(1, 2, 0, 5))``.
    """

    def __init__(
        self,
        fx: Scalar | float = 0.0,
        fy: Scalar | float = 0.0,
        z: Scalar | float = 0.0,
        psi: Scalar | float = 0.0,
        duration: float | None = None,
    ) -> None:
        self.fx = as_scalar(fx)
        self.fy = as_scalar(fy)
        self.z = as_scalar(z)
        self.psi = as_scalar(psi)
        self._duration = None if duration is None else _non_negative("duration", duration)

    @property
    def channels(self) -> tuple[Scalar, Scalar, Scalar, Scalar]:
        return (self.fx, self.fy, self.z, self.psi)

    @property
    def duration(self) -> float:
        """Natural length (s): configured, else the time the last finite channel motion ends (>= 0)."""
        if self._duration is not None:
            return self._duration
        ends = [c.end for c in self.channels if math.isfinite(c.end)]
        return max([0.0, *ends])

    @property
    def breakpoints(self) -> tuple[float, ...]:
        return tuple(sorted({b for c in self.channels for b in c.breakpoints}))

    def replace(
        self,
        fx: Scalar | float | None = None,
        fy: Scalar | float | None = None,
        z: Scalar | float | None = None,
        psi: Scalar | float | None = None,
        duration: float | None = None,
    ) -> Composite:
        """A copy with the given channels (and duration) overridden."""
        return Composite(
            self.fx if fx is None else fx,
            self.fy if fy is None else fy,
            self.z if z is None else z,
            self.psi if psi is None else psi,
            self._duration if duration is None else duration,
        )

    def jets(self, t: float, n: int = ORDERS) -> tuple[Jet, Jet, Jet, Jet]:
        """Jets of (fx, fy, z, psi) with ``n`` coefficients (orders 0..n-1) at ``t`` (s)."""
        return (self.fx.jet(t, n), self.fy.jet(t, n), self.z.jet(t, n), self.psi.jet(t, n))

    def sample(self, t: float) -> FlatSample:
        """Flat outputs and derivatives of orders 0..6 at ``t`` (s); any finite t (held outside the motion).

        Raises ValueError for a non-finite ``t`` (so no NaN can leave a reference).
        """
        if not math.isfinite(t):
            raise ValueError(f"reference sampled at a non-finite time t = {t!r} s")
        f = FACTORIALS
        out = []
        for ch in (self.fx, self.fy, self.z, self.psi):
            c = ch.jet(t, ORDERS).c
            out.append((c[0], c[1], c[2] * f[2], c[3] * f[3], c[4] * f[4], c[5] * f[5], c[6] * f[6]))
        return FlatSample(out[0], out[1], out[2], out[3])


def hover(x: float, y: float, z: float, psi: float = 0.0) -> Composite:
    """Hold F = (x, y) (m), height z (m) and heading psi (rad); duration 0."""
    return Composite(Constant(x), Constant(y), Constant(z), Constant(psi))


def _pose(name: str, p: Sequence[float]) -> tuple[float, float, float, float]:
    if isinstance(p, (str, bytes)) or not hasattr(p, "__len__") or len(p) not in (3, 4):
        raise TrajectoryError(f"{name} must be (x, y, z) or (x, y, z, psi), got {p!r}")
    vals = [_finite(f"{name}[{i}]", v) for i, v in enumerate(p)]
    if len(vals) == 3:
        vals.append(0.0)
    return vals[0], vals[1], vals[2], vals[3]


def rest_to_rest(
    start: Sequence[float], end: Sequence[float], t_start: float, move_time: float
) -> Composite:
    """Rest at ``start`` (x, y, z[, psi]) until ``t_start`` (s), move with the degree-15 step during ``move_time``
    (s), rest at ``end``. psi is taken literally (no angle wrapping). Duration: ``t_start + move_time``."""
    a = _pose("start", start)
    b = _pose("end", end)
    t0 = _finite("t_start", t_start)
    T = _positive("move_time", move_time)
    return Composite(*(SmoothStep(u, v, t0, T) for u, v in zip(a, b)))


def _phase_for(period: float, t_start: float, ramp_time: float | None, laps: int | None) -> tuple[Phase, float]:
    P = _positive("period", period)
    t0 = _finite("t_start", t_start)
    Tr = 0.5 * P if ramp_time is None else _positive("ramp_time", ramp_time)
    rate = 2.0 * math.pi / P
    if laps is None:
        return Phase(rate, t0, Tr), t0 + Tr + 2.0 * P
    if isinstance(laps, bool) or not isinstance(laps, int) or laps < 1:
        raise TrajectoryError(f"laps must be a whole number >= 1 (or None for endless), got {laps!r}")
    cruise = laps * P - Tr
    if cruise < 0.0:
        raise TrajectoryError(f"ramp_time {Tr!r} s is longer than {laps} lap(s) of {P!r} s")
    phase = Phase(rate, t0, Tr, cruise)
    return phase, phase.end


def circle(
    center: Sequence[float],
    radius: float,
    period: float,
    z: float,
    t_start: float = 0.0,
    ramp_time: float | None = None,
    laps: int | None = None,
    psi: float = 0.0,
) -> Composite:
    """Counter-clockwise circle (seen from above, NWU) of ``radius`` (m) around ``center`` (x, y) (m) at height ``z``.

    Starts at rest at ``(cx + radius, cy)`` at ``t_start`` (s); the angular rate ramps smoothly (degree-15 step,
    ``ramp_time`` s, default period/2) to 2 pi / ``period`` (s). ``laps``: whole number of laps after which it has
    ramped down and rests at the start point again (the ramps included); None: endless, and ``duration`` reports
    the end of the ramp-in plus two periods. Heading held at ``psi`` (rad).
    """
    cx, cy = _center(center)
    R = _positive_len("radius", radius)
    phase, end = _phase_for(period, t_start, ramp_time, laps)
    return Composite(
        PhaseSine(phase, R, cosine=True, offset=cx), PhaseSine(phase, R, offset=cy), Constant(z), Constant(psi), end
    )


def figure_eight(
    center: Sequence[float],
    size_x: float,
    size_y: float,
    period: float,
    z: float,
    t_start: float = 0.0,
    ramp_time: float | None = None,
    laps: int | None = None,
    psi: float = 0.0,
) -> Composite:
    """Lissajous 1:2 figure-eight: ``x = cx + size_x/2 sin(phase)``, ``y = cy + size_y/2 sin(2 phase)``.

    Full extent ``size_x`` by ``size_y`` (m) around ``center`` (m), one figure per ``period`` (s) at cruise, height
    ``z`` (m), heading ``psi`` (rad). Starts at rest at the center at ``t_start`` (s), phase rate ramped in over
    ``ramp_time`` (s, default period/2) like :func:`circle`; ``laps`` as in :func:`circle`.
    """
    cx, cy = _center(center)
    ax = 0.5 * _positive_len("size_x", size_x)
    ay = 0.5 * _positive_len("size_y", size_y)
    phase, end = _phase_for(period, t_start, ramp_time, laps)
    return Composite(
        PhaseSine(phase, ax, offset=cx), PhaseSine(phase, ay, multiple=2.0, offset=cy), Constant(z), Constant(psi), end
    )


def _center(center: object) -> tuple[float, float]:
    if isinstance(center, (str, bytes)) or not hasattr(center, "__len__") or len(center) != 2:
        raise TrajectoryError(f"center must be (x, y) in m, got {center!r}")
    return _finite("center x", center[0]), _finite("center y", center[1])


def _positive_len(name: str, value: object) -> float:
    v = _finite(name, value)
    if v <= 0.0:
        raise TrajectoryError(f"{name} must be > 0 m, got {value!r}")
    return v


SLOPE_LIMIT = 1.4  # interior waypoint slope / smaller neighbouring secant (keeps monotone data monotone)


def _knot_slopes(times: Sequence[float], values: Sequence[float]) -> list[float]:
    """Interior slopes: centred difference, zero at a local extremum or flat spot (no overshoot there), limited to
    ``SLOPE_LIMIT`` times the smaller neighbouring secant; zero at both ends (start and end at rest).

    The limit keeps monotone data monotone: for the degree-15 Hermite piece with zero derivatives 2..7 at its
    ends, ``S' + a h0' + b h1' >= 0`` on [0, 1] for all end slopes ``a, b`` in [0, 1.4] (in units of the
    segment's secant; checked on a fine grid, the feasible set is convex and holds the corners of that square,
    it fails from about a = b = 1.45). A straight line (slope = secant) is reproduced exactly.
    """
    m = [0.0] * len(values)
    for i in range(1, len(values) - 1):
        d0 = (values[i] - values[i - 1]) / (times[i] - times[i - 1])
        d1 = (values[i + 1] - values[i]) / (times[i + 1] - times[i])
        if d0 * d1 <= 0.0:
            continue
        c = (values[i + 1] - values[i - 1]) / (times[i + 1] - times[i - 1])
        lim = SLOPE_LIMIT * min(abs(d0), abs(d1))
        m[i] = math.copysign(min(abs(c), lim), c)
    return m


def waypoints(
    points: Sequence[Sequence[float]],
    speed: float | None = None,
    segment_times: Sequence[float] | None = None,
    t_start: float = 0.0,
    yaw_rate: float = 0.5,
    min_segment_time: float = 1.0,
) -> Composite:
    """A C^7 path through ``points`` (x, y, z[, psi]) (m, m, m, rad), at rest at the first and last point.

    Timing: either ``segment_times`` (s, one per segment) or ``speed`` (m/s, mean along the straight chords): a
    segment takes ``max(chord / speed, |dpsi| / yaw_rate, min_segment_time)`` s. The first point is held until
    ``t_start``. Per channel, a degree-15 Hermite piece joins consecutive points. The path does not stop at interior
    waypoints: the slope there is the centred difference, zero where that channel has a local extremum, limited to
    1.4 times the smaller neighbouring secant so monotone data give a monotone path. Derivatives 2..7 vanish at each
    waypoint, so the path is C^7. psi is taken literally (no angle wrapping). One point: hover there.
    """
    if isinstance(points, (str, bytes)):
        raise TrajectoryError(f"waypoints: expected a sequence of (x, y, z[, psi]), got {points!r}")
    points = list(points)
    if len(points) == 0:
        raise TrajectoryError("waypoints: the list of points is empty; give at least one (x, y, z[, psi])")
    poses = [_pose(f"waypoint {i}", p) for i, p in enumerate(points)]
    t0 = _finite("t_start", t_start)
    if len(poses) == 1:
        return hover(*poses[0])
    nseg = len(poses) - 1
    if segment_times is not None:
        if speed is not None:
            raise TrajectoryError("waypoints: give either speed or segment_times, not both")
        if len(segment_times) != nseg:
            raise TrajectoryError(f"waypoints: {len(segment_times)} segment times for {nseg} segments")
        durs = [_positive(f"segment_times[{i}]", d) for i, d in enumerate(segment_times)]
    else:
        if speed is None:
            raise TrajectoryError("waypoints: give speed (m/s) or segment_times (s)")
        v = _finite("speed", speed)
        if v <= 0.0:
            raise TrajectoryError(f"speed must be > 0 m/s, got {speed!r}")
        wr = _finite("yaw_rate", yaw_rate)
        if wr <= 0.0:
            raise TrajectoryError(f"yaw_rate must be > 0 rad/s, got {yaw_rate!r}")
        tmin = _positive("min_segment_time", min_segment_time)
        durs = []
        for a, b in itertools.pairwise(poses):
            chord = math.dist(a[:3], b[:3])
            durs.append(max(chord / v, abs(b[3] - a[3]) / wr, tmin))
    times = [t0]
    for d in durs:
        times.append(times[-1] + d)
    chans = []
    for k in range(4):
        vals = [p[k] for p in poses]
        if all(x == vals[0] for x in vals):
            chans.append(Constant(vals[0]))
        else:
            chans.append(HermiteSpline(times, vals, _knot_slopes(times, vals)))
    return Composite(*chans, duration=times[-1])


# --------------------------------------------------------------------------------------------------------------
# trajectory files
# --------------------------------------------------------------------------------------------------------------
_KINDS = ("waypoints", "hover", "circle", "figure_eight")
_KEYS = {
    "waypoints": {"kind", "t_start", "speed", "segment_times", "yaw_rate", "min_segment_time", "waypoint"},
    "hover": {"kind", "x", "y", "z", "psi", "psi_deg"},
    "circle": {"kind", "center", "radius", "period", "z", "t_start", "ramp_time", "laps", "psi", "psi_deg"},
    "figure_eight": {
        "kind", "center", "size_x", "size_y", "period", "z", "t_start", "ramp_time", "laps", "psi", "psi_deg",
    },
}


def _file_psi(where: str, d: dict) -> float:
    if "psi" in d and "psi_deg" in d:
        raise TrajectoryError(f"{where}: give psi (rad) or psi_deg (degrees), not both")
    if "psi_deg" in d:
        return math.radians(_finite(f"{where}: psi_deg", d["psi_deg"]))
    return _finite(f"{where}: psi", d.get("psi", 0.0))


def _need(where: str, d: dict, key: str) -> object:
    if key not in d:
        raise TrajectoryError(f"{where}: missing '{key}'")
    return d[key]


def _reference_from_table(data: dict, where: str) -> Composite:
    kind = data.get("kind", "waypoints")
    if kind not in _KINDS:
        raise TrajectoryError(f"{where}: kind must be one of {', '.join(_KINDS)}, got {kind!r}")
    unknown = sorted(set(data) - _KEYS[kind])
    if unknown:
        raise TrajectoryError(f"{where}: unknown key(s) for kind '{kind}': {', '.join(unknown)}")
    num = {k: v for k, v in data.items() if k not in ("kind", "waypoint", "center", "segment_times")}
    for k, v in num.items():
        if k != "laps":
            _finite(f"{where}: {k}", v)
    if kind == "hover":
        return hover(_need(where, data, "x"), _need(where, data, "y"), _need(where, data, "z"), _file_psi(where, data))
    if kind in ("circle", "figure_eight"):
        center = _need(where, data, "center")
        if not isinstance(center, list) or len(center) != 2:
            raise TrajectoryError(f"{where}: center must be [x, y] in m, got {center!r}")
        common = {
            "period": _need(where, data, "period"),
            "z": _finite(f"{where}: z", _need(where, data, "z")),
            "t_start": data.get("t_start", 0.0),
            "ramp_time": data.get("ramp_time"),
            "laps": data.get("laps"),
            "psi": _file_psi(where, data),
        }
        try:
            if kind == "circle":
                return circle(center, _need(where, data, "radius"), **common)
            return figure_eight(center, _need(where, data, "size_x"), _need(where, data, "size_y"), **common)
        except TrajectoryError as exc:
            raise TrajectoryError(f"{where}: {exc}") from None
    wps = data.get("waypoint")
    if not isinstance(wps, list) or not wps:
        raise TrajectoryError(f"{where}: no [[waypoint]] entries")
    pts = []
    times = []
    for i, w in enumerate(wps):
        wh = f"{where}: waypoint {i + 1}"
        if not isinstance(w, dict):
            raise TrajectoryError(f"{wh}: must be a table with x, y, z")
        bad = sorted(set(w) - {"x", "y", "z", "psi", "psi_deg", "t"})
        if bad:
            raise TrajectoryError(f"{wh}: unknown key(s) {', '.join(bad)}")
        pts.append(
            (
                _finite(f"{wh}: x", _need(wh, w, "x")),
                _finite(f"{wh}: y", _need(wh, w, "y")),
                _finite(f"{wh}: z", _need(wh, w, "z")),
                _file_psi(wh, w),
            )
        )
        if "t" in w:
            times.append(_finite(f"{wh}: t", w["t"]))
    try:
        if times:
            if len(times) != len(pts):
                raise TrajectoryError("give t on every waypoint or on none")
            if any(k in data for k in ("speed", "segment_times", "t_start")):
                raise TrajectoryError("waypoint times t exclude speed, segment_times and t_start")
            seg = [b - a for a, b in itertools.pairwise(times)]
            for i, d in enumerate(seg):
                if not d > 0.0:
                    raise TrajectoryError(f"waypoint times must increase (waypoint {i + 2} at t = {times[i + 1]!r} s)")
            return waypoints(pts, segment_times=seg or None, t_start=times[0]) if seg else hover(*pts[0])
        seg_times = data.get("segment_times")
        if seg_times is not None and not isinstance(seg_times, list):
            raise TrajectoryError(f"segment_times must be a list of seconds, got {seg_times!r}")
        return waypoints(
            pts,
            speed=data.get("speed"),
            segment_times=seg_times,
            t_start=data.get("t_start", 0.0),
            yaw_rate=data.get("yaw_rate", 0.5),
            min_segment_time=data.get("min_segment_time", 1.0),
        )
    except TrajectoryError as exc:
        msg = str(exc)
        raise TrajectoryError(msg if msg.startswith(where) else f"{where}: {msg}") from None


def load_trajectory_file(path: str | Path) -> Composite:
    """Read a trajectory file (TOML, format in ``docs/references.md``); bad files raise :class:`TrajectoryError`
    (a :class:`~estimators.errors.UserError`) with a one-line message naming the file and the bad value."""
    p = Path(path)
    where = str(p)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise TrajectoryError(f"cannot read trajectory file {where}: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise TrajectoryError(f"{where}: not a UTF-8 text file") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise TrajectoryError(f"{where}: not valid TOML ({str(exc).splitlines()[0]})") from None
    return _reference_from_table(data, where)


__all__ = [
    "ORDERS",
    "Composite",
    "Constant",
    "FlatSample",
    "HermiteSpline",
    "Mapped",
    "Phase",
    "PhaseSine",
    "Reference",
    "Scalar",
    "Scaled",
    "Shifted",
    "SmoothStep",
    "Sum",
    "TrajectoryError",
    "as_scalar",
    "circle",
    "figure_eight",
    "hover",
    "load_trajectory_file",
    "rest_to_rest",
    "smooth_step_value",
    "waypoints",
]
