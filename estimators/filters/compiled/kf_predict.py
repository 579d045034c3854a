"""The measured-input filter's prediction in a compiled run (:mod:`.kf`): each block's closed-form model over a step
(``estimators.filters.small_kf``'s, the same expressions), its prediction in place (:func:`kf_advance`, the
schedule's block advance event) and the mean-only prediction of the estimate (:func:`_rate_mean`,
:func:`_mean3`). The arrays ``c``, ``f``, ``n`` are :mod:`.kf_layout`'s; SI units, world
NWU, times in s.
"""

from __future__ import annotations

import numpy as np

from estimators.filters import small_kf
from estimators.filters.compiled.kf_layout import (
    B_P,
    B_T,
    B_X,
    BLOCK_SIZE,
    C_G,
    C_IMU_TIMEOUT,
    C_L,
    C_Q_A,
    C_Q_B,
    C_Q_E,
    C_Q_N,
    C_Q_PSI,
    C_Q_V,
    C_Q_V_NO_IMU,
    C_Q_VZ,
    F_BLOCKS,
    F_Q_P,
    F_T_IMU,
    F_U,
    F_U_TILT,
    HEAD,
    KIN_Z,
    P00,
    P01,
    P02,
    P11,
    P12,
    P22,
    SWING_X,
    TILT_X,
)
from estimators.kernels import inline_kernel, maximum, pure_kernel

#: this module's kernels: no kernel here creates, keeps or returns an array (``kernels.pure_kernel``)
_kernel = pure_kernel


# ---- small_kf over one run (the same expressions) -----------------------------------------------------------------
@_kernel
def _kinematic_model(h, q_v, q_b, q_p):
    """``[p, v, b]`` over ``h`` s (``small_kf.kinematic_model``): Phi (9, row-major), Gamma (3), Q's upper triangle
    (6); ``q_v`` ((m/s^2)^2/Hz), ``q_b`` ((m/s^3)^2/Hz), ``q_p`` (m^2/s)."""
    h2 = h * h
    h3 = h2 * h
    h4 = h3 * h
    phi = (1.0, h, -0.5 * h2, 0.0, 1.0, -h, 0.0, 0.0, 1.0)
    q = (
        q_p * h + q_v * h3 / 3.0 + q_b * h4 * h / 20.0,
        q_v * h2 / 2.0 + q_b * h4 / 8.0,
        -q_b * h3 / 6.0,
        q_v * h + q_b * h3 / 3.0,
        -q_b * h2 / 2.0,
        q_b * h,
    )
    return phi, (0.5 * h2, h, 0.0), q


#: the swing's transition and noise over a step: ``small_kf``'s own functions, compiled (the package's
#: ``SHARED_SOURCES``)
_pendulum_terms = inline_kernel(small_kf.pendulum_terms)
_pendulum_noise = inline_kernel(small_kf.pendulum_noise)
_sandwich3 = inline_kernel(small_kf.sandwich3)


@_kernel
def _predict3(f, o, phi, gam, u, q):
    """A block's prediction of three states in place (``small_kf._predict3``, its covariance by ``sandwich3``): the
    block at ``f[o:]`` moved by ``Phi``, ``Gamma u`` (when ``u != 0``) and ``Q`` (upper triangle)."""
    f00, f01, f02, f10, f11, f12, f20, f21, f22 = phi
    x, p = o + B_X, o + B_P
    x0, x1, x2 = f[x], f[x + 1], f[x + 2]
    y0 = f00 * x0 + f01 * x1 + f02 * x2
    y1 = f10 * x0 + f11 * x1 + f12 * x2
    y2 = f20 * x0 + f21 * x1 + f22 * x2
    if u != 0.0:
        y0, y1, y2 = y0 + gam[0] * u, y1 + gam[1] * u, y2 + gam[2] * u
    f[x], f[x + 1], f[x + 2] = y0, y1, y2
    upper = (f[p + P00], f[p + P01], f[p + P02], f[p + P11], f[p + P12], f[p + P22])
    n00, n01, n02, n11, n12, n22 = _sandwich3(phi, upper, q)
    f[p + P00], f[p + P01], f[p + P02], f[p + P11], f[p + P12], f[p + P22] = n00, n01, n02, n11, n12, n22


@_kernel
def _predict2(f, o, h, q, g0, g1, u):
    """A block's prediction of two states in place with ``_rate_model(h, q)`` (the generic loop: Python's
    ``sum`` starts from 0, hence the ``0.0 +``, which turns a -0.0 into 0.0 as it does), and the input column
    ``[g0, g1]`` of ``u`` moving the mean only (none: ``u = 0``)."""
    h2 = h * h
    f00, f01, f10, f11 = 1.0, h, 0.0, 1.0
    q00, q01, q11 = q * h2 * h / 3.0, q * h2 / 2.0, q * h
    x, p = o + B_X, o + B_P
    x0, x1 = f[x], f[x + 1]
    y0, y1 = 0.0 + f00 * x0 + f01 * x1, 0.0 + f10 * x0 + f11 * x1
    if u != 0.0:
        y0, y1 = y0 + g0 * u, y1 + g1 * u
    f[x], f[x + 1] = y0, y1
    p00, p01, p11 = f[p + P00], f[p + P01], f[p + P11]
    a00, a01 = 0.0 + f00 * p00 + f01 * p01, 0.0 + f00 * p01 + f01 * p11  # Phi P
    a10, a11 = 0.0 + f10 * p00 + f11 * p01, 0.0 + f10 * p01 + f11 * p11
    f[p + P00] = 0.0 + a00 * f00 + a01 * f01 + q00  # (Phi P) Phi^T + Q
    f[p + P01] = 0.0 + a00 * f10 + a01 * f11 + q01
    f[p + P11] = 0.0 + a10 * f10 + a11 * f11 + q11


# ---- models and prediction ----------------------------------------------------------------------------------------
@_kernel
def _fresh(c, f, t):
    """The acceleration input is in force at ``t`` (s): sampled at most ``imu_timeout_s`` before."""
    return t - f[F_T_IMU] <= c[C_IMU_TIMEOUT]


@_kernel
def _swing_input(c, f, bi, t):
    """Swing block ``bi``'s squared frequency ``w2`` (1/s^2) and input ``f`` (rad/s^2) at block time ``t``
    (``_model``'s swing branch: none and ``w2 = g / l`` without a fresh input)."""
    fresh = _fresh(c, f, t)
    g, l = c[C_G], c[C_L]
    uz = f[F_U + 2] if fresh else 0.0
    w2 = maximum(g + uz, 0.2 * g) / l
    axis = bi - SWING_X
    u = f[F_U + axis] - f[F_BLOCKS + BLOCK_SIZE * axis + B_X + 2] if fresh else 0.0
    return w2, -u / l


@_kernel
def kf_advance(c: np.ndarray, f: np.ndarray, n: np.ndarray, bi: int, t: float) -> None:
    """Predict block ``bi`` (``KIN_X`` .. ``SWING_Y``) to ``t`` (s) with the inputs in force (``advance``; a step
    ``h <= 0`` leaves it). The schedule's block advance event (code ``kernels.ADVANCE + bi``)."""
    o = F_BLOCKS + BLOCK_SIZE * bi
    tb = f[o + B_T]
    h = t - tb
    if not h > 0.0:
        return
    if bi < TILT_X:
        fresh = _fresh(c, f, tb)
        q_v = (c[C_Q_V] if bi < KIN_Z else c[C_Q_VZ]) if fresh else c[C_Q_V_NO_IMU]
        phi, gam, q = _kinematic_model(h, q_v, c[C_Q_B], f[F_Q_P + bi])
        _predict3(f, o, phi, gam, f[F_U + bi] if fresh else 0.0, q)
    elif bi > HEAD:
        w2, u = _swing_input(c, f, bi, tb)
        f00, f01, f10, _, g0, g1 = _pendulum_terms(h, w2)
        qaa, qad, qdd = _pendulum_noise(h, w2, c[C_Q_A])
        phi = (f00, f01, 0.0, f10, f00, 0.0, 0.0, 0.0, 1.0)
        _predict3(f, o, phi, (g0, g1, 0.0), u, (qaa, qad, 0.0, qdd, 0.0, c[C_Q_E] * h))
    elif bi == HEAD:
        _predict2(f, o, h, c[C_Q_PSI], 0.0, 0.0, 0.0)
    else:  # a tilt block: the commanded acceleration as its input
        _predict2(f, o, h, c[C_Q_N], 0.5 * h * h, h, f[F_U_TILT + bi - TILT_X])
    f[o + B_T] = t


# ---- output -------------------------------------------------------------------------------------------------------
@_kernel
def _rate_mean(c, f, bi, t):
    """A tilt or heading block's mean at ``t`` (s): the commanded tilt acceleration held, the heading rate held."""
    o = F_BLOCKS + BLOCK_SIZE * bi
    x0, x1 = f[o + B_X], f[o + B_X + 1]
    h = t - f[o + B_T]
    if not h > 0.0:
        return x0, x1
    if bi == HEAD:
        return x0 + h * x1, x1
    u = f[F_U_TILT + bi - TILT_X]
    return x0 + h * x1 + 0.5 * h * h * u, x1 + h * u


@_kernel
def _mean3(c, f, bi, t):
    """A three-state block's mean at ``t`` (s): a kinematic block's with the acceleration input in force held; a swing
    block's by its model's transition and input (``Phi x + Gamma u``, the scalar filter's three-state sums with the
    model's zeros and ones)."""
    o = F_BLOCKS + BLOCK_SIZE * bi
    tb = f[o + B_T]
    x0, x1, x2 = f[o + B_X], f[o + B_X + 1], f[o + B_X + 2]
    h = t - tb
    if not h > 0.0:
        return x0, x1, x2
    if bi < TILT_X:
        acc = (f[F_U + bi] if _fresh(c, f, tb) else 0.0) - x2
        return x0 + h * x1 + 0.5 * h * h * acc, x1 + h * acc, x2
    w2, u = _swing_input(c, f, bi, tb)
    f00, f01, f10, _, g0, g1 = _pendulum_terms(h, w2)
    y0 = f00 * x0 + f01 * x1 + 0.0 * x2
    y1 = f10 * x0 + f00 * x1 + 0.0 * x2
    y2 = 0.0 * x0 + 0.0 * x1 + 1.0 * x2
    if u != 0.0:
        y0, y1, y2 = y0 + g0 * u, y1 + g1 * u, y2 + 0.0 * u
    return y0, y1, y2
