"""What both Kalman filters (``estimators.filters.kf``, ``estimators.filters.measured_kf``) do alike around their
algebra: admit a measurement record (finite, initialized, a sensor that is fitted), queue it in sampling-time order
behind a fusion horizon (late records dropped, out-of-order ones counted and still fused), the chi-square gates with a
stream reopened after ``gate_reopen`` refusals in a row, the counters, and the fall-back to the last good estimate when
the filter's output is not finite; and the attitude record's world tilt, which both filters measure. Times in s
(vehicle clock)."""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass
from typing import Any

from estimators.model.control_state import ControlState
from estimators.model.flatness import world_tilt
from estimators.model.measurements import LoadAngle, Measurement
from estimators.model.rotations import euler_rates

_DEG = math.pi / 180.0


@dataclass(frozen=True)
class MeasurementNoise:
    """Measurement standard deviations both filters start from (SI, rad): those of the ``px4-typical`` sensor
    preset (``sim_bridge.plant.sensors``); each filter's tuning adds its process noises and priors."""

    sigma_pos_xy: float = 0.02
    sigma_pos_z: float = 0.03
    sigma_vel_xy: float = 0.03
    sigma_vel_z: float = 0.03
    sigma_tilt: float = 0.3 * _DEG
    sigma_yaw: float = 0.6 * _DEG
    sigma_rate: float = 0.01
    sigma_acc: float = 0.2
    sigma_load: float = 0.5 * _DEG


#: ``scipy.stats.chi2.ppf(0.9999, dof)`` (the default gate) as scipy computes it, for the degrees of freedom used
_CHI2_9999 = {1: 15.136705226623606, 2: 18.420680743952584, 3: 21.107513466160444, 4: 23.512742444991076}

#: the counters every filter keeps (``stats()``), before its own per-stream ones
BASE_STATS: tuple[str, ...] = (
    "accepted",
    "late_dropped",
    "out_of_order",
    "gated_outliers",
    "nan_rejected",
    "gate_reopened",
    "commands_rejected",
    "not_used",
    "nonfinite_resets",
)


def chi2_quantile(p: float, dof: int) -> float:
    """The chi-square quantile ``scipy.stats.chi2.ppf(p, dof)``, computed as scipy computes it,
    ``2 gammaincinv(dof / 2, p)`` (identical values; the default gate's are stored: importing scipy.stats costs
    about half a second and scipy.special 0.15 s at every start of ``slung fly`` / ``slung replay``)."""
    if p == 0.9999 and dof in _CHI2_9999:
        return _CHI2_9999[dof]
    from scipy.special import gammaincinv

    return float(2 * gammaincinv(dof / 2, p))


def attitude_tilt(
    phi: float, theta: float, psi: float, p: float, q: float, r: float
) -> tuple[float, float, float, float, float] | None:
    """The world tilt ``(n_x, n_y)``, its rate ``(n_x', n_y')`` (rad, rad/s; ``estimators.model.flatness.world_tilt``)
    and the heading rate (rad/s) from model-frame ZYX angles and body rates (FLU, rad/s; errata E4); None where the
    Euler rates are singular (pitched to the vertical: the record is not used)."""
    if abs(math.cos(theta)) < 1e-3:
        return None
    phi_rate, theta_rate, psi_rate = euler_rates(phi, theta, p, q, r)
    nx, ny, nxd, nyd = world_tilt(phi, theta, psi, phi_rate, theta_rate, psi_rate)
    return nx, ny, nxd, nyd, psi_rate


def check_rates(rate_hz: float, delay_s: float) -> None:
    """A filter's control rate (Hz, > 0) and fusion horizon (s, >= 0), finite, or ValueError."""
    if not (rate_hz > 0.0 and math.isfinite(rate_hz)):
        raise ValueError(f"rate_hz must be > 0, got {rate_hz!r}")
    if not (delay_s >= 0.0 and math.isfinite(delay_s)):
        raise ValueError(f"delay_s must be >= 0, got {delay_s!r}")


class BlockState:
    """One filter block's state: its time ``t`` (s, the block's fusion horizon), mean ``x`` and covariance ``p``
    (each filter's storage: lists of floats, or numpy views)."""

    __slots__ = ("p", "t", "x")

    def __init__(self, t: float, x: Any, p: Any) -> None:
        self.t, self.x, self.p = t, x, p


class RecordFusion:
    """Mixin of the two filters. The filter provides ``_stats`` (counters, :data:`BASE_STATS` among them),
    ``_gated_run`` (refusals in a row per stream), ``tuning.gate_reopen``, ``load_sensor``, ``_initialized`` and
    ``_t_out`` (its output time), and calls :meth:`_start_records` from ``initialize``."""

    _stats: dict[str, int]
    _gated_run: dict[str, int]
    tuning: Any
    load_sensor: bool
    _initialized: bool
    _t_out: float

    def _start_records(self, guess: ControlState) -> None:
        self._seq = 0
        self._latest_t = -math.inf  # the newest sampling time pushed (any kind): out_of_order counts the others
        self._last_good = guess

    def _admit(self, m: Measurement) -> bool:
        """Whether record ``m`` may be queued: non-finite records (``nan_rejected``) and cable angles without a
        fitted sensor (``not_used``) are counted and refused."""
        try:  # a finite sum proves every field finite; otherwise look (the sum may overflow)
            finite = math.isfinite(sum(m)) or all(math.isfinite(v) for v in m)
        except TypeError:
            finite = False
        if not finite:
            self._stats["nan_rejected"] += 1
            return False
        if not self._initialized:
            raise RuntimeError("initialize() the estimator before pushing measurements")
        if isinstance(m, LoadAngle) and not self.load_sensor:
            self._stats["not_used"] += 1
            return False
        return True

    def _enqueue(self, queue: list[tuple[float, int, Measurement]], m: Measurement, horizon: float) -> None:
        """Queue ``m`` in sampling-time order unless it was sampled before ``horizon`` (s: the oldest time of the
        blocks it updates; counted ``late_dropped``)."""
        if m.t < horizon:
            self._stats["late_dropped"] += 1
            return
        if m.t < self._latest_t:
            self._stats["out_of_order"] += 1
        else:
            self._latest_t = m.t
        heapq.heappush(queue, (m.t, self._seq, m))
        self._seq += 1

    def _gated(self, name: str) -> bool:
        """Count a gated update of stream ``name``; True when the gate must reopen (the stream has been
        rejected too long: the filter, not the sensor, is wrong) and the update be done ungated."""
        self._stats["gated_" + name] += 1
        run = self._gated_run[name] + 1
        if run <= self.tuning.gate_reopen:
            self._gated_run[name] = run
            return False
        self._stats["gate_reopened"] += 1
        return True

    def _pair_gain(
        self, name: str, s00: float, s01: float, s11: float, y0: float, y1: float, gate: float
    ) -> tuple[float, float, float, float, float] | None:
        """The gated two-channel update of stream ``name`` with innovation ``(y0, y1)`` and innovation covariance
        ``S = [[s00, s01], [s01, s11]]``: ``(a, b, d, w0, w1)`` with ``S^-1 = [[a, b], [b, d]]`` and
        ``(w0, w1) = S^-1 y`` when the normalized innovation squared ``y S^-1 y`` is within ``gate`` (or the stream
        reopens, :meth:`_gated`); None when refused (or S is not positive definite)."""
        det = s00 * s11 - s01 * s01
        while True:
            if det > 0.0:
                a, b, d = s11 / det, -s01 / det, s00 / det
                w0, w1 = y0 * a + y1 * b, y0 * b + y1 * d
                if w0 * y0 + w1 * y1 <= gate:
                    return a, b, d, w0, w1
            if gate == math.inf or not self._gated(name):
                return None
            gate = math.inf

    def _checked(self, est: ControlState) -> ControlState:
        """``est`` when finite; else the last good estimate, the filter restarted from it (``nonfinite_resets``)."""
        if not est.is_finite():
            self._stats["nonfinite_resets"] += 1
            last = self._last_good
            self.initialize(self._t_out, last)  # type: ignore[attr-defined]
            return last
        self._last_good = est
        return est


__all__ = [
    "BASE_STATS",
    "BlockState",
    "MeasurementNoise",
    "RecordFusion",
    "attitude_tilt",
    "check_rates",
    "chi2_quantile",
]
