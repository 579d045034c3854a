"""The nominal open-loop demands of a reference (``offboard.control.feasibility``): its flat outputs and their
derivatives sampled on a grid fine enough for its fastest motion, mapped through the flatness chain of the
tangent-linearized model to the swing, tilt, tilt rate / acceleration / jerk, thrust and torques the controller
would command if the vehicle flew the reference exactly. World NWU, z up; SI units, radians; times in s.
Formulas: ``offboard.control.feasibility``'s docstring and ``docs/references.md``.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from estimators.model.vehicle import Vehicle

#: Grid: step = GRID_OMEGA_STEP / omega, omega the ratio estimate of :func:`_omega_estimate`. A peak whose local
#: angular frequency (sqrt(|f''| / |f|) at the peak) is w is sampled within a relative error (w h)^2 / 8; the sharpest
#: peak of the 6th derivative of the degree-15 step (the torque) has w about twice the ratio estimate (its extrema are
#: 0.14 T apart near the ends), so the error is at most (2 x 0.05)^2 / 8 = 0.13 %.
GRID_OMEGA_STEP = 0.05


MAX_SAMPLES = 100_000


COARSE_PER_PIECE = 50


COARSE_MIN = 400


# X mixer sign patterns (sim_bridge/inner/airframe.py): roll, pitch, yaw contributions of motors 0..3
_SX = (1.0, -1.0, -1.0, 1.0)


_SY = (-1.0, -1.0, 1.0, 1.0)


_SZ = (1.0, -1.0, 1.0, -1.0)


# ----------------------------------------------------------------------------------------------------------------
# grid
# ----------------------------------------------------------------------------------------------------------------
def sample_grid(reference: Any, ts: np.ndarray) -> np.ndarray:
    """Array (len(ts), 4, 8): channels fx, fy, z, psi, derivative orders 0..7.

    Order 7 is exact when the reference offers ``jets(t, n)`` (``offboard.control.reference.Composite``: truncated
    Taylor coefficients), NaN otherwise (then differenced from order 6 on the grid)."""
    out = np.full((len(ts), 4, 8), np.nan)
    jets = getattr(reference, "jets", None)
    if callable(jets):
        fact = np.array([math.factorial(k) for k in range(8)])
        for i, t in enumerate(ts.tolist()):
            out[i] = np.array([j.c for j in jets(t, 8)]) * fact
        return out
    for i, t in enumerate(ts.tolist()):
        s = reference.sample(t)
        out[i, 0, :7] = s.fx[:7]
        out[i, 1, :7] = s.fy[:7]
        out[i, 2, :7] = s.z[:7]
        out[i, 3, :7] = s.psi[:7]
    return out


def _pieces(reference: Any, duration: float) -> list[float]:
    """Window edges: 0, the reference's breakpoints inside (0, duration) if it has any, duration."""
    bps = getattr(reference, "breakpoints", ())
    inner = sorted({float(b) for b in bps if 0.0 < b < duration and math.isfinite(b)})
    return [0.0, *inner, duration]


def _omega_estimate(jets: np.ndarray) -> float:
    """Largest ratio max|f^(k+1)| / max|f^(k)| over channels and orders k = 1..5 (rad/s): exactly omega for a
    sinusoid of frequency omega, 13-15 / T for the degree-15 step of duration T."""
    peak = np.abs(jets[:, :, :7]).max(axis=0)  # (4, 7)
    best = 0.0
    for ch in range(4):
        scale = peak[ch, 1:].max()
        if scale <= 0.0:
            continue
        for k in range(1, 6):
            if peak[ch, k] > 1e-9 * scale and peak[ch, k + 1] > 0.0:
                best = max(best, peak[ch, k + 1] / peak[ch, k])
    return best


def demand_grid(reference: Any, duration: float) -> np.ndarray:
    """Time grid over [0, duration]: a coarse pass (COARSE_PER_PIECE points per piece between breakpoints) finds
    the fastest local time scale 1/omega of the reference; the step is GRID_OMEGA_STEP / omega, capped at
    MAX_SAMPLES points; the breakpoints are always on the grid."""
    edges = _pieces(reference, duration)
    if duration <= 0.0:
        return np.array([0.0])
    coarse = [np.linspace(a, b, COARSE_PER_PIECE, endpoint=False) for a, b in itertools.pairwise(edges) if b > a]
    coarse.append(np.linspace(0.0, duration, COARSE_MIN))
    ct = np.unique(np.concatenate(coarse))
    omega = _omega_estimate(sample_grid(reference, ct))
    h = duration / COARSE_MIN if omega <= 0.0 else GRID_OMEGA_STEP / omega
    h = max(h, duration / MAX_SAMPLES)
    parts = []
    for a, b in itertools.pairwise(edges):
        if b > a:
            n = max(2, math.ceil((b - a) / h) + 1)
            parts.append(np.linspace(a, b, n))
    return np.unique(np.concatenate(parts))


def profile(ts: np.ndarray, J: np.ndarray, v: Vehicle) -> dict[str, np.ndarray]:
    """Nominal signals on the grid ``ts`` from the sampled jets ``J`` (see :func:`nominal_profile`)."""
    g, l = v.gravity, v.cable_length
    M, m, Mt = v.mass_vehicle, v.mass_load, v.total_mass
    c = Mt * g * g / (M * l)
    I1, I2, I3 = v.inertia
    F = J[:, 0:2, :]  # (N, 2 axes, orders)
    z2 = J[:, 2, 2]
    psi, w, wd = J[:, 3, 0], J[:, 3, 1], J[:, 3, 2]

    a = -F[:, :, 2] / g
    ad = -F[:, :, 3] / g
    add = -F[:, :, 4] / g
    n = F[:, :, 4] / c + F[:, :, 2] / g
    nd = F[:, :, 5] / c + F[:, :, 3] / g
    ndd = F[:, :, 6] / c + F[:, :, 4] / g
    # n''' needs F^(7): exact from the jets, else central differences of F^(6) on the grid (the references are
    # C^7, so it is continuous)
    F7 = F[:, :, 7]
    if not np.all(np.isfinite(F7)):
        F7 = np.gradient(F[:, :, 6], ts, axis=0) if len(ts) > 2 else np.zeros_like(ndd)
    nddd = F7 / c + F[:, :, 5] / g

    swing = np.hypot(a[:, 0], a[:, 1])
    # heading-aligned frame: t = Rz(-psi) n = [theta, -phi]
    cp, sp = np.cos(psi), np.sin(psi)
    t1 = cp * n[:, 0] + sp * n[:, 1]
    t2 = -sp * n[:, 0] + cp * n[:, 1]
    t1d = cp * nd[:, 0] + sp * nd[:, 1] + w * t2
    t2d = -sp * nd[:, 0] + cp * nd[:, 1] - w * t1
    t1dd = cp * ndd[:, 0] + sp * ndd[:, 1] + 2.0 * w * t2d + wd * t2 + w * w * t1
    t2dd = -sp * ndd[:, 0] + cp * ndd[:, 1] - 2.0 * w * t1d - wd * t1 + w * w * t2
    tau_theta = I2 * t1dd
    tau_phi = -I1 * t2dd
    tau_psi = I3 * wd
    tilt_rate = np.maximum(np.abs(t1d), np.abs(t2d))
    tilt_jerk = np.hypot(nddd[:, 0], nddd[:, 1])

    # thrust: centre-of-mass acceleration (vehicle at F + l F''/g, load at F; load height z - l cos|a|)
    second = (a * add).sum(axis=1) + (ad * ad).sum(axis=1)  # d^2/dt^2 of |a|^2 / 2
    acom_h = F[:, :, 2] + (M / Mt) * l * F[:, :, 4] / g
    acom_z = z2 + (m / Mt) * l * second
    # signed: negative when the force would have to point downward (a descent faster than free fall), which a
    # quadrotor cannot produce at any tilt it flies
    thrust = np.copysign(Mt * np.sqrt(acom_h[:, 0] ** 2 + acom_h[:, 1] ** 2 + (g + acom_z) ** 2), g + acom_z)
    # tilt per Euler axis as the controller's chain defines it: theta = t1, phi = -t2
    tilt = np.maximum(np.abs(t1), np.abs(t2))
    linear = np.maximum(swing, np.hypot(t1, t2))
    # cable tension: m |xi_p'' + g e3|, load height acceleration z'' + l (a.a'' + |a'|^2)
    # signed like the thrust: negative when the load would have to be pushed down (a slack cable)
    gz_load = g + z2 + l * second
    tension = np.copysign(m * np.sqrt(F[:, 0, 2] ** 2 + F[:, 1, 2] ** 2 + gz_load**2), gz_load)
    # motor thrusts (X mixer of sim_bridge/inner/airframe.py)
    arm = v.arm_length / math.sqrt(2.0)
    kx, ky, kz = tau_phi / (4.0 * arm), tau_theta / (4.0 * arm), tau_psi / (4.0 * v.yaw_moment_coefficient)
    motors = np.stack([thrust / 4.0 + sx * kx + sy * ky + sz * kz for sx, sy, sz in zip(_SX, _SY, _SZ)], axis=1)

    # the load's height above the take-off point (the reference's heights are above it): z - l cos|a|
    load_height = J[:, 2, 0] - l * np.cos(swing)

    return {
        "t": ts,
        "swing": swing,
        "load_height": load_height,
        "alpha_y": a[:, 0],
        "alpha_x": a[:, 1],
        "theta": t1,
        "phi": -t2,
        "theta_rate": t1d,
        "phi_rate": -t2d,
        "tilt": tilt,
        "linearity": linear,
        "tilt_rate": tilt_rate,
        "tilt_accel": np.hypot(ndd[:, 0], ndd[:, 1]),
        "tilt_jerk": tilt_jerk,
        "thrust": thrust,
        "tau_phi": tau_phi,
        "tau_theta": tau_theta,
        "tau_psi": tau_psi,
        "tension": tension,
        "motor_max": motors.max(axis=1),
        "motor_min": motors.min(axis=1),
    }


def nominal_profile(reference: Any, times: Sequence[float], vehicle: Vehicle) -> dict[str, np.ndarray]:
    """The nominal open-loop signals of ``reference`` at ``times`` (s, increasing) on ``vehicle``, as arrays.

    Keys (SI, model frame): ``t``; ``swing`` (rad, linear ``|F''| / g``), ``alpha_y``, ``alpha_x`` (rad);
    ``theta``, ``phi`` (rad, Euler tilt of the linear chain at the reference heading) and their rates (rad/s);
    ``tilt`` (rad, the larger of ``|phi|``, ``|theta|``); ``linearity`` (rad, the larger of the swing and the tilt
    magnitude); ``tilt_rate`` (rad/s); ``tilt_accel`` (rad/s^2, the magnitude of the world tilt's second derivative,
    ``F^(6)/c + F^(4)/g`` per axis); ``tilt_jerk`` (rad/s^3, the magnitude of the third derivative of the world
    tilt, by differences: needs a fine grid); ``thrust`` (N); ``tau_phi``, ``tau_theta``, ``tau_psi`` (N m, body
    FLU); ``tension`` (N); ``motor_max``, ``motor_min`` (N, X mixer).
    """
    ts = np.asarray(times, dtype=float)
    return profile(ts, sample_grid(reference, ts), vehicle)
