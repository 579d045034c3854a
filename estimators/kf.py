"""The Kalman filter that turns autopilot telemetry into the controller's :class:`ControlState`.

Design (``docs/estimation.md`` gives the derivation, the observability argument and the tuning):

- **Horizontal block** (one model, both world axes side by side): per axis the 8 states
  ``[p, v, a, a', n, n', d, b]``: vehicle position and velocity, the planar swing angle ``a`` (``alpha_y`` for
  x, ``alpha_x`` for y), the world thrust tilt ``n`` (``estimators.flatness.world_tilt``) and its rate, an
  unknown acceleration ``d`` on the vehicle (random walk: external forces, thrust mismatch) and the
  accelerometer bias ``b`` (random walk, world axes). The model is the tangent linearization at hover
  (errata section 2) driven by the commanded torque::

      v'  = (M_t g / M) n + (m g / M) a + d
      a'' = -w^2 (a + n) - d / l
      n'' = Rz(psi) [tau_theta / I_theta, -tau_phi / I_phi]

  so ``[p, v, a, a', n, n']`` maps one-to-one and linearly onto the flat-output chain (F, ..., F^(5)).
- **Heading block** ``[psi, psi']`` driven by ``tau_psi / I_psi``; **height block** ``[z, z', d_z]`` driven by
  ``u cos(phi) cos(theta) / M_t - g``.
- Measurements: position/velocity (p, v, z, z'), attitude (tilt n and its rate from the Euler angles and the
  body rates converted to Euler rates, heading and its rate), accelerometer (horizontal specific force in
  the heading frame ``= (T / M)(a + n) + d + b``, with ``T / M = (m / M) f_z`` from its own vertical
  specific force: the cable pulls the vehicle along the cable, which is what makes the swing observable
  without a cable sensor), and the optional cable-angle sensor (a).
- **Time**: the filter proper runs on a delayed horizon ``t - delay``: measurements are buffered and fused
  in timestamp order (each block predicted exactly to the measurement's sampling time), so any measurement
  whose latency is below ``delay`` is used, whatever order it arrives in; older ones are dropped and
  counted. The output is the delayed state predicted to ``t`` with the commands (an output predictor, as
  in PX4's EKF2); being linear, each correction of the delayed state is carried to the output by
  ``Phi(t_out - t_m)``, so a tick costs one prediction step per block.
- Robustness: non-finite records are rejected and counted; innovations are chi-square gated (all channels
  of one update together) and the gate reopens after ``gate_reopen`` consecutive rejections of one stream so
  that a filter that has drifted away (e.g. after a long sensor silence) recovers.

Filter state ordering (:meth:`KalmanEstimator.covariance`, 21 x 21, block diagonal)::

    0-7   x axis: p_x, v_x, alpha_y, alpha_y', n_x, n_x', d_x, b_x
    8-15  y axis: p_y, v_y, alpha_x, alpha_x', n_y, n_y', d_y, b_y
    16-17 psi, psi'
    18-20 z, z', d_z
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from estimators.control_state import ControlState
from estimators.flatness import flat_chain, flat_constants, planar_state, world_tilt
from estimators.frames import wrap_angle
from estimators.linear_block import LinearBlock
from estimators.measurements import Attitude, Imu, LoadAngle, Measurement, PositionVelocity
from estimators.vehicle import Vehicle

_DEG = math.pi / 180.0

STATE_NAMES: tuple[str, ...] = (
    "p_x", "v_x", "alpha_y", "alpha_y_rate", "n_x", "n_x_rate", "d_x", "b_x",
    "p_y", "v_y", "alpha_x", "alpha_x_rate", "n_y", "n_y_rate", "d_y", "b_y",
    "psi", "psi_rate",
    "z", "z_rate", "d_z",
)
#: indices in one horizontal axis
IP, IV, IA, IAD, IN, IND, ID, IB = range(8)
#: dimension of the NEES (p, v, a, a', n, n' per axis; psi, psi'; z, z')
NEES_DOF = 16


@dataclass(frozen=True)
class Tuning:
    """Noise assumptions of the filter (SI, rad). Measurement standard deviations are those of the
    ``px4-typical`` sensor preset; process noises are continuous spectral densities (units^2 / Hz of the
    driven state's derivative); prior standard deviations are used by :meth:`KalmanEstimator.initialize`.
    """

    sigma_pos_xy: float = 0.02
    sigma_pos_z: float = 0.03
    sigma_vel_xy: float = 0.03
    sigma_vel_z: float = 0.03
    sigma_tilt: float = 0.3 * _DEG
    sigma_yaw: float = 0.6 * _DEG
    sigma_rate: float = 0.01
    sigma_acc: float = 0.2
    sigma_load: float = 0.5 * _DEG
    q_v: float = 0.05  # (m/s^2)^2/Hz, white acceleration on v'
    q_a: float = 0.5  # (rad/s^2)^2/Hz, white angular acceleration of the swing
    q_n: float = 0.5  # (rad/s^2)^2/Hz, tilt acceleration not explained by the torque command
    q_d: float = 4.0  # (m/s^3)^2/Hz, random walk of the unknown acceleration d
    q_b: float = 1e-5  # (m/s^3)^2/Hz, random walk of the accelerometer bias
    q_psi: float = 0.05  # (rad/s^2)^2/Hz
    q_vz: float = 0.05  # (m/s^2)^2/Hz
    q_dz: float = 1.0  # (m/s^3)^2/Hz
    prior_pos: float = 0.05
    prior_vel: float = 0.1
    prior_swing: float = 0.15
    prior_swing_rate: float = 0.5
    prior_tilt: float = 0.02
    prior_tilt_rate: float = 0.05
    prior_d: float = 0.3
    prior_bias: float = 0.1
    prior_psi: float = 0.02
    prior_psi_rate: float = 0.05
    prior_z: float = 0.05
    prior_z_rate: float = 0.1
    prior_dz: float = 0.3
    gate_probability: float = 0.9999
    gate_reopen: int = 10
    accel_gain_filter: float = 0.1  # weight of a new sample in the low-pass of the vertical specific force


class KalmanEstimator:
    """Kalman filter on the measurement records of ``estimators.measurements`` (see the module docstring).

    vehicle: the controller's nominal vehicle; load_sensor: whether a cable-angle sensor is fitted (without
    it the swing comes from the accelerometer); rate_hz: the control rate (pre-computes its step);
    delay_s: the fusion horizon behind the output (must exceed the sensors' latency).
    """

    def __init__(
        self,
        vehicle: Vehicle,
        *,
        load_sensor: bool,
        rate_hz: float,
        tuning: Tuning = Tuning(),
        delay_s: float = 0.012,
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
        M, m, l, g = vehicle.mass_vehicle, vehicle.mass_load, vehicle.cable_length, vehicle.gravity
        Mt = M + m
        self._Mt, self._g, self._m_over_M = Mt, g, m / M
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
        b = np.zeros(8)
        b[IND] = 1.0
        self._hb = LinearBlock(a, b, (0.0, tn.q_v, 0.0, tn.q_a, 0.0, tn.q_n, tn.q_d, tn.q_b), batch=2)
        self._yb = LinearBlock(np.array([[0.0, 1.0], [0.0, 0.0]]), (0.0, 1.0), (0.0, tn.q_psi), batch=1)
        self._zb = LinearBlock(
            np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]]), (0.0, 1.0, 0.0), (0.0, tn.q_vz, tn.q_dz),
            batch=1,
        )
        self._blocks = (self._hb, self._yb, self._zb)
        for blk in self._blocks:  # warm the cache with the control step
            blk.discrete(1.0 / rate_hz)
        self._acc_row = np.zeros(8)
        self._acc_row[[ID, IB]] = 1.0
        self._gate1 = float(chi2.ppf(tn.gate_probability, 1))
        self._gate2 = float(chi2.ppf(tn.gate_probability, 2))
        self._r = {
            "pos_xy": tn.sigma_pos_xy**2, "pos_z": tn.sigma_pos_z**2, "vel_xy": tn.sigma_vel_xy**2,
            "vel_z": tn.sigma_vel_z**2, "tilt": tn.sigma_tilt**2, "yaw": tn.sigma_yaw**2,
            "rate": tn.sigma_rate**2, "acc": tn.sigma_acc**2, "load": tn.sigma_load**2,
        }
        self._stats = {
            "accepted": 0, "late_dropped": 0, "out_of_order": 0, "gated_outliers": 0, "nan_rejected": 0,
            "gate_reopened": 0, "commands_rejected": 0, "not_used": 0, "nonfinite_resets": 0,
        }
        self._initialized = False

    # --------------------------------------------------------------------------------------------------------
    def initialize(self, t: float, guess: ControlState) -> None:
        """Start at time ``t`` (s) from the prior mean ``guess`` with the tuning's prior covariance."""
        if not (math.isfinite(t) and guess.is_finite()):
            raise ValueError("initialize needs a finite time and a finite ControlState")
        tn = self.tuning
        k = self.k
        hx = np.zeros((2, 8))
        for i, chain in enumerate((guess.fx, guess.fy)):
            hx[i, :6] = planar_state(k, chain)
        sd = (tn.prior_pos, tn.prior_vel, tn.prior_swing, tn.prior_swing_rate, tn.prior_tilt, tn.prior_tilt_rate,
              tn.prior_d, tn.prior_bias)
        hp = np.tile(np.diag(np.square(sd)), (2, 1, 1))
        yx = np.array([[guess.psi, guess.psi_rate]])
        yp = np.diag([tn.prior_psi**2, tn.prior_psi_rate**2])[None]
        zx = np.array([[guess.z, guess.z_rate, 0.0]])
        zp = np.diag([tn.prior_z**2, tn.prior_z_rate**2, tn.prior_dz**2])[None]
        # core (delayed horizon) per block: [time, mean, covariance]
        self._core = [[float(t), hx, hp], [float(t), yx, yp], [float(t), zx, zp]]
        self._out = [hx.copy(), yx.copy(), zx.copy()]
        self._t_out = float(t)
        self._pending: list[tuple[float, int, Measurement]] = []
        self._seq = 0
        self._latest_t = -math.inf
        # command history: (time, (horizontal input (2,), heading input (1,), height input (1,)))
        self._cmds: list[tuple[float, tuple[np.ndarray, np.ndarray, np.ndarray]]] = [
            (float(t), (np.zeros(2), np.zeros(1), np.zeros(1)))
        ]
        self._gated_run = {"pos": 0, "vel": 0, "z": 0, "vz": 0, "tilt": 0, "tilt_rate": 0, "psi": 0, "psi_rate": 0,
                           "acc": 0, "load": 0}
        self._fz = self._g
        self._last_good = guess
        self._initialized = True

    def push(self, m: Measurement) -> None:
        """Queue a measurement (any order). Non-finite, late (sampled before the fusion horizon) or unusable
        records are counted and dropped; the rest are fused when the horizon passes their time."""
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
        if isinstance(m, LoadAngle) and not self.load_sensor:
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
        """The controller's command from time ``t`` (s): thrust (N) and body torques (N m, FLU), held until the
        next one. A command older than the last output time is applied from the output time on."""
        if not (math.isfinite(t) and math.isfinite(thrust) and all(math.isfinite(v) for v in torque)):
            self._stats["commands_rejected"] += 1
            return
        t = max(float(t), self._t_out)
        hx, yx = self._out[0], self._out[1]
        psi = float(yx[0, 0])
        cp, sp = math.cos(psi), math.sin(psi)
        ip, it, iy = self._inv_inertia
        ttheta, tphi = torque[1] * it, -torque[0] * ip  # accelerations of (theta, -phi)
        w_h = np.array((cp * ttheta - sp * tphi, sp * ttheta + cp * tphi))
        # tilt of the output estimate (world tilt -> theta, phi) for the vertical thrust component
        nx, ny = float(hx[0, IN]), float(hx[1, IN])
        theta, phi = nx * cp + ny * sp, nx * sp - ny * cp
        w_z = np.array((thrust * math.cos(phi) * math.cos(theta) / self._Mt - self._g,))
        w_y = np.array((torque[2] * iy,))
        cmds = self._cmds
        if cmds and cmds[-1][0] >= t:
            cmds[-1] = (cmds[-1][0], (w_h, w_y, w_z))
        else:
            cmds.append((t, (w_h, w_y, w_z)))

    # --------------------------------------------------------------------------------------------------------
    def estimate(self, t: float) -> ControlState:
        """The estimate predicted to time ``t`` (s); fuses every queued measurement sampled before ``t - delay``."""
        if not self._initialized:
            raise RuntimeError("initialize() the estimator before asking for an estimate")
        if t > self._t_out:
            self._advance_output(t)
        horizon = min(t - self.delay, self._t_out)
        pending = self._pending
        while pending and pending[0][0] <= horizon:
            _, _, m = heapq.heappop(pending)
            self._fuse(m)
        # keep the delayed horizon within reach so that a silent sensor does not leave a block far behind
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
        """Covariance (21 x 21, ordering :data:`STATE_NAMES`) of the filter state at the last output time."""
        out = np.zeros((21, 21))
        ps = self._output_covariances()
        out[0:8, 0:8] = ps[0][0]
        out[8:16, 8:16] = ps[0][1]
        out[16:18, 16:18] = ps[1][0]
        out[18:21, 18:21] = ps[2][0]
        return out

    def nees(self, t: float, truth: ControlState) -> float:
        """Normalized estimation error squared of (p, v, a, a', n, n') per axis, (psi, psi') and (z, z') at
        time ``t`` against ``truth`` mapped into the filter's coordinates (:data:`NEES_DOF` degrees of freedom)."""
        if t > self._t_out:
            self.estimate(t)
        ps = self._output_covariances()
        total = 0.0
        hx = self._out[0]
        for i, chain in enumerate((truth.fx, truth.fy)):
            e = hx[i, :6] - np.array(planar_state(self.k, chain))
            total += float(e @ np.linalg.solve(ps[0][i][:6, :6], e))
        yx = self._out[1]
        e = np.array((wrap_angle(float(yx[0, 0]) - truth.psi), float(yx[0, 1]) - truth.psi_rate))
        total += float(e @ np.linalg.solve(ps[1][0], e))
        zx = self._out[2]
        e = np.array((float(zx[0, 0]) - truth.z, float(zx[0, 1]) - truth.z_rate))
        total += float(e @ np.linalg.solve(ps[2][0][:2, :2], e))
        return total

    def stats(self) -> dict[str, int]:
        """Counters: accepted (records fused), late_dropped, out_of_order (arrived after a newer one; still
        fused), gated_outliers (records with at least one gated update), nan_rejected, gate_reopened,
        commands_rejected, not_used (cable-angle records in sensorless mode), nonfinite_resets, buffered."""
        out = dict(self._stats)
        out["buffered"] = len(self._pending) if self._initialized else 0
        return out

    # internals ---------------------------------------------------------------------------------------------
    def _min_core_time(self) -> float:
        c = self._core
        return max(c[0][0], c[1][0], c[2][0])

    def _advance_core(self, bi: int, t: float) -> None:
        """Predict block ``bi`` of the delayed state to ``t`` with the commands in force (mean piecewise,
        covariance in one step: it does not depend on the input)."""
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
                x = blk.predict_mean(x, end - tc, cmds[j][1][bi])
                tc = end
            if end >= t:
                break
            j += 1
        core[1] = x
        core[0] = t
        # forget the commands no block needs any more
        tmin = min(c[0] for c in self._core)
        k = 0
        while k + 1 < len(cmds) and cmds[k + 1][0] <= tmin:
            k += 1
        if k:
            del cmds[:k]

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
                w = cmds[j][1]
                h = end - tc
                out[0] = self._hb.predict_mean(out[0], h, w[0])
                out[1] = self._yb.predict_mean(out[1], h, w[1])
                out[2] = self._zb.predict_mean(out[2], h, w[2])
                tc = end
            if end >= t:
                break
            j += 1
        self._t_out = t

    def _correct_output(self, bi: int, dx: np.ndarray) -> None:
        """Carry a correction of the delayed state of block ``bi`` to the output."""
        h = self._t_out - self._core[bi][0]
        if h > 0.0:
            dx = dx @ self._blocks[bi].discrete(h).phi_t
        self._out[bi] += dx

    def _output_covariances(self) -> list[list[np.ndarray]]:
        res = []
        for bi, blk in enumerate(self._blocks):
            t0, _, p = self._core[bi]
            h = self._t_out - t0
            pp = blk.predict_cov(p, h) if h > 0.0 else p
            res.append([pp[i] for i in range(blk.batch)])
        return res

    def _update(self, bi: int, name: str, i: int | None, z: np.ndarray, r: float, gate: float,
                row: np.ndarray | None = None) -> bool:
        """One gated update of block ``bi``; returns False when gated."""
        core = self._core[bi]
        if row is None:
            _, dx = LinearBlock.update_unit(core[1], core[2], i, z, r, gate)
        else:
            _, dx = LinearBlock.update_row(core[1], core[2], row, z, r, gate)
        if dx is None:
            run = self._gated_run[name] + 1
            if run <= self.tuning.gate_reopen:
                self._gated_run[name] = run
                return False
            # the stream has been rejected too long: the filter, not the sensor, is wrong; accept it
            self._stats["gate_reopened"] += 1
            if row is None:
                _, dx = LinearBlock.update_unit(core[1], core[2], i, z, r, math.inf)
            else:
                _, dx = LinearBlock.update_row(core[1], core[2], row, z, r, math.inf)
            assert dx is not None
        self._gated_run[name] = 0
        self._correct_output(bi, dx)
        return True

    def _fuse(self, m: Measurement) -> None:
        t = m.t
        r = self._r
        g1, g2 = self._gate1, self._gate2
        ok = True
        if isinstance(m, PositionVelocity):
            self._advance_core(0, t)
            self._advance_core(2, t)
            ok &= self._update(0, "pos", IP, np.array((m.x, m.y)), r["pos_xy"], g2)
            ok &= self._update(0, "vel", IV, np.array((m.vx, m.vy)), r["vel_xy"], g2)
            ok &= self._update(2, "z", 0, np.array((m.z,)), r["pos_z"], g1)
            ok &= self._update(2, "vz", 1, np.array((m.vz,)), r["vel_z"], g1)
        elif isinstance(m, Attitude):
            self._advance_core(0, t)
            self._advance_core(1, t)
            phi, theta, psi = m.phi, m.theta, m.psi
            sf, cf = math.sin(phi), math.cos(phi)
            ct = math.cos(theta)
            if abs(ct) < 1e-3:
                self._stats["not_used"] += 1
                return
            tt = math.tan(theta)
            phi_rate = m.p + sf * tt * m.q + cf * tt * m.r
            theta_rate = cf * m.q - sf * m.r
            psi_rate = (sf * m.q + cf * m.r) / ct
            nx, ny, nxd, nyd = world_tilt(phi, theta, psi, phi_rate, theta_rate, psi_rate)
            ycore = self._core[1][1]
            psi_est = float(ycore[0, 0])
            ok &= self._update(0, "tilt", IN, np.array((nx, ny)), r["tilt"], g2)
            ok &= self._update(0, "tilt_rate", IND, np.array((nxd, nyd)), r["rate"], g2)
            ok &= self._update(1, "psi", 0, np.array((psi_est + wrap_angle(psi - psi_est),)), r["yaw"], g1)
            ok &= self._update(1, "psi_rate", 1, np.array((psi_rate,)), r["rate"], g1)
        elif isinstance(m, Imu):
            self._advance_core(0, t)
            a = self.tuning.accel_gain_filter
            fz = min(max(m.az, 0.2 * self._g), 3.0 * self._g)
            self._fz += a * (fz - self._fz)
            gain = self._m_over_M * self._fz
            psi = float(self._core[1][1][0, 0])
            cp, sp = math.cos(psi), math.sin(psi)
            z = np.array((cp * m.ax - sp * m.ay, sp * m.ax + cp * m.ay))
            row = self._acc_row
            row[IA] = gain
            row[IN] = gain
            ok &= self._update(0, "acc", None, z, r["acc"], g2, row=row)
        elif isinstance(m, LoadAngle):
            self._advance_core(0, t)
            ok &= self._update(0, "load", IA, np.array((m.alpha_y, m.alpha_x)), r["load"], g2)
        else:  # pragma: no cover - the type union is closed
            self._stats["not_used"] += 1
            return
        self._stats["accepted"] += 1
        if not ok:
            self._stats["gated_outliers"] += 1

    def _control_state(self) -> ControlState:
        k = self.k
        hx = self._out[0]
        ax_, ay_ = hx[0].tolist(), hx[1].tolist()
        psi, psi_rate = self._out[1][0].tolist()
        z, z_rate, _ = self._out[2][0].tolist()
        cp, sp = math.cos(psi), math.sin(psi)
        nx, nxd, ny, nyd = ax_[IN], ax_[IND], ay_[IN], ay_[IND]
        theta = nx * cp + ny * sp
        phi = nx * sp - ny * cp
        theta_rate = nxd * cp + nyd * sp + psi_rate * (-nx * sp + ny * cp)
        phi_rate = nxd * sp - nyd * cp + psi_rate * (nx * cp + ny * sp)
        return ControlState(
            flat_chain(k, ax_[IP], ax_[IV], ax_[IA], ax_[IAD], nx, nxd),
            flat_chain(k, ay_[IP], ay_[IV], ay_[IA], ay_[IAD], ny, nyd),
            z, z_rate, phi, theta, wrap_angle(psi), phi_rate, theta_rate, psi_rate,
            ay_[IA], ax_[IA], ay_[IAD], ax_[IAD],
        )


__all__ = ["NEES_DOF", "STATE_NAMES", "KalmanEstimator", "Tuning"]
