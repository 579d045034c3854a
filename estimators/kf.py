"""The Kalman filter that turns autopilot telemetry into the controller's :class:`ControlState`.

Design (``docs/estimation.md`` gives the derivation, the observability argument and the tuning):

- **Horizontal block** (one model, both world axes side by side): per axis the 8 states
  ``[p, v, a, a', n, n', d, b]``: vehicle position and velocity, the planar swing angle ``a`` (``alpha_y`` for
  x, ``alpha_x`` for y), the world thrust tilt ``n`` (``estimators.flatness.world_tilt``) and its rate, an
  unknown acceleration ``d`` on the vehicle (random walk: external forces, thrust mismatch) and the
  accelerometer bias ``b`` (random walk, world axes). The model is the tangent linearization at hover
  (errata section 2) driven by the commanded torque::

      v'  = (M_t g / M) n + (m g / M) a + d
      a'' = -w^2 (a + n) - d / l + c_a
      n'' = Rz(psi) [tau_theta / I_theta, -tau_phi / I_phi]

  where the known input ``c_a`` is the remainder of the exact swing acceleration (sphere form, errata E16)
  over the linear term, evaluated at the estimate when the command is pushed (large swings stay modelled)
  so ``[p, v, a, a', n, n']`` maps one-to-one and linearly onto the flat-output chain (F, ..., F^(5)).
- **Heading block** ``[psi, psi']`` driven by ``tau_psi / I_psi``; **height block** ``[z, z', d_z, b_z]`` driven by
  the vehicle's vertical acceleration ``(u n_3 + T r_3) / M - g`` evaluated at the estimate (thrust direction
  from the tilt, cable direction and tension from the swing estimate).
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

Filter state ordering (:meth:`KalmanEstimator.covariance`, 22 x 22, block diagonal)::

    0-7   x axis: p_x, v_x, alpha_y, alpha_y', n_x, n_x', d_x, b_x
    8-15  y axis: p_y, v_y, alpha_x, alpha_x', n_y, n_y', d_y, b_y
    16-17 psi, psi'
    18-21 z, z', d_z, b_z
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass

import numpy as np

from estimators.cable import cable_from_planar
from estimators.control_state import ControlState
from estimators.flatness import flat_chain, flat_constants, planar_state, world_tilt
from estimators.frames import wrap_angle
from estimators.linear_block import AugWorkspace, LinearBlock, update_one, update_pair, update_row
from estimators.measurements import Attitude, Imu, LoadAngle, Measurement, PositionVelocity
from estimators.vehicle import Vehicle

_DEG = math.pi / 180.0
#: command input columns of each block (horizontal x and y, heading, height) and its slice of the output
_N_INPUTS = 6  # x axis: n'' and the nonlinear remainder of a''; the same for y; psi''; z''

#: the in-place updates of :meth:`KalmanEstimator._update` by kind: adjacent pair, row, one state
_FAST_UPDATES = (update_pair, update_row, update_one)

STATE_NAMES: tuple[str, ...] = (
    "p_x", "v_x", "alpha_y", "alpha_y_rate", "n_x", "n_x_rate", "d_x", "b_x",
    "p_y", "v_y", "alpha_x", "alpha_x_rate", "n_y", "n_y_rate", "d_y", "b_y",
    "psi", "psi_rate",
    "z", "z_rate", "d_z", "b_z",
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
    q_v: float = 2e-3  # (m/s^2)^2/Hz, white acceleration on v'
    q_a: float = 0.05  # (rad/s^2)^2/Hz, white angular acceleration of the swing
    q_n: float = 0.05  # (rad/s^2)^2/Hz, tilt acceleration not explained by the torque command
    q_d: float = 0.5  # (m/s^3)^2/Hz, random walk of the unknown acceleration d
    q_b: float = 1e-7  # (m/s^3)^2/Hz, random walk of the accelerometer bias
    q_psi: float = 0.005  # (rad/s^2)^2/Hz
    q_vz: float = 3e-4  # (m/s^2)^2/Hz
    q_dz: float = 0.05  # (m/s^3)^2/Hz
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


#: ``scipy.stats.chi2.ppf(0.9999, dof)`` (the default gate) as scipy computes it, for the degrees of freedom used
_CHI2_9999 = {1: 15.136705226623606, 2: 18.420680743952584, 4: 23.512742444991076}


def chi2_quantile(p: float, dof: int) -> float:
    """The chi-square quantile ``scipy.stats.chi2.ppf(p, dof)``, computed as scipy computes it,
    ``2 gammaincinv(dof / 2, p)`` (identical values; the default gate's are stored: importing scipy.stats costs
    about half a second and scipy.special 0.15 s at every start of ``slung fly`` / ``slung replay``)."""
    if p == 0.9999 and dof in _CHI2_9999:
        return _CHI2_9999[dof]
    from scipy.special import gammaincinv

    return float(2 * gammaincinv(dof / 2, p))


def _planar_accel(ri: float, r3: float, di: float, d3: float, ei: float, e3: float) -> float:
    """Second derivative of the planar angle ``atan2(r_i, -r_3)`` from r, r', r'' components (rad/s^2)."""
    q = ri * ri + r3 * r3
    num = ri * d3 - r3 * di
    return ((ri * e3 - r3 * ei) * q - num * 2.0 * (ri * di + r3 * d3)) / (q * q)


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
        self._M, self._m, self._l = M, m, l
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
        b[IND, 0] = 1.0  # world tilt acceleration from the torque command
        b[IAD, 1] = 1.0  # nonlinear remainder of a'' at the estimate
        self._hb = LinearBlock(a, b, (0.0, tn.q_v, 0.0, tn.q_a, 0.0, tn.q_n, tn.q_d, tn.q_b), batch=2)
        self._yb = LinearBlock(np.array([[0.0, 1.0], [0.0, 0.0]]), (0.0, 1.0), (0.0, tn.q_psi), batch=1)
        az = np.zeros((4, 4))
        az[0, 1] = az[1, 2] = 1.0
        self._zb = LinearBlock(az, (0.0, 1.0, 0.0, 0.0), (0.0, tn.q_vz, tn.q_dz, tn.q_b), batch=1)
        self._blocks = (self._hb, self._yb, self._zb)
        for blk in self._blocks:  # warm the cache with the control step
            blk.discrete(1.0 / rate_hz)
        self._acc_row = np.zeros(8)
        self._acc_row[[ID, IB]] = 1.0
        self._gate = {dof: chi2_quantile(tn.gate_probability, dof) for dof in (1, 2, 4)}
        self._r: dict[str, object] = {
            "pv_xy": (tn.sigma_pos_xy**2, tn.sigma_vel_xy**2), "pv_z": (tn.sigma_pos_z**2, tn.sigma_vel_z**2),
            "tilt": (tn.sigma_tilt**2, tn.sigma_rate**2), "yaw": (tn.sigma_yaw**2, tn.sigma_rate**2),
            "acc": tn.sigma_acc**2, "load": tn.sigma_load**2,
        }
        self._stats = {
            "accepted": 0, "late_dropped": 0, "out_of_order": 0, "gated_outliers": 0, "nan_rejected": 0,
            "gate_reopened": 0, "commands_rejected": 0, "not_used": 0, "nonfinite_resets": 0,
            "gated_pos": 0, "gated_z": 0, "gated_tilt": 0, "gated_psi": 0, "gated_acc": 0, "gated_acc_z": 0,
            "gated_load": 0,
        }
        self._out_cache: dict[int, np.ndarray] = {}
        self._ycache: dict[int, tuple[float, ...]] = {}
        self._zcache: dict[int, tuple[float, ...]] = {}
        self._gate_reopen = tn.gate_reopen
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
        hp = np.diag(np.square(sd))
        yx = [guess.psi, guess.psi_rate]  # the heading block is plain floats: mean, covariance row-major
        yp = [tn.prior_psi**2, 0.0, 0.0, tn.prior_psi_rate**2]
        zx = [guess.z, guess.z_rate, 0.0, 0.0]  # the height block is plain floats: mean, upper triangle of P
        zp = [tn.prior_z**2, 0.0, 0.0, 0.0, tn.prior_z_rate**2, 0.0, 0.0, tn.prior_dz**2, 0.0, tn.prior_bias**2]
        # delayed state per block: [time, means, covariance]. Horizontal: views of one array [P; x] (10, 8) (see
        # _advance_horizontal); heading: plain floats, mean [psi, psi'] and P row-major (4); height: plain
        # floats, mean (4) and the upper triangle of P (10)
        self._aug = aug = np.concatenate((hp, hx))
        self._ws = AugWorkspace(aug)
        self._core = [[float(t), aug[8:], aug[:8]], [float(t), yx, yp], [float(t), zx, zp]]
        # output: the 22 means in STATE_NAMES order, followed by the 6 command inputs in force (see _advance_output)
        self._outw = np.concatenate((hx.ravel(), yx, zx, np.zeros(_N_INPUTS)))
        self._out = out = self._outw[:22]
        self._out_view_h = out[0:16].reshape(2, 8)
        self._t_out = float(t)
        self._pending: list[tuple[float, int, Measurement]] = []
        self._seq = 0
        self._latest_t = -math.inf
        # command history: (time, (horizontal input (2,), heading input (1,), height input (1,)))
        self._cmds: list[tuple[float, tuple[np.ndarray, ...]]] = [(float(t), self._command_views(np.zeros(_N_INPUTS)))]
        self._gated_run = {"pos": 0, "z": 0, "tilt": 0, "psi": 0, "acc": 0, "acc_z": 0, "load": 0}
        self._fz = self._g
        self._last_good = guess
        self._initialized = True

    def push(self, m: Measurement) -> None:
        """Queue a measurement (any order). Non-finite, late (sampled before the fusion horizon) or unusable
        records are counted and dropped; the rest are fused when the horizon passes their time."""
        st = self._stats
        try:  # a finite sum proves every field finite; otherwise look (the sum may overflow)
            finite = math.isfinite(sum(m)) or all(math.isfinite(v) for v in m)
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
        c = self._core
        if m.t < max(c[0][0], c[1][0], c[2][0]):  # sampled before the fusion horizon of some block
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
        if not (math.isfinite(t + thrust + sum(torque))  # a finite sum proves each finite (else look: overflow)
                or (math.isfinite(t) and math.isfinite(thrust) and all(math.isfinite(v) for v in torque))):
            self._stats["commands_rejected"] += 1
            return
        t = max(float(t), self._t_out)
        o = self._out.tolist()
        psi = o[16]
        cp, sp = math.cos(psi), math.sin(psi)
        ip, it, iy = self._inv_inertia
        ttheta, tphi = torque[1] * it, -torque[0] * ip  # accelerations of (theta, -phi)
        # exact swing and vertical accelerations at the output estimate (sphere form, errata E16); for the
        # swing, the remainder over the linear model is a known input
        nx, ny = o[IN], o[8 + IN]
        theta, phi = nx * cp + ny * sp, nx * sp - ny * cp
        sf, cf, st, ct = math.sin(phi), math.cos(phi), math.sin(theta), math.cos(theta)
        n1, n2, n3 = sf * sp + cf * cp * st, cf * sp * st - cp * sf, cf * ct
        ay, ax = o[IA], o[8 + IA]
        (r1, r2, r3), (d1, d2, d3) = cable_from_planar(ay, ax, o[IAD], o[8 + IAD])
        M, m, l, g = self._M, self._m, self._l, self._g
        rd2 = d1 * d1 + d2 * d2 + d3 * d3
        nr = n1 * r1 + n2 * r2 + n3 * r3
        tension = m * (M * l * rd2 - thrust * nr) / self._Mt
        # r'' = -(u / (M l)) (n - (n.r) r) - |r'|^2 r
        ku = thrust / (M * l)
        e1 = -ku * (n1 - nr * r1) - rd2 * r1
        e2 = -ku * (n2 - nr * r2) - rd2 * r2
        e3 = -ku * (n3 - nr * r3) - rd2 * r3
        wl = [
            cp * ttheta - sp * tphi,
            _planar_accel(r1, r3, d1, d3, e1, e3) + self._w2 * (ay + nx),
            sp * ttheta + cp * tphi,
            _planar_accel(r2, r3, d2, d3, e2, e3) + self._w2 * (ax + ny),
            torque[2] * iy,
            (thrust * n3 + tension * r3) / M - g,
        ]
        if not (math.isfinite(sum(wl)) or all(math.isfinite(v) for v in wl)):
            self._stats["commands_rejected"] += 1
            return
        w_all = np.array(wl)
        w = (w_all, w_all[0:4].reshape(2, 2), wl[4], wl[5])
        cmds = self._cmds
        if cmds[-1][0] >= t:
            cmds[-1] = (cmds[-1][0], w)
        else:
            cmds.append((t, w))

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
        self._forget_commands()
        est = self._control_state()
        if not est.is_finite():
            self._stats["nonfinite_resets"] += 1
            last = self._last_good
            self.initialize(self._t_out, last)
            return last
        self._last_good = est
        return est

    def covariance(self) -> np.ndarray:
        """Covariance (22 x 22, ordering :data:`STATE_NAMES`) of the filter state at the last output time."""
        out = np.zeros((22, 22))
        ps = self._output_covariances()
        out[0:8, 0:8] = ps[0]
        out[8:16, 8:16] = ps[0]
        out[16:18, 16:18] = ps[1]
        out[18:22, 18:22] = ps[2]
        return out

    def nees(self, t: float, truth: ControlState) -> float:
        """Normalized estimation error squared of (p, v, a, a', n, n') per axis, (psi, psi') and (z, z') at
        time ``t`` against ``truth`` mapped into the filter's coordinates (:data:`NEES_DOF` degrees of freedom)."""
        if t > self._t_out:
            self.estimate(t)
        hp, yp, zp = self._output_covariances_raw()
        out = self._out.tolist()
        e = np.array((
            *(a - b for a, b in zip(out[0:6], planar_state(self.k, truth.fx))),
            *(a - b for a, b in zip(out[8:14], planar_state(self.k, truth.fy))),
        )).reshape(2, 6)
        total = float(np.sum(e * np.linalg.solve(hp[:6, :6], e.T).T))
        # the two 2 x 2 blocks in closed form: e^T P^-1 e
        e0, e1 = wrap_angle(out[16] - truth.psi), out[17] - truth.psi_rate
        a, b, c, d = yp
        total += (d * e0 * e0 - b * e0 * e1 - c * e0 * e1 + a * e1 * e1) / (a * d - b * c)
        e0, e1 = out[18] - truth.z, out[19] - truth.z_rate
        a, b, d = zp[0], zp[1], zp[4]
        total += (d * e0 * e0 - 2.0 * b * e0 * e1 + a * e1 * e1) / (a * d - b * b)
        return total

    def stats(self) -> dict[str, int]:
        """Counters: accepted (records fused), late_dropped, out_of_order (arrived after a newer one; still
        fused), gated_outliers (records with at least one gated update), nan_rejected, gate_reopened,
        commands_rejected, not_used (cable-angle records in sensorless mode), nonfinite_resets, buffered, and
        gated_<stream>: refused updates per stream (pos, z, tilt, psi, acc, acc_z, load)."""
        out = dict(self._stats)
        out["buffered"] = len(self._pending) if self._initialized else 0
        return out

    # internals ---------------------------------------------------------------------------------------------
    def _advance_core(self, bi: int, t: float) -> None:
        """Predict block ``bi`` of the delayed state to ``t`` with the commands in force (mean piecewise,
        covariance in one step: it does not depend on the input)."""
        core = self._core[bi]
        t0 = core[0]
        if t <= t0:
            return
        cmds = self._cmds
        ncmd = len(cmds)
        j = 0
        while j + 1 < ncmd and cmds[j + 1][0] <= t0:
            j += 1
        if bi == 1:
            self._advance_heading(core, t0, t, j)
        elif bi == 2:
            self._advance_height(core, t0, t, j)
        else:
            self._advance_horizontal(core, t0, t, j)
        core[0] = t

    def _forget_commands(self) -> None:
        """Drop the commands no block needs any more (those replaced before every block's time)."""
        c = self._core
        tmin = min(c[0][0], c[1][0], c[2][0])
        cmds = self._cmds
        ncmd = len(cmds)
        k = 0
        while k + 1 < ncmd and cmds[k + 1][0] <= tmin:
            k += 1
        if k:
            del cmds[:k]

    def _advance_horizontal(self, core: list, t0: float, t: float, j: int) -> None:
        """:meth:`_advance_core` for the horizontal block, stored as one array ``[P; x]`` (10, 8) whose views
        are ``core[2]`` (P) and ``core[1]`` (x): with one command over the step, ``[P; x] Phi^T`` gives both
        ``P Phi^T`` and the mean's ``x Phi^T`` in one product."""
        blk = self._hb
        h = t - t0
        d = blk.discrete(h)
        cmds = self._cmds
        ncmd = len(cmds)
        p, x = core[2], core[1]
        ws = self._ws
        self._aug.dot(d.phi_t, out=ws.pred)  # [P Phi^T; x Phi^T]
        d.phi.dot(ws.pred_p, out=p)
        p += d.q
        if j + 1 >= ncmd or cmds[j + 1][0] >= t:  # one command in force over the whole step
            np.add(ws.pred_x, cmds[j][1][1].dot(d.gamma_t), out=x)
        else:  # the mean piecewise, one segment per command
            tc = t0
            while True:
                end = cmds[j + 1][0] if j + 1 < ncmd and cmds[j + 1][0] < t else t
                if end > tc:
                    d = blk.discrete(end - tc)
                    np.add(x.dot(d.phi_t), cmds[j][1][1].dot(d.gamma_t), out=x)
                    tc = end
                if end >= t:
                    break
                j += 1
        blk._n_predict += 1
        if blk._n_predict % 16 == 0:  # the updates keep P symmetric up to rounding; re-symmetrize now and then
            p[...] = 0.5 * (p + p.T)

    def _heading_model(self, h: float) -> tuple[float, ...]:
        """The heading block's discrete model for a step ``h`` as plain floats (phi00, phi01, phi10, phi11,
        gamma0, gamma1, q00, q01, q10, q11), cached like :meth:`LinearBlock.discrete`."""
        key = round(h * 1e7)
        mdl = self._ycache.get(key)
        if mdl is None:
            d = self._yb.discrete(h)
            (f00, f01), (f10, f11) = d.phi.tolist()
            g0, g1 = d.gamma_t[0].tolist()
            (q00, q01), (q10, q11) = d.q.tolist()
            if len(self._ycache) >= 4096:
                self._ycache.clear()
            mdl = self._ycache[key] = (f00, f01, f10, f11, g0, g1, q00, q01, q10, q11)
        return mdl

    def _heading_cov(self, p: list[float], h: float) -> list[float]:
        """The heading covariance (row-major floats) predicted by ``h`` s: ``Phi P Phi^T + Q`` (re-symmetrized
        every 16th prediction of the block, like :meth:`LinearBlock.predict_cov`)."""
        f00, f01, f10, f11, _, _, q00, q01, q10, q11 = self._heading_model(h)
        p00, p01, p10, p11 = p
        a0, a1 = p00 * f00 + p01 * f01, p00 * f10 + p01 * f11  # (P Phi^T) row 0
        b0, b1 = p10 * f00 + p11 * f01, p10 * f10 + p11 * f11  # row 1
        p00, p01 = f00 * a0 + f01 * b0 + q00, f00 * a1 + f01 * b1 + q01
        p10, p11 = f10 * a0 + f11 * b0 + q10, f10 * a1 + f11 * b1 + q11
        yb = self._yb
        yb._n_predict += 1
        if yb._n_predict % 16 == 0:
            p01 = p10 = 0.5 * (p01 + p10)
        return [p00, p01, p10, p11]

    def _advance_heading(self, core: list, t0: float, t: float, j: int) -> None:
        """:meth:`_advance_core` for the heading block, whose mean and covariance are plain floats."""
        core[2] = self._heading_cov(core[2], t - t0)
        x0, x1 = core[1]
        cmds = self._cmds
        ncmd = len(cmds)
        tc = t0
        while True:
            end = cmds[j + 1][0] if j + 1 < ncmd and cmds[j + 1][0] < t else t
            if end > tc:
                f00, f01, f10, f11, g0, g1 = self._heading_model(end - tc)[:6]
                w = cmds[j][1][2]
                x0, x1 = x0 * f00 + x1 * f01 + w * g0, x0 * f10 + x1 * f11 + w * g1
                tc = end
            if end >= t:
                break
            j += 1
        core[1] = [x0, x1]

    def _height_model(self, h: float) -> tuple[float, ...]:
        """The height block's discrete model for a step ``h`` as plain floats: the three off-diagonal entries
        (phi01, phi02, phi12) of Phi (the rest of Phi is the identity exactly: ``A`` is nilpotent and only
        chains z, z', d_z), the input column (gamma0, gamma1; the rest is zero) and the 10 entries of the upper
        triangle of Q, row-major; cached like :meth:`LinearBlock.discrete`."""
        key = round(h * 1e7)
        mdl = self._zcache.get(key)
        if mdl is None:
            d = self._zb.discrete(h)
            f = d.phi
            structure = f.copy()
            structure[0, 1] = structure[0, 2] = structure[1, 2] = 0.0
            g = d.gamma_t[0]
            if not (np.array_equal(structure, np.eye(4)) and g[2] == 0.0 and g[3] == 0.0):  # pragma: no cover
                raise RuntimeError("height model: Phi or Gamma lost the structure the float code relies on")
            q = d.q
            mdl = (float(f[0, 1]), float(f[0, 2]), float(f[1, 2]), float(g[0]), float(g[1]),
                   *(float(q[i, j]) for i in range(4) for j in range(i, 4)))
            if len(self._zcache) >= 4096:
                self._zcache.clear()
            self._zcache[key] = mdl
        return mdl

    def _height_cov(self, p: list[float], h: float) -> list[float]:
        """The height covariance (upper triangle, row-major floats) predicted by ``h`` s: ``Phi P Phi^T + Q``."""
        a, b, c, _, _, q00, q01, q02, q03, q11, q12, q13, q22, q23, q33 = self._height_model(h)
        p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = p
        # M = Phi P (rows 0 and 1 change), then Phi M Phi^T's upper triangle
        m00, m01, m02, m03 = p00 + a * p01 + b * p02, p01 + a * p11 + b * p12, p02 + a * p12 + b * p22, \
            p03 + a * p13 + b * p23
        m11, m12, m13 = p11 + c * p12, p12 + c * p22, p13 + c * p23
        return [m00 + a * m01 + b * m02 + q00, m01 + c * m02 + q01, m02 + q02, m03 + q03,
                m11 + c * m12 + q11, m12 + q12, m13 + q13, p22 + q22, p23 + q23, p33 + q33]

    def _advance_height(self, core: list, t0: float, t: float, j: int) -> None:
        """:meth:`_advance_core` for the height block (mean and covariance plain floats; the covariance is kept
        as its upper triangle, row-major: P00 P01 P02 P03 P11 P12 P13 P22 P23 P33)."""
        core[2] = self._height_cov(core[2], t - t0)
        x0, x1, x2, x3 = core[1]
        cmds = self._cmds
        ncmd = len(cmds)
        tc = t0
        while True:
            end = cmds[j + 1][0] if j + 1 < ncmd and cmds[j + 1][0] < t else t
            if end > tc:
                a, b, c, g0, g1 = self._height_model(end - tc)[:5]
                w = cmds[j][1][3]
                x0, x1 = x0 + a * x1 + b * x2 + g0 * w, x1 + c * x2 + g1 * w
                tc = end
            if end >= t:
                break
            j += 1
        core[1] = [x0, x1, x2, x3]

    def _correct_height(self, dx0: float, dx1: float, dx2: float, dx3: float) -> None:
        """Carry a correction of the delayed height state to the output (``Phi(t_out - t_core) dx``)."""
        h = self._t_out - self._core[2][0]
        out = self._out
        if h > 0.0:
            a, b, c = self._height_model(h)[:3]
            out[18] += dx0 + a * dx1 + b * dx2
            out[19] += dx1 + c * dx2
        else:
            out[18] += dx0
            out[19] += dx1
        out[20] += dx2
        out[21] += dx3

    def _update_height_pv(self, z0: float, z1: float) -> bool:
        """Gated update of the height block with height ``z0`` (m) and vertical velocity ``z1`` (m/s): the same
        arithmetic as :meth:`LinearBlock.update_states` on states (0, 1), in plain floats."""
        core = self._core[2]
        r0, r1 = self._r["pv_z"]
        gate = self._gate[2]
        x0, x1, x2, x3 = core[1]
        p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = core[2]
        s11, s12, s22 = p00 + r0, p01, p11 + r1
        det = s11 * s22 - s12 * s12
        y0, y1 = z0 - x0, z1 - x1
        while True:
            if det > 0.0:
                ia, ib, id_ = s22 / det, -s12 / det, s11 / det
                ys0, ys1 = y0 * ia + y1 * ib, y0 * ib + y1 * id_
                if ys0 * y0 + ys1 * y1 <= gate:
                    break
            if gate == math.inf or not self._gated("z"):
                return False
            gate = math.inf
        # columns 0 and 1 of P: (p00, p01, p02, p03) and (p01, p11, p12, p13); G = [col0 col1] S^-1
        g00, g01 = p00 * ia + p01 * ib, p00 * ib + p01 * id_
        g10, g11 = p01 * ia + p11 * ib, p01 * ib + p11 * id_
        g20, g21 = p02 * ia + p12 * ib, p02 * ib + p12 * id_
        g30, g31 = p03 * ia + p13 * ib, p03 * ib + p13 * id_
        core[2] = [p00 - (g00 * p00 + g01 * p01), p01 - (g00 * p01 + g01 * p11), p02 - (g00 * p02 + g01 * p12),
                   p03 - (g00 * p03 + g01 * p13), p11 - (g10 * p01 + g11 * p11), p12 - (g10 * p02 + g11 * p12),
                   p13 - (g10 * p03 + g11 * p13), p22 - (g20 * p02 + g21 * p12), p23 - (g20 * p03 + g21 * p13),
                   p33 - (g30 * p03 + g31 * p13)]
        dx0, dx1, dx2, dx3 = ys0 * p00 + ys1 * p01, ys0 * p01 + ys1 * p11, ys0 * p02 + ys1 * p12, \
            ys0 * p03 + ys1 * p13
        core[1] = [x0 + dx0, x1 + dx1, x2 + dx2, x3 + dx3]
        self._gated_run["z"] = 0
        self._correct_height(dx0, dx1, dx2, dx3)
        return True

    def _update_height_acc(self, z: float) -> bool:
        """Gated update of the height block with ``z`` = measured ``z'' - commanded part = d_z + b_z`` (m/s^2):
        :meth:`LinearBlock.update_row` with the row (0, 0, 1, 1), in plain floats."""
        core = self._core[2]
        r = self._r["acc"]
        gate = self._gate[1]
        x0, x1, x2, x3 = core[1]
        p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = core[2]
        h0, h1, h2, h3 = p02 + p03, p12 + p13, p22 + p23, p23 + p33  # P h
        s = h2 + h3 + r
        y = z - (x2 + x3)
        while not y * y <= gate * s:
            if gate == math.inf or not self._gated("acc_z"):
                return False
            gate = math.inf
        k0, k1, k2, k3 = h0 / s, h1 / s, h2 / s, h3 / s
        core[2] = [p00 - h0 * k0, p01 - h0 * k1, p02 - h0 * k2, p03 - h0 * k3, p11 - h1 * k1, p12 - h1 * k2,
                   p13 - h1 * k3, p22 - h2 * k2, p23 - h2 * k3, p33 - h3 * k3]
        dx0, dx1, dx2, dx3 = y * k0, y * k1, y * k2, y * k3
        core[1] = [x0 + dx0, x1 + dx1, x2 + dx2, x3 + dx3]
        self._gated_run["acc_z"] = 0
        self._correct_height(dx0, dx1, dx2, dx3)
        return True

    @staticmethod
    def _command_views(w: np.ndarray) -> tuple:
        """(all 6 inputs, horizontal (2, 2), heading (float), height (float)): the inputs of each block."""
        return (w, w[0:4].reshape(2, 2), float(w[4]), float(w[5]))

    def _active_command(self, t: float) -> tuple:
        """The command in force at time ``t`` (s), as the block inputs of :meth:`_command_views`."""
        cmds = self._cmds
        j = len(cmds) - 1
        while j > 0 and cmds[j][0] > t:
            j -= 1
        return cmds[j][1]

    def _advance_output(self, t: float) -> None:
        """Predict the output means to ``t`` with the commands in force: per command segment one product
        ``[out, w] [Phi^T; Gamma^T]``."""
        cmds = self._cmds
        t0 = self._t_out
        j = len(cmds) - 1
        while j > 0 and cmds[j][0] > t0:
            j -= 1
        tc = t0
        outw = self._outw
        out = self._out
        while True:
            end = cmds[j + 1][0] if j + 1 < len(cmds) and cmds[j + 1][0] < t else t
            if end > tc:
                outw[22:] = cmds[j][1][0]
                out[:] = outw.dot(self._output_model(end - tc))
                tc = end
            if end >= t:
                break
            j += 1
        self._t_out = t

    def _output_model(self, h: float) -> np.ndarray:
        """``[Phi^T; Gamma^T]`` (28, 22), block diagonal per block, of all 22 output means and the 6 command
        inputs for a step ``h`` (cached)."""
        key = round(h * 1e7)
        mdl = self._out_cache.get(key)
        if mdl is None:
            mdl = np.zeros((22 + _N_INPUTS, 22))
            phi_t, gamma_t = mdl[:22], mdl[22:]
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
            self._out_cache[key] = mdl
        return mdl

    def _output_covariances_raw(self) -> tuple[np.ndarray, list[float], list[float]]:
        """The blocks' covariances predicted to the output time, in their storage forms: horizontal (8, 8),
        heading row-major floats (4), height upper-triangle floats (10)."""
        c = self._core
        t_out = self._t_out
        hp = c[0][2]
        h = t_out - c[0][0]
        if h > 0.0:
            blk = self._hb
            d = blk.discrete(h)
            hp = d.phi.dot(hp).dot(d.phi_t)
            hp += d.q
            blk._n_predict += 1
            if blk._n_predict % 16 == 0:
                hp = 0.5 * (hp + hp.T)
        h = t_out - c[1][0]
        yp = self._heading_cov(c[1][2], h) if h > 0.0 else c[1][2]
        h = t_out - c[2][0]
        zp = self._height_cov(c[2][2], h) if h > 0.0 else c[2][2]
        return hp, yp, zp

    def _output_covariances(self) -> list[np.ndarray]:
        hp, yp, zp = self._output_covariances_raw()
        p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = zp
        return [hp.copy(), np.array(yp).reshape(2, 2),
                np.array(((p00, p01, p02, p03), (p01, p11, p12, p13), (p02, p12, p22, p23), (p03, p13, p23, p33)))]

    def _gated(self, name: str) -> bool:
        """Count a gated update of stream ``name``; True when the gate must reopen (the stream has been
        rejected too long: the filter, not the sensor, is wrong) and the update be done ungated."""
        self._stats["gated_" + name] += 1
        run = self._gated_run[name] + 1
        if run <= self._gate_reopen:
            self._gated_run[name] = run
            return False
        self._stats["gate_reopened"] += 1
        return True

    def _update(self, name: str, kind: int, arg: object, z: tuple[float, ...], r: object, dof: int) -> bool:
        """One gated update of the horizontal block (``kind``: 0 = two adjacent states (arg = first index),
        1 = a measurement row (arg = the row), 2 = one state (arg = its index)); returns False when gated."""
        fn = _FAST_UPDATES[kind]
        ws = self._ws
        ndx = fn(ws, arg, z, r, self._gate[dof])
        if ndx is None:
            if not self._gated(name):
                return False
            ndx = fn(ws, arg, z, r, math.inf)
            if ndx is None:
                return False
        self._gated_run[name] = 0
        # carry the correction to the output (_correct_output, inlined)
        h = self._t_out - self._core[0][0]
        if h > 0.0:
            self._out_view_h -= ndx.dot(self._hb.discrete(h).phi_t)
        else:
            self._out_view_h -= ndx
        return True

    def _update_heading(self, z0: float, z1: float) -> bool:
        """Gated update of the heading block with heading ``z0`` (rad) and its rate ``z1`` (rad/s), plain floats
        (the same arithmetic as :meth:`LinearBlock.update_states` on the 2 x 2 block)."""
        core = self._core[1]
        r0, r1 = self._r["yaw"]
        gate = self._gate[2]
        x0, x1 = core[1]
        p00, p01, p10, p11 = core[2]
        s11 = p00 + r0
        s12 = p01
        s22 = p11 + r1
        det = s11 * s22 - s12 * s12
        y0, y1 = z0 - x0, z1 - x1
        while True:
            if det > 0.0:
                i00, i01, i10, i11 = s22 / det, -s12 / det, -s12 / det, s11 / det
                ys0, ys1 = y0 * i00 + y1 * i10, y0 * i01 + y1 * i11
                if ys0 * y0 + ys1 * y1 <= gate:
                    break
            if gate == math.inf or not self._gated("psi"):
                return False
            gate = math.inf
        dx0, dx1 = ys0 * p00 + ys1 * p01, ys0 * p10 + ys1 * p11
        g00, g01 = p00 * i00 + p01 * i10, p00 * i01 + p01 * i11  # G = P S^-1
        g10, g11 = p10 * i00 + p11 * i10, p10 * i01 + p11 * i11
        core[2] = [p00 - (g00 * p00 + g01 * p01), p01 - (g00 * p10 + g01 * p11),
                   p10 - (g10 * p00 + g11 * p01), p11 - (g10 * p10 + g11 * p11)]
        core[1] = [x0 + dx0, x1 + dx1]
        self._gated_run["psi"] = 0
        h = self._t_out - core[0]
        out = self._out
        if h > 0.0:
            f00, f01, f10, f11 = self._heading_model(h)[:4]
            out[16] += dx0 * f00 + dx1 * f01
            out[17] += dx0 * f10 + dx1 * f11
        else:
            out[16] += dx0
            out[17] += dx1
        return True

    def _fuse(self, m: Measurement) -> None:
        t = m.t
        r = self._r
        ok = True
        if isinstance(m, PositionVelocity):
            self._advance_core(0, t)
            self._advance_core(2, t)
            ok &= self._update("pos", 0, IP, (m.x, m.vx, m.y, m.vy), r["pv_xy"], 4)
            ok &= self._update_height_pv(m.z, m.vz)
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
            psi_est = self._core[1][1][0]
            ok &= self._update("tilt", 0, IN, (nx, nxd, ny, nyd), r["tilt"], 4)
            ok &= self._update_heading(psi_est + wrap_angle(psi - psi_est), psi_rate)
        elif isinstance(m, Imu):
            self._advance_core(0, t)
            a = self.tuning.accel_gain_filter
            fz = min(max(m.az, 0.2 * self._g), 3.0 * self._g)
            self._fz += a * (fz - self._fz)
            gain = self._m_over_M * self._fz
            psi = self._core[1][1][0]
            cp, sp = math.cos(psi), math.sin(psi)
            row = self._acc_row
            row[IA] = gain
            row[IN] = gain
            z = (cp * m.ax - sp * m.ay, sp * m.ax + cp * m.ay)
            ok &= self._update("acc", 1, row, z, r["acc"], 2)
            # vertical: the world-vertical specific force minus g is z'' = (commanded part) + d_z, plus b_z
            self._advance_core(2, t)
            nx, ny = self._core[0][1][:, IN].tolist()
            theta, phi = nx * cp + ny * sp, nx * sp - ny * cp
            ct = math.cos(theta)
            fz_world = -math.sin(theta) * m.ax + ct * math.sin(phi) * m.ay + ct * math.cos(phi) * m.az
            w_z = self._active_command(self._core[2][0])[3]
            ok &= self._update_height_acc(fz_world - self._g - w_z)
        elif isinstance(m, LoadAngle):
            self._advance_core(0, t)
            ok &= self._update("load", 2, IA, (m.alpha_y, m.alpha_x), r["load"], 2)
        else:  # pragma: no cover - the type union is closed
            self._stats["not_used"] += 1
            return
        self._stats["accepted"] += 1
        if not ok:
            self._stats["gated_outliers"] += 1

    def _control_state(self) -> ControlState:
        k = self.k
        out = self._out.tolist()
        ax_, ay_ = out[0:8], out[8:16]
        psi, psi_rate = out[16], out[17]
        z, z_rate = out[18], out[19]
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
