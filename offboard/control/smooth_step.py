"""The degree-15 smooth step, the building block of every reference transition: exact rational polynomial
coefficients (derivatives 1..7 vanish at both ends), converted to floats once, and its Taylor series.

``x`` is the normalized time in [0, 1] (dimensionless); :func:`scaled` turns normalized-time Taylor coefficients
into those of real time (s) for a transition of length ``1 / inv_t``. Used by ``offboard.control.reference``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from fractions import Fraction
from math import comb

from offboard.control.jet import PolynomialTaylor

# --------------------------------------------------------------------------------------------------------------
# polynomials of the smooth step (exact rational coefficients, converted once)
# --------------------------------------------------------------------------------------------------------------
STEP_ORDER = 7  # derivatives 1..7 vanish at both ends -> degree 2*7+1 = 15


def step_coefficients(order: int) -> list[Fraction]:
    """Monomial coefficients of S(x) = x^(N+1) sum_k C(N+k, k) C(2N+1, N-k) (-x)^k (the order-N smooth step: degree
    2N+1, derivatives 1..N zero at 0 and 1; N = 7 is every reference's step, lower orders shape a move's ramps)."""
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


STEP = PolynomialTaylor([float(c) for c in step_coefficients(STEP_ORDER)])
STEP_INTEGRAL = PolynomialTaylor([float(c) for c in _antiderivative(step_coefficients(STEP_ORDER))])  # 1/2 at 1
#: the velocity step on [0, 1/2]: G(x) = I(2x), I the integral of S (G(1/2) = 1/2); on [1/2, 1] G(x) = 1 - G(1 - x).
#: Its velocity G'(x) = 2 S(2x) rises with the smooth step over the first half and falls with it over the second:
#: peak 2 (the mean's 2x, against S's 3.14x) and peak acceleration 4 max S' = 12.6 against S's 15.1 per unit step and
#: time; derivatives 1..8 vanish at 0 and 1 and 2..8 at 1/2 (C^8)
VELOCITY_STEP_HALF = PolynomialTaylor(
    [float(c * 2**j) for j, c in enumerate(_antiderivative(step_coefficients(STEP_ORDER)))]
)
_H0_EXACT, _H1_EXACT = _hermite_velocity_basis(STEP_ORDER)
H0 = PolynomialTaylor([float(c) for c in _H0_EXACT])
H1 = PolynomialTaylor([float(c) for c in _H1_EXACT])


def mirrored(c: tuple[float, ...]) -> tuple[float, ...]:
    """Series of g(1 - x) at x from the series of g at 1 - x: coefficient k times (-1)^k."""
    return tuple(-v if k & 1 else v for k, v in enumerate(c))


def step_series(x: float, n: int) -> tuple[float, ...]:
    """Series of the smooth step S at x in (0, 1); for x > 1/2 via S(x) = 1 - S(1 - x) (no cancellation near 1)."""
    if x <= 0.5:
        return STEP.taylor(x, n)
    c = mirrored(STEP.taylor(1.0 - x, n))
    return (1.0 - c[0], *(-v for v in c[1:]))


def step_integral_series(x: float, n: int) -> tuple[float, ...]:
    """Series of I(x) = integral_0^x S; for x > 1/2 via I(x) = x - 1/2 + I(1 - x)."""
    if x <= 0.5:
        return STEP_INTEGRAL.taylor(x, n)
    c = list(mirrored(STEP_INTEGRAL.taylor(1.0 - x, n)))
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
    return step_series(x, 1)[0]


def scaled(c: tuple[float, ...], inv_t: float) -> tuple[float, ...]:
    """Series in tau = (t - t0) / T  ->  series in t (coefficient k times T^-k)."""
    out = []
    f = 1.0
    for x in c:
        out.append(x * f)
        f *= inv_t
    return tuple(out)
