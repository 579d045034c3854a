"""The Kalman filter that turns autopilot telemetry into the controller's :class:`ControlState`.

Design (``docs/estimation.md`` gives the derivation, the observability argument and the tuning):

- **Horizontal block** (one model, both world axes side by side): per axis the 8 states
  ``[p, v, a, a', n, n', d, b]``: vehicle position and velocity, the planar swing angle ``a`` (``alpha_y`` for
  x, ``alpha_x`` for y), the world thrust tilt ``n`` (``estimators.model.flatness.world_tilt``) and its rate, an
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

The filter is four modules by job: this one, the public :class:`KalmanEstimator` (records in, estimate and
read-outs out); ``kf_model`` (the state layout, :class:`Tuning`, the continuous-time blocks); ``kf_predict`` (the
blocks' discrete models and their prediction, a mixin) and ``kf_update`` (the gated updates, a mixin).
"""

from __future__ import annotations

import heapq
import math

import numpy as np

from estimators.filters.fusion import BASE_STATS, BlockState, RecordFusion, check_rates, chi2_quantile
from estimators.filters.kf_model import IA, IAD, IB, ID, IN, IP, N_INPUTS, NEES_DOF, STATE_NAMES, Tuning, model_blocks
from estimators.filters.kf_predict import KfPrediction
from estimators.filters.kf_update import KfUpdates
from estimators.filters.linear_block import AugWorkspace
from estimators.model.cable import cable_from_planar
from estimators.model.control_state import ControlState
from estimators.model.flatness import control_state_from_tilt, flat_constants, planar_state
from estimators.model.frames import wrap_angle
from estimators.model.measurements import Measurement, ReportedAccuracy
from estimators.model.vehicle import Vehicle


def _planar_accel(ri: float, r3: float, di: float, d3: float, ei: float, e3: float) -> float:
    """Second derivative of the planar angle ``atan2(r_i, -r_3)`` from r, r', r'' components (rad/s^2)."""
    q = ri * ri + r3 * r3
    num = ri * d3 - r3 * di
    return ((ri * e3 - r3 * ei) * q - num * 2.0 * (ri * di + r3 * d3)) / (q * q)


class KalmanEstimator(KfPrediction, KfUpdates, RecordFusion):
    """Kalman filter on the measurement records of ``estimators.model.measurements`` (see the module docstring).

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
        check_rates(rate_hz, delay_s)
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

        self._hb, self._yb, self._zb = model_blocks(vehicle, k, tn)
        self._blocks = (self._hb, self._yb, self._zb)
        for blk in self._blocks:  # warm the cache with the control step
            blk.discrete(1.0 / rate_hz)
        self._acc_row = np.zeros(8)
        self._acc_row[[ID, IB]] = 1.0
        self._gate = {dof: chi2_quantile(tn.gate_probability, dof) for dof in (1, 2, 4)}
        self._r: dict[str, object] = {
            "pv_xy": (tn.sigma_pos_xy**2, tn.sigma_vel_xy**2),
            "pv_z": (tn.sigma_pos_z**2, tn.sigma_vel_z**2),
            "tilt": (tn.sigma_tilt**2, tn.sigma_rate**2),
            "yaw": (tn.sigma_yaw**2, tn.sigma_rate**2),
            "acc": tn.sigma_acc**2,
            "load": tn.sigma_load**2,
        }
        self._stats = {
            **dict.fromkeys(BASE_STATS, 0),
            "gated_pos": 0,
            "gated_z": 0,
            "gated_tilt": 0,
            "gated_psi": 0,
            "gated_acc": 0,
            "gated_acc_z": 0,
            "gated_load": 0,
        }
        self._out_cache: dict[int, np.ndarray] = {}
        self._ycache: dict[int, tuple[float, ...]] = {}
        self._zcache: dict[int, tuple[float, ...]] = {}
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
        yx = [guess.psi, guess.psi_rate]  # the heading block is plain floats: mean, covariance row-major
        yp = [tn.prior_psi**2, 0.0, 0.0, tn.prior_psi_rate**2]
        zx = [guess.z, guess.z_rate, 0.0, 0.0]  # the height block is plain floats: mean, upper triangle of P
        zp = [tn.prior_z**2, 0.0, 0.0, 0.0, tn.prior_z_rate**2, 0.0, 0.0, tn.prior_dz**2, 0.0, tn.prior_bias**2]
        # delayed state per block (time, mean, covariance). Horizontal: views of one array [P; x] (10, 8) (see
        # _advance_horizontal); heading: plain floats, mean [psi, psi'] and P row-major (4); height: plain
        # floats, mean (4) and the upper triangle of P (10)
        self._aug = aug = np.concatenate((hp, hx))
        self._ws = AugWorkspace(aug)
        self._core = [
            BlockState(float(t), aug[8:], aug[:8]),
            BlockState(float(t), yx, yp),
            BlockState(float(t), zx, zp),
        ]
        # output: the 22 means in STATE_NAMES order, followed by the 6 command inputs in force (see _advance_output)
        self._outw = np.concatenate((hx.ravel(), yx, zx, np.zeros(N_INPUTS)))
        self._out = out = self._outw[:22]
        self._out_view_h = out[0:16].reshape(2, 8)
        self._t_out = float(t)
        self._pending: list[tuple[float, int, Measurement]] = []
        # command history: (time, (horizontal input (2,), heading input (1,), height input (1,)))
        self._cmds: list[tuple[float, tuple[np.ndarray, ...]]] = [(float(t), self._command_views(np.zeros(N_INPUTS)))]
        self._gated_run = {"pos": 0, "z": 0, "tilt": 0, "psi": 0, "acc": 0, "acc_z": 0, "load": 0}
        self._fz = self._g
        self._start_records(guess)
        self._initialized = True

    def push(self, m: Measurement) -> None:
        """Queue a measurement (any order). Non-finite, late (sampled before the fusion horizon) or unusable
        records are counted and dropped; the rest are fused when the horizon passes their time."""
        if isinstance(m, ReportedAccuracy):  # its noise is fixed by its tuning: an accuracy report has nothing to move
            self._stats["not_used"] += 1
            return
        if self._admit(m):
            c = self._core  # the fusion horizon: the oldest time of the three blocks
            self._enqueue(self._pending, m, max(c[0].t, c[1].t, c[2].t))

    def push_command(self, t: float, thrust: float, torque: tuple[float, float, float]) -> None:
        """The controller's command from time ``t`` (s): thrust (N) and body torques (N m, FLU), held until the
        next one. A command older than the last output time is applied from the output time on."""
        if not (
            math.isfinite(t + thrust + sum(torque))  # a finite sum proves each finite (else look: overflow)
            or (math.isfinite(t) and math.isfinite(thrust) and all(math.isfinite(v) for v in torque))
        ):
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
    def estimate(self, t: float, lead_s: float = 0.0) -> ControlState:
        """The estimate predicted to time ``t + lead_s`` (s); fuses every queued measurement sampled before
        ``t - delay``. ``lead_s`` (>= 0): how much later than ``t`` the state is wanted (the time a setpoint takes
        to reach the vehicle), predicted with the commands in force; the filter's own output time stays ``t``."""
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
            if horizon - self._core[bi].t > 0.05:
                self._advance_core(bi, horizon)
        self._forget_commands()
        if lead_s > 0.0 and math.isfinite(lead_s):
            saved, t_saved = self._outw.copy(), self._t_out
            self._advance_output(t_saved + lead_s)
            est = self._control_state()
            self._outw[:] = saved
            self._t_out = t_saved
        else:
            est = self._control_state()
        return self._checked(est)

    def covariance(self) -> np.ndarray:
        """Covariance (22 x 22, ordering :data:`STATE_NAMES`) of the filter state at the last output time."""
        out = np.zeros((22, 22))
        ps = self._output_covariances()
        out[0:8, 0:8] = ps[0]
        out[8:16, 8:16] = ps[0]
        out[16:18, 16:18] = ps[1]
        out[18:22, 18:22] = ps[2]
        return out

    def sigmas(self) -> tuple[float, ...]:
        """Standard deviations at the last output time of ``estimators.filters.factory.SIGMA_NAMES`` (F_x, F_y, z in m;
        roll, pitch, heading, alpha_x, alpha_y in rad; p_x, p_y in m), from the covariance read without changing
        the filter. Both horizontal axes share one covariance; roll and pitch carry the tilt's and (to first
        order) the heading's."""
        hp, yp, zp = self._output_covariances_raw()
        l = self.k.l
        v_p, v_a, v_n = hp[IP, IP], hp[IA, IA], hp[IN, IN]
        v_f = v_p + l * l * v_a + 2.0 * l * hp[IP, IA]
        out = self._out.tolist()
        psi = out[16]
        cp, sp = math.cos(psi), math.sin(psi)
        nx, ny = out[IN], out[8 + IN]
        theta, phi = nx * cp + ny * sp, nx * sp - ny * cp
        v_psi = yp[0]
        sq = math.sqrt
        s_f, s_a, s_p = sq(v_f), sq(v_a), sq(v_p)
        s_phi, s_theta = sq(v_n + theta * theta * v_psi), sq(v_n + phi * phi * v_psi)
        return (s_f, s_f, sq(zp[0]), s_phi, s_theta, sq(v_psi), s_a, s_a, s_p, s_p)

    def innovations(self) -> tuple[float, ...]:
        """``estimators.filters.factory.INNOVATION_STREAMS``' normalized innovations (NaN: this filter, which runs in
        ``slung sim`` only, does not record them) and its refused updates per stream (``gated_<stream>``)."""
        st = self._stats
        streams = ("pos", "z", "tilt", "psi", "acc", "load")
        return (*(math.nan for _ in streams), *(float(st["gated_" + s]) for s in streams))

    def nees(self, t: float, truth: ControlState) -> float:
        """Normalized estimation error squared of (p, v, a, a', n, n') per axis, (psi, psi') and (z, z') at
        time ``t`` against ``truth`` mapped into the filter's coordinates (:data:`NEES_DOF` degrees of freedom)."""
        if t > self._t_out:
            self.estimate(t)
        hp, yp, zp = self._output_covariances_raw()
        out = self._out.tolist()
        e = np.array(
            (
                *(a - b for a, b in zip(out[0:6], planar_state(self.k, truth.fx))),
                *(a - b for a, b in zip(out[8:14], planar_state(self.k, truth.fy))),
            )
        ).reshape(2, 6)
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

    # internals (the rest: the prediction in kf_predict, the gated updates in kf_update) -------------------------

    def _control_state(self) -> ControlState:
        out = self._out.tolist()  # per axis p, v, a, a', n, n' lead the block (IP ... IND)
        return control_state_from_tilt(self.k, out[0:6], out[8:14], out[18], out[19], out[16], out[17])


__all__ = ["NEES_DOF", "STATE_NAMES", "KalmanEstimator", "Tuning"]
