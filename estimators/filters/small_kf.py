"""Kalman-filter arithmetic for blocks of two or three states in plain Python floats, with closed-form models.

The measured-input filter (``estimators.filters.measured_kf``) is made of small independent blocks; each one's discrete
model is a closed form in the step length ``h`` (no matrix exponential, no cache keyed by step length), so a
step costs the same whatever its length: a stream stamped in microseconds with thousands of distinct steps
(ArduPilot's HIGHRES_IMU) is as cheap as a fixed-rate one. Covariances are lists of rows; means lists.

The filter's hot path does not build the matrices: :func:`predict_kinematic`, :func:`predict_pendulum` and
:func:`predict_rate` are :func:`predict` with each model's zeros and ones multiplied out, the remaining products
and sums in the general prediction's order, so that they give the very same floats
(``tests/test_measured_kf.py``); with the unrolled updates they cut the filter's cost per 250 Hz tick by about 40 %
(``bench/bench_estimator.py --sensors px4-fast``).

Models (all SI; ``q`` are continuous spectral densities of the white noise driving the named derivative):

- :func:`rate_model`: ``[x, x']`` with ``x''`` white (``q``): tilt, heading.
- :func:`kinematic_model`: ``[p, v, b]`` with ``v' = u - b + w_v`` (u: measured acceleration, known input),
  ``b' = w_b`` (accelerometer bias random walk): position / velocity / bias along one world axis.
- :func:`pendulum_model`: ``[a, a', e]`` with ``a'' = -w^2 a + f + w_a`` (f: known input), ``e' = w_e``: the
  planar swing angle driven by the pivot's measured acceleration, and an external acceleration seen by the
  accelerometer.
"""

from __future__ import annotations

import math

Matrix = list[list[float]]


def rate_model(h: float, q: float) -> tuple[Matrix, Matrix]:
    """``(Phi, Q)`` of ``[x, x']`` with white ``x''`` of density ``q`` over ``h`` s."""
    h2 = h * h
    return [[1.0, h], [0.0, 1.0]], [[q * h2 * h / 3.0, q * h2 / 2.0], [q * h2 / 2.0, q * h]]


def kinematic_model(h: float, q_v: float, q_b: float, q_p: float = 0.0) -> tuple[Matrix, list[float], Matrix]:
    """``(Phi, Gamma, Q)`` of ``[p, v, b]``, ``p' = v + w_p``, ``v' = u - b + w_v``, ``b' = w_b``; Gamma: the input
    column of a held ``u`` (m/s^2) over ``h`` s. ``w_p`` (density ``q_p``, m^2/s) lets the position wander apart
    from the integrated velocity, as an autopilot's estimate does when it fuses GNSS."""
    h2 = h * h
    h3 = h2 * h
    h4 = h3 * h
    phi = [[1.0, h, -0.5 * h2], [0.0, 1.0, -h], [0.0, 0.0, 1.0]]
    q = [
        [q_p * h + q_v * h3 / 3.0 + q_b * h4 * h / 20.0, q_v * h2 / 2.0 + q_b * h4 / 8.0, -q_b * h3 / 6.0],
        [q_v * h2 / 2.0 + q_b * h4 / 8.0, q_v * h + q_b * h3 / 3.0, -q_b * h2 / 2.0],
        [-q_b * h3 / 6.0, -q_b * h2 / 2.0, q_b * h],
    ]
    return phi, [0.5 * h2, h, 0.0], q


def pendulum_terms(h: float, w2: float) -> tuple[float, float, float, float, float, float]:
    """The swing's transition over ``h`` s, ``a'' = -w2 a + f`` (``w2`` > 0, 1/s^2): ``(c00, c01, c10, c11, g0, g1)``,
    the rows ``[[c00, c01], [c10, c11]]`` of ``[a, a']``'s transition and ``[g0, g1]`` the input column of a held
    ``f``. One place for :func:`pendulum_model`, :func:`predict_pendulum` and the filter's mean-only prediction."""
    w = math.sqrt(w2)
    wh = w * h
    if wh < 1e-3:  # series: the closed forms below lose digits to cancellation
        h2 = h * h
        c = 1.0 - 0.5 * w2 * h2
        return c, h, -w2 * h, c, 0.5 * h2, h
    c, s = math.cos(wh), math.sin(wh)
    return c, s / w, -w * s, c, (1.0 - c) / w2, s / w


def pendulum_noise(h: float, w2: float, q_a: float) -> tuple[float, float, float]:
    """``(Q_aa, Q_aa', Q_a'a')`` of the swing's white ``q_a`` over ``h`` s (series where ``w h`` < 1e-3)."""
    w = math.sqrt(w2)
    wh = w * h
    if wh < 1e-3:
        h2 = h * h
        return q_a * h2 * h / 3.0, q_a * h2 / 2.0, q_a * h
    s = math.sin(wh)
    s2 = math.sin(2.0 * wh) / (4.0 * w)
    return q_a * (0.5 * h - s2) / w2, q_a * s * s / (2.0 * w2), q_a * (0.5 * h + s2)


def pendulum_model(h: float, w2: float, q_a: float, q_e: float) -> tuple[Matrix, list[float], Matrix]:
    """``(Phi, Gamma, Q)`` of ``[a, a', e]``, ``a'' = -w2 a + f``, ``e'`` white; Gamma: the input column of a held
    ``f`` (rad/s^2) over ``h`` s; ``w2`` (1/s^2) > 0."""
    c00, c01, c10, c11, g0, g1 = pendulum_terms(h, w2)
    qaa, qad, qdd = pendulum_noise(h, w2, q_a)
    phi = [[c00, c01, 0.0], [c10, c11, 0.0], [0.0, 0.0, 1.0]]
    q = [[qaa, qad, 0.0], [qad, qdd, 0.0], [0.0, 0.0, q_e * h]]
    return phi, [g0, g1, 0.0], q


def predict(x: list[float], p: Matrix, phi: Matrix, gamma: list[float] | None, u: float, q: Matrix) -> None:
    """In place: ``x <- Phi x + Gamma u``, ``P <- Phi P Phi^T + Q``."""
    n = len(x)
    if n == 3:
        _predict3(x, p, phi, gamma, u, q)
        return
    if n == 2:
        _predict2(x, p, phi, q)
        if gamma is not None and u != 0.0:  # an input moves the mean only (the tilt's commanded acceleration)
            x[0] += gamma[0] * u
            x[1] += gamma[1] * u
        return
    rn = range(n)
    xs = [sum(phi[i][j] * x[j] for j in rn) for i in rn]
    if gamma is not None and u != 0.0:
        xs = [xs[i] + gamma[i] * u for i in rn]
    x[:] = xs
    propagate_cov(p, phi, q)


def propagate_cov(p: Matrix, phi: Matrix, q: Matrix) -> None:
    """``P <- Phi P Phi^T + Q`` in place for any number of states (the sums of the general loop)."""
    rn = range(len(p))
    fp = [[sum(phi[i][k] * p[k][j] for k in rn) for j in rn] for i in rn]  # Phi P
    for i in rn:
        row = fp[i]
        for j in range(i, len(p)):
            pj = phi[j]
            v = sum(row[k] * pj[k] for k in rn) + q[i][j]
            p[i][j] = v
            p[j][i] = v


def _predict2(x: list[float], p: Matrix, phi: Matrix, q: Matrix) -> None:
    """:func:`predict` for two states without input (the tilt and heading blocks: every attitude record), unrolled:
    the same products and sums in the same order as the general loop (identical results), 4-9x faster than it
    (1.2-1.5 against 5.4-13 us per call, ``python -m timeit`` at load 10, against main's loop in the same run)."""
    # each sum starts from 0.0 as sum() does (the same bits, the sign of a zero included)
    (f00, f01), (f10, f11) = phi
    x0, x1 = x
    x[0], x[1] = 0.0 + f00 * x0 + f01 * x1, 0.0 + f10 * x0 + f11 * x1
    (p00, p01), (p10, p11) = p
    a00, a01 = 0.0 + f00 * p00 + f01 * p10, 0.0 + f00 * p01 + f01 * p11  # Phi P (rows), then A Phi^T
    a10, a11 = 0.0 + f10 * p00 + f11 * p10, 0.0 + f10 * p01 + f11 * p11
    n00 = 0.0 + a00 * f00 + a01 * f01 + q[0][0]
    n01 = 0.0 + a00 * f10 + a01 * f11 + q[0][1]
    n11 = 0.0 + a10 * f10 + a11 * f11 + q[1][1]
    r0, r1 = p
    r0[0], r0[1] = n00, n01
    r1[0], r1[1] = n01, n11


def _predict3(x: list[float], p: Matrix, phi: Matrix, gamma: list[float] | None, u: float, q: Matrix) -> None:
    """:func:`predict` for three states, unrolled (the hot path: every position and IMU record runs it)."""
    (f00, f01, f02), (f10, f11, f12), (f20, f21, f22) = phi
    x0, x1, x2 = x
    y0, y1, y2 = f00 * x0 + f01 * x1 + f02 * x2, f10 * x0 + f11 * x1 + f12 * x2, f20 * x0 + f21 * x1 + f22 * x2
    if gamma is not None and u != 0.0:
        y0, y1, y2 = y0 + gamma[0] * u, y1 + gamma[1] * u, y2 + gamma[2] * u
    x[0], x[1], x[2] = y0, y1, y2
    propagate_cov3(p, phi, q)


def propagate_cov3(p: Matrix, phi: Matrix, q: Matrix) -> None:
    """``P <- Phi P Phi^T + Q`` in place for three states, unrolled (:func:`sandwich3`), ``P`` and ``Q`` symmetric
    (their upper triangles are read)."""
    (f00, f01, f02), (f10, f11, f12), (f20, f21, f22) = phi
    r0, r1, r2 = p
    (q00, q01, q02), (_, q11, q12), (_, _, q22) = q
    upper = (r0[0], r0[1], r0[2], r1[1], r1[2], r2[2])
    phi9 = (f00, f01, f02, f10, f11, f12, f20, f21, f22)
    n00, n01, n02, n11, n12, n22 = sandwich3(phi9, upper, (q00, q01, q02, q11, q12, q22))
    r0[0], r0[1], r0[2] = n00, n01, n02
    r1[0], r1[1], r1[2] = n01, n11, n12
    r2[0], r2[1], r2[2] = n02, n12, n22


def sandwich3(
    phi: tuple[float, ...], p: tuple[float, ...], q: tuple[float, ...]
) -> tuple[float, float, float, float, float, float]:
    """``Phi P Phi^T + Q`` of three states: ``phi`` the transition's 9 entries row by row, ``p`` and ``q`` the upper
    triangles ``(x00, x01, x02, x11, x12, x22)`` of symmetric ``P`` and ``Q``; the result's upper triangle. Plain
    floats and tuples: the compiled filter (``estimators.filters.compiled.kf_predict``) compiles this very function."""
    f00, f01, f02, f10, f11, f12, f20, f21, f22 = phi
    p00, p01, p02, p11, p12, p22 = p
    # A = Phi P (rows), then A Phi^T
    a00, a01, a02 = (
        f00 * p00 + f01 * p01 + f02 * p02,
        f00 * p01 + f01 * p11 + f02 * p12,
        f00 * p02 + f01 * p12 + f02 * p22,
    )
    a10, a11, a12 = (
        f10 * p00 + f11 * p01 + f12 * p02,
        f10 * p01 + f11 * p11 + f12 * p12,
        f10 * p02 + f11 * p12 + f12 * p22,
    )
    a20, a21, a22 = (
        f20 * p00 + f21 * p01 + f22 * p02,
        f20 * p01 + f21 * p11 + f22 * p12,
        f20 * p02 + f21 * p12 + f22 * p22,
    )
    q00, q01, q02, q11, q12, q22 = q
    return (
        a00 * f00 + a01 * f01 + a02 * f02 + q00,
        a00 * f10 + a01 * f11 + a02 * f12 + q01,
        a00 * f20 + a01 * f21 + a02 * f22 + q02,
        a10 * f10 + a11 * f11 + a12 * f12 + q11,
        a10 * f20 + a11 * f21 + a12 * f22 + q12,
        a20 * f20 + a21 * f21 + a22 * f22 + q22,
    )


def predict_kinematic(x: list[float], p: Matrix, h: float, q_v: float, q_b: float, q_p: float, u: float) -> None:
    """In place, :func:`predict` with :func:`kinematic_model` ``(h, q_v, q_b, q_p)`` and the input ``u`` (m/s^2), with
    the transition's zeros and ones multiplied out: the same products and sums in the same order as the general
    3-state prediction (identical values but for the sign of a zero; ``tests/test_measured_kf.py``), no matrices
    built. The hot path: every position and IMU record advances the three kinematic blocks."""
    h2 = h * h
    h3 = h2 * h
    h4 = h3 * h
    c = -0.5 * h2  # Phi = [[1, h, c], [0, 1, -h], [0, 0, 1]]
    x0, x1, x2 = x
    y0, y1 = x0 + h * x1 + c * x2, x1 + -h * x2
    if u != 0.0:
        y0, y1 = y0 + 0.5 * h2 * u, y1 + h * u
    x[0], x[1] = y0, y1
    r0, r1, r2 = p
    p00, p01, p02 = r0
    p11, p12, p22 = r1[1], r1[2], r2[2]
    a00, a01, a02 = p00 + h * p01 + c * p02, p01 + h * p11 + c * p12, p02 + h * p12 + c * p22  # Phi P
    a11, a12 = p11 + -h * p12, p12 + -h * p22
    n00 = a00 + a01 * h + a02 * c + (q_p * h + q_v * h3 / 3.0 + q_b * h4 * h / 20.0)  # (Phi P) Phi^T + Q
    n01 = a01 + a02 * -h + (q_v * h2 / 2.0 + q_b * h4 / 8.0)
    n02 = a02 + -q_b * h3 / 6.0
    n11 = a11 + a12 * -h + (q_v * h + q_b * h3 / 3.0)
    n12 = a12 + -q_b * h2 / 2.0
    n22 = p22 + q_b * h
    r0[0], r0[1], r0[2] = n00, n01, n02
    r1[0], r1[1], r1[2] = n01, n11, n12
    r2[0], r2[1], r2[2] = n02, n12, n22


def predict_pendulum(x: list[float], p: Matrix, h: float, w2: float, q_a: float, q_e: float, f: float) -> None:
    """In place, :func:`predict` with :func:`pendulum_model` ``(h, w2, q_a, q_e)`` and the input ``f`` (rad/s^2), the
    transition's zeros and ones multiplied out (as :func:`predict_kinematic`): every IMU record advances the two
    swing blocks."""
    c00, c01, c10, c11, g0, g1 = pendulum_terms(h, w2)
    qaa, qad, qdd = pendulum_noise(h, w2, q_a)
    x0, x1 = x[0], x[1]
    y0, y1 = c00 * x0 + c01 * x1, c10 * x0 + c11 * x1
    if f != 0.0:
        y0, y1 = y0 + g0 * f, y1 + g1 * f
    x[0], x[1] = y0, y1
    r0, r1, r2 = p
    p00, p01, p02 = r0
    p11, p12, p22 = r1[1], r1[2], r2[2]
    a00, a01, a02 = c00 * p00 + c01 * p01, c00 * p01 + c01 * p11, c00 * p02 + c01 * p12  # Phi P
    a10, a11, a12 = c10 * p00 + c11 * p01, c10 * p01 + c11 * p11, c10 * p02 + c11 * p12
    n00 = a00 * c00 + a01 * c01 + qaa  # (Phi P) Phi^T + Q
    n01 = a00 * c10 + a01 * c11 + qad
    n11 = a10 * c10 + a11 * c11 + qdd
    n22 = p22 + q_e * h
    r0[0], r0[1], r0[2] = n00, n01, a02
    r1[0], r1[1], r1[2] = n01, n11, a12
    r2[0], r2[1], r2[2] = a02, a12, n22


def predict_rate(x: list[float], p: Matrix, h: float, q: float, u: float) -> None:
    """In place, :func:`predict` with :func:`rate_model` ``(h, q)`` and the input column ``[h^2 / 2, h]`` of a held
    ``u`` (rad/s^2; 0: none), multiplied out as :func:`predict_kinematic`: the tilt and heading blocks, every
    attitude record."""
    h2 = h * h
    x0, x1 = x
    p00, p01 = p[0]
    p11 = p[1][1]
    a00, a01 = p00 + h * p01, p01 + h * p11  # Phi P; Phi = [[1, h], [0, 1]]
    n00 = a00 + a01 * h + q * h2 * h / 3.0
    n01 = a01 + q * h2 / 2.0
    n11 = p11 + q * h
    x0 = x0 + h * x1
    if u != 0.0:
        x0, x1 = x0 + 0.5 * h * h * u, x1 + h * u
    x[0], x[1] = x0, x1
    r0, r1 = p
    r0[0], r0[1] = n00, n01
    r1[0], r1[1] = n01, n11


def kinematic_first_row(h: float, q_v: float, q_b: float, q_p: float) -> tuple[tuple[float, float, float], float]:
    """Row 0 of :func:`kinematic_model`'s Phi and ``Q[0][0]`` (the same floats), alone: a position's predicted variance
    without the rest of the model (the filter's standard deviations, every tick)."""
    h2 = h * h
    h3 = h2 * h
    h4 = h3 * h
    return (1.0, h, -0.5 * h2), q_p * h + q_v * h3 / 3.0 + q_b * h4 * h / 20.0


def pendulum_first_row(h: float, w2: float, q_a: float) -> tuple[tuple[float, float, float], float]:
    """Row 0 of :func:`pendulum_model`'s Phi and ``Q[0][0]``, alone (as :func:`kinematic_first_row`)."""
    c00, c01, _, _, _, _ = pendulum_terms(h, w2)
    return (c00, c01, 0.0), pendulum_noise(h, w2, q_a)[0]


def rate_first_row(h: float, q: float) -> tuple[tuple[float, float], float]:
    """Row 0 of :func:`rate_model`'s Phi and ``Q[0][0]``, alone (as :func:`kinematic_first_row`)."""
    h2 = h * h
    return (1.0, h), q * h2 * h / 3.0


def predict_mean(x: list[float], phi: Matrix, gamma: list[float] | None, u: float) -> list[float]:
    """``Phi x + Gamma u`` (a new list; ``x`` untouched)."""
    rn = range(len(x))
    xs = [sum(phi[i][j] * x[j] for j in rn) for i in rn]
    if gamma is not None and u != 0.0:
        xs = [xs[i] + gamma[i] * u for i in rn]
    return xs


def apply_gain(x: list[float], p: Matrix, ph: list[float], y: float, s: float) -> None:
    """In place, the accepted scalar update with ``ph = P h`` (the column of the measured direction), innovation
    ``y`` and its variance ``s``: ``x += ph y / s``, ``P -= ph ph^T / s`` (upper triangle computed, mirrored)."""
    n = len(x)
    if n == 3:  # the kinematic and swing blocks: unrolled, the same products in the same order as the loop below
        # (identical results): an update_one 1.6-1.9x faster (1.5-3.1 against 2.8-4.8 us, ``python -m timeit``, load 10)
        c0, c1, c2 = ph
        x[0] += c0 * y / s
        x[1] += c1 * y / s
        x[2] += c2 * y / s
        k0, k1, k2 = c0 / s, c1 / s, c2 / s
        r0, r1, r2 = p
        r0[0], r0[1], r0[2] = r0[0] - k0 * c0, r0[1] - k0 * c1, r0[2] - k0 * c2
        r1[1], r1[2] = r1[1] - k1 * c1, r1[2] - k1 * c2
        r2[2] = r2[2] - k2 * c2
        r1[0], r2[0], r2[1] = r0[1], r0[2], r1[2]
        return
    if n == 2:  # the tilt and heading blocks, unrolled as above
        c0, c1 = ph
        x[0] += c0 * y / s
        x[1] += c1 * y / s
        k0, k1 = c0 / s, c1 / s
        r0, r1 = p
        r0[0], r0[1] = r0[0] - k0 * c0, r0[1] - k0 * c1
        r1[1] = r1[1] - k1 * c1
        r1[0] = r0[1]
        return
    for k in range(n):
        x[k] += ph[k] * y / s
        kk = ph[k] / s
        row = p[k]
        for m in range(k, n):
            v = row[m] - kk * ph[m]
            row[m] = v
            p[m][k] = v


def update_one(x: list[float], p: Matrix, i: int, z: float, r: float, gate: float) -> tuple[float, float] | None:
    """Gated scalar update with state ``i`` measured directly (value z, variance r); ``(y, s)`` when accepted,
    ``None`` when gated (nothing changed)."""
    s = p[i][i] + r
    y = z - x[i]
    if not (s > 0.0 and y * y <= gate * s):
        return None
    apply_gain(x, p, [row[i] for row in p], y, s)
    return y, s


def update_row(
    x: list[float], p: Matrix, hrow: list[float], z: float, r: float, gate: float
) -> tuple[bool, float, float]:
    """Gated scalar update ``z = h . x + noise(r)``; returns ``(accepted, y, h P h^T)`` (the innovation and its
    variance without the noise, for the noise statistics, whether or not the gate let it through)."""
    if len(x) == 3:  # the swing blocks (every IMU record), unrolled: the sums below in the same order
        h0, h1, h2 = hrow
        r0, r1, r2 = p
        ph = [r0[0] * h0 + r0[1] * h1 + r0[2] * h2, r1[0] * h0 + r1[1] * h1 + r1[2] * h2]
        ph.append(r2[0] * h0 + r2[1] * h1 + r2[2] * h2)
        hph = h0 * ph[0] + h1 * ph[1] + h2 * ph[2]
        y = z - (h0 * x[0] + h1 * x[1] + h2 * x[2])
    else:
        rn = range(len(x))
        ph = [sum(p[k][m] * hrow[m] for m in rn) for k in rn]
        hph = sum(hrow[k] * ph[k] for k in rn)
        y = z - sum(hrow[k] * x[k] for k in rn)
    s = hph + r
    if not (s > 0.0 and y * y <= gate * s):
        return False, y, hph
    apply_gain(x, p, ph, y, s)
    return True, y, hph


__all__ = [
    "apply_gain",
    "kinematic_first_row",
    "kinematic_model",
    "pendulum_first_row",
    "pendulum_model",
    "pendulum_noise",
    "pendulum_terms",
    "predict",
    "predict_kinematic",
    "predict_mean",
    "predict_pendulum",
    "predict_rate",
    "propagate_cov",
    "propagate_cov3",
    "rate_first_row",
    "rate_model",
    "sandwich3",
    "update_one",
    "update_row",
]
