"""Robust choice of the attitude-level law's horizontal gains: the fastest poles whose closed loop stays stable
with the autopilot's attitude and rate loops off by 2x either way and up to 30 ms of delay (``docs/model.md`` §12.3).

The loop checked is the X-Z plane's tangent linearization at hover (``docs/model.md`` §7) with the inner loop as
PX4 and ArduPilot build it (attitude P ``k`` feeding a rate loop of bandwidth ``B``:
``n'' = B k (n_sp - n) - B n'``), the delay as a second-order Pade approximant on the setpoint, and the law's
linearization inside its boundary layer (``offboard.control.smc_attitude``). Pure numpy; a few milliseconds per vehicle.

Also what the law assumes of the autopilot's loops (:class:`InnerLoop`), its gains (:class:`AttitudeGains`) and their
derivation from the vehicle (:func:`design_gains`); ``offboard.control.smc_attitude`` (the law's step) re-exports them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from estimators.model.flatness import flat_constants
from estimators.model.vehicle import Vehicle

#: (pole ratio wn_F / w_i, reaching pole / wn_F), tried fastest first
CANDIDATES: tuple[tuple[float, float], ...] = tuple(
    (wr, lr) for wr in (0.5, 0.45, 0.4, 0.35, 0.3, 0.25, 0.2) for lr in (2.0, 1.0, 0.5)
)
#: attitude-loop and rate-loop bandwidth factors and delays (s) the chosen gains must survive (a rate loop at half
#: its bandwidth also stands for one whose torque saturates now and then)
BANDWIDTH_FACTORS = (0.5, 1.0, 2.0)
RATE_FACTORS = (0.5, 1.0, 2.0)
DELAYS_S = (0.0, 0.015, 0.03)
#: the most commanded tilt rate one rad/s of error in the swing-rate estimate may ask for (rad/s per rad/s; with a
#: load). The law reads the swing rate a' in ``F' = p' + l a'`` and ``F''' = -g a'``, and both reach its tilt-rate
#: command through ``(k1 l - k3 g + reach (k2 l - k4 g)) / c + 1`` (:func:`swing_rate_gain`): 0.5-2.7 on lines up
#: to 2 m whatever the poles the inner loop allows (every shipped vehicle), but with ArduPilot's attitude loop (wn_F
#: 2.25 1/s on every line) 45 on 5 m, 231 on 10 m, 1030 on 20 m: on ArduPilot SITL the 10 m hover from rest asked
#: for the tilt limit within 0.22 s on the estimate's first errors (the IMU 25 ms behind the attitude at a tilt
#: onset) and ended on the swing watchdog (docs/deploy.md section 3a). 4: above every short line's.
SWING_RATE_GAIN_MAX = 4.0


def surface_coefficients(wn: float, zeta: float, order: int) -> list[float]:
    """(k0 .. k_{order-1}) of ``(p + wn)^(order % 2) (p^2 + 2 zeta wn p + wn^2)^(order // 2)`` (monic, low first)."""
    poly = np.poly1d([1.0])
    for _ in range(order // 2):
        poly *= np.poly1d([1.0, 2.0 * zeta * wn, wn * wn])
    if order % 2:
        poly *= np.poly1d([1.0, wn])
    return [float(c) for c in poly.coeffs[::-1][:-1]]


def closed_loop_abscissa(
    with_load: bool,
    w_swing: float,
    g: float,
    ell: float,
    mass_ratio: float,
    w_i_nominal: float,
    w_i: float,
    rate_bandwidth: float,
    delay: float,
    wn: float,
    zeta: float,
    reach: float,
) -> float:
    """Largest real part (1/s) of the closed loop's eigenvalues; ``mass_ratio`` = m / M."""
    c = g * w_swing * w_swing
    order = 5 if with_load else 3
    k = surface_coefficients(wn, zeta, order)
    # state: x, x', a, a', n, n', I, pade1, pade2; the law is linear in it: build the setpoint's row first
    nx = 9
    E = np.zeros((order, nx))  # e^(i) as rows over the state
    if with_load:
        E[0, 0], E[0, 2] = 1.0, ell
        E[1, 1], E[1, 3] = 1.0, ell
        E[2, 2] = -g
        E[3, 3] = -g
        E[4, 2], E[4, 4] = c, c
    else:
        E[0, 0] = 1.0
        E[1, 1] = 1.0
        E[2, 4] = g
    integ = np.zeros(nx)
    integ[6] = 1.0
    sigma = E[order - 1] + k[0] * integ + sum(k[i + 1] * E[i] for i in range(order - 1))
    v = -sum(k[i] * E[i] for i in range(order)) - reach * sigma
    ad = np.zeros(nx)
    ad[3] = 1.0
    n_rate = v / c - ad if with_load else v / g
    n_sp = np.zeros(nx)
    n_sp[4] = 1.0
    n_sp = n_sp + n_rate / w_i_nominal
    A = np.zeros((nx, nx))
    A[0, 1] = 1.0
    if with_load:  # x'' = g ((1 + m/M) n + (m/M) a), a'' = -w^2 (a + n)
        A[1, 4], A[1, 2] = g * (1.0 + mass_ratio), g * mass_ratio
        A[2, 3] = 1.0
        A[3, 2], A[3, 4] = -(w_swing**2), -(w_swing**2)
    else:
        A[1, 4] = g
    A[4, 5] = 1.0
    A[6] = E[0]
    if delay > 0.0:
        d0, d1, d2 = delay * delay / 12.0, delay / 2.0, 1.0
        # y = (d0 s^2 - d1 s + 1) / (d0 s^2 + d1 s + 1) u, controllable canonical form
        a1, a0 = d1 / d0, d2 / d0
        A[7, 8] = 1.0
        A[8] = -a0 * np.eye(nx)[7] - a1 * np.eye(nx)[8] + n_sp
        y = (-2.0 * a1) * np.eye(nx)[8] + n_sp  # num/den = 1 - 2 a1 s / (s^2 + a1 s + a0)
    else:
        y = n_sp
    A[5] = rate_bandwidth * w_i * (y - np.eye(nx)[4]) - rate_bandwidth * np.eye(nx)[5]
    keep = list(range(nx))
    if not with_load:
        keep = [i for i in keep if i not in (2, 3)]
    if delay <= 0.0:
        keep = [i for i in keep if i not in (7, 8)]
    return float(np.max(np.linalg.eigvals(A[np.ix_(keep, keep)]).real))


def swing_rate_gain(wn: float, reach: float, zeta: float, g: float, ell: float, w_swing: float) -> float:
    """The attitude-level law's commanded tilt rate per rad/s of error in its swing-rate estimate (rad/s per rad/s)
    with surface poles ``wn`` (damping ``zeta``) and reaching pole ``reach`` (1/s), on a line of ``ell`` m whose
    pendulum swings at ``w_swing`` rad/s: ``|(k1 l - k3 g + reach (k2 l - k4 g)) / c + 1|``, ``c = g w_swing^2``
    (``offboard.control.smc_attitude``: the error enters ``e' = l a'``, ``e''' = -g a'`` and the ``- a'`` of the
    commanded tilt rate; inside the boundary layer the reaching terms add to ``-reach sigma``)."""
    k = surface_coefficients(wn, zeta, 5)
    c = g * w_swing * w_swing
    return abs((k[1] * ell - k[3] * g + reach * (k[2] * ell - k[4] * g)) / c + 1.0)


@lru_cache(maxsize=256)
def swing_rate_cap(
    reach_ratio: float, zeta: float, g: float, ell: float, w_swing: float, gain_max: float = SWING_RATE_GAIN_MAX
) -> float:
    """The largest ``wn`` (1/s) whose :func:`swing_rate_gain` with ``reach = reach_ratio wn`` is at most ``gain_max``
    (rad/s per rad/s). Beyond the pendulum's frequency the gain grows as ``(wn / w_swing)^4`` whatever the line
    (``l / c = (M / M_t) / w_swing^2``), so the cap is a multiple of ``w_swing`` (1.0-1.2 for the ArduPilot SITL
    quad); searched down from ``20 w_swing`` in steps, then refined by bisection. Cached: the robust design asks it
    for each of its candidates, which share three reach ratios (uncached, 9 300 gain evaluations put 4 s on every
    flight's start-up)."""

    def gain(wn: float) -> float:
        return swing_rate_gain(wn, reach_ratio * wn, zeta, g, ell, w_swing)

    step = w_swing / 20.0
    hi = 20.0 * w_swing
    while hi > step and gain(hi) > gain_max:
        hi -= step
    lo, hi = hi, hi + step  # gain(lo) <= gain_max < gain(hi), or lo is the smallest step
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if gain(mid) <= gain_max else (lo, mid)
    return lo


@lru_cache(maxsize=64)
def robust_horizontal_poles(
    with_load: bool,
    w_swing: float,
    g: float,
    ell: float,
    mass_ratio: float,
    w_i: float,
    rate_bandwidth: float,
    zeta: float = 1.0,
    wn_cap: float = float("inf"),
    swing_rate_gain_max: float = SWING_RATE_GAIN_MAX,
) -> tuple[float, float, bool]:
    """(wn_F, reach_F, robust): the first candidate whose loop is stable, with a margin of 5 % of wn_F, over every
    attitude-loop and rate-loop bandwidth factor and delay, and True; the slowest candidate and False if none is
    (a load swinging faster than the autopilot's attitude loop can follow: the attitude-level law cannot damp it
    robustly, use the torque-level law). With a load each candidate's wn_F is also capped so that an error in the
    swing-rate estimate reaches the tilt-rate command at most ``swing_rate_gain_max`` times (:func:`swing_rate_cap`:
    on a long line the pendulum, not the attitude loop, bounds the law's bandwidth)."""

    def capped(wr: float, lr: float) -> float:
        wn = min(wr * w_i, wn_cap)
        if with_load:
            wn = min(wn, swing_rate_cap(lr, zeta, g, ell, w_swing, swing_rate_gain_max))
        return wn

    for wr, lr in CANDIDATES:
        wn = capped(wr, lr)
        reach = lr * wn
        worst = max(
            closed_loop_abscissa(
                with_load, w_swing, g, ell, mass_ratio, w_i, f * w_i, b * rate_bandwidth, d, wn, zeta, reach
            )
            for f in BANDWIDTH_FACTORS
            for b in RATE_FACTORS
            for d in DELAYS_S
        )
        if worst < -0.05 * wn:
            return wn, reach, True
    wr, lr = CANDIDATES[-1]
    wn = capped(wr, lr)
    return wn, lr * wn, False


#: default inner-loop bandwidths (1/s): PX4's MC_ROLL_P / MC_PITCH_P and MC_YAW_P (the PX4 SITL build here reads
#: 4.0 and 2.8; PX4's documentation lists 6.5 for older releases), used until the autopilot's own are read
PX4_ATTITUDE_P = 4.0
PX4_YAW_P = 2.8


@dataclass(frozen=True)
class InnerLoop:
    """What the law assumes of the autopilot's own loops (nominal; the real ones may differ, see the tests).

    attitude_bandwidth: roll / pitch attitude-loop bandwidth w_i (1/s), the P gain of PX4 / ArduPilot's attitude
    loop; yaw_bandwidth: heading loop (1/s); rate_bandwidth: roll, pitch, yaw rate-loop bandwidths (1/s), used only
    to report the torque the autopilot is expected to apply.
    """

    attitude_bandwidth: float = PX4_ATTITUDE_P
    yaw_bandwidth: float = PX4_YAW_P
    rate_bandwidth: tuple[float, float, float] = (10.0, 10.0, 1.2)

    def __post_init__(self) -> None:
        vals = (self.attitude_bandwidth, self.yaw_bandwidth, *self.rate_bandwidth)
        if not all(math.isfinite(v) and v > 0.0 for v in vals):
            raise ValueError(f"inner-loop bandwidths must be finite and > 0, got {vals!r}")


@dataclass(frozen=True)
class AttitudeGains:
    """Gains of the attitude-level law, as pole locations (1/s) and switching amplitudes.

    Horizontal: the sliding surface's poles ``(p + wn_F)`` and ``(p^2 + 2 zeta_F wn_F p + wn_F^2)^2`` with a load
    (5 poles), ``(p + wn_F) (p^2 + 2 zeta_F wn_F p + wn_F^2)`` without (3); reach_F: the pole of the reaching phase
    inside the boundary layer; rho_F: switching amplitude in units of the commanded derivative (m/s^5 with a load,
    m/s^3 without). Height: ``p^2 + 2 zeta_z wn_z p + wn_z^2``, reach_z, rho_z (m/s^2). Yaw: k_psi (1/s), reach_psi,
    rho_psi (rad/s). wn_d: double pole (1/s) of the horizontal disturbance observer (no load only; 0 switches it off).
    """

    wn_F: float
    zeta_F: float
    reach_F: float
    rho_F: float
    wn_z: float
    zeta_z: float
    reach_z: float
    rho_z: float
    k_psi: float
    reach_psi: float
    rho_psi: float
    wn_d: float = 0.0

    def __post_init__(self) -> None:
        for k, v in self.__dict__.items():
            if k == "wn_d":  # 0 switches the disturbance observer off
                if not (math.isfinite(v) and v >= 0.0):
                    raise ValueError(f"gain wn_d must be a finite number >= 0, got {v!r}")
            elif not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"gain {k} must be a finite number > 0, got {v!r}")

    def horizontal_coefficients(self, with_load: bool) -> tuple[float, ...]:
        """(k0, k1, ...) of the surface polynomial ``p^r + k_{r-1} p^(r-1) + ... + k0`` (r = 5 or 3)."""
        w, z = self.wn_F, self.zeta_F
        quad = [w * w, 2.0 * z * w, 1.0]  # low -> high
        poly = [w, 1.0]  # (p + w)
        for _ in range(2 if with_load else 1):
            out = [0.0] * (len(poly) + 2)
            for i, a in enumerate(poly):
                for j, b in enumerate(quad):
                    out[i + j] += a * b
            poly = out
        return tuple(poly[:-1])


#: names a vehicle file's [gains] table may set (the AttitudeGains fields)
GAIN_NAMES = tuple(AttitudeGains.__dataclass_fields__)


def _robust_poles(vehicle: Vehicle, inner: InnerLoop, tilt_max: float) -> tuple[float, float, bool]:
    alpha_max = vehicle.roll_pitch_torque_max / max(vehicle.inertia[0], vehicle.inertia[1])
    wn_cap = math.sqrt(0.5 * alpha_max / max(tilt_max, 1e-3))
    return robust_horizontal_poles(
        vehicle.mass_load > 0.0,
        vehicle.pendulum_frequency,
        vehicle.gravity,
        vehicle.cable_length,
        vehicle.mass_load / vehicle.mass_vehicle,
        inner.attitude_bandwidth,
        0.5 * (inner.rate_bandwidth[0] + inner.rate_bandwidth[1]),
        wn_cap=wn_cap,
    )


def robust_gains_exist(vehicle: Vehicle, inner: InnerLoop, tilt_max: float = 0.6) -> bool:
    """Whether :func:`design_gains` finds horizontal gains that stay stable over the whole uncertainty set
    (``offboard.control.smc_attitude_design``); False for a load that swings faster than the attitude loop can follow
    (the paper's vehicle, 6.8 rad/s, behind PX4's MC_ROLL_P = 4): fly it with the torque-level law."""
    return _robust_poles(vehicle, inner, tilt_max)[2]


def design_gains(
    vehicle: Vehicle, inner: InnerLoop, overrides: dict[str, float] | None = None, tilt_max: float = 0.6
) -> AttitudeGains:
    """Gains derived from the vehicle and its autopilot (docs/model.md §12.3); ``overrides`` replace any of them.

    - horizontal poles and reaching pole: the fastest of ``wn_F = (0.5 ... 0.2) w_i`` (``w_i`` the attitude loop's
      bandwidth) and ``reach_F = (2, 1, 0.5) wn_F`` whose linearized loop stays stable with the attitude and rate
      loops off by 2x either way and 0-30 ms of delay (``offboard.control.smc_attitude_design``), ``zeta_F = 1``; capped
      so that the tilt acceleration the law asks for a tilt of ``tilt_max`` at that bandwidth, ``wn_F^2 tilt_max``,
      stays within half the vehicle's angular acceleration authority (torque / inertia);
    - height poles at ``wn_z = min(3, sqrt(a_margin / 1 m))`` with the thrust margin ``a_margin = T_max / M_t - g``
      (a 1 m height error does not saturate the thrust), ``zeta_z = 1``, and at most a fifth of the motors' bandwidth;
    - yaw ``k_psi = 0.4 w_psi``;
    - the disturbance observer off (``wn_d = 0``; set it in the vehicle file's [gains], no load only): on PX4 SITL the
      accelerations it sees are EKF2's own attitude and velocity errors, which it then makes the vehicle chase
      (docs/model.md section 12.2);
    - switching amplitudes sized to the uncertainty the linear part does not see: 0.02 rad/s of tilt rate, 2 % of
      g of vertical acceleration, 0.02 rad/s of yaw rate.
    """
    wn_f, reach_f, _ = _robust_poles(vehicle, inner, tilt_max)
    with_load = vehicle.mass_load > 0.0
    g = vehicle.gravity
    a_margin = vehicle.thrust_max / vehicle.total_mass - g
    wn_z = min(3.0, math.sqrt(a_margin / 1.0))
    if vehicle.motor_time_constant > 0.0:
        wn_z = min(wn_z, 0.2 / vehicle.motor_time_constant)
    c = flat_constants(vehicle).c if with_load else g
    k_psi = 0.4 * inner.yaw_bandwidth
    gains = {
        "wn_F": wn_f,
        "zeta_F": 1.0,
        "reach_F": reach_f,
        "rho_F": 0.02 * c,
        "wn_z": wn_z,
        "zeta_z": 1.0,
        "reach_z": wn_z,
        "rho_z": 0.02 * g,
        "k_psi": k_psi,
        "reach_psi": k_psi,
        "rho_psi": 0.02,
        "wn_d": 0.0,
    }
    for k, v in (overrides or {}).items():
        if k not in gains:
            raise ValueError(f"unknown gain {k!r} (known: {', '.join(GAIN_NAMES)})")
        gains[k] = float(v)
    return AttitudeGains(**gains)


__all__ = [
    "BANDWIDTH_FACTORS",
    "CANDIDATES",
    "DELAYS_S",
    "GAIN_NAMES",
    "PX4_ATTITUDE_P",
    "PX4_YAW_P",
    "RATE_FACTORS",
    "SWING_RATE_GAIN_MAX",
    "AttitudeGains",
    "InnerLoop",
    "closed_loop_abscissa",
    "design_gains",
    "robust_gains_exist",
    "robust_horizontal_poles",
    "surface_coefficients",
    "swing_rate_cap",
    "swing_rate_gain",
]
