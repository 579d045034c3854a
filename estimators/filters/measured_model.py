"""The measured-input Kalman filter's model (``estimators.filters.measured_kf``): its noise assumptions, its blocks
and the adapted variance of a measurement channel (the derivation is in ``measured_kf``'s docstring and
``docs/estimation.md``).

Shared by the filter's public class (``measured_kf``), its prediction (``measured_predict``) and its gated updates
(``measured_update``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import NamedTuple

from estimators.filters.fusion import BlockState, MeasurementNoise
from estimators.filters.small_kf import Matrix


@dataclass(frozen=True)
class MeasuredTuning(MeasurementNoise):
    """Noise assumptions (SI, rad). Measurement standard deviations are floors: the filter raises a channel's
    variance to what its innovations show. Process noises are continuous spectral densities."""

    q_v: float = 0.005  # (m/s^2)^2/Hz: acceleration the held accelerometer sample misses (noise, between samples)
    q_vz: float = 0.05  # (m/s^2)^2/Hz: the same vertically, where a sign-switching height law's 1 kHz thrust chatter
    # aliases into 50 Hz accelerometer samples (0.005 gave the sensorless paper scenario e_z 0.053 m, above Table 2)
    q_v_no_imu: float = 5.0  # (m/s^2)^2/Hz: white acceleration when no IMU telemetry arrives
    q_b: float = 1e-6  # (m/s^3)^2/Hz: accelerometer bias random walk
    # position wandering apart from the integrated velocity (an EKF's GNSS / baro corrections: PX4 SITL's position
    # drifted 3 m, its height 0.4 m from the integrals of its own velocity in 16 s), m^2/s: adapted between these
    # bounds from the position innovations' running mean (white innovations: the lower bound)
    q_p_min: float = 1e-5
    q_p_max: float = 0.03
    wander_rate: float = 0.05  # weight of one innovation in the running mean that detects a wander
    sigma_gyro: float = 0.01  # rad/s: the IMU's gyro as a body-rate measurement (floor; adapted like the others)
    q_n: float = 20.0  # (rad/s^2)^2/Hz: tilt acceleration beyond the commanded one (the autopilot's own loops)
    tilt_command: bool = True  # the commanded tilt acceleration as the tilt blocks' input (False: n'' white only)
    fuse_gyro: bool = False  # the IMU's gyro as a second rate measurement of the tilt and heading blocks
    q_psi: float = 1.0  # (rad/s^2)^2/Hz: yaw acceleration
    q_a: float = 0.05  # (rad/s^2)^2/Hz: swing acceleration the pendulum model misses
    q_e: float = 0.5  # (m/s^3)^2/Hz: external acceleration seen by the accelerometer
    imu_timeout_s: float = 0.1  # an IMU sample older than this is no longer the acceleration input
    # the acceleration input's plausibility gate widened by the thrust changes pushed over the last imu_timeout_s:
    # a jump of the measured acceleration that the commanded thrust explains is not an outlier (False: the gate
    # takes only the sensor noise, which refused the law's own thrust steps; docs/estimation.md section 0.1)
    thrust_explains_jumps: bool = True
    # the law acts on the external acceleration the swing blocks estimate (their e, beyond external_significance of
    # its standard deviations): F^(4) of the chain gets (g / l) e, so that the vehicle tilts against a force on it
    # as soon as the accelerometer shows it (False, the default: the chain of the pendulum model alone).
    # docs/compare.md: the late gusts of slung sweep
    external_feedforward: bool = False
    external_significance: float = 3.0
    prior_pos: float = 0.05
    prior_vel: float = 0.1
    prior_bias: float = 0.1
    prior_swing: float = 0.15
    prior_swing_rate: float = 0.5
    prior_e: float = 0.3
    prior_tilt: float = 0.02
    prior_tilt_rate: float = 0.05
    prior_psi: float = 0.02
    prior_psi_rate: float = 0.05
    gate_probability: float = 0.9999
    gate_reopen: int = 10
    noise_adapt_rate: float = 0.01  # weight of one innovation in the running innovation statistics
    noise_ceiling: float = 30.0  # an adapted standard deviation stays below this multiple of the nominal one
    accel_gain_filter: float = 0.1  # weight of a new sample in the low-pass of the vertical specific force g + u_z


#: the tuning with the external acceleration fed forward (``MeasuredTuning.external_feedforward``): the ``smc`` and
#: ``smc-attitude`` rows of compare / sweep (``registry.filter_tuning``) and ``--external-feedforward`` (sim, fly,
#: demo; replay rebuilds it)
FEEDFORWARD_TUNING = MeasuredTuning(external_feedforward=True)


#: the line length the swing's noise densities and prior rate are set for (every shipped vehicle's is 0.3-1 m), m
LINE_REFERENCE_M = 1.0


def for_line(tuning: MeasuredTuning, cable_length: float) -> MeasuredTuning:
    """``tuning`` as a filter on a line of ``cable_length`` m uses it: unchanged up to ``LINE_REFERENCE_M``; beyond,
    with ``r = cable_length / LINE_REFERENCE_M``, the swing acceleration the model misses ``q_a / r^2`` (the same
    unmodelled acceleration of the load, m/s^2, is an ``l``-times smaller angular one), the external acceleration's
    random walk ``q_e / r`` (its density at the pendulum frequency, ``q_e / w^2`` with ``w^2 ~ g / l``, stays what it
    is at 1 m, so that it does not absorb the slower swing) and the prior swing rate ``prior_swing_rate / sqrt(r)``
    (the same amplitude swinging at the slower ``w``). With the 1 m densities a 30 m line's estimate, started at 0
    on a load swinging 8 deg, wandered 10-20 deg/s off and the law chased it (docs/estimation.md, lines 0.5-30 m).
    The one place the line scales the tuning: every implementation of the filter builds on its result."""
    r = cable_length / LINE_REFERENCE_M
    if not r > 1.0:
        return tuning
    return replace(
        tuning,
        q_a=tuning.q_a / (r * r),
        q_e=tuning.q_e / r,
        prior_swing_rate=tuning.prior_swing_rate / math.sqrt(r),
    )


def channel_floors(tuning: MeasuredTuning) -> dict[str, float]:
    """Each measurement channel's nominal variance (its floor; the adapted one stays between it and
    ``noise_ceiling**2`` times it), from ``tuning``'s standard deviations: SI units squared, rad^2, (rad/s)^2. The
    acceleration input's is twice the accelerometer's (two samples differ)."""
    tn = tuning
    return {
        "pos_xy": tn.sigma_pos_xy**2,
        "vel_xy": tn.sigma_vel_xy**2,
        "pos_z": tn.sigma_pos_z**2,
        "vel_z": tn.sigma_vel_z**2,
        "tilt": tn.sigma_tilt**2,
        "tilt_rate": tn.sigma_rate**2,
        "yaw": tn.sigma_yaw**2,
        "yaw_rate": tn.sigma_rate**2,
        "gyro_rate": tn.sigma_gyro**2,
        "gyro_yaw_rate": tn.sigma_gyro**2,
        "acc": tn.sigma_acc**2,
        "acc_in": 2.0 * tn.sigma_acc**2,
        "load": tn.sigma_load**2,
    }


def thrust_window(tuning: MeasuredTuning, rate_hz: float) -> int:
    """How many pushed commands (one per control tick at ``rate_hz``, Hz) span ``tuning.imu_timeout_s``: the window
    of thrusts whose range widens the acceleration input's gate (at least 1)."""
    return max(1, math.ceil(tuning.imu_timeout_s * rate_hz - 1e-9))


#: the roles of a block (:attr:`Block.role`): position / velocity / bias, swing, tilt or heading
KIN, SWING, RATE = range(3)


class Gyro(NamedTuple):
    """The gyro of an IMU record (body FLU, rad/s), queued with the attitude records."""

    t: float
    p: float
    q: float
    r: float


class Block(BlockState):
    """One filter block (:class:`~estimators.filters.fusion.BlockState`: time s, mean and covariance as lists) with
    its role (``KIN``, ``SWING``, ``RATE``) and axis (0, 1, 2: x, y, z; 0 for the heading), so that the hot path
    finds its model without searching the lists; the prior covariance diagonal from the standard deviations ``sd``."""

    __slots__ = ("axis", "role")
    p: Matrix

    def __init__(self, t: float, x: list[float], sd: tuple[float, ...], role: int, axis: int) -> None:
        n = len(x)
        super().__init__(t, list(x), [[sd[i] ** 2 if i == j else 0.0 for j in range(n)] for i in range(n)])
        self.role, self.axis = role, axis


class Channel:
    """Adapted variance of one measurement channel: max(floor, E[y^2] - E[h P h]) over recent innovations."""

    __slots__ = ("ceiling", "ehph", "ey2", "floor", "nominal")

    def __init__(self, floor: float, ceiling_factor: float) -> None:
        self.nominal = floor
        self.floor = floor
        self.ceiling = floor * ceiling_factor**2
        self.ey2 = floor
        self.ehph = 0.0

    def value(self) -> float:
        v = self.ey2 - self.ehph
        if v > self.ceiling:  # a filter that has drifted off must not explain it away as sensor noise
            return self.ceiling
        return v if v > self.floor else self.floor

    def bound(self, reported: float) -> None:
        """Keep the adapted variance between the nominal floor and the autopilot's ``reported`` variance, whichever
        is the larger (the innovation statistics choose within)."""
        self.floor, self.ceiling = (reported, self.nominal) if reported < self.nominal else (self.nominal, reported)

    def learn(self, y: float, hph: float, r: float, gate: float, rate: float) -> None:
        """One innovation ``y`` whose predicted variance was ``hph + r``; clipped at the gate so that one wild
        outlier moves the statistics by a bounded amount."""
        y2 = y * y
        lim = gate * (hph + r)
        if y2 > lim:  # min(), written out (the hot path: 15-20 innovations per control tick)
            y2 = lim
        self.ey2 += rate * (y2 - self.ey2)
        self.ehph += rate * (hph - self.ehph)


__all__ = [
    "FEEDFORWARD_TUNING",
    "KIN",
    "LINE_REFERENCE_M",
    "RATE",
    "SWING",
    "Block",
    "Channel",
    "Gyro",
    "MeasuredTuning",
    "channel_floors",
    "for_line",
    "thrust_window",
]
