"""The measured-input filter's gated updates in a compiled run (:mod:`.kf`): one block's correction by a state or a
row (``estimators.filters.small_kf``'s ``update_one`` / ``update_row``, the same expressions), the channels' adapted
noise, the gates' counters and their reopening, and the position wander's adaptation (``MeasuredKalmanEstimator``'s
methods of the same names). The arrays ``c``, ``f``, ``n`` are :mod:`.kf_layout`'s.
"""

from __future__ import annotations

import math

from estimators.filters.compiled.kf_layout import (
    B_P,
    B_X,
    BLOCK_SIZE,
    C_ADAPT_RATE,
    C_CEILING,
    C_FLOOR,
    C_GATE1,
    C_GATE_REOPEN,
    C_Q_P_MAX,
    C_Q_P_MIN,
    C_WANDER_RATE,
    F_BLOCKS,
    F_EHPH,
    F_EY2,
    F_Q_P,
    F_Y_MEAN,
    HEAD,
    N_GATED_RUN,
    N_REFUSED,
    N_REOPENED,
    P00,
    P01,
    P02,
    P11,
    P12,
    P22,
    TILT_X,
    _pk,
)
from estimators.kernels import maximum, minimum, pure_kernel

#: this module's kernels: no kernel here creates, keeps or returns an array (``kernels.pure_kernel``)
_kernel = pure_kernel


@_kernel
def _correct(f, o, three, ph0, ph1, ph2, y, s):
    """The correction of an accepted update in place: ``x += ph y / s``, ``P -= ph ph^T / s`` with
    ``ph = P h`` (taken before the update), innovation ``y`` and its variance ``s``; ``ph2`` unused for a
    two-state block (``three`` False)."""
    x, p = o + B_X, o + B_P
    f[x] = f[x] + ph0 * y / s
    k0 = ph0 / s
    f[p + P00] = f[p + P00] - k0 * ph0
    f[p + P01] = f[p + P01] - k0 * ph1
    f[x + 1] = f[x + 1] + ph1 * y / s
    k1 = ph1 / s
    if not three:
        f[p + P11] = f[p + P11] - k1 * ph1
        return
    f[p + P02] = f[p + P02] - k0 * ph2
    f[p + P11] = f[p + P11] - k1 * ph1
    f[p + P12] = f[p + P12] - k1 * ph2
    f[x + 2] = f[x + 2] + ph2 * y / s
    k2 = ph2 / s
    f[p + P22] = f[p + P22] - k2 * ph2


@_kernel
def _update_one(f, bi, i, z, r, gate):
    """One state's update: block ``bi``'s state ``i`` measured as ``z`` with variance ``r``, gated at
    ``gate`` (chi-square, 1 dof); True when accepted (else nothing changes)."""
    o = F_BLOCKS + BLOCK_SIZE * bi
    p = o + B_P
    s = f[p + _pk(i, i)] + r
    y = z - f[o + B_X + i]
    if not (s > 0.0 and y * y <= gate * s):
        return False
    three = bi < TILT_X or bi > HEAD
    ph2 = f[p + _pk(2, i)] if three else 0.0
    _correct(f, o, three, f[p + _pk(0, i)], f[p + _pk(1, i)], ph2, y, s)
    return True


@_kernel
def _update_row(f, bi, h0, h1, h2, z, r, gate):
    """A row's update on three-state block ``bi``: ``z = h . x + noise(r)``, gated at ``gate``; True when
    accepted."""
    o = F_BLOCKS + BLOCK_SIZE * bi
    x, p = o + B_X, o + B_P
    p00, p01, p02, p11, p12, p22 = f[p + P00], f[p + P01], f[p + P02], f[p + P11], f[p + P12], f[p + P22]
    ph0 = 0.0 + p00 * h0 + p01 * h1 + p02 * h2
    ph1 = 0.0 + p01 * h0 + p11 * h1 + p12 * h2
    ph2 = 0.0 + p02 * h0 + p12 * h1 + p22 * h2
    s = 0.0 + h0 * ph0 + h1 * ph1 + h2 * ph2 + r
    y = z - (0.0 + h0 * f[x] + h1 * f[x + 1] + h2 * f[x + 2])
    if not (s > 0.0 and y * y <= gate * s):
        return False
    _correct(f, o, True, ph0, ph1, ph2, y, s)
    return True


# ---- channels and gates (BatchedMeasuredKalman's methods of the same names) ---------------------------------------
@_kernel
def _value(c, f, ch):
    """Channel ``ch``'s adapted variance: ``E[y^2] - E[h P h]`` between its floor and its ceiling (NaN: the floor)."""
    v = f[F_EY2 + ch] - f[F_EHPH + ch]
    if v > c[C_CEILING + ch]:
        return c[C_CEILING + ch]
    return v if v > c[C_FLOOR + ch] else c[C_FLOOR + ch]


@_kernel
def _learn(c, f, ch, y, hph, r, gate):
    """Channel ``ch`` learns innovation ``y`` of predicted variance ``hph + r``, its square clipped at the gate."""
    rate = c[C_ADAPT_RATE]
    y2 = minimum(y * y, gate * (hph + r))
    e = f[F_EY2 + ch]
    f[F_EY2 + ch] = e + rate * (y2 - e)
    h = f[F_EHPH + ch]
    f[F_EHPH + ch] = h + rate * (hph - h)


@_kernel
def _gated(c, n, stream):
    """A refused update of ``stream`` counted; True when its gate reopens (refused more than ``gate_reopen`` times in
    a row: the update is then made ungated; the run counter stays, as in the scalar filter)."""
    n[N_REFUSED + stream] += 1
    run = n[N_GATED_RUN + stream] + 1
    if run <= c[C_GATE_REOPEN]:
        n[N_GATED_RUN + stream] = run
        return False
    n[N_REOPENED] += 1
    return True


@_kernel
def _one(c, f, n, stream, bi, i, z, ch):
    """``_one``: the gated update of block ``bi``'s state ``i`` measured as ``z`` on channel ``ch``; True when
    accepted."""
    r = _value(c, f, ch)
    o = F_BLOCKS + BLOCK_SIZE * bi
    pii = f[o + B_P + _pk(i, i)]
    y = z - f[o + B_X + i]
    gate = c[C_GATE1]
    ok = _update_one(f, bi, i, z, r, gate)
    if not ok and _gated(c, n, stream):
        _update_one(f, bi, i, z, r, math.inf)
    _learn(c, f, ch, y, pii, r, gate)
    if ok:
        n[N_GATED_RUN + stream] = 0
    return ok


@_kernel
def _row(c, f, n, stream, bi, h0, h1, h2, z, ch, extra_r):
    """``_row``: the gated update ``z = h . x`` of three-state block ``bi`` on channel ``ch`` plus ``extra_r`` of
    variance; True when accepted."""
    r = _value(c, f, ch) + extra_r
    o = F_BLOCKS + BLOCK_SIZE * bi
    x, p = o + B_X, o + B_P
    p00, p01, p02, p11, p12, p22 = f[p + P00], f[p + P01], f[p + P02], f[p + P11], f[p + P12], f[p + P22]
    hph = 0.0 + h0 * (0.0 + p00 * h0 + p01 * h1 + p02 * h2) + h1 * (0.0 + p01 * h0 + p11 * h1 + p12 * h2)
    hph = hph + h2 * (0.0 + p02 * h0 + p12 * h1 + p22 * h2)
    y = z - (0.0 + h0 * f[x] + h1 * f[x + 1] + h2 * f[x + 2])
    gate = c[C_GATE1]
    ok = _update_row(f, bi, h0, h1, h2, z, r, gate)
    if not ok and _gated(c, n, stream):
        _update_row(f, bi, h0, h1, h2, z, r, math.inf)
    _learn(c, f, ch, y, hph + extra_r, r - extra_r, gate)
    if ok:
        n[N_GATED_RUN + stream] = 0
    return ok


@_kernel
def _learn_wander(c, f, i, y, s):
    """Axis ``i``'s position wander density from its innovation ``y`` of variance ``s`` (``_learn_wander``)."""
    lam = c[C_WANDER_RATE]
    ym = f[F_Y_MEAN + i]
    rs = math.sqrt(s)
    m = ym + lam * (maximum(-3.0, minimum(3.0, y / rs)) * rs - ym)
    f[F_Y_MEAN + i] = m
    q = f[F_Q_P + i] * (1.2 if m * m > 9.0 * s * lam / (2.0 - lam) else 0.995)
    f[F_Q_P + i] = minimum(maximum(q, c[C_Q_P_MIN]), c[C_Q_P_MAX])


@_kernel
def _pair(c, f, n, stream, bi, z0, z1, c0, c1):
    """``_pair``: block ``bi``'s states 0 and 1 measured as ``z0``, ``z1`` on channels ``c0``, ``c1``, one at a time;
    a kinematic block's position innovation adapts its axis's wander."""
    o = F_BLOCKS + BLOCK_SIZE * bi
    y0, s0 = z0 - f[o + B_X], f[o + B_P + P00] + _value(c, f, c0)
    _one(c, f, n, stream, bi, 0, z0, c0)
    if bi < TILT_X:
        _learn_wander(c, f, bi, y0, s0)
    _one(c, f, n, stream, bi, 1, z1, c1)
