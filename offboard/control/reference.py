"""Smooth references for the flat outputs (F_x, F_y, z, psi) with exact derivatives of orders 0..6.

Frames and units: world NWU, z up. ``F_x, F_y`` are the LOAD's horizontal position to first order (m), ``z`` is the
height (m), ``psi`` the heading (rad). Time ``t`` in seconds. Each channel is a scalar trajectory (:class:`Scalar`)
that returns a :class:`~offboard.control.jet.Jet` (truncated Taylor series), so derivatives are exact up to rounding,
never differenced. Every transition is at least C^7: the building block is the degree-15 smooth step whose
derivatives 1..7 vanish at both ends, and phase-driven patterns (circle, figure-eight) ramp their angular rate with
that step, which makes the position C^8 at the ramp ends.

This module holds the blocks and :class:`Composite`; the named patterns (hover, rest-to-rest, circle,
figure-eight, waypoints) are in ``offboard.control.reference_patterns``, the trajectory file reader in
``offboard.control.trajectory_file``, the smooth step's polynomials in ``offboard.control.smooth_step``.
Design and file format: ``docs/references.md``.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Iterable
from typing import NamedTuple, Protocol

from estimators.errors import UserError
from offboard.control.jet import FACTORIALS, Jet
from offboard.control.smooth_step import scaled, step_integral_series, step_series

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


def _latest_end(parts: Iterable[Scalar]) -> float:
    """The latest :attr:`Scalar.end` of ``parts`` (s; -inf for none): where a combination of them stops moving."""
    return max((x.end for x in parts), default=-math.inf)


def _all_breakpoints(parts: Iterable[Scalar]) -> tuple[float, ...]:
    """Every breakpoint of ``parts``, sorted, each once (s)."""
    return tuple(sorted({b for x in parts for b in x.breakpoints}))


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
        c = scaled(step_series(x, n), self._inv)
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
        return _latest_end(self.terms)

    @property
    def breakpoints(self) -> tuple[float, ...]:
        return _all_breakpoints(self.terms)


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
        return _latest_end(self.args)

    @property
    def breakpoints(self) -> tuple[float, ...]:
        return _all_breakpoints(self.args)


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
            c = scaled(step_integral_series(s * self._inv, n), self._inv)
            k = w * Tr
            return Jet._raw((self.phase0 + k * c[0], *(k * v for v in c[1:])))
        s -= Tr
        if self.Tc is None or s <= self.Tc:
            return (
                Jet._raw((self.phase0 + self._half + w * s, w) + (0.0,) * (n - 2))
                if n > 1
                else Jet._raw((self.phase0 + self._half + w * s,))
            )
        base = self.phase0 + self._half + w * self.Tc
        s -= self.Tc
        if s >= Tr:
            return Jet.constant(base + self._half, n)
        c = scaled(step_integral_series(s * self._inv, n), self._inv)
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
        return _all_breakpoints(self.channels)

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


__all__ = [
    "ORDERS",
    "Composite",
    "Constant",
    "FlatSample",
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
]
