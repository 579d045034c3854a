"""Does a load hang under the vehicle, and what are its mass and cable length? Identified from the autopilot's
accelerometer and attitude alone (no cable-angle sensor, no commands).

The physics it rests on (model frame: world NWU z up, body FLU; small swing angles):

* A multirotor without a load feels no horizontal force in its body frame but its rotors' drag: the accelerometer's
  body x / y specific force is ``-k v_body / M`` plus a bias (and vibration). The thrust is along body z.
* A load of mass ``m`` on a cable of length ``L`` pulls the vehicle along the cable with the tension
  ``T ~ m (g + a_z)``; the cable's direction seen in the body frame, ``d_b = R^T (theta_x, theta_y, -1)``, has
  horizontal components ``Rz(psi)^T theta + tilt_b`` (``theta``: the load's horizontal offset from the vehicle over
  ``L``, world frame; ``tilt_b``: the body x / y components of world down). So the body-horizontal specific force
  gains ``mu (g + a_z) d_b,xy`` with the mass ratio ``mu = m / M``.
* The load is a pendulum hung from an accelerating point: ``L theta'' + g theta = -a_xy``, with ``a_xy`` the
  vehicle's horizontal acceleration. That acceleration is measured (the accelerometer rotated to the world, gravity
  removed), so ``theta`` is known from ``L`` up to the free swing ``A cos(w0 t) + B sin(w0 t)``, ``w0 = sqrt(g/L)``.

**The coupled mode is not sqrt(g/L).** The vehicle's acceleration itself contains the cable's pull,
``M a_xy = F_h + m g theta``; with the attitude held (``F_h`` fixed) ``L theta'' = -g (1 + mu) theta``: the mode a
free vehicle shows is ``sqrt(g (1 + mu) / L)`` (:func:`coupled_mode_frequency`, ``Vehicle.pendulum_frequency``);
under a stiff position hold (``a_xy ~ 0``) it is ``sqrt(g / L)``, and a real position loop lies in between. Reading
``L`` off a spectral peak with ``sqrt(g/L)`` would be up to ``1 + mu`` off in ``L``. Here the pendulum is driven by the
*measured* acceleration, so the coupling, whatever the autopilot's loop makes of it, is in the data, and ``L`` is
the length of the pendulum itself.

**The test.** On a uniform grid (the accelerometer low-passed, zero phase, below its Nyquist rate; the pendulum
discretized with a first-order hold: a zero-order hold's half-sample lag at 25 Hz put the length 11 % off on the
plant's own log), per window of about 8 s, the body-horizontal specific force is explained by (H0) a bias per window
and axis and the rotors' drag (where the log has a velocity), or by (H1) those plus the cable's pull ``mu`` times
(forced swing + hanging direction) plus the free swing ``mu A`` per window. ``A`` is marginalized with a Gaussian
prior of :data:`SWING_PRIOR_RAD`, so a free swing only counts with the mass ratio that makes it felt (with free
amplitudes, a bare vehicle's narrow-band motion fits as a "swing" of ``mu ~ 0``); the noise variance is concentrated
out. The marginal likelihood is scanned over cable length x mass ratio x damping grids and refined (Nelder-Mead).
The log-likelihood ratio over H0 is counted with the effective number of independent residuals (their lag-1
correlation) and penalized as BIC for the three extra parameters. A load is attached when H1 wins, ``mu`` is more
than 3 sigma and :data:`MIN_MASS_RATIO` and the free swing it implies is one a hanging load can have (< 1 rad).
Uncertainties (1 sigma): the ranges of ``L`` and ``mu`` over which the profile log-likelihood, with the effective
samples, stays within 1/2 of its maximum (a free swing alone ties ``mu`` to ``L`` along the coupled mode; the
vehicle's own accelerations separate them), the mass's as ``mu``'s times the vehicle's mass (the vehicle file's,
taken as exact).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from scipy import optimize, signal

from estimators.model.frames import STANDARD_GRAVITY

#: cable lengths tried, m (log-spaced); the result is refined between grid points
CABLE_GRID_M = np.geomspace(0.1, 8.0, 48)
#: load-to-vehicle mass ratios tried (log-spaced); the result is refined between grid points
MASS_RATIO_GRID = np.geomspace(0.005, 4.0, 48)
#: pendulum damping ratios tried (aerodynamic drag of the load, a cable's own losses)
DAMPING_GRID = (0.0, 0.05)
#: the prior on a free swing's amplitude (1 sigma, rad): what a hanging load's initial swing may be
SWING_PRIOR_RAD = 0.3
#: the identification's grid rate at most, Hz (the pendulum modes of cables of 0.1 m and up are below 2.5 Hz)
GRID_RATE_HZ = 25.0
#: window over which each free swing's amplitudes are fitted, s
WINDOW_S = 8.0
#: shortest stretch of data used, s
MIN_WINDOW_S = 3.0
#: a free swing larger than this (rad) is not one a hanging load can have
MAX_SWING_RAD = 1.0
#: the mass ratio must exceed this many of its standard deviations for a load to be declared
MU_SIGMA = 3.0
#: ... and this fraction of the vehicle's mass: a lighter load moves neither the law nor the filter measurably
MIN_MASS_RATIO = 0.02


def coupled_mode_frequency(cable_m: float, mass_ratio: float, gravity: float = STANDARD_GRAVITY) -> float:
    """The pendulum mode of a load on a vehicle whose thrust is held (attitude held, no position loop), rad/s:
    ``sqrt(g (1 + m/M) / L)`` (module docstring). A stiff position hold gives ``sqrt(g / L)``."""
    return math.sqrt(gravity * (1.0 + mass_ratio) / cable_m)


@dataclass
class LoadIdentification:
    """The answer: whether a load is attached, and its mass and cable length with 1-sigma uncertainties.

    mass_kg / cable_m: None when no load is attached (or nothing could be identified). ``mass_ratio``: m / M.
    ``log_likelihood_ratio``: of the load model over the bare one, with the effective sample size; ``bic_margin``:
    that ratio minus the BIC penalty of the load model's extra parameters (> 0: the load model wins).
    ``swing_amplitude_rad``: the largest free swing the fit implies. ``reason``: the decision in words."""

    attached: bool
    mass_kg: float | None
    cable_m: float | None
    uncertainty: dict[str, float | None]
    mass_ratio: float | None
    mass_ratio_sigma: float | None
    damping_ratio: float | None
    coupled_mode_rad_s: float | None
    log_likelihood_ratio: float
    bic_margin: float
    explained_fraction: float
    swing_amplitude_rad: float | None
    samples: int
    effective_samples: float
    windows: int
    grid_rate_hz: float
    used_velocity: bool
    reason: str
    notes: list[str] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready (``metrics.json``'s ``load``)."""
        return asdict(self)


@dataclass
class Signals:
    """The inputs on a uniform grid: ``t`` (s), ``f_body`` (n, 3) accelerometer specific force body FLU (m/s^2),
    ``euler`` (n, 3) phi / theta / psi (rad), ``v_world`` (n, 3) velocity world NWU (m/s) or None, ``window``
    (n,) index of the window each sample belongs to."""

    t: np.ndarray
    f_body: np.ndarray
    euler: np.ndarray
    v_world: np.ndarray | None
    window: np.ndarray
    rate_hz: float


def _rotations(euler: np.ndarray) -> np.ndarray:
    """(n, 3, 3) body -> world rotations ``Rz(psi) Ry(theta) Rx(phi)``."""
    sf, cf = np.sin(euler[:, 0]), np.cos(euler[:, 0])
    st, ct = np.sin(euler[:, 1]), np.cos(euler[:, 1])
    sp, cp = np.sin(euler[:, 2]), np.cos(euler[:, 2])
    r = np.empty((len(euler), 3, 3))
    r[:, 0, 0] = cp * ct
    r[:, 0, 1] = cp * st * sf - sp * cf
    r[:, 0, 2] = sf * sp + cf * cp * st
    r[:, 1, 0] = sp * ct
    r[:, 1, 1] = sp * st * sf + cp * cf
    r[:, 1, 2] = cf * sp * st - cp * sf
    r[:, 2, 0] = -st
    r[:, 2, 1] = ct * sf
    r[:, 2, 2] = cf * ct
    return r


def resample(
    stretches: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]],
    rate_hz: float | None = None,
) -> Signals | None:
    """Put contiguous stretches of flight on one uniform grid, cut into windows of about :data:`WINDOW_S`.

    Each stretch: (t_imu, f_body (n, 3), t_att, euler (m, 3), t_vel or None, v_world (k, 3) or None), times in s.
    The accelerometer is low-passed (zero phase) below the grid's Nyquist rate first, so vibration does not alias
    into the pendulum's band. None when no stretch is long enough."""
    ts, fs, es, vs, ws = [], [], [], [], []
    have_vel = all(s[4] is not None and len(s[4]) > 1 for s in stretches) and bool(stretches)
    w_index = 0
    grid_rate = 0.0
    for t_imu, f_body, t_att, euler, t_vel, v_world in stretches:
        if len(t_imu) < 4 or len(t_att) < 4:
            continue
        imu_rate = (len(t_imu) - 1) / (t_imu[-1] - t_imu[0])
        rate = min(GRID_RATE_HZ, imu_rate, rate_hz or math.inf)
        grid_rate = rate if grid_rate == 0.0 else min(grid_rate, rate)
        t0, t1 = max(t_imu[0], t_att[0]), min(t_imu[-1], t_att[-1])
        if have_vel:
            t0, t1 = max(t0, t_vel[0]), min(t1, t_vel[-1])  # type: ignore[index]
        if t1 - t0 < MIN_WINDOW_S:
            continue
        f = np.asarray(f_body, dtype=float)
        if imu_rate > 2.5 * rate and len(f) > 30:
            sos = signal.butter(4, 0.4 * rate, fs=imu_rate, output="sos")
            f = signal.sosfiltfilt(sos, f, axis=0)
        grid = np.arange(t0, t1, 1.0 / rate)
        fb = np.column_stack([np.interp(grid, t_imu, f[:, i]) for i in range(3)])
        eu = np.asarray(euler, dtype=float).copy()
        eu[:, 2] = np.unwrap(eu[:, 2])
        eg = np.column_stack([np.interp(grid, t_att, eu[:, i]) for i in range(3)])
        n_win = max(1, round((t1 - t0) / WINDOW_S))
        win = w_index + np.minimum((np.arange(len(grid)) * n_win) // len(grid), n_win - 1)
        w_index += n_win
        ts.append(grid)
        fs.append(fb)
        es.append(eg)
        ws.append(win)
        if have_vel:
            vv = np.asarray(v_world, dtype=float)
            vs.append(np.column_stack([np.interp(grid, t_vel, vv[:, i]) for i in range(3)]))  # type: ignore[arg-type]
    if not ts:
        return None
    return Signals(
        np.concatenate(ts),
        np.concatenate(fs),
        np.concatenate(es),
        np.concatenate(vs) if have_vel else None,
        np.concatenate(ws),
        grid_rate,
    )


def _pendulum_response(
    a_xy: np.ndarray, window: np.ndarray, cable: float, zeta: float, dt: float, g: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Forced swing ``theta`` (n, 2) of ``L theta'' + 2 zeta w0 L theta' + g theta = -a_xy`` from rest at each
    window's start (zero-order hold of the input), and the free swing's two solutions (n,) in window time."""
    w0 = math.sqrt(g / cable)
    num, den, _ = signal.cont2discrete(([-1.0 / cable], [1.0, 2.0 * zeta * w0, w0 * w0]), dt, method="foh")
    b = np.ravel(num)
    theta = np.empty_like(a_xy)
    c = np.empty(len(window))
    s = np.empty(len(window))
    wd = w0 * math.sqrt(max(1.0 - zeta * zeta, 1e-9))
    for w in np.unique(window):
        idx = np.nonzero(window == w)[0]
        theta[idx] = signal.lfilter(b, den, a_xy[idx], axis=0)
        tau = np.arange(len(idx)) * dt
        decay = np.exp(-zeta * w0 * tau)
        c[idx] = decay * np.cos(wd * tau)
        s[idx] = decay * np.sin(wd * tau)
    return theta, c, s


class _Window:
    """One window's rows of the stacked (body x, then body y) vector, with its nuisance columns (biases, drag; flat
    prior) projected out: ``proj(v)`` is v's part orthogonal to them."""

    def __init__(self, rows: np.ndarray, nuisance: np.ndarray):
        self.rows = rows
        self.q, _ = np.linalg.qr(nuisance)
        self.dof = len(rows) - nuisance.shape[1]

    def proj(self, v: np.ndarray) -> np.ndarray:
        v = v[self.rows]
        return v - self.q @ (self.q.T @ v)


class _Evidence:
    """The marginal likelihood of the load model for one cable length and damping, as a function of the mass ratio.

    Per window: ``y = mu pull + H B + nuisance + e``, e ~ N(0, s2 I), the free swing's amplitudes ``B = mu A`` with
    ``A ~ N(0, A0^2 I)`` (a hanging load's initial swing, :data:`SWING_PRIOR_RAD`): marginalized, so a free swing is
    tied to the mass ratio that makes it felt (a bare vehicle's narrow-band motion cannot pass for a swing of
    ``mu ~ 0``). s2 is concentrated out (a few fixed-point passes)."""

    def __init__(self, y: list[np.ndarray], pull: list[np.ndarray], free: list[np.ndarray], dof: int):
        self.parts = []
        for yw, pw, hw in zip(y, pull, free):
            g, v = np.linalg.eigh(hw.T @ hw)
            a, b = v.T @ (hw.T @ yw), v.T @ (hw.T @ pw)
            self.parts.append((float(yw @ yw), float(yw @ pw), float(pw @ pw), a, b, np.maximum(g, 0.0)))
        self.dof = dof

    def loglik(self, mu: np.ndarray) -> np.ndarray:
        """Concentrated log-likelihood (up to a constant shared with the bare model) for each mass ratio."""
        mu = np.atleast_1d(np.asarray(mu, dtype=float))
        rss = sum(yy - 2 * mu * yp + mu * mu * pp for yy, yp, pp, _, _, _ in self.parts)
        s2 = np.maximum(rss / self.dof, 1e-12)
        for _ in range(6):
            rho = (mu * SWING_PRIOR_RAD) ** 2 / s2
            quad = np.zeros_like(mu)
            logdet = np.zeros_like(mu)
            for yy, yp, pp, a, b, g in self.parts:
                r2 = (a[None, :] - mu[:, None] * b[None, :]) ** 2
                quad += yy - 2 * mu * yp + mu * mu * pp - np.sum(r2 / (g[None, :] + 1.0 / rho[:, None]), axis=1)
                logdet += np.sum(np.log1p(rho[:, None] * g[None, :]), axis=1)
            s2 = np.maximum(quad / self.dof, 1e-12)
        return -0.5 * (self.dof * np.log(s2) + logdet)

    def swing(self, mu: float) -> float:
        """The largest free swing (rad) the posterior gives over the windows at this mass ratio."""
        rss = sum(yy - 2 * mu * yp + mu * mu * pp for yy, yp, pp, _, _, _ in self.parts)
        s2 = max(rss / self.dof, 1e-12)
        rho = (mu * SWING_PRIOR_RAD) ** 2 / s2
        amps = [float(np.linalg.norm((a - mu * b) / (g + 1.0 / rho))) / mu for _, _, _, a, b, g in self.parts]
        return max(amps)


def _effective_fraction(res: list[np.ndarray]) -> float:
    """(1 - rho) / (1 + rho) of the residuals' lag-1 correlation within each window and channel: the fraction of
    the samples that count as independent."""
    num = den = 0.0
    for part in res:
        half = len(part) // 2
        for p in (part[:half], part[half:]):
            if len(p) > 2:
                num += float(p[1:] @ p[:-1])
                den += float(p @ p)
    rho = min(max(num / den if den > 0 else 0.0, 0.0), 0.98)
    return (1.0 - rho) / (1.0 + rho)


def identify_load(sig: Signals, vehicle_mass_kg: float, gravity: float = STANDARD_GRAVITY) -> LoadIdentification:
    """Whether a load hangs under the vehicle, its mass and cable length, from the grid signals (module docstring).
    ``vehicle_mass_kg``: the vehicle's own mass without the load (the vehicle file's), taken as exact."""
    g = gravity
    dt = 1.0 / sig.rate_hz
    n = len(sig.t)
    r = _rotations(sig.euler)
    f_world = np.einsum("nij,nj->ni", r, sig.f_body)
    accel = f_world - np.array([0.0, 0.0, g])  # the vehicle's acceleration, world
    tension = np.maximum(g + accel[:, 2], 0.2 * g)  # the cable's tension per unit load mass
    down_b = -r[:, 2, :]  # world down in the body frame: R^T (0, 0, -1)
    y = np.concatenate([sig.f_body[:, 0], sig.f_body[:, 1]])
    vb = np.einsum("nji,nj->ni", r, sig.v_world) if sig.v_world is not None else None  # R^T v: the rotors' drag
    windows = []
    for w in range(int(sig.window.max()) + 1):
        idx = np.nonzero(sig.window == w)[0]
        rows = np.concatenate([idx, idx + n])
        k = len(idx)
        cols = [np.r_[np.ones(k), np.zeros(k)], np.r_[np.zeros(k), np.ones(k)]]
        if vb is not None:
            cols.append(np.r_[vb[idx, 0], vb[idx, 1]])
        windows.append(_Window(rows, np.column_stack(cols)))
    dof = sum(wd.dof for wd in windows)
    y_w = [wd.proj(y) for wd in windows]
    ll0 = -0.5 * dof * math.log(max(sum(float(v @ v) for v in y_w) / dof, 1e-12))
    # the cable's direction's body-horizontal components per unit swing along world x / y, times the tension
    ex = np.concatenate([tension * r[:, 0, 0], tension * r[:, 0, 1]])
    ey = np.concatenate([tension * r[:, 1, 0], tension * r[:, 1, 1]])
    hang = np.concatenate([tension * down_b[:, 0], tension * down_b[:, 1]])

    def columns(cable: float, zeta: float) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """Per window, the cable's pull per unit mass ratio (forced swing + hanging) and the free swing's four
        columns, nuisance projected out."""
        theta, c, s = _pendulum_response(accel[:, :2], sig.window, cable, zeta, dt, g)
        pull = ex * np.r_[theta[:, 0], theta[:, 0]] + ey * np.r_[theta[:, 1], theta[:, 1]] + hang
        c2, s2 = np.r_[c, c], np.r_[s, s]
        free = [ex * c2, ex * s2, ey * c2, ey * s2]
        return [wd.proj(pull) for wd in windows], [np.column_stack([wd.proj(f) for f in free]) for wd in windows]

    def evidence(cable: float, zeta: float) -> _Evidence:
        return _Evidence(y_w, *columns(cable, zeta), dof)

    table = np.empty((len(DAMPING_GRID), len(CABLE_GRID_M), len(MASS_RATIO_GRID)))
    for iz, zeta in enumerate(DAMPING_GRID):
        for il, cable in enumerate(CABLE_GRID_M):
            table[iz, il] = evidence(float(cable), zeta).loglik(MASS_RATIO_GRID)
    iz, il, im = np.unravel_index(int(np.argmax(table)), table.shape)
    z_best = DAMPING_GRID[iz]

    def neg(p: np.ndarray) -> float:
        return -float(evidence(math.exp(p[0]), z_best).loglik(math.exp(p[1]))[0])

    start = np.array([math.log(CABLE_GRID_M[il]), math.log(MASS_RATIO_GRID[im])])
    opt = optimize.minimize(neg, start, method="Nelder-Mead", options={"xatol": 1e-3, "fatol": 1e-3, "maxiter": 200})
    p_best = opt.x if opt.fun <= neg(start) else start
    l_ref, mu = math.exp(p_best[0]), math.exp(p_best[1])
    ev = evidence(l_ref, z_best)
    ll1 = float(ev.loglik(mu)[0])
    # residuals at the optimum (free swings by least squares: only their lag-1 correlation is wanted), for the
    # effective sample size
    res = []
    for yw, pw, hw in zip(y_w, *columns(l_ref, z_best)):
        e = yw - mu * pw
        res.append(e - hw @ np.linalg.lstsq(hw, e, rcond=None)[0])
    frac = _effective_fraction(res)
    n_eff = max(2 * n * frac, 10.0)
    llr = frac * (ll1 - ll0)
    k_extra = 3  # the mass ratio, the length and the damping (the free swings are marginalized)
    bic_margin = llr - 0.5 * k_extra * math.log(n_eff)
    # 1-sigma intervals: where the profile log-likelihood, counted with the effective samples, falls by 1/2
    prof = frac * (table[iz] - ll1)
    inside = prof >= -0.5
    l_in = CABLE_GRID_M[np.any(inside, axis=1)]
    m_in = MASS_RATIO_GRID[np.any(inside, axis=0)]
    step_l = CABLE_GRID_M[1] / CABLE_GRID_M[0]
    step_m = MASS_RATIO_GRID[1] / MASS_RATIO_GRID[0]
    lo_l = min(float(l_in.min()) if len(l_in) else l_ref, l_ref / math.sqrt(step_l))
    hi_l = max(float(l_in.max()) if len(l_in) else l_ref, l_ref * math.sqrt(step_l))
    lo_m = min(float(m_in.min()) if len(m_in) else mu, mu / math.sqrt(step_m))
    hi_m = max(float(m_in.max()) if len(m_in) else mu, mu * math.sqrt(step_m))
    cable_sigma = 0.5 * (hi_l - lo_l)
    mu_sigma = 0.5 * (hi_m - lo_m)
    swing = ev.swing(mu)
    explained = 1.0 - math.exp(-2.0 * (ll1 - ll0) / dof)
    if bic_margin <= 0:
        attached = False
        reason = f"the bare vehicle's model explains the body-horizontal force as well (BIC margin {bic_margin:.1f})"
    elif not mu > MU_SIGMA * mu_sigma:
        attached = False
        reason = f"no clear pull of a load: mass ratio {mu:.3g} +- {mu_sigma:.2g} (needs > {MU_SIGMA:g} sigma)"
    elif mu < MIN_MASS_RATIO:
        attached = False
        reason = f"no load worth the name: mass ratio {mu:.3g} below {MIN_MASS_RATIO:g}"
    elif swing > MAX_SWING_RAD:
        attached = False
        reason = f"the fit's free swing ({swing:.2g} rad) is not one a hanging load has: the vehicle's own motion"
    else:
        attached = True
        reason = (
            f"the load model wins (log-likelihood ratio {llr:.0f}, BIC margin {bic_margin:.0f}; mass ratio "
            f"{mu:.3g} +- {mu_sigma:.2g})"
        )
    notes = [] if sig.v_world is not None else ["no velocity in the log: the rotors' drag is not modelled"]
    return LoadIdentification(
        attached=attached,
        mass_kg=mu * vehicle_mass_kg if attached else None,
        cable_m=l_ref if attached else None,
        uncertainty={
            "mass_kg": mu_sigma * vehicle_mass_kg if attached else None,
            "cable_m": cable_sigma if attached else None,
        },
        mass_ratio=mu,
        mass_ratio_sigma=mu_sigma,
        damping_ratio=z_best,
        coupled_mode_rad_s=coupled_mode_frequency(l_ref, mu, g),
        log_likelihood_ratio=llr,
        bic_margin=bic_margin,
        explained_fraction=explained,
        swing_amplitude_rad=swing,
        samples=n,
        effective_samples=n_eff,
        windows=len(windows),
        grid_rate_hz=float(sig.rate_hz),
        used_velocity=sig.v_world is not None,
        reason=reason,
        notes=notes,
    )


__all__ = [
    "CABLE_GRID_M",
    "MASS_RATIO_GRID",
    "LoadIdentification",
    "Signals",
    "coupled_mode_frequency",
    "identify_load",
    "resample",
]
