"""The Kalman filter fed by what the vehicle measures: attitude and IMU specific force; the commands only carry the
tilt from one attitude sample to the next.

A real autopilot runs its own attitude and rate loops, allocator and saturation: the commanded torques are not
what the vehicle does, and a filter that predicts tilt and acceleration from them refuses about half of real
PX4's telemetry (``docs/estimation.md`` section 2). This filter takes the vehicle's own measurements as its
inputs and measurements instead (derivation, tuning and evidence in ``docs/estimation.md``):

- **Kinematics, per world axis** ``[p, v, b]``: ``v' = u - b``, where ``u`` is the vehicle's acceleration
  measured by the accelerometer, ``u = R f - g e_3`` (f: specific force, body FLU; R from the attitude
  estimate), held from one IMU sample to the next; ``b`` the accelerometer bias along that axis (random walk).
  Measured by the autopilot's position / velocity estimate. Without IMU telemetry ``u = 0`` and ``v'`` is white
  noise of a larger density (a constant-velocity model).
- **Tilt, per world axis** ``[n, n']`` (``n = Rz(psi) [theta, -phi]``, ``estimators.model.flatness.world_tilt``) and
  **heading** ``[psi, psi']``: ``n'' = u_n + w`` with ``u_n`` the commanded tilt acceleration (the torque command
  over the inertia, rotated to the world, :meth:`MeasuredKalmanEstimator.push_command`) and ``w`` white, ``psi''``
  white; measured by ATTITUDE (angles and body rates turned into Euler rates, errata E4) and by the IMU's gyro
  (HIGHRES_IMU's body rates, turned the same way), a second, independently delivered rate stream, opt-in
  (``MeasuredTuning.fuse_gyro``: against real PX4 SITL, whose HIGHRES_IMU gyro is the raw, noisier one, it made
  the filter refuse 10-19 % of ATTITUDE records).
  Why the command: the torque-level law's gain on the tilt is ``I K4`` = 46 N m/rad and on its rate ``I K5`` =
  3.2 N m per rad/s; between attitude samples (10 ms apart at 100 Hz, 20-40 ms when a sample is lost) and over
  their latency a tilt carried on at constant rate misses what the last command started, by a few milliradians:
  at 30 % packet loss that rocked the load 0.5-1 m off in half the hovers, while the same tilt taken from the
  plant itself flew every one (``tests/test_loop_failsafe.py``, docs/estimation.md section 0.3). The mapping
  (``offboard.flight.command_mapping``) builds each setpoint so that the autopilot's rate loop delivers that
  torque; what it delivers otherwise (allocator, saturation, a different vehicle) is the white ``w``, and every
  attitude and gyro sample corrects it. Position, velocity and swing take no command.
- **Swing, per world axis, only with a load** ``[a, a', e]``: the pendulum hanging from a pivot whose
  acceleration is measured, ``a'' = -((g + u_z) / l) a - (u - b) / l``; ``e`` an external acceleration the
  accelerometer sees (random walk). Measured by the heading-rotated body-horizontal specific force
  ``(T / M)(a + n) + e`` (the cable's pull: what makes the swing observable without a cable sensor) and by the
  optional cable-angle sensor. With ``mass_load = 0`` these states do not exist (they are unobservable).

Every block's discrete model is a closed form in the step length (``estimators.filters.small_kf``): no matrix
exponential, no cache, the same cost for any step. Measurement noise adapts to the autopilot: each channel's
variance is the larger of its nominal value and the innovation variance not explained by the filter's own
covariance (covariance matching over about ``1 / noise_adapt_rate`` samples), up to ``noise_ceiling`` times the
nominal; where the autopilot reports its position accuracy (:class:`~estimators.model.measurements.ReportedAccuracy`:
ESTIMATOR_STATUS, GPS_RAW_INT) the position channels adapt between the nominal and the reported accuracy instead
(why a bound and not the noise itself: ``docs/estimation.md``). Innovations are chi-square gated
per block; a stream refused ``gate_reopen`` times in a row is let through once.

Time: as in ``estimators.filters.kf``, records are fused in sampling-time order on a horizon ``delay_s`` behind the
output; :meth:`estimate` predicts every block to the output time with the latest measured acceleration, and,
given ``lead_s``, further ahead by that much (the link delay a setpoint needs to reach the vehicle).

The filter is four modules by job: this one, the public :class:`MeasuredKalmanEstimator` (records in, estimate and
read-outs out); ``measured_model`` (:class:`MeasuredTuning`, the blocks, the adapted channel noise);
``measured_predict`` (the blocks' models and predictions, a mixin) and ``measured_update`` (the gated updates, a
mixin).
"""

from __future__ import annotations

import heapq
import math
from collections import deque

import numpy as np

from estimators.filters.fusion import BASE_STATS, RecordFusion, check_rates, chi2_quantile
from estimators.filters.measured_model import (
    KIN,
    RATE,
    SWING,
    Block,
    Channel,
    Gyro,
    MeasuredTuning,
    channel_floors,
    for_line,
    thrust_window,
)
from estimators.filters.measured_predict import MeasuredPrediction
from estimators.filters.measured_update import KINDS, STREAMS, MeasuredUpdates
from estimators.model.control_state import ControlState
from estimators.model.flatness import flat_constants, planar_state
from estimators.model.frames import wrap_angle
from estimators.model.measurements import Attitude, Imu, Measurement, ReportedAccuracy
from estimators.model.vehicle import Vehicle


class MeasuredKalmanEstimator(MeasuredPrediction, MeasuredUpdates, RecordFusion):
    """See the module docstring. vehicle: the controller's nominal vehicle (``mass_load = 0``: no swing states);
    load_sensor: a cable-angle sensor is fitted; rate_hz: the control rate; delay_s: fusion horizon (s)."""

    def __init__(
        self,
        vehicle: Vehicle,
        *,
        load_sensor: bool,
        rate_hz: float,
        tuning: MeasuredTuning = MeasuredTuning(),
        delay_s: float = 0.012,
    ) -> None:
        check_rates(rate_hz, delay_s)
        self.vehicle = vehicle
        #: how many pushed commands the acceleration input's gate looks back over (imu_timeout_s of them)
        self._n_thrust = thrust_window(tuning, rate_hz)
        self.tuning = tn = for_line(tuning, vehicle.cable_length)
        self.delay = float(delay_s)
        self.k = flat_constants(vehicle)
        self.has_load = vehicle.mass_load > 0.0
        self.load_sensor = load_sensor and self.has_load
        self._g = vehicle.gravity
        self._l = vehicle.cable_length
        self._m_over_M = vehicle.mass_load / vehicle.mass_vehicle
        self._gate = {d: chi2_quantile(tn.gate_probability, d) for d in (1, 2, 3)}
        self._rate = tn.noise_adapt_rate
        self._ch = {name: Channel(floor, tn.noise_ceiling) for name, floor in channel_floors(tn).items()}
        self._stats = {
            **dict.fromkeys(BASE_STATS, 0),
            "accuracy_reports": 0,
            **{f"gated_{s}": 0 for s in ("pos", "z", "tilt", "psi", "acc", "acc_in", "load", "gyro")},
            "gyro_fused": 0,
            "gyro_late": 0,
            **{f"records_{k}": 0 for k in KINDS},
            **{f"refused_{k}": 0 for k in KINDS},
        }
        names = []
        for ax in ("x", "y"):
            names += [f"p_{ax}", f"v_{ax}", f"b_{ax}"]
        names += ["z", "z_rate", "b_z", "n_x", "n_x_rate", "n_y", "n_y_rate", "psi", "psi_rate"]
        if self.has_load:
            names += ["alpha_y", "alpha_y_rate", "e_x", "alpha_x", "alpha_x_rate", "e_y"]
        #: the order of :meth:`covariance`
        self.state_names: tuple[str, ...] = tuple(names)
        #: degrees of freedom of :meth:`nees`
        self.nees_dof = 16 if self.has_load else 12
        #: per stream, the newest record's sum of squared normalized innovations and their count (:meth:`innovations`)
        # (and the gyro's, kept apart: the log's innovation columns are the streams both filters share)
        self._nu2 = dict.fromkeys((*STREAMS, "gyro"), 0.0)
        self._nu_n = dict.fromkeys((*STREAMS, "gyro"), 0)
        self._initialized = False

    # ------------------------------------------------------------------------------------------------------
    def initialize(self, t: float, guess: ControlState) -> None:
        """Start at time ``t`` (s) from the prior mean ``guess`` with the tuning's prior covariance."""
        if not (math.isfinite(t) and guess.is_finite()):
            raise ValueError("initialize needs a finite time and a finite ControlState")
        tn = self.tuning
        t = float(t)
        kin_sd = (tn.prior_pos, tn.prior_vel, tn.prior_bias)
        px, py = planar_state(self.k, guess.fx), planar_state(self.k, guess.fy)
        if not self.has_load:  # the chain's swing terms are zero: F = p, F^(4) = c n
            px = (guess.fx[0], guess.fx[1], 0.0, 0.0, guess.fx[4] / self.k.c, guess.fx[5] / self.k.c)
            py = (guess.fy[0], guess.fy[1], 0.0, 0.0, guess.fy[4] / self.k.c, guess.fy[5] / self.k.c)
        blk = Block
        self._kin = [blk(t, [px[0], px[1], 0.0], kin_sd, KIN, 0), blk(t, [py[0], py[1], 0.0], kin_sd, KIN, 1)]
        self._kin.append(blk(t, [guess.z, guess.z_rate, 0.0], kin_sd, KIN, 2))
        tilt_sd = (tn.prior_tilt, tn.prior_tilt_rate)
        self._tilt = [blk(t, [px[4], px[5]], tilt_sd, RATE, 0), blk(t, [py[4], py[5]], tilt_sd, RATE, 1)]
        self._head = blk(t, [guess.psi, guess.psi_rate], (tn.prior_psi, tn.prior_psi_rate), RATE, 0)
        sw_sd = (tn.prior_swing, tn.prior_swing_rate, tn.prior_e)
        self._swing = (
            [blk(t, [px[2], px[3], 0.0], sw_sd, SWING, 0), blk(t, [py[2], py[3], 0.0], sw_sd, SWING, 1)]
            if self.has_load
            else []
        )
        self._blocks = [*self._kin, *self._tilt, self._head, *self._swing]
        self._u = [0.0, 0.0, 0.0]  # measured vehicle acceleration, world NWU, m/s^2 (gravity removed)
        self._q_p = [tn.q_p_min] * 3  # adapted position wander density per axis, m^2/s
        self._y_mean = [0.0, 0.0, 0.0]  # running mean of each axis's position innovation, m
        self._t_imu = -math.inf
        self._u_tilt = (0.0, 0.0)  # commanded world tilt acceleration (x, y), rad/s^2, since the last command
        self._thrusts: deque[float] = deque(maxlen=self._n_thrust)  # the last pushed (delivered) thrusts, N
        self._fz = self._g
        self._t_out = t
        self._pending: list[tuple[float, int, Measurement]] = []
        self._pending_att: list[tuple[float, int, Measurement | Gyro]] = []
        self._gated_run = {"pos": 0, "z": 0, "tilt": 0, "psi": 0, "acc": 0, "acc_in": 0, "load": 0, "gyro": 0}
        self._newest: dict[type, float] = {}  # per kind of horizon-fused record, the newest sampling time pushed
        self._spacing: dict[type, float] = {}  # per kind, the shortest interval seen between its sampling times
        self._start_records(guess)
        self._initialized = True

    def push(self, m: Measurement) -> None:
        """Queue a measurement (any order within the horizon); non-finite, late or unusable records are counted
        and dropped."""
        if not self._admit(m):
            return
        if isinstance(m, ReportedAccuracy):  # applies at once, in the order received (live and replay alike)
            self._ch["pos_xy"].bound(m.pos_h * m.pos_h)
            self._ch["pos_z"].bound(m.pos_v * m.pos_v)
            self._stats["accuracy_reports"] += 1
            return
        if isinstance(m, Attitude):  # fused as soon as the output time passes it (see estimate)
            self._enqueue(self._pending_att, m, self._head.t)
            return
        if isinstance(m, Imu) and self.tuning.fuse_gyro:  # its gyro to the tilt and heading blocks, as the attitude
            if m.t < self._head.t:
                self._stats["gyro_late"] += 1
            else:
                heapq.heappush(self._pending_att, (m.t, self._seq, Gyro(m.t, m.gx, m.gy, m.gz)))
                self._seq += 1
        kind = type(m)
        last = self._newest.get(kind, -math.inf)
        if m.t > last:
            if m.t - last < self._spacing.get(kind, math.inf):
                self._spacing[kind] = m.t - last
            self._newest[kind] = m.t
        self._enqueue(self._pending, m, self._horizon_floor())

    def prefuse(self, t_next: float) -> int:
        """Fuse now, between ticks, what ``estimate(t_next)`` would fuse of the position, IMU and cable-angle records
        already queued: those sampled before ``t_next - delay`` (s) and before the earliest time the next record of
        any stream still streaming (its newest sample within 0.05 s of the newest of all) can have, its newest
        sample plus the shortest interval seen between its samples, so that no record still to come, each
        stream arriving in order, is made late by it. The live loop calls it right after a setpoint has left
        (with the next tick's time: its own plus a period, less half a millisecond so that a record on the 1 ms
        grid is never on the cut) and ``slung replay`` at the same place, so the two stay equal; the next
        estimate then fuses only what arrived since. Attitude records are not touched (``estimate`` fuses them up
        to its output time). Returns the number of records fused."""
        newest = self._newest
        if not (self._initialized and self._pending and newest and math.isfinite(t_next)):
            return 0
        top = max(newest.values())
        spacing = self._spacing
        cut = t_next - self.delay
        for kind, t_new in newest.items():
            if top - t_new <= 0.05:
                cut = min(cut, t_new + spacing.get(kind, 0.0))
        pending = self._pending
        n = 0
        while pending and pending[0][0] <= cut:
            self._fuse(heapq.heappop(pending)[2])
            n += 1
        return n

    def push_command(self, t: float, thrust: float, torque: tuple[float, float, float]) -> None:
        """The command from time ``t`` (s) on: its torques (N m, body FLU) over the inertia, rotated to the world
        with the heading estimate, are the tilt blocks' acceleration input until the next command (``tilt_command``;
        the thrust (N) only widens the acceleration input's gate by what its changes explain, ``thrust_explains_jumps``:
        the accelerometer measures what it does). Non-finite commands are counted and ignored."""
        if not (math.isfinite(t) and math.isfinite(thrust) and all(math.isfinite(v) for v in torque)):
            self._stats["commands_rejected"] += 1
            return
        if self._initialized and self.tuning.thrust_explains_jumps:
            th = self._thrusts
            if not th:  # the first command: the window starts full of it (no change yet)
                th.extend([thrust] * self._n_thrust)
            th.append(thrust)
        if self.tuning.tilt_command and self._initialized:
            i_phi, i_theta, _ = self.vehicle.inertia
            t1, t2 = torque[1] / i_theta, -torque[0] / i_phi  # heading frame: t = [theta, -phi] (smc's convention)
            psi = self._head.x[0]
            cp, sp = math.cos(psi), math.sin(psi)
            self._u_tilt = (cp * t1 - sp * t2, sp * t1 + cp * t2)

    def estimate(self, t: float, lead_s: float = 0.0) -> ControlState:
        """The state at ``t + lead_s`` (s): every queued record sampled before ``t - delay`` fused, then each block
        predicted forward with the latest measured acceleration. ``lead_s`` (>= 0): how much later than ``t`` the
        state is wanted, e.g. the time a setpoint takes to reach the vehicle (the filter's own time is ``t``)."""
        if not self._initialized:
            raise RuntimeError("initialize() the estimator before asking for an estimate")
        if t > self._t_out:
            self._t_out = t
        horizon = min(t - self.delay, self._t_out)
        pending, pending_att = self._pending, self._pending_att
        # attitude first, up to the output time: the tilt and heading blocks take no input, so they need no
        # horizon (the stream arrives in order); their lag is then the link's, not the fusion horizon's
        while pending_att and pending_att[0][0] <= self._t_out:
            self._fuse(heapq.heappop(pending_att)[2])
        while pending and pending[0][0] <= horizon:
            self._fuse(heapq.heappop(pending)[2])
        for b in self._blocks:  # a silent sensor must not leave a block far behind
            if horizon - b.t > 0.05:  # (the attitude blocks may be ahead of the horizon: never moved back)
                self._advance(b, horizon)
        lead = lead_s if lead_s > 0.0 and math.isfinite(lead_s) else 0.0
        est = self._control_state(self._t_out + lead)
        return self._checked(est)

    def covariance(self) -> np.ndarray:
        """Covariance at the last output time, block diagonal, ordered as :attr:`state_names`."""
        ps = [self._predicted(b, self._t_out)[1] for b in self._blocks]
        n = sum(len(p) for p in ps)
        out = np.zeros((n, n))
        i = 0
        for p in ps:
            k = len(p)
            out[i : i + k, i : i + k] = p
            i += k
        return out

    def sigmas(self) -> tuple[float, ...]:
        """Standard deviations at the last output time of ``estimators.filters.factory.SIGMA_NAMES``: F_x, F_y, z (m),
        roll, pitch, heading, alpha_x, alpha_y (rad; NaN without a load), p_x, p_y (m). Only the variances needed
        are predicted, on copies: the filter is not changed. The blocks are independent, so F = p + l a has the
        variance var(p) + l^2 var(a); roll and pitch carry the tilt's and (to first order) the heading's."""
        t = self._t_out
        var0 = self._var0
        vpx, vpy, vz = (var0(b, t) for b in self._kin)
        tx, ty, hd = self._tilt[0], self._tilt[1], self._head
        vnx, vny, vpsi = var0(tx, t), var0(ty, t), var0(hd, t)
        nx, ny, psi = self._mean_at(tx, t)[0], self._mean_at(ty, t)[0], self._mean_at(hd, t)[0]
        cp, sp = math.cos(psi), math.sin(psi)
        theta, phi = nx * cp + ny * sp, nx * sp - ny * cp
        v_theta = cp * cp * vnx + sp * sp * vny + phi * phi * vpsi
        v_phi = sp * sp * vnx + cp * cp * vny + theta * theta * vpsi
        sq = math.sqrt
        if self.has_load:
            vay, vax = var0(self._swing[0], t), var0(self._swing[1], t)
            l2 = self.k.l * self.k.l
            vfx, vfy, s_ax, s_ay = vpx + l2 * vay, vpy + l2 * vax, sq(vax), sq(vay)
        else:
            vfx, vfy, s_ax, s_ay = vpx, vpy, math.nan, math.nan
        return (sq(vfx), sq(vfy), sq(vz), sq(v_phi), sq(v_theta), sq(vpsi), s_ax, s_ay, sq(vpx), sq(vpy))

    def innovations(self) -> tuple[float, ...]:
        """Per stream of ``estimators.filters.factory.INNOVATION_STREAMS`` (pos, z, tilt, psi, acc, load): the newest
        record's RMS over its channels of the normalized innovation ``y / sqrt(h P h + r)`` (each channel as it is
        fused, one after the other; about 1 on average when the filter's covariance and noise match what it sees;
        NaN before the first record; a channel beyond ``sqrt(chi2 gate)``, 3.89 by default, is refused), then the
        cumulative count of refused updates per stream (``gated_<stream>`` of :meth:`stats`). A plain read."""
        nu2, cnt, st = self._nu2, self._nu_n, self._stats
        rms = (math.sqrt(nu2[s] / cnt[s]) if cnt[s] else math.nan for s in STREAMS)
        return (*rms, *(float(st["gated_" + s]) for s in STREAMS))

    def nees(self, t: float, truth: ControlState) -> float:
        """Normalized estimation error squared of (p, v) and (n, n') per axis, (psi, psi'), (z, z') and, with a
        load, (a, a') per axis, against ``truth`` at ``t`` (:attr:`nees_dof` degrees of freedom)."""
        if t > self._t_out:
            self.estimate(t)
        k = self.k
        tx, ty = planar_state(k, truth.fx), planar_state(k, truth.fy)
        if not self.has_load:
            tx = (truth.fx[0], truth.fx[1], 0.0, 0.0, truth.fx[4] / k.c, truth.fx[5] / k.c)
            ty = (truth.fy[0], truth.fy[1], 0.0, 0.0, truth.fy[4] / k.c, truth.fy[5] / k.c)
        pairs = [
            (self._kin[0], tx[0], tx[1]),
            (self._kin[1], ty[0], ty[1]),
            (self._kin[2], truth.z, truth.z_rate),
            (self._tilt[0], tx[4], tx[5]),
            (self._tilt[1], ty[4], ty[5]),
            (self._head, None, truth.psi_rate),
        ]
        if self.has_load:
            pairs += [(self._swing[0], tx[2], tx[3]), (self._swing[1], ty[2], ty[3])]
        total = 0.0
        for b, v0, v1 in pairs:
            x, p = self._predicted(b, self._t_out)
            e0 = wrap_angle(x[0] - truth.psi) if v0 is None else x[0] - v0
            e1 = x[1] - v1
            a, c, d = p[0][0], p[0][1], p[1][1]
            total += (d * e0 * e0 - 2.0 * c * e0 * e1 + a * e1 * e1) / (a * d - c * c)
        return total

    def stats(self) -> dict[str, int]:
        """Counters: accepted (records fused), late_dropped, out_of_order, gated_outliers (records with at least
        one refused update), nan_rejected, gate_reopened, commands_rejected, not_used, nonfinite_resets,
        accuracy_reports (ReportedAccuracy records applied), buffered, gated_<stream> (refused updates: pos, z, tilt,
        psi, acc, load, gyro; acc_in: accelerometer samples refused as the acceleration input), gyro_fused /
        gyro_late (IMU gyro samples fused into the tilt and heading rates / older than those blocks), and per
        measurement kind (pos, att, imu, load) records_<kind> (records fused) and refused_<kind> (of those, records
        with a refused update)."""
        out = dict(self._stats)
        out["buffered"] = len(self._pending) + len(self._pending_att) if self._initialized else 0
        return out

    def noise_bounds(self) -> dict[str, tuple[float, float]]:
        """Per measurement channel, the (lowest, highest) standard deviation its adaptation may reach, SI / rad:
        (nominal, nominal x noise_ceiling) until the autopilot reports its position accuracy, then the position
        channels' lie between the nominal and the reported one."""
        return {name: (math.sqrt(c.floor), math.sqrt(c.ceiling)) for name, c in self._ch.items()}

    def noise_levels(self) -> dict[str, float]:
        """The measurement standard deviations in use (adapted), per channel, SI / rad, and the adapted position
        wander densities ``q_p_x``, ``q_p_y``, ``q_p_z`` (m^2/s)."""
        out = {name: math.sqrt(c.value()) for name, c in self._ch.items()}
        out.update(zip(("q_p_x", "q_p_y", "q_p_z"), self._q_p, strict=True))
        return out


def acceptance(stats: dict[str, int]) -> dict[str, float]:
    """Fraction of the fused records of each kind that every update accepted (``records_<kind>`` > 0 only)."""
    out = {}
    for k in KINDS:
        n = stats.get("records_" + k, 0)
        if n:
            out[k] = 1.0 - stats.get("refused_" + k, 0) / n
    return out


__all__ = ["KINDS", "MeasuredKalmanEstimator", "MeasuredTuning", "acceptance", "thrust_window"]
