"""Frozen reference: the Kalman filter of ``estimators.filters.kf`` / ``estimators.filters.linear_block`` as first
written (commit 4a43cdc), before its hot paths were optimized; docstrings stripped, code otherwise unchanged.

``tests/test_kf_regression.py`` runs it side by side with the optimized filter on the same measurement stream
and requires the same estimates, covariances, gating decisions and counters. Do not "fix" or speed up this file:
its value is that it is the straightforward original.
"""

# ruff: noqa: B008
from __future__ import annotations

import heapq
import math
from collections.abc import Sequence
from typing import ClassVar, NamedTuple

import numpy as np
from filterpy.common import van_loan_discretization
from scipy.linalg import expm
from scipy.stats import chi2

from estimators.filters.kf import Tuning
from estimators.model.cable import cable_from_planar
from estimators.model.control_state import ControlState
from estimators.model.flatness import flat_chain, flat_constants, planar_state, world_tilt
from estimators.model.frames import wrap_angle
from estimators.model.measurements import Attitude, Imu, LoadAngle, Measurement, PositionVelocity
from estimators.model.vehicle import Vehicle


class Discrete(NamedTuple):
    phi: np.ndarray
    phi_t: np.ndarray
    gamma_t: np.ndarray
    q: np.ndarray


class LinearBlock:
    _CACHE_LIMIT = 4096
    _SHARED: ClassVar[dict[bytes, dict[int, Discrete]]] = {}

    def __init__(self, a: np.ndarray, b: Sequence[float], q_c: Sequence[float], batch: int) -> None:
        self.a = np.asarray(a, dtype=float)
        self.n = self.a.shape[0]
        self.b = np.asarray(b, dtype=float).reshape(self.n, -1)
        self.g = np.diag(np.sqrt(np.asarray(q_c, dtype=float)))
        self.batch = batch
        model = self.a.tobytes() + self.b.tobytes() + self.g.tobytes()
        if len(self._SHARED) > 64:
            self._SHARED.clear()
        self._cache: dict[int, Discrete] = self._SHARED.setdefault(model, {})
        self._n_predict = 0

    def discrete(self, h: float) -> Discrete:
        key = round(h * 10000000.0)
        d = self._cache.get(key)
        if d is None:
            d = self._discretize(key * 1e-07)
            if len(self._cache) >= self._CACHE_LIMIT:
                self._cache.clear()
            self._cache[key] = d
        return d

    def _discretize(self, h: float) -> Discrete:
        n, k = (self.n, self.b.shape[1])
        m = np.zeros((n + k, n + k))
        m[:n, :n] = self.a * h
        m[:n, n:] = self.b * h
        e = expm(m)
        phi = np.ascontiguousarray(e[:n, :n])
        gamma_t = np.ascontiguousarray(e[:n, n:].T)
        if h > 0.0:
            _, q = van_loan_discretization(self.a, self.g, h)
            q = 0.5 * (q + q.T)
        else:
            q = np.zeros((n, n))
        return Discrete(phi, np.ascontiguousarray(phi.T), gamma_t, q)

    def predict_mean(self, x: np.ndarray, h: float, w: np.ndarray) -> np.ndarray:
        d = self.discrete(h)
        return x @ d.phi_t + w @ d.gamma_t

    def predict_cov(self, p: np.ndarray, h: float) -> np.ndarray:
        d = self.discrete(h)
        p = d.phi @ p @ d.phi_t + d.q
        self._n_predict += 1
        if self._n_predict % 16 == 0:
            p = 0.5 * (p + p.T)
        return p

    @staticmethod
    def update_states(
        x: np.ndarray, p: np.ndarray, idx: tuple[int, int], z: tuple[float, ...], r: tuple[float, float], gate: float
    ) -> np.ndarray | None:
        i, j = idx
        ph = p[:, idx]
        s11 = float(ph[i, 0]) + r[0]
        s12 = float(ph[i, 1])
        s22 = float(ph[j, 1]) + r[1]
        det = s11 * s22 - s12 * s12
        if not det > 0.0:
            return None
        s_inv = np.array(((s22 / det, -s12 / det), (-s12 / det, s11 / det)))
        y = np.subtract(z, x[:, idx].ravel()).reshape(-1, 2)
        ys = y @ s_inv
        if not float(np.vdot(ys, y)) <= gate:
            return None
        dx = ys @ ph.T
        x += dx
        p -= ph @ s_inv @ ph.T
        return dx

    @staticmethod
    def update_state(
        x: np.ndarray, p: np.ndarray, i: int, z: tuple[float, ...], r: float, gate: float
    ) -> np.ndarray | None:
        ph = p[:, i].copy()
        s = float(ph[i]) + r
        y = np.subtract(z, x[:, i])
        if not (s > 0.0 and float(y @ y) <= gate * s):
            return None
        k = ph / s
        dx = np.multiply.outer(y, k)
        x += dx
        p -= np.multiply.outer(ph, ph) * (1.0 / s)
        return dx

    @staticmethod
    def update_row(
        x: np.ndarray, p: np.ndarray, h: np.ndarray, z: tuple[float, ...], r: float, gate: float
    ) -> np.ndarray | None:
        ph = p @ h
        s = float(ph @ h) + r
        y = np.subtract(z, x @ h)
        if not float(y @ y) <= gate * s:
            return None
        k = ph / s
        dx = np.multiply.outer(y, k)
        x += dx
        p -= np.multiply.outer(ph, ph) * (1.0 / s)
        return dx


_DEG = math.pi / 180.0
_N_INPUTS = 6
_SLICE = (slice(0, 16), slice(16, 18), slice(18, 22))
_UPDATES = {"state": LinearBlock.update_state, "states": LinearBlock.update_states, "row": LinearBlock.update_row}
STATE_NAMES: tuple[str, ...] = (
    "p_x",
    "v_x",
    "alpha_y",
    "alpha_y_rate",
    "n_x",
    "n_x_rate",
    "d_x",
    "b_x",
    "p_y",
    "v_y",
    "alpha_x",
    "alpha_x_rate",
    "n_y",
    "n_y_rate",
    "d_y",
    "b_y",
    "psi",
    "psi_rate",
    "z",
    "z_rate",
    "d_z",
    "b_z",
)
IP, IV, IA, IAD, IN, IND, ID, IB = range(8)
NEES_DOF = 16


def _planar_accel(ri: float, r3: float, di: float, d3: float, ei: float, e3: float) -> float:
    q = ri * ri + r3 * r3
    num = ri * d3 - r3 * di
    return ((ri * e3 - r3 * ei) * q - num * 2.0 * (ri * di + r3 * d3)) / (q * q)


class ReferenceKalmanEstimator:
    def __init__(
        self, vehicle: Vehicle, *, load_sensor: bool, rate_hz: float, tuning: Tuning = Tuning(), delay_s: float = 0.012
    ) -> None:
        if not (rate_hz > 0.0 and math.isfinite(rate_hz)):
            raise ValueError(f"rate_hz must be > 0, got {rate_hz!r}")
        if not (delay_s >= 0.0 and math.isfinite(delay_s)):
            raise ValueError(f"delay_s must be >= 0, got {delay_s!r}")
        self.vehicle = vehicle
        self.load_sensor = load_sensor
        self.tuning = tn = tuning
        self.delay = float(delay_s)
        self.k = k = flat_constants(vehicle)
        M, m, l, g = (vehicle.mass_vehicle, vehicle.mass_load, vehicle.cable_length, vehicle.gravity)
        Mt = M + m
        self._Mt, self._g, self._m_over_M = (Mt, g, m / M)
        self._M, self._m, self._l = (M, m, l)
        self._w2 = k.omega2
        self._inv_inertia = tuple(1.0 / i for i in vehicle.inertia)
        a = np.zeros((8, 8))
        a[IP, IV] = 1.0
        a[IV, IN] = Mt * g / M
        a[IV, IA] = m * g / M
        a[IV, ID] = 1.0
        a[IA, IAD] = 1.0
        a[IAD, IA] = -k.omega2
        a[IAD, IN] = -k.omega2
        a[IAD, ID] = -1.0 / l
        a[IN, IND] = 1.0
        b = np.zeros((8, 2))
        b[IND, 0] = 1.0
        b[IAD, 1] = 1.0
        self._hb = LinearBlock(a, b, (0.0, tn.q_v, 0.0, tn.q_a, 0.0, tn.q_n, tn.q_d, tn.q_b), batch=2)
        self._yb = LinearBlock(np.array([[0.0, 1.0], [0.0, 0.0]]), (0.0, 1.0), (0.0, tn.q_psi), batch=1)
        az = np.zeros((4, 4))
        az[0, 1] = az[1, 2] = 1.0
        self._zb = LinearBlock(az, (0.0, 1.0, 0.0, 0.0), (0.0, tn.q_vz, tn.q_dz, tn.q_b), batch=1)
        self._blocks = (self._hb, self._yb, self._zb)
        for blk in self._blocks:
            blk.discrete(1.0 / rate_hz)
        self._accz_row = np.array((0.0, 0.0, 1.0, 1.0))
        self._acc_row = np.zeros(8)
        self._acc_row[[ID, IB]] = 1.0
        self._gate = {dof: float(chi2.ppf(tn.gate_probability, dof)) for dof in (1, 2, 4)}
        self._r: dict[str, object] = {
            "pv_xy": (tn.sigma_pos_xy**2, tn.sigma_vel_xy**2),
            "pv_z": (tn.sigma_pos_z**2, tn.sigma_vel_z**2),
            "tilt": (tn.sigma_tilt**2, tn.sigma_rate**2),
            "yaw": (tn.sigma_yaw**2, tn.sigma_rate**2),
            "acc": tn.sigma_acc**2,
            "load": tn.sigma_load**2,
        }
        self._stats = {
            "accepted": 0,
            "late_dropped": 0,
            "out_of_order": 0,
            "gated_outliers": 0,
            "nan_rejected": 0,
            "gate_reopened": 0,
            "commands_rejected": 0,
            "not_used": 0,
            "nonfinite_resets": 0,
            "gated_pos": 0,
            "gated_z": 0,
            "gated_tilt": 0,
            "gated_psi": 0,
            "gated_acc": 0,
            "gated_acc_z": 0,
            "gated_load": 0,
        }
        self._out_cache: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._initialized = False

    def initialize(self, t: float, guess: ControlState) -> None:
        if not (math.isfinite(t) and guess.is_finite()):
            raise ValueError("initialize needs a finite time and a finite ControlState")
        tn = self.tuning
        k = self.k
        hx = np.zeros((2, 8))
        for i, chain in enumerate((guess.fx, guess.fy)):
            hx[i, :6] = planar_state(k, chain)
        sd = (
            tn.prior_pos,
            tn.prior_vel,
            tn.prior_swing,
            tn.prior_swing_rate,
            tn.prior_tilt,
            tn.prior_tilt_rate,
            tn.prior_d,
            tn.prior_bias,
        )
        hp = np.diag(np.square(sd))
        yx = np.array([[guess.psi, guess.psi_rate]])
        yp = np.diag([tn.prior_psi**2, tn.prior_psi_rate**2])
        zx = np.array([[guess.z, guess.z_rate, 0.0, 0.0]])
        zp = np.diag([tn.prior_z**2, tn.prior_z_rate**2, tn.prior_dz**2, tn.prior_bias**2])
        self._core = [[float(t), hx, hp], [float(t), yx, yp], [float(t), zx, zp]]
        self._out = np.concatenate((hx.ravel(), yx.ravel(), zx.ravel()))
        self._t_out = float(t)
        self._pending: list[tuple[float, int, Measurement]] = []
        self._seq = 0
        self._latest_t = -math.inf
        self._cmds: list[tuple[float, tuple[np.ndarray, ...]]] = [(float(t), self._command_views(np.zeros(_N_INPUTS)))]
        self._gated_run = {"pos": 0, "z": 0, "tilt": 0, "psi": 0, "acc": 0, "acc_z": 0, "load": 0}
        self._fz = self._g
        self._last_good = guess
        self._initialized = True

    def push(self, m: Measurement) -> None:
        st = self._stats
        try:
            finite = all(math.isfinite(v) for v in m)
        except TypeError:
            finite = False
        if not finite:
            st["nan_rejected"] += 1
            return
        if not self._initialized:
            raise RuntimeError("initialize() the estimator before pushing measurements")
        if isinstance(m, LoadAngle) and (not self.load_sensor):
            st["not_used"] += 1
            return
        if m.t < self._min_core_time():
            st["late_dropped"] += 1
            return
        if m.t < self._latest_t:
            st["out_of_order"] += 1
        else:
            self._latest_t = m.t
        heapq.heappush(self._pending, (m.t, self._seq, m))
        self._seq += 1

    def push_command(self, t: float, thrust: float, torque: tuple[float, float, float]) -> None:
        if not (math.isfinite(t) and math.isfinite(thrust) and all(math.isfinite(v) for v in torque)):
            self._stats["commands_rejected"] += 1
            return
        t = max(float(t), self._t_out)
        o = self._out.tolist()
        psi = o[16]
        cp, sp = (math.cos(psi), math.sin(psi))
        ip, it, iy = self._inv_inertia
        ttheta, tphi = (torque[1] * it, -torque[0] * ip)
        nx, ny = (o[IN], o[8 + IN])
        theta, phi = (nx * cp + ny * sp, nx * sp - ny * cp)
        sf, cf, st, ct = (math.sin(phi), math.cos(phi), math.sin(theta), math.cos(theta))
        n1, n2, n3 = (sf * sp + cf * cp * st, cf * sp * st - cp * sf, cf * ct)
        ay, ax = (o[IA], o[8 + IA])
        (r1, r2, r3), (d1, d2, d3) = cable_from_planar(ay, ax, o[IAD], o[8 + IAD])
        M, m, l, g = (self._M, self._m, self._l, self._g)
        rd2 = d1 * d1 + d2 * d2 + d3 * d3
        nr = n1 * r1 + n2 * r2 + n3 * r3
        tension = m * (M * l * rd2 - thrust * nr) / self._Mt
        ku = thrust / (M * l)
        e1 = -ku * (n1 - nr * r1) - rd2 * r1
        e2 = -ku * (n2 - nr * r2) - rd2 * r2
        e3 = -ku * (n3 - nr * r3) - rd2 * r3
        w = np.array(
            (
                cp * ttheta - sp * tphi,
                _planar_accel(r1, r3, d1, d3, e1, e3) + self._w2 * (ay + nx),
                sp * ttheta + cp * tphi,
                _planar_accel(r2, r3, d2, d3, e2, e3) + self._w2 * (ax + ny),
                torque[2] * iy,
                (thrust * n3 + tension * r3) / M - g,
            )
        )
        if not all(math.isfinite(v) for v in w.tolist()):
            self._stats["commands_rejected"] += 1
            return
        w = self._command_views(w)
        cmds = self._cmds
        if cmds[-1][0] >= t:
            cmds[-1] = (cmds[-1][0], w)
        else:
            cmds.append((t, w))

    def estimate(self, t: float) -> ControlState:
        if not self._initialized:
            raise RuntimeError("initialize() the estimator before asking for an estimate")
        if t > self._t_out:
            self._advance_output(t)
        horizon = min(t - self.delay, self._t_out)
        pending = self._pending
        while pending and pending[0][0] <= horizon:
            _, _, m = heapq.heappop(pending)
            self._fuse(m)
        for bi in range(3):
            if horizon - self._core[bi][0] > 0.05:
                self._advance_core(bi, horizon)
        est = self._control_state()
        if not est.is_finite():
            self._stats["nonfinite_resets"] += 1
            last = self._last_good
            self.initialize(self._t_out, last)
            return last
        self._last_good = est
        return est

    def covariance(self) -> np.ndarray:
        out = np.zeros((22, 22))
        ps = self._output_covariances()
        out[0:8, 0:8] = ps[0]
        out[8:16, 8:16] = ps[0]
        out[16:18, 16:18] = ps[1]
        out[18:22, 18:22] = ps[2]
        return out

    def nees(self, t: float, truth: ControlState) -> float:
        if t > self._t_out:
            self.estimate(t)
        ps = self._output_covariances()
        out = self._out.tolist()
        e = np.array(
            (
                *(a - b for a, b in zip(out[0:6], planar_state(self.k, truth.fx))),
                *(a - b for a, b in zip(out[8:14], planar_state(self.k, truth.fy))),
            )
        ).reshape(2, 6)
        hp = ps[0][:6, :6]
        total = float(np.sum(e * np.linalg.solve(hp, e.T).T))
        e = np.array((wrap_angle(out[16] - truth.psi), out[17] - truth.psi_rate))
        total += float(e @ np.linalg.solve(ps[1], e))
        e = np.array((out[18] - truth.z, out[19] - truth.z_rate))
        total += float(e @ np.linalg.solve(ps[2][:2, :2], e))
        return total

    def stats(self) -> dict[str, int]:
        out = dict(self._stats)
        out["buffered"] = len(self._pending) if self._initialized else 0
        return out

    def _min_core_time(self) -> float:
        c = self._core
        return max(c[0][0], c[1][0], c[2][0])

    def _advance_core(self, bi: int, t: float) -> None:
        core = self._core[bi]
        t0 = core[0]
        if t <= t0:
            return
        blk = self._blocks[bi]
        core[2] = blk.predict_cov(core[2], t - t0)
        x = core[1]
        cmds = self._cmds
        j = 0
        while j + 1 < len(cmds) and cmds[j + 1][0] <= t0:
            j += 1
        tc = t0
        while True:
            end = cmds[j + 1][0] if j + 1 < len(cmds) and cmds[j + 1][0] < t else t
            if end > tc:
                x = blk.predict_mean(x, end - tc, cmds[j][1][1 + bi])
                tc = end
            if end >= t:
                break
            j += 1
        core[1] = x
        core[0] = t
        tmin = min(c[0] for c in self._core)
        k = 0
        while k + 1 < len(cmds) and cmds[k + 1][0] <= tmin:
            k += 1
        if k:
            del cmds[:k]

    @staticmethod
    def _command_views(w: np.ndarray) -> tuple[np.ndarray, ...]:
        return (w, w[0:4].reshape(2, 2), w[4:5].reshape(1, 1), w[5:6].reshape(1, 1))

    def _active_command(self, t: float) -> np.ndarray:
        cmds = self._cmds
        j = len(cmds) - 1
        while j > 0 and cmds[j][0] > t:
            j -= 1
        return cmds[j][1][0]

    def _advance_output(self, t: float) -> None:
        cmds = self._cmds
        t0 = self._t_out
        j = len(cmds) - 1
        while j > 0 and cmds[j][0] > t0:
            j -= 1
        tc = t0
        out = self._out
        while True:
            end = cmds[j + 1][0] if j + 1 < len(cmds) and cmds[j + 1][0] < t else t
            if end > tc:
                phi_t, gamma_t = self._output_model(end - tc)
                out = out @ phi_t + cmds[j][1][0] @ gamma_t
                tc = end
            if end >= t:
                break
            j += 1
        self._out = out
        self._t_out = t

    def _output_model(self, h: float) -> tuple[np.ndarray, np.ndarray]:
        key = round(h * 10000000.0)
        mdl = self._out_cache.get(key)
        if mdl is None:
            phi_t = np.zeros((22, 22))
            gamma_t = np.zeros((_N_INPUTS, 22))
            dh, dy, dz = (blk.discrete(h) for blk in self._blocks)
            phi_t[0:8, 0:8] = dh.phi_t
            phi_t[8:16, 8:16] = dh.phi_t
            phi_t[16:18, 16:18] = dy.phi_t
            phi_t[18:22, 18:22] = dz.phi_t
            gamma_t[0:2, 0:8] = dh.gamma_t
            gamma_t[2:4, 8:16] = dh.gamma_t
            gamma_t[4, 16:18] = dy.gamma_t[0]
            gamma_t[5, 18:22] = dz.gamma_t[0]
            if len(self._out_cache) >= 4096:
                self._out_cache.clear()
            mdl = self._out_cache[key] = (phi_t, gamma_t)
        return mdl

    def _correct_output(self, bi: int, dx: np.ndarray) -> None:
        h = self._t_out - self._core[bi][0]
        if h > 0.0:
            dx = dx @ self._blocks[bi].discrete(h).phi_t
        self._out[_SLICE[bi]] += dx.ravel()

    def _output_covariances(self) -> list[np.ndarray]:
        res = []
        for bi, blk in enumerate(self._blocks):
            t0, _, p = self._core[bi]
            h = self._t_out - t0
            res.append(blk.predict_cov(p, h) if h > 0.0 else p)
        return res

    def _update(self, bi: int, name: str, kind: str, arg: object, z: tuple[float, ...], r: object, dof: int) -> bool:
        core = self._core[bi]
        fn = _UPDATES[kind]
        dx = fn(core[1], core[2], arg, z, r, self._gate[dof])
        if dx is None:
            self._stats["gated_" + name] += 1
            run = self._gated_run[name] + 1
            if run <= self.tuning.gate_reopen:
                self._gated_run[name] = run
                return False
            self._stats["gate_reopened"] += 1
            dx = fn(core[1], core[2], arg, z, r, math.inf)
            if dx is None:
                return False
        self._gated_run[name] = 0
        self._correct_output(bi, dx)
        return True

    def _fuse(self, m: Measurement) -> None:
        t = m.t
        r = self._r
        ok = True
        if isinstance(m, PositionVelocity):
            self._advance_core(0, t)
            self._advance_core(2, t)
            ok &= self._update(0, "pos", "states", (IP, IV), (m.x, m.vx, m.y, m.vy), r["pv_xy"], 4)
            ok &= self._update(2, "z", "states", (0, 1), (m.z, m.vz), r["pv_z"], 2)
        elif isinstance(m, Attitude):
            self._advance_core(0, t)
            self._advance_core(1, t)
            phi, theta, psi = (m.phi, m.theta, m.psi)
            sf, cf = (math.sin(phi), math.cos(phi))
            ct = math.cos(theta)
            if abs(ct) < 0.001:
                self._stats["not_used"] += 1
                return
            tt = math.tan(theta)
            phi_rate = m.p + sf * tt * m.q + cf * tt * m.r
            theta_rate = cf * m.q - sf * m.r
            psi_rate = (sf * m.q + cf * m.r) / ct
            nx, ny, nxd, nyd = world_tilt(phi, theta, psi, phi_rate, theta_rate, psi_rate)
            psi_est = float(self._core[1][1][0, 0])
            ok &= self._update(0, "tilt", "states", (IN, IND), (nx, nxd, ny, nyd), r["tilt"], 4)
            ok &= self._update(1, "psi", "states", (0, 1), (psi_est + wrap_angle(psi - psi_est), psi_rate), r["yaw"], 2)
        elif isinstance(m, Imu):
            self._advance_core(0, t)
            a = self.tuning.accel_gain_filter
            fz = min(max(m.az, 0.2 * self._g), 3.0 * self._g)
            self._fz += a * (fz - self._fz)
            gain = self._m_over_M * self._fz
            psi = float(self._core[1][1][0, 0])
            cp, sp = (math.cos(psi), math.sin(psi))
            row = self._acc_row
            row[IA] = gain
            row[IN] = gain
            z = (cp * m.ax - sp * m.ay, sp * m.ax + cp * m.ay)
            ok &= self._update(0, "acc", "row", row, z, r["acc"], 2)
            self._advance_core(2, t)
            hx = self._core[0][1]
            nx, ny = (float(hx[0, IN]), float(hx[1, IN]))
            theta, phi = (nx * cp + ny * sp, nx * sp - ny * cp)
            ct = math.cos(theta)
            fz_world = -math.sin(theta) * m.ax + ct * math.sin(phi) * m.ay + ct * math.cos(phi) * m.az
            w_z = float(self._active_command(self._core[2][0])[5])
            ok &= self._update(2, "acc_z", "row", self._accz_row, (fz_world - self._g - w_z,), r["acc"], 1)
        elif isinstance(m, LoadAngle):
            self._advance_core(0, t)
            ok &= self._update(0, "load", "state", IA, (m.alpha_y, m.alpha_x), r["load"], 2)
        else:
            self._stats["not_used"] += 1
            return
        self._stats["accepted"] += 1
        if not ok:
            self._stats["gated_outliers"] += 1

    def _control_state(self) -> ControlState:
        k = self.k
        out = self._out.tolist()
        ax_, ay_ = (out[0:8], out[8:16])
        psi, psi_rate = (out[16], out[17])
        z, z_rate = (out[18], out[19])
        cp, sp = (math.cos(psi), math.sin(psi))
        nx, nxd, ny, nyd = (ax_[IN], ax_[IND], ay_[IN], ay_[IND])
        theta = nx * cp + ny * sp
        phi = nx * sp - ny * cp
        theta_rate = nxd * cp + nyd * sp + psi_rate * (-nx * sp + ny * cp)
        phi_rate = nxd * sp - nyd * cp + psi_rate * (nx * cp + ny * sp)
        return ControlState(
            flat_chain(k, ax_[IP], ax_[IV], ax_[IA], ax_[IAD], nx, nxd),
            flat_chain(k, ay_[IP], ay_[IV], ay_[IA], ay_[IAD], ny, nyd),
            z,
            z_rate,
            phi,
            theta,
            wrap_angle(psi),
            phi_rate,
            theta_rate,
            psi_rate,
            ay_[IA],
            ax_[IA],
            ay_[IAD],
            ax_[IAD],
        )
