"""The measured-input Kalman filter (``estimators.filters.measured_kf``) over many runs at once, for the batched sweep.

Every quantity of :class:`~estimators.filters.measured_kf.MeasuredKalmanEstimator` is here a numpy array over the runs
(blocks' means, covariances and times, the adapted channel variances, the position-wander densities, the
acceleration input, the gate counters), and each operation of the scalar filter is written once more with the
same expressions in the same order, so that a run's estimate equals the scalar filter's on the same records
(``tests/test_batched_filter.py``: to 1e-9). A gate's branch becomes a mask.

What is not here: the record queues and their timing (which records are fused when, or dropped as late, does
not depend on the state; ``offboard.batched_schedule`` works it out per run beforehand and calls :meth:`fuse`
with the runs that fuse a record of one kind at this point) and the statistics counters. A non-finite estimate
is returned as it is (the scalar filter re-initializes; such a run has diverged). The nominal vehicle must carry
a load (the sweep's does).

Arrays: a block of ``n`` states is ``x`` (n, B), ``p`` (n, n, B), ``t`` (B,); a subset of runs is gathered
(``idx``), computed on as lists of (k,) arrays and scattered back. Units as in ``estimators.filters.measured_kf``.

Over 500 lines because it follows ``estimators.filters.measured_kf`` and ``estimators.filters.small_kf``
operation by operation (the equality to 1e-9 rests on it); split, the two would no longer read side by side.
"""

from __future__ import annotations

import math

import numpy as np

from estimators.filters.fusion import chi2_quantile
from estimators.filters.measured_kf import MeasuredTuning, thrust_window
from estimators.filters.measured_model import channel_floors, for_line
from estimators.filters.small_kf import propagate_cov, propagate_cov3
from estimators.model.flatness import flat_constants
from estimators.model.vehicle import Vehicle

Array = np.ndarray
Lst = list  # a list of (k,) arrays (a vector) or of such lists (a matrix)

#: measurement kinds (the codes ``offboard.batched_schedule`` uses)
POS, ATT, IMU, LOAD = 0, 1, 2, 3
#: an IMU record's gyro, fused with the attitude records (its own event; the record is the IMU's)
GYRO = 12
#: the blocks in the scalar filter's order (``_blocks``): kinematics x, y, z, tilt x, y, heading, swing x, y
BLOCKS = ("kin_x", "kin_y", "kin_z", "tilt_x", "tilt_y", "head", "swing_x", "swing_y")
#: the measurement channels, each with its adapted noise (``MeasuredKalmanEstimator``'s ``_ch``), in this order
CHANNELS = (
    "pos_xy",
    "vel_xy",
    "pos_z",
    "vel_z",
    "tilt",
    "tilt_rate",
    "yaw",
    "yaw_rate",
    "acc",
    "acc_in",
    "load",
    "gyro_rate",
    "gyro_yaw_rate",
)
_DEFAULT_TUNING = MeasuredTuning()
#: the gate streams (the scalar filter's ``gated_<stream>`` counters), in this order
GATE_STREAMS = ("pos", "z", "tilt", "psi", "acc", "acc_in", "load", "gyro")


def wrap_angles(a: Array) -> Array:
    """``estimators.model.frames.wrap_angle`` over arrays (finite inputs)."""
    two_pi = 2.0 * math.pi
    w = np.fmod(a + math.pi, two_pi)
    return np.where(w <= 0.0, w + two_pi, w) - math.pi


class _Block:
    """One block over the runs: x (n arrays of (B,)), p (n x n arrays of (B,), the entry below the diagonal the
    same array as the one above: every update writes both the same), t (B,)."""

    def __init__(self, t: Array, x: list[Array], sd: tuple[float, ...]) -> None:
        n, B = len(x), len(t)
        self.n = n
        self.t = t.copy()
        self.x = [np.array(v, dtype=float) for v in x]
        self.p: Lst = [[None] * n for _ in range(n)]
        for i in range(n):
            for j in range(i, n):
                a = np.full(B, sd[i] ** 2 if i == j else 0.0)
                self.p[i][j] = self.p[j][i] = a

    def get(self, idx: Array) -> tuple[Lst, Lst, Array]:
        n = self.n
        x = [v[idx] for v in self.x]
        p: Lst = [[None] * n for _ in range(n)]
        for i in range(n):
            for j in range(i, n):
                p[i][j] = p[j][i] = self.p[i][j][idx]
        return x, p, self.t[idx]

    def put(self, idx: Array, x: Lst, p: Lst, t: Array | None = None) -> None:
        n = self.n
        for i in range(n):
            self.x[i][idx] = x[i]
            for j in range(i, n):
                self.p[i][j][idx] = p[i][j]
        if t is not None:
            self.t[idx] = t


# ---- small_kf over arrays (same expressions) --------------------------------------------------------------------
def _rate_model(h: Array, q: float) -> tuple[Lst, Lst]:
    h2 = h * h
    one, zero = np.ones_like(h), np.zeros_like(h)
    return [[one, h], [zero, one]], [[q * h2 * h / 3.0, q * h2 / 2.0], [q * h2 / 2.0, q * h]]


def _kinematic_model(h: Array, q_v: Array, q_b: float, q_p: Array) -> tuple[Lst, Lst, Lst]:
    h2 = h * h
    h3 = h2 * h
    h4 = h3 * h
    one, zero = np.ones_like(h), np.zeros_like(h)
    phi = [[one, h, -0.5 * h2], [zero, one, -h], [zero, zero, one]]
    q = [
        [q_p * h + q_v * h3 / 3.0 + q_b * h4 * h / 20.0, q_v * h2 / 2.0 + q_b * h4 / 8.0, -q_b * h3 / 6.0],
        [q_v * h2 / 2.0 + q_b * h4 / 8.0, q_v * h + q_b * h3 / 3.0, -q_b * h2 / 2.0],
        [-q_b * h3 / 6.0, -q_b * h2 / 2.0, q_b * h],
    ]
    return phi, [0.5 * h2, h, zero], q


def _pendulum_model(h: Array, w2: Array, q_a: float, q_e: float) -> tuple[Lst, Lst, Lst]:
    w = np.sqrt(w2)
    wh = w * h
    series = wh < 1e-3
    h2 = h * h
    c, s = np.cos(wh), np.sin(wh)
    ws = np.where(series, 1.0, w)
    w2s = np.where(series, 1.0, w2)
    s2 = np.sin(2.0 * wh) / (4.0 * ws)
    d = 1.0 - 0.5 * w2 * h2
    f00 = np.where(series, d, c)
    f01 = np.where(series, h, s / ws)
    f10 = np.where(series, -w2 * h, -w * s)
    g0 = np.where(series, 0.5 * h2, (1.0 - c) / w2s)
    g1 = np.where(series, h, s / ws)
    qaa = np.where(series, q_a * h2 * h / 3.0, q_a * (0.5 * h - s2) / w2s)
    qad = np.where(series, q_a * h2 / 2.0, q_a * s * s / (2.0 * w2s))
    qdd = np.where(series, q_a * h, q_a * (0.5 * h + s2))
    one, zero = np.ones_like(h), np.zeros_like(h)
    phi = [[f00, f01, zero], [f10, f00, zero], [zero, zero, one]]
    q = [[qaa, qad, zero], [qad, qdd, zero], [zero, zero, q_e * h]]
    return phi, [g0, g1, zero], q


def _predict(x: Lst, p: Lst, phi: Lst, gamma: Lst | None, u: Array, q: Lst) -> None:
    """``small_kf.predict`` in place on lists of arrays (2 states: the generic loop's sums; 3: ``_predict3``)."""
    n = len(x)
    if n == 3:
        (f00, f01, f02), (f10, f11, f12), (f20, f21, f22) = phi
        x0, x1, x2 = x
        y0, y1, y2 = f00 * x0 + f01 * x1 + f02 * x2, f10 * x0 + f11 * x1 + f12 * x2, f20 * x0 + f21 * x1 + f22 * x2
        if gamma is not None:
            nz = u != 0.0
            y0 = np.where(nz, y0 + gamma[0] * u, y0)
            y1 = np.where(nz, y1 + gamma[1] * u, y1)
            y2 = np.where(nz, y2 + gamma[2] * u, y2)
        x[0], x[1], x[2] = y0, y1, y2
        propagate_cov3(p, phi, q)
        return
    rn = range(n)
    xs = [sum(phi[i][j] * x[j] for j in rn) for i in rn]
    if gamma is not None:  # small_kf: an input moves the mean only (the tilt's commanded acceleration)
        nz = u != 0.0
        xs = [np.where(nz, xs[i] + gamma[i] * u, xs[i]) for i in rn]
    x[:] = xs
    propagate_cov(p, phi, q)


def _update_one(x: Lst, p: Lst, i: int, z: Array, r: Array, gate: float) -> Array:
    """``small_kf.update_one`` on lists of arrays; returns the accepted mask (the others unchanged)."""
    s = p[i][i] + r
    y = z - x[i]
    ok = (s > 0.0) & (y * y <= gate * s)
    _correct(x, p, [p[k][i] for k in range(len(x))], y, s, ok)
    return ok


def _update_row(x: Lst, p: Lst, hrow: Lst, z: Array, r: Array, gate: float) -> Array:
    """``small_kf.update_row`` on lists of arrays (``hrow`` entries arrays or floats); the accepted mask."""
    n = len(x)
    rn = range(n)
    ph = [sum(p[k][m] * hrow[m] for m in rn) for k in rn]
    s = sum(hrow[k] * ph[k] for k in rn) + r
    y = z - sum(hrow[k] * x[k] for k in rn)
    ok = (s > 0.0) & (y * y <= gate * s)
    _correct(x, p, ph, y, s, ok)
    return ok


def _correct(x: Lst, p: Lst, ph: Lst, y: Array, s: Array, ok: Array) -> None:
    """The accepted runs' (``ok``) scalar update in place, ``ph`` = ``P h`` (for one state, its column of P), with the
    innovation ``y`` and its variance ``s``: ``small_kf``'s arithmetic; the refused runs unchanged."""
    n = len(x)
    ss = np.where(ok, s, 1.0)
    for k in range(n):
        x[k] = np.where(ok, x[k] + ph[k] * y / ss, x[k])
        pk = ph[k] / ss
        for m in range(k, n):
            v = np.where(ok, p[k][m] - pk * ph[m], p[k][m])
            p[k][m] = v
            p[m][k] = v


class BatchedMeasuredKalman:
    """:class:`~estimators.filters.measured_kf.MeasuredKalmanEstimator` over ``B`` runs (see the module docstring)."""

    def __init__(
        self,
        vehicle: Vehicle,
        B: int,
        *,
        load_sensor: bool,
        tuning: MeasuredTuning = _DEFAULT_TUNING,
        delay_s: float = 0.012,
        rate_hz: float = 1000.0,
    ) -> None:
        if not vehicle.mass_load > 0.0:
            raise ValueError("the batched filter needs a nominal vehicle with a load")
        if not tuning.tilt_command:  # its tilt blocks always take the commanded tilt acceleration as input
            raise ValueError("the batched filter always takes the commanded tilt acceleration (tuning.tilt_command)")
        self.B = B
        self.tuning = tn = for_line(tuning, vehicle.cable_length)
        self.delay = float(delay_s)
        self.k = flat_constants(vehicle)
        self.inertia = vehicle.inertia
        self.mass_vehicle = vehicle.mass_vehicle
        self._n_thrust = thrust_window(tn, rate_hz)
        self.load_sensor = load_sensor
        self._g = vehicle.gravity
        self._l = vehicle.cable_length
        self._m_over_M = vehicle.mass_load / vehicle.mass_vehicle
        self._gate = {d: chi2_quantile(tn.gate_probability, d) for d in (1, 2, 3)}
        self._rate = tn.noise_adapt_rate
        floors = channel_floors(tn)
        self._floor = floors
        self._ceiling = {c: f * tn.noise_ceiling**2 for c, f in floors.items()}

    # ------------------------------------------------------------------------------------------------------
    def initialize(self, t: float, fx: Array, fy: Array, z: Array, z_rate: Array, psi: Array, psi_rate: Array) -> None:
        """``initialize(t, guess)`` with the guess's flat chains ``fx``, ``fy`` (6, B) and scalars (B,)."""
        tn, k, B = self.tuning, self.k, self.B
        T = np.full(B, float(t))

        def planar(F: Array) -> list[Array]:  # estimators.model.flatness.planar_state over runs
            a = -F[2] / k.g
            a_rate = -F[3] / k.g
            return [F[0] + k.l * F[2] / k.g, F[1] + k.l * F[3] / k.g, a, a_rate, F[4] / k.c - a, F[5] / k.c - a_rate]

        px, py = planar(fx), planar(fy)
        zero = np.zeros(B)
        kin_sd = (tn.prior_pos, tn.prior_vel, tn.prior_bias)
        tilt_sd = (tn.prior_tilt, tn.prior_tilt_rate)
        sw_sd = (tn.prior_swing, tn.prior_swing_rate, tn.prior_e)
        self.blocks = [
            _Block(T, [px[0], px[1], zero], kin_sd),
            _Block(T, [py[0], py[1], zero], kin_sd),
            _Block(T, [z, z_rate, zero], kin_sd),
            _Block(T, [px[4], px[5]], tilt_sd),
            _Block(T, [py[4], py[5]], tilt_sd),
            _Block(T, [psi, psi_rate], (tn.prior_psi, tn.prior_psi_rate)),
            _Block(T, [px[2], px[3], zero], sw_sd),
            _Block(T, [py[2], py[3], zero], sw_sd),
        ]
        self.u = np.zeros((3, B))
        self.u_tilt = np.zeros((2, B))  # commanded world tilt acceleration (x, y), rad/s^2
        # the last pushed (delivered) thrusts, N: a ring of the scalar filter's window (zeros: no command yet)
        self.thrusts = np.zeros((self._n_thrust, B))
        self._thrust_pos = -1  # -1: no command pushed yet
        self.q_p = np.full((3, B), tn.q_p_min)
        self.y_mean = np.zeros((3, B))
        self.t_imu = np.full(B, -math.inf)
        self.fz = np.full(B, self._g)
        self.ey2 = {c: np.full(B, f) for c, f in self._floor.items()}
        self.ehph = {c: np.zeros(B) for c in self._floor}
        self.gated_run = {s: np.zeros(B, dtype=int) for s in GATE_STREAMS}

    # ---- channels and gates ---------------------------------------------------------------------------------
    def _value(self, c: str, idx: Array) -> Array:
        v = self.ey2[c][idx] - self.ehph[c][idx]
        return np.where(v > self._ceiling[c], self._ceiling[c], np.where(v > self._floor[c], v, self._floor[c]))

    def _learn(self, c: str, idx: Array, y: Array, hph: Array, r: Array, gate: float) -> None:
        y2 = np.minimum(y * y, gate * (hph + r))
        e = self.ey2[c][idx]
        self.ey2[c][idx] = e + self._rate * (y2 - e)
        h = self.ehph[c][idx]
        self.ehph[c][idx] = h + self._rate * (hph - h)

    def _gated(self, name: str, idx: Array, refused: Array) -> Array:
        """``_gated`` for the refused runs: their counters advance; the mask of those whose gate reopens."""
        run = self.gated_run[name][idx] + 1
        stay = refused & (run <= self.tuning.gate_reopen)
        cur = self.gated_run[name][idx]
        self.gated_run[name][idx] = np.where(stay, run, cur)
        return refused & ~stay

    def _accepted(self, name: str, idx: Array, ok: Array) -> None:
        cur = self.gated_run[name][idx]
        self.gated_run[name][idx] = np.where(ok, 0, cur)

    def _one(self, name: str, x: Lst, p: Lst, idx: Array, i: int, z: Array, chan: str) -> Array:
        r = self._value(chan, idx)
        pii = p[i][i]
        y = z - x[i]
        gate = self._gate[1]
        ok = _update_one(x, p, i, z, r, gate)
        reopen = self._gated(name, idx, ~ok)
        if reopen.any():
            _update_one(x, p, i, z, np.where(reopen, r, -np.inf), math.inf)  # r = -inf: s < 0, refused
        self._learn(chan, idx, y, pii, r, gate)
        self._accepted(name, idx, ok)
        return ok

    def _row(self, name: str, x: Lst, p: Lst, idx: Array, hrow: Lst, z: Array, chan: str, extra_r: Array) -> Array:
        r = self._value(chan, idx) + extra_r
        n = len(hrow)
        ph = sum(hrow[i] * sum(p[i][j] * hrow[j] for j in range(n)) for i in range(n))
        y = z - sum(hrow[i] * x[i] for i in range(n))
        gate = self._gate[1]
        ok = _update_row(x, p, hrow, z, r, gate)
        reopen = self._gated(name, idx, ~ok)
        if reopen.any():
            _update_row(x, p, hrow, z, np.where(reopen, r, -np.inf), math.inf)
        self._learn(chan, idx, y, ph + extra_r, r - extra_r, gate)
        self._accepted(name, idx, ok)
        return ok

    def _learn_wander(self, i: int, idx: Array, y: Array, s: Array) -> None:
        tn = self.tuning
        lam = tn.wander_rate
        ym = self.y_mean[i, idx]
        rs = np.sqrt(s)
        m = ym + lam * (np.maximum(-3.0, np.minimum(3.0, y / rs)) * rs - ym)
        self.y_mean[i, idx] = m
        q = self.q_p[i, idx] * np.where(m * m > 9.0 * s * lam / (2.0 - lam), 1.2, 0.995)
        self.q_p[i, idx] = np.minimum(np.maximum(q, tn.q_p_min), tn.q_p_max)

    def _pair(self, name: str, bi: int, x: Lst, p: Lst, idx: Array, z0: Array, z1: Array, c0: str, c1: str) -> None:
        y0, s0 = z0 - x[0], p[0][0] + self._value(c0, idx)
        self._one(name, x, p, idx, 0, z0, c0)
        if bi < 3:
            self._learn_wander(bi, idx, y0, s0)
        self._one(name, x, p, idx, 1, z1, c1)

    # ---- models -------------------------------------------------------------------------------------------
    def _fresh(self, t: Array, idx: Array) -> Array:
        return t - self.t_imu[idx] <= self.tuning.imu_timeout_s

    def _model(self, bi: int, idx: Array, t: Array, h: Array) -> tuple[Lst, Lst | None, Array, Lst]:
        """(Phi, Gamma, input, Q) of block ``bi`` for runs ``idx`` at block time ``t``, step ``h``."""
        tn = self.tuning
        if bi < 3:
            fresh = self._fresh(t, idx)
            q_v = np.where(fresh, tn.q_v if bi < 2 else tn.q_vz, tn.q_v_no_imu)
            phi, gam, q = _kinematic_model(h, q_v, tn.q_b, self.q_p[bi, idx])
            return phi, gam, np.where(fresh, self.u[bi, idx], 0.0), q
        if bi >= 6:
            i = bi - 6
            fresh = self._fresh(t, idx)
            uz = np.where(fresh, self.u[2, idx], 0.0)
            w2 = np.maximum(self._g + uz, 0.2 * self._g) / self._l
            u = np.where(fresh, self.u[i, idx] - self.blocks[i].x[2][idx], 0.0)
            phi, gam, q = _pendulum_model(h, w2, tn.q_a, tn.q_e)
            return phi, gam, -u / self._l, q
        if bi == 5:
            phi, q = _rate_model(h, tn.q_psi)
            return phi, None, np.zeros_like(h), q
        phi, q = _rate_model(h, tn.q_n)  # a tilt block: the commanded acceleration as its input
        return phi, [0.5 * h * h, h], self.u_tilt[bi - 3, idx], q

    def advance(self, bi: int, idx: Array, t: Array) -> None:
        """``_advance(block, t)`` for runs ``idx`` (a step h <= 0 leaves the block)."""
        b = self.blocks[bi]
        tb = b.t[idx]
        h = t - tb
        go = h > 0.0
        if not go.all():  # only the runs whose block is behind move
            if not go.any():
                return
            idx, t, tb, h = idx[go], t[go], tb[go], h[go]
        x, p, _ = b.get(idx)
        phi, gam, u, q = self._model(bi, idx, tb, h)
        _predict(x, p, phi, gam, u, q)
        b.put(idx, x, p, t)

    # ---- fusion -------------------------------------------------------------------------------------------
    def push_command(self, tau_phi: Array, tau_theta: Array, thrust: Array | None = None) -> None:
        """``push_command`` of every run's (finite) command: the torques over the inertia, rotated to the world with
        the heading estimate, the tilt blocks' input from now on; the thrust (N) into the window of thrusts that
        widens the acceleration input's gate (``thrust_explains_jumps``; a run's non-finite thrust keeps that
        slot's old value, where the scalar filter skips the command: met only by diverged runs)."""
        if thrust is not None and self.tuning.thrust_explains_jumps:
            th = self.thrusts
            if self._thrust_pos < 0:  # the first command: the window starts full of it
                th[:] = thrust
                self._thrust_pos = 0
            else:
                pos = self._thrust_pos
                th[pos] = np.where(np.isfinite(thrust), thrust, th[pos])
                self._thrust_pos = (pos + 1) % self._n_thrust
        i_phi, i_theta, _ = self.inertia
        t1, t2 = tau_theta / i_theta, -tau_phi / i_phi
        psi = self.blocks[5].x[0]
        cp, sp = np.cos(psi), np.sin(psi)
        ok = np.isfinite(tau_phi) & np.isfinite(tau_theta)
        self.u_tilt[0] = np.where(ok, cp * t1 - sp * t2, self.u_tilt[0])
        self.u_tilt[1] = np.where(ok, sp * t1 + cp * t2, self.u_tilt[1])

    def fuse_gyro(self, idx: Array, t: Array, gyro: Array) -> None:
        """``_fuse_gyro``: the IMU's body rates (3, k) as a measurement of the tilt rates and the heading rate."""
        for bi in (3, 4, 5):
            self.advance(bi, idx, t)
        tx, ty, hd = (self.blocks[bi] for bi in (3, 4, 5))
        nx, ny, psi = tx.x[0][idx], ty.x[0][idx], hd.x[0][idx]
        cp, sp = np.cos(psi), np.sin(psi)
        theta, phi = nx * cp + ny * sp, nx * sp - ny * cp
        usable = np.abs(np.cos(theta)) >= 1e-3
        if not usable.all():
            idx, nx, ny, psi, cp, sp, theta, phi = (v[usable] for v in (idx, nx, ny, psi, cp, sp, theta, phi))
            gyro = gyro[:, usable]
        mp, mq, mr = gyro
        sf, cf, ct = np.sin(phi), np.cos(phi), np.cos(theta)  # estimators.model.rotations.euler_rates
        tt = np.tan(theta)
        phi_rate, theta_rate, psi_rate = mp + sf * tt * mq + cf * tt * mr, cf * mq - sf * mr, (sf * mq + cf * mr) / ct
        nxd = theta_rate * cp + phi_rate * sp - psi_rate * (theta * sp - phi * cp)  # world_tilt's rates
        nyd = theta_rate * sp - phi_rate * cp + psi_rate * (theta * cp + phi * sp)
        for bi, zz, chan in ((3, nxd, "gyro_rate"), (4, nyd, "gyro_rate"), (5, psi_rate, "gyro_yaw_rate")):
            x, p, _ = self.blocks[bi].get(idx)
            self._one("gyro", x, p, idx, 1, zz, chan)
            self.blocks[bi].put(idx, x, p)

    def fuse(self, kind: int, idx: Array, t: Array, z: Array) -> None:
        """Fuse one record of ``kind`` sampled at ``t`` (k,) for runs ``idx`` (k,), values ``z`` (n, k): the
        fields of the record after its time, in the order of ``estimators.model.measurements``."""
        if kind == POS:
            for bi in range(3):
                self.advance(bi, idx, t)
            for bi, zp, zv, cp, cv, name in (
                (0, z[0], z[3], "pos_xy", "vel_xy", "pos"),
                (1, z[1], z[4], "pos_xy", "vel_xy", "pos"),
                (2, z[2], z[5], "pos_z", "vel_z", "z"),
            ):
                x, p, _ = self.blocks[bi].get(idx)
                self._pair(name, bi, x, p, idx, zp, zv, cp, cv)
                self.blocks[bi].put(idx, x, p)
        elif kind == ATT:
            self._fuse_att(idx, t, z)
        elif kind == IMU:
            self._fuse_imu(idx, t, z)
        else:
            for bi in (6, 7):
                self.advance(bi, idx, t)
            for bi, zi in ((6, z[1]), (7, z[0])):  # LoadAngle(t, alpha_x, alpha_y): swing x is alpha_y
                x, p, _ = self.blocks[bi].get(idx)
                self._row("load", x, p, idx, [1.0, 0.0, 0.0], zi, "load", 0.0)
                self.blocks[bi].put(idx, x, p)

    def _fuse_att(self, idx: Array, t: Array, z: Array) -> None:
        phi, theta, psi, mp, mq, mr = z
        sf, cf, ct = np.sin(phi), np.cos(phi), np.cos(theta)
        usable = np.abs(ct) >= 1e-3
        if not usable.all():  # the scalar filter skips such a record ("not_used")
            idx, t = idx[usable], t[usable]
            phi, theta, psi, mp, mq, mr, sf, cf, ct = (v[usable] for v in (phi, theta, psi, mp, mq, mr, sf, cf, ct))
        tt = np.tan(theta)
        phi_rate = mp + sf * tt * mq + cf * tt * mr
        theta_rate = cf * mq - sf * mr
        psi_rate = (sf * mq + cf * mr) / ct
        cp, sp = np.cos(psi), np.sin(psi)  # estimators.model.flatness.world_tilt
        nx = theta * cp + phi * sp
        ny = theta * sp - phi * cp
        nxd = theta_rate * cp + phi_rate * sp - psi_rate * ny
        nyd = theta_rate * sp - phi_rate * cp + psi_rate * nx
        for bi in (3, 4, 5):
            self.advance(bi, idx, t)
        for bi, z0, z1 in ((3, nx, nxd), (4, ny, nyd)):
            x, p, _ = self.blocks[bi].get(idx)
            self._pair("tilt", bi, x, p, idx, z0, z1, "tilt", "tilt_rate")
            self.blocks[bi].put(idx, x, p)
        x, p, _ = self.blocks[5].get(idx)
        psi_est = x[0]
        self._pair("psi", 5, x, p, idx, psi_est + wrap_angles(psi - psi_est), psi_rate, "yaw", "yaw_rate")
        self.blocks[5].put(idx, x, p)

    def _fuse_imu(self, idx: Array, t: Array, z: Array) -> None:
        for bi in (0, 1, 2, 6, 7):
            self.advance(bi, idx, t)
        for bi in (3, 4, 5):
            self.advance(bi, idx, t)  # only those behind move (h <= 0 leaves a block)
        tx, ty, hd = (self.blocks[bi] for bi in (3, 4, 5))
        nx, ny, psi = (b.x[0][idx] - b.x[1][idx] * (b.t[idx] - t) for b in (tx, ty, hd))
        cp, sp = np.cos(psi), np.sin(psi)
        theta, phi = nx * cp + ny * sp, nx * sp - ny * cp
        sf, cf, st, ct = np.sin(phi), np.cos(phi), np.sin(theta), np.cos(theta)
        ax, ay, az = z[0], z[1], z[2]
        hx = ct * ax + st * sf * ay + st * cf * az
        hy = cf * ay - sf * az
        hz = -st * ax + ct * sf * ay + ct * cf * az
        a = self.tuning.accel_gain_filter
        g = self._g
        fz = self.fz[idx]
        fz = fz + a * (np.minimum(np.maximum(az, 0.2 * g), 3.0 * g) - fz)
        self.fz[idx] = fz
        gain = self._m_over_M * fz
        bx, by = cp * ax - sp * ay, sp * ax + cp * ay
        for i, (zi, ni, tb) in enumerate(((bx, nx, tx), (by, ny, ty))):
            extra = gain * gain * tb.p[0][0][idx]
            x, p, _ = self.blocks[6 + i].get(idx)
            self._row("acc", x, p, idx, [gain, 0.0, 1.0], zi - gain * ni, "acc", extra)
            self.blocks[6 + i].put(idx, x, p)
        u = [cp * hx - sp * hy, sp * hx + cp * hy, hz - g]
        fresh = self._fresh(t, idx)
        var = self._value("acc_in", idx)
        gate = self._gate[3]
        dy = [u[i] - self.u[i, idx] for i in range(3)]
        th = self.thrusts[:, idx]  # what the pushed thrusts explain (measured_update._fuse_imu)
        jump = (th.max(axis=0) - th.min(axis=0)) / self.mass_vehicle
        plausible = sum(d * d for d in dy) <= gate * var + jump * jump
        # the channel learns only where the input was fresh (the scalar filter's branch)
        for d in dy:
            y2 = np.minimum(d * d, gate * (0.0 + var))
            e = self.ey2["acc_in"][idx]
            self.ey2["acc_in"][idx] = np.where(fresh, e + self._rate * (y2 - e), e)
            h = self.ehph["acc_in"][idx]
            self.ehph["acc_in"][idx] = np.where(fresh, h + self._rate * (0.0 - h), h)
        cur = self.gated_run["acc_in"][idx]
        self.gated_run["acc_in"][idx] = np.where(fresh & plausible, 0, cur)
        refused = fresh & ~plausible
        reopen = self._gated("acc_in", idx, refused)
        take = ~refused | reopen
        for i in range(3):
            self.u[i, idx] = np.where(take, u[i], self.u[i, idx])
        self.t_imu[idx] = np.where(take, t, self.t_imu[idx])

    # ---- output -------------------------------------------------------------------------------------------
    def _mean_at(self, bi: int, t: float) -> list[Array]:
        b = self.blocks[bi]
        h = t - b.t
        x = list(b.x)
        pos = h > 0.0
        hh = np.where(pos, h, 0.0)
        if bi == 5:
            return [np.where(pos, x[0] + hh * x[1], x[0]), x[1]]
        if bi in (3, 4):  # a tilt block: the commanded acceleration held
            u = self.u_tilt[bi - 3]
            return [np.where(pos, x[0] + hh * x[1] + 0.5 * hh * hh * u, x[0]), np.where(pos, x[1] + hh * u, x[1])]
        if bi < 3:
            acc = np.where(self._fresh(b.t, slice(None)), self.u[bi], 0.0) - x[2]
            return [
                np.where(pos, x[0] + hh * x[1] + 0.5 * hh * hh * acc, x[0]),
                np.where(pos, x[1] + hh * acc, x[1]),
                x[2],
            ]
        phi, gam, u, _ = self._model(bi, slice(None), b.t, hh)
        xs = [phi[i][0] * x[0] + phi[i][1] * x[1] + phi[i][2] * x[2] for i in range(3)]
        nz = u != 0.0
        xs = [np.where(nz, xs[i] + gam[i] * u, xs[i]) for i in range(3)]
        return [np.where(pos, xs[i], x[i]) for i in range(3)]

    def estimate_arrays(self, t: float) -> dict[str, Array]:
        """``_control_state(t)`` over the runs: ``fx``, ``fy`` (6, B) and the named scalars of ``ControlState``
        (the records due were fused by the caller)."""
        k = self.k
        px, vx, _ = self._mean_at(0, t)
        py, vy, _ = self._mean_at(1, t)
        z, z_rate, _ = self._mean_at(2, t)
        nx, nxd = self._mean_at(3, t)
        ny, nyd = self._mean_at(4, t)
        psi, psi_rate = self._mean_at(5, t)
        ay_, ayd, e_x = self._mean_at(6, t)
        ax_, axd, e_y = self._mean_at(7, t)
        cp, sp = np.cos(psi), np.sin(psi)
        theta = nx * cp + ny * sp
        phi = nx * sp - ny * cp
        theta_rate = nxd * cp + nyd * sp + psi_rate * (-nx * sp + ny * cp)
        phi_rate = nxd * sp - nyd * cp + psi_rate * (nx * cp + ny * sp)

        def chain(p: Array, v: Array, a: Array, ad: Array, n: Array, nd: Array) -> Array:
            return np.stack([p + k.l * a, v + k.l * ad, -k.g * a, -k.g * ad, k.c * (a + n), k.c * (ad + nd)])

        fx, fy = chain(px, vx, ay_, ayd, nx, nxd), chain(py, vy, ax_, axd, ny, nyd)
        if self.tuning.external_feedforward:  # MeasuredPrediction._control_state's external acceleration in F^(4)
            z_sig = self.tuning.external_significance
            g_l = k.g / k.l
            sx, sy = np.sqrt(self.blocks[6].p[2][2]), np.sqrt(self.blocks[7].p[2][2])
            fx[4] = fx[4] + g_l * np.copysign(np.maximum(np.abs(e_x) - z_sig * sx, 0.0), e_x)
            fy[4] = fy[4] + g_l * np.copysign(np.maximum(np.abs(e_y) - z_sig * sy, 0.0), e_y)
        return {
            "fx": fx,
            "fy": fy,
            "z": z,
            "z_rate": z_rate,
            "phi": phi,
            "theta": theta,
            "psi": wrap_angles(psi),
            "phi_rate": phi_rate,
            "theta_rate": theta_rate,
            "psi_rate": psi_rate,
            "alpha_x": ax_,
            "alpha_y": ay_,
            "alpha_x_rate": axd,
            "alpha_y_rate": ayd,
        }


__all__ = ["ATT", "BLOCKS", "CHANNELS", "GATE_STREAMS", "IMU", "LOAD", "POS", "BatchedMeasuredKalman"]
