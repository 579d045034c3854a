"""When the approach before offboard control has settled (``offboard.flight.loop.FlightLoop``): the vehicle's
position estimate within ``START_TOLERANCE`` of the goal, told apart from its own noise by the standard error of
the recent samples. Positions in m (model frame), times in s."""

from __future__ import annotations

import math
from typing import Any


def standard_error(values: list[float]) -> float:
    """Standard error of the mean of a window of correlated samples: ``s / sqrt(n_eff)`` with the sample standard
    deviation ``s`` and the effective count ``n_eff = n (1 - rho) / (1 + rho)`` from the lag-1 autocorrelation
    ``rho`` (clipped to 0..0.99): white samples count fully, samples that wander together nearly as one."""
    n = len(values)
    if n < 3:
        return math.inf
    mean = sum(values) / n
    dev = [v - mean for v in values]
    var = sum(d * d for d in dev) / (n - 1)
    if var <= 0.0:
        return 0.0
    rho = sum(dev[i] * dev[i + 1] for i in range(n - 1)) / (var * (n - 1))
    rho = min(max(rho, 0.0), 0.99)
    n_eff = max(1.0, n * (1.0 - rho) / (1.0 + rho))
    return math.sqrt(var / n_eff)


#: floors of the start criterion: position (m), speed (m/s), swing (rad) of the window means
START_TOLERANCE = (0.01, 0.03, 0.02)


def settled(
    pos: Any,
    swing: Any,
    gx: float,
    gy: float,
    gz: float,
    long_enough: bool,
    has_load: bool,
    noise: Any = None,
) -> bool:
    """The approach criterion of :meth:`FlightLoop._approach` on the windows of position samples
    (t, x, y, z, vx, vy, vz) and load-angle samples (t, alpha_x, alpha_y): the window means within 1 cm of the
    goal, 3 cm/s of rest and 0.02 rad of hanging straight, or within two standard errors of the mean
    (:func:`standard_error`, per axis, combined) where the telemetry is noisier than that. The standard errors
    of position and velocity come from ``noise``, a longer window of the same samples when given (an estimate
    that wanders over seconds looks precise over half a second)."""
    if not long_enough or len(pos) < 3 or (has_load and len(swing) < 3):
        return False
    n = len(pos)
    cols = [[s[i] for s in pos] for i in range(1, 7)]
    mx, my, mz, mvx, mvy, mvz = (sum(c) / n for c in cols)
    spread = noise if noise is not None and len(noise) >= n else pos
    se = [standard_error([s[i] for s in spread]) for i in range(1, 7)]
    tol_p = max(START_TOLERANCE[0], 2.0 * math.sqrt(se[0] ** 2 + se[1] ** 2 + se[2] ** 2))
    tol_v = max(START_TOLERANCE[1], 2.0 * math.sqrt(se[3] ** 2 + se[4] ** 2 + se[5] ** 2))
    if math.sqrt((mx - gx) ** 2 + (my - gy) ** 2 + (mz - gz) ** 2) >= tol_p:
        return False
    if math.sqrt(mvx * mvx + mvy * mvy + mvz * mvz) >= tol_v:
        return False
    if has_load:
        k = len(swing)
        sx, sy = [s[1] for s in swing], [s[2] for s in swing]
        tol_s = max(START_TOLERANCE[2], 2.0 * math.hypot(standard_error(sx), standard_error(sy)))
        if math.hypot(sum(sx) / k, sum(sy) / k) >= tol_s:
            return False
    return True


def offset_and_noise(pos: Any, gx: float, gy: float, gz: float) -> tuple[float, float]:
    """Distance of the window's mean position from the goal and the RMS scatter of its samples about their mean, m
    (NaN without samples)."""
    n = len(pos)
    if n == 0:
        return math.nan, math.nan
    m = [sum(s[i] for s in pos) / n for i in (1, 2, 3)]
    off = math.sqrt((m[0] - gx) ** 2 + (m[1] - gy) ** 2 + (m[2] - gz) ** 2)
    scatter = math.sqrt(sum(sum((s[i + 1] - m[i]) ** 2 for i in range(3)) for s in pos) / n)
    return off, scatter
