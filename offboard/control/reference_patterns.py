"""Named reference patterns built from the blocks of ``offboard.control.reference``: hover, rest-to-rest, circle,
figure-eight and waypoints (a shape-preserving C^7 spline through timed or speed-timed points).

Frames and units: world NWU, z up; positions in m, heading in rad, times in s. Bad arguments raise
:class:`~offboard.control.reference.TrajectoryError` naming the value. Design: ``docs/references.md``.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

from offboard.control.jet import Jet, PolynomialTaylor
from offboard.control.reference import (
    ORDERS,
    Composite,
    Constant,
    Phase,
    PhaseSine,
    Scalar,
    SmoothStep,
    TrajectoryError,
    _finite,
    _positive,
)
from offboard.control.smooth_step import H0, H1, STEP, VELOCITY_STEP_HALF, mirrored, scaled

#: how a waypoint segment that starts and ends at rest (in its channel) moves: ``position`` the degree-15 smooth step
#: on the position (the default), ``velocity`` the smooth step on the velocity (it accelerates over the first half and
#: brakes over the second: peak speed twice the mean instead of 3.14 times, peak acceleration 0.83 times;
#: ``smooth_step.VELOCITY_STEP_HALF``)
SHAPES = ("position", "velocity")


class HermiteSpline(Scalar):
    """Piecewise degree-15 polynomial through ``values`` at ``times`` with the given ``slopes`` (unit/s).

    At every knot the value and slope are as given and derivatives 2..7 are zero, so the curve is C^7. Before
    the first and after the last knot the end values are held (C^7 there too when the end slopes are zero).
    ``shape`` (:data:`SHAPES`) ``velocity``: a segment with both slopes zero follows the velocity step instead (degree
    16, C^8, also at its midpoint).
    """

    def __init__(
        self, times: Sequence[float], values: Sequence[float], slopes: Sequence[float], shape: str = "position"
    ) -> None:
        if shape not in SHAPES:
            raise TrajectoryError(f"shape must be one of {', '.join(SHAPES)}, got {shape!r}")
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
        sc, h0c, h1c = STEP.coefficients, H0.coefficients, H1.coefficients
        self._pieces: list[tuple[float, float, PolynomialTaylor, PolynomialTaylor]] = []
        for i in range(len(self.times) - 1):
            T = self.times[i + 1] - self.times[i]
            dp = self.values[i + 1] - self.values[i]
            m0 = self.slopes[i] * T
            m1 = self.slopes[i + 1] * T
            if shape == "velocity" and m0 == 0.0 and m1 == 0.0:
                # p(x) = p0 + dp G(x) on [0, 1/2], p = p1 - dp G(y) in y = 1 - x on [0, 1/2]
                gc = VELOCITY_STEP_HALF.coefficients
                left = [dp * a for a in gc]
                left[0] += self.values[i]
                right = [-dp * a for a in gc]
                right[0] += self.values[i + 1]
                self._pieces.append((self.times[i], 1.0 / T, PolynomialTaylor(left), PolynomialTaylor(right)))
                continue
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
            return Jet._raw(scaled(left.taylor(x, n), inv))
        return Jet._raw(scaled(mirrored(right.taylor(1.0 - x, n)), inv))

    @property
    def end(self) -> float:
        return self.times[-1]

    @property
    def breakpoints(self) -> tuple[float, ...]:
        return self.times


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


def rest_to_rest(start: Sequence[float], end: Sequence[float], t_start: float, move_time: float) -> Composite:
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
    shape: str = "position",
) -> Composite:
    """A C^7 path through ``points`` (x, y, z[, psi]) (m, m, m, rad), at rest at the first and last point.

    Timing: either ``segment_times`` (s, one per segment) or ``speed`` (m/s, mean along the straight chords): a
    segment takes ``max(chord / speed, |dpsi| / yaw_rate, min_segment_time)`` s. The first point is held until
    ``t_start``. Per channel, a degree-15 Hermite piece joins consecutive points. The path does not stop at interior
    waypoints: the slope there is the centred difference, zero where that channel has a local extremum, limited to
    1.4 times the smaller neighbouring secant so monotone data give a monotone path. Derivatives 2..7 vanish at each
    waypoint, so the path is C^7. psi is taken literally (no angle wrapping). One point: hover there. ``shape``
    (:data:`SHAPES`): how a segment that starts and ends at rest in a channel moves (``velocity``: accelerate over its
    first half, brake over its second, the lower peak speed and acceleration).
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
            chans.append(HermiteSpline(times, vals, _knot_slopes(times, vals), shape))
    return Composite(*chans, duration=times[-1])


__all__ = ["SHAPES", "SLOPE_LIMIT", "HermiteSpline", "circle", "figure_eight", "hover", "rest_to_rest", "waypoints"]
