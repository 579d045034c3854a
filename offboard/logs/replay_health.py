"""Is the replayed estimate still usable? Checks of the estimate against itself and against the autopilot's own
estimate, tick by tick, and the noise the filter should assume for the log's own sensors.

A log has no truth, but it has the autopilot's estimate (ATTITUDE, LOCAL_POSITION_NED, their ULog and DataFlash
counterparts): the filter's implied vehicle position (``F - l alpha``, model frame, m) and height must stay near
it. A tick is **diverged** when any of these holds (the first that holds is the reason):

- an estimated number is not finite or beyond :data:`ABSURD` (no quantity of a flying vehicle comes near it);
- the swing is beyond :data:`MAX_SWING_RAD` (a hanging load does not swing past 70 degrees in flight);
- the implied position is more than :data:`MAX_POSITION_ERROR_M` from the autopilot's (horizontally), or the
  height more than :data:`MAX_HEIGHT_ERROR_M`, while the autopilot's position is fresh (:data:`FRESH_S`);
- the innovation tests fail persistently: the filter's chi-square gate refused :data:`INNOVATION_REJECTS` of the
  autopilot's position and height samples within :data:`INNOVATION_WINDOW_S` (the filter disagrees with the
  autopilot's own estimate; the accelerometer's streams are aiding ones and are not counted).

The replay then reports the time and reason and restarts the filter from the autopilot's state.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from estimators.model.measurements import Attitude, Imu, PositionVelocity

#: no estimated quantity of a flying multirotor is anywhere near this (m, m/s^k, rad, rad/s)
ABSURD = 1e6
#: swing angle (rad) beyond which the estimate is not of a load hanging below a flying vehicle
MAX_SWING_RAD = 1.2
#: implied horizontal position vs the autopilot's (m)
MAX_POSITION_ERROR_M = 5.0
#: height vs the autopilot's (m)
MAX_HEIGHT_ERROR_M = 3.0
#: the autopilot's position is compared only when it is at most this old (s)
FRESH_S = 1.0
#: innovation test: this many of the autopilot's position and height samples refused by the filter's chi-square
#: gate within INNOVATION_WINDOW_S is a divergence (one now and then is an outlier, or a manoeuvre caught up with)
INNOVATION_REJECTS = 30
INNOVATION_WINDOW_S = 2.0
#: ... and at least this fraction of the position and height updates offered in that window
INNOVATION_FRACTION = 0.5


@dataclass
class HealthMonitor:
    """Tick-by-tick divergence checks (see module docstring). ``cable_length``: m. ``events``: every divergence
    as ``{"t_s", "reason", "segment"}``; ``diverged_ticks``: how many ticks were unusable."""

    cable_length: float
    events: list[dict[str, Any]] = field(default_factory=list)
    diverged_ticks: int = 0
    _rejects: list[tuple[float, int, int]] = field(default_factory=list)

    def check(
        self,
        t: float,
        est: Sequence[Any],
        pv: PositionVelocity | None,
        stats: dict[str, int] | None,
        positions: int = 0,
    ) -> str:
        """The reason the estimate ``est`` (a ``ControlState``) at vehicle time ``t`` is unusable, or "" when it
        is usable. ``pv``: the autopilot's latest position; ``stats``: the filter's counters (None: not looked at
        this tick; ``gated_pos`` / ``gated_z`` are compared with the looks of the last window); ``positions``: how
        many position records the filter has been given so far."""
        fx, fy = est[0], est[1]
        values = (*fx, *fy, *est[2:])
        total = math.fsum(abs(v) for v in values) if math.isfinite(sum(values)) else math.inf
        if not total < ABSURD:
            worst = max(values, key=lambda v: abs(v) if math.isfinite(v) else math.inf)
            return f"estimate not finite or absurd ({worst:.3g})" if math.isfinite(worst) else "estimate not finite"
        ax, ay = est[10], est[11]  # ControlState: fx, fy, z, z_rate, phi, theta, psi, 3 rates, alpha_x, alpha_y
        swing = math.hypot(ax, ay)
        if swing > MAX_SWING_RAD:
            return f"swing estimate {swing:.2f} rad, beyond a hanging load"
        if pv is not None and abs(t - pv.t) <= FRESH_S:
            ell = self.cable_length
            d = math.hypot(fx[0] - ell * ay - pv.x, fy[0] - ell * ax - pv.y)
            if d > MAX_POSITION_ERROR_M:
                return f"estimate {d:.1f} m from the autopilot's position"
            dz = abs(est[2] - pv.z)
            if dz > MAX_HEIGHT_ERROR_M:
                return f"height estimate {dz:.1f} m from the autopilot's"
        if stats is not None:
            rejected = int(stats.get("gated_pos", 0)) + int(stats.get("gated_z", 0))
            hist = self._rejects
            hist.append((t, rejected, positions))
            while hist and hist[0][0] < t - INNOVATION_WINDOW_S:
                hist.pop(0)
            n = rejected - hist[0][1]
            offered = 2 * (positions - hist[0][2])  # each position record is two updates: horizontal, height
            if n >= INNOVATION_REJECTS and n >= INNOVATION_FRACTION * offered:
                hist.clear()
                return (
                    f"innovation tests failed: {n} of {offered} position / height updates rejected in "
                    f"{INNOVATION_WINDOW_S:g} s (the filter disagrees with the autopilot)"
                )
        return ""

    def restarted(self, stats: dict[str, int]) -> None:
        """The filter was restarted: the innovation history starts over."""
        self._rejects = []

    def report(self, t: float, reason: str, segment: int) -> None:
        self.diverged_ticks += 1
        if len(self.events) < 200:
            self.events.append({"t_s": t, "reason": reason, "segment": segment})


def _noise(values: list[float]) -> float:
    """Standard deviation of a signal's sample-to-sample noise: the RMS of second differences / sqrt(6) (white
    noise of std s gives second differences of variance 6 s^2; a smooth motion contributes little)."""
    if len(values) < 8:
        return math.nan
    d2 = [values[i + 1] - 2.0 * values[i] + values[i - 1] for i in range(1, len(values) - 1)]
    return math.sqrt(math.fsum(v * v for v in d2) / len(d2) / 6.0)


def _resolution(values: list[float]) -> float:
    """The smallest non-zero step between consecutive samples (a quantized sensor's resolution), or 0."""
    steps = [abs(b - a) for a, b in itertools.pairwise(values) if b != a]
    return min(steps) if steps else 0.0


def fit_sensor_noise(meas: Sequence[Any], t0: float = -math.inf, t1: float = math.inf) -> dict[str, Any]:
    """The noise of the log's own sensors over vehicle time ``t0`` .. ``t1``: per stream its rate (Hz, from the
    sample stamps), the sample-to-sample noise (second differences) and the resolution (smallest step) of the
    accelerometer, gyro, attitude and position. Used to set the filter's measurement noise
    (:func:`tuning_for`)."""
    acc: list[float] = []
    gyr: list[float] = []
    tilt: list[float] = []
    pos: list[float] = []
    stamps: dict[str, list[float]] = {"imu": [], "attitude": [], "position": []}
    for m in meas:
        if not t0 <= m.t <= t1:
            continue
        if isinstance(m, Imu):
            acc.append(m.ax)
            gyr.append(m.gx)
            stamps["imu"].append(m.t)
        elif isinstance(m, Attitude):
            tilt.append(m.phi)
            stamps["attitude"].append(m.t)
        elif isinstance(m, PositionVelocity):
            pos.append(m.x)
            stamps["position"].append(m.t)
    rates = {}
    for k, ts in stamps.items():
        rates[k] = (len(ts) - 1) / (ts[-1] - ts[0]) if len(ts) > 2 and ts[-1] > ts[0] else None
    fitted = {
        "rates_hz": rates,
        "acc_noise": _noise(acc),
        "acc_resolution": _resolution(acc[:2000]),
        "gyro_noise": _noise(gyr),
        "gyro_resolution": _resolution(gyr[:2000]),
        "tilt_noise": _noise(tilt),
        "position_noise": _noise(pos),
    }
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in fitted.items()}


def tuning_for(fitted: dict[str, Any], base: Any) -> Any:
    """The filter's noise assumptions (``estimators.filters.kf.Tuning``) with the measurement noise set from the log's
    own sensors (:func:`fit_sensor_noise`), never below ``base``'s (the sensor preset's floor: the second differences
    of an autopilot's smoothed outputs understate the noise of what they measure) nor below a quantized sensor's
    resolution / sqrt(12); capped at ten times ``base``'s."""

    def pick(name: str, noise: float | None, resolution: float | None = None) -> float:
        b = getattr(base, name)
        v = max(b, noise or 0.0, (resolution or 0.0) / math.sqrt(12.0))
        return min(v, 10.0 * b)

    return replace(
        base,
        sigma_acc=pick("sigma_acc", fitted.get("acc_noise"), fitted.get("acc_resolution")),
        sigma_rate=pick("sigma_rate", fitted.get("gyro_noise"), fitted.get("gyro_resolution")),
        sigma_tilt=pick("sigma_tilt", fitted.get("tilt_noise")),
        sigma_pos_xy=pick("sigma_pos_xy", fitted.get("position_noise")),
    )


#: metres per degree of latitude (WGS-84 mean radius), for the payload's offset from the vehicle
M_PER_DEG = 6_371_000.0 * math.pi / 180.0


def _swing_of_offset(n: float, e: float, d: float) -> tuple[float, float]:
    """(alpha_x, alpha_y) (rad, model frame) of the cable along the payload's offset from the vehicle (north, east,
    down, m), NaN when the offset is too short to give a direction; converted with ``estimators.model.frames`` and the
    planar angles of ``estimators.model.cable``."""
    from estimators.model.cable import planar_swing
    from estimators.model.frames import ned_to_model_vector

    norm = math.sqrt(n * n + e * e + d * d)
    if norm < 0.05:
        return math.nan, math.nan
    r1, r2, r3 = ned_to_model_vector(n / norm, e / norm, d / norm)
    a_y, a_x, _, _ = planar_swing(r1, r2, r3, 0.0, 0.0, 0.0)
    return a_x, a_y


def truth_swing(
    t: Sequence[float], vehicle: Sequence[tuple[float, Any]], load: Sequence[tuple[float, Any]], max_age_s: float = 0.2
) -> tuple[list[float], list[float]]:
    """The swing (alpha_x, alpha_y per tick time ``t``, rad, model frame) from the payload's own position and the
    vehicle's (GLOBAL_POSITION_INT: (vehicle time, (lat deg, lon deg, alt m))), each the latest at the tick and at
    most ``max_age_s`` old, else NaN. The offset is taken flat (north, east, down metres: the cable is short)."""
    import bisect

    tv = [a for a, _ in vehicle]
    tl = [a for a, _ in load]
    ax: list[float] = []
    ay: list[float] = []
    for tk in t:
        i = bisect.bisect_right(tv, tk) - 1
        j = bisect.bisect_right(tl, tk) - 1
        if i < 0 or j < 0 or tk - tv[i] > max_age_s or tk - tl[j] > max_age_s:
            ax.append(math.nan)
            ay.append(math.nan)
            continue
        (la, lo, al), (lb, lob, alb) = vehicle[i][1], load[j][1]
        a_x, a_y = _swing_of_offset(
            (lb - la) * M_PER_DEG, (lob - lo) * M_PER_DEG * math.cos(math.radians(la)), al - alb
        )
        ax.append(a_x)
        ay.append(a_y)
    return ax, ay


def offset_swing(
    t: Sequence[float], offsets: Sequence[tuple[float, tuple[float, float, float]]], max_gap_s: float = 0.5
) -> tuple[list[float], list[float]]:
    """The swing (alpha_x, alpha_y per tick time ``t``, rad, model frame) from samples of the payload's offset from
    the vehicle ((vehicle time s, (north, east, down m)): DataFlash SLUP), interpolated between the samples around
    each tick (Catmull-Rom through the four nearest, linear at the ends) when they are at most ``max_gap_s`` apart,
    else NaN. Why interpolated, and not linearly: ArduPilot's SITL logs SLUP at 5 Hz only; a 1 m pendulum turns
    by a large fraction of its amplitude in 0.2 s, so the latest sample lags the swing, and a straight line between
    two samples cuts its peaks (on ``tests/dataflash_writer.sim_dataflash``'s 0.17 rad swing, against the simulated
    truth: linear 0.007 / 0.014 rad RMS in alpha_x / alpha_y, this cubic 0.003 / 0.006)."""
    import bisect

    ts = [a for a, _ in offsets]
    ps = [b for _, b in offsets]
    n = len(ts)
    ax: list[float] = []
    ay: list[float] = []
    for tk in t:
        j = bisect.bisect_right(ts, tk)  # ts[j - 1] <= tk < ts[j]
        if j and ts[j - 1] == tk:  # on a sample (the last one included)
            a_x, a_y = _swing_of_offset(*ps[j - 1])
            ax.append(a_x)
            ay.append(a_y)
            continue
        if j == 0 or j == n or ts[j] - ts[j - 1] > max_gap_s:
            ax.append(math.nan)
            ay.append(math.nan)
            continue
        t1, t2 = ts[j - 1], ts[j]
        u = (tk - t1) / (t2 - t1) if t2 > t1 else 0.0
        p1, p2 = ps[j - 1], ps[j]
        cubic = j >= 2 and j + 1 < n and t1 - ts[j - 2] <= max_gap_s and ts[j + 1] - t2 <= max_gap_s
        if cubic:
            p0, p3 = ps[j - 2], ps[j + 1]
            # Catmull-Rom on (nearly) uniform samples: tangents (p2 - p0) / 2 and (p3 - p1) / 2 per interval
            u2, u3 = u * u, u * u * u
            h00, h10, h01, h11 = 2 * u3 - 3 * u2 + 1, u3 - 2 * u2 + u, -2 * u3 + 3 * u2, u3 - u2
            off = tuple(
                h00 * b + h10 * 0.5 * (c - a) + h01 * c + h11 * 0.5 * (d - b) for a, b, c, d in zip(p0, p1, p2, p3)
            )
        else:
            off = tuple(b + u * (c - b) for b, c in zip(p1, p2))
        a_x, a_y = _swing_of_offset(*off)
        ax.append(a_x)
        ay.append(a_y)
    return ax, ay


__all__ = [
    "ABSURD",
    "MAX_POSITION_ERROR_M",
    "MAX_SWING_RAD",
    "HealthMonitor",
    "fit_sensor_noise",
    "offset_swing",
    "truth_swing",
    "tuning_for",
]
