"""Truncated Taylor series ("jets") of a scalar function of time, for exact derivatives without differencing.

A :class:`Jet` of length ``n`` holds the normalized Taylor coefficients of a function ``f`` at one instant ``t``::

    c[k] = f^(k)(t) / k!        k = 0 .. n-1

Sums, products, ``sin``/``cos`` and composition of jets are the corresponding operations on truncated power
series, so every derivative up to order ``n - 1`` of a composed expression is exact up to floating-point rounding
(Faa di Bruno's formula is applied implicitly by the series arithmetic). :meth:`Jet.derivatives` turns the
coefficients back into derivatives ``(f, f', ..., f^(n-1))``.

Everything is plain Python floats and tuples: a jet operation costs a few microseconds, which keeps reference
sampling cheap enough for a 1 kHz control loop.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

FACTORIALS: tuple[float, ...] = tuple(float(math.factorial(k)) for k in range(32))


def mul_series(a: Sequence[float], b: Sequence[float]) -> tuple[float, ...]:
    """Cauchy product of two truncated series of the same length."""
    n = len(a)
    out = []
    for k in range(n):
        s = 0.0
        for j in range(k + 1):
            s += a[j] * b[k - j]
        out.append(s)
    return tuple(out)


def sincos_series(a: Sequence[float]) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """(sin a, cos a) as truncated series, by the recurrences of s' = c a' and c' = -s a'."""
    n = len(a)
    s = [math.sin(a[0])]
    c = [math.cos(a[0])]
    ja = [j * a[j] for j in range(n)]
    for k in range(1, n):
        ss = 0.0
        cc = 0.0
        for j in range(1, k + 1):
            ss += ja[j] * c[k - j]
            cc += ja[j] * s[k - j]
        s.append(ss / k)
        c.append(-cc / k)
    return tuple(s), tuple(c)


def compose_series(outer: Sequence[float], inner: Sequence[float]) -> tuple[float, ...]:
    """Series of ``f(g(t))`` from the series of ``f`` at ``g(t)`` (``outer``) and of ``g`` at ``t`` (``inner``).

    Horner's scheme in truncated arithmetic: ``sum_k outer[k] (g - g(t))^k``.
    """
    n = len(inner)
    d = (0.0, *inner[1:])
    r: tuple[float, ...] = (outer[n - 1],) + (0.0,) * (n - 1)
    for k in range(n - 2, -1, -1):
        r = mul_series(r, d)
        r = (r[0] + outer[k], *r[1:])
    return r


class Jet:
    """Truncated Taylor series of a scalar function at one instant: ``c[k] = f^(k)(t) / k!``.

    Supports ``+``, ``-``, ``*`` (with jets of the same length and with plain numbers), unary minus, division by a
    number, :meth:`sin`, :meth:`cos`, and :meth:`sincos`.
    """

    __slots__ = ("c",)

    def __init__(self, coefficients: Sequence[float]) -> None:
        self.c: tuple[float, ...] = tuple(float(x) for x in coefficients)

    # construction -------------------------------------------------------------------------------------------
    @classmethod
    def constant(cls, value: float, n: int) -> Jet:
        """Jet of a constant: value, then zeros."""
        return cls._raw((float(value),) + (0.0,) * (n - 1))

    @classmethod
    def variable(cls, t: float, n: int) -> Jet:
        """Jet of the identity function at ``t`` (the independent variable itself)."""
        if n == 1:
            return cls._raw((float(t),))
        return cls._raw((float(t), 1.0) + (0.0,) * (n - 2))

    @classmethod
    def from_derivatives(cls, derivatives: Sequence[float]) -> Jet:
        """Jet from ``(f, f', ..., f^(n-1))``."""
        return cls._raw(tuple(float(d) / FACTORIALS[k] for k, d in enumerate(derivatives)))

    @classmethod
    def _raw(cls, c: tuple[float, ...]) -> Jet:
        j = object.__new__(cls)
        j.c = c
        return j

    # read-out -------------------------------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.c)

    @property
    def value(self) -> float:
        return self.c[0]

    def derivatives(self) -> tuple[float, ...]:
        """``(f, f', ..., f^(n-1))`` in the units of f per second^k."""
        return tuple(x * FACTORIALS[k] for k, x in enumerate(self.c))

    def __repr__(self) -> str:
        return f"Jet.from_derivatives({list(self.derivatives())!r})"

    # arithmetic -------------------------------------------------------------------------------------------------
    def __add__(self, other: Jet | float) -> Jet:
        if isinstance(other, Jet):
            return Jet._raw(tuple(x + y for x, y in zip(self.c, other.c)))
        return Jet._raw((self.c[0] + other, *self.c[1:]))

    __radd__ = __add__

    def __neg__(self) -> Jet:
        return Jet._raw(tuple(-x for x in self.c))

    def __sub__(self, other: Jet | float) -> Jet:
        if isinstance(other, Jet):
            return Jet._raw(tuple(x - y for x, y in zip(self.c, other.c)))
        return Jet._raw((self.c[0] - other, *self.c[1:]))

    def __rsub__(self, other: float) -> Jet:
        return (-self) + other

    def __mul__(self, other: Jet | float) -> Jet:
        if isinstance(other, Jet):
            return Jet._raw(mul_series(self.c, other.c))
        k = float(other)
        return Jet._raw(tuple(k * x for x in self.c))

    __rmul__ = __mul__

    def __truediv__(self, other: float) -> Jet:
        k = 1.0 / float(other)
        return Jet._raw(tuple(k * x for x in self.c))

    def sincos(self) -> tuple[Jet, Jet]:
        s, c = sincos_series(self.c)
        return Jet._raw(s), Jet._raw(c)

    def sin(self) -> Jet:
        return self.sincos()[0]

    def cos(self) -> Jet:
        return self.sincos()[1]


class PolynomialTaylor:
    """A fixed polynomial with precomputed tables for fast Taylor coefficients: ``p^(k)(x) / k!`` for k < n.

    ``coefficients[j]`` multiplies ``x^j``: one Horner pass per order over a precomputed table.
    """

    __slots__ = ("coefficients", "tables")

    def __init__(self, coefficients: Sequence[float]) -> None:
        self.coefficients = tuple(float(v) for v in coefficients)
        a = self.coefficients
        # table k: coefficients of p^(k)/k!, highest power first, for Horner
        self.tables: tuple[tuple[float, ...], ...] = tuple(
            tuple(a[j] * math.comb(j, k) for j in range(k, len(a)))[::-1] for k in range(len(a))
        )

    def taylor(self, x: float, n: int) -> tuple[float, ...]:
        out = []
        tabs = self.tables
        for k in range(n):
            if k >= len(tabs):
                out.append(0.0)
                continue
            acc = 0.0
            for a in tabs[k]:
                acc = acc * x + a
            out.append(acc)
        return tuple(out)
