"""The measured-input Kalman filter's gated updates (``estimators.filters.measured_kf``): one record fused, channel
by channel, with the adapted measurement noise, the position wander and the accelerometer as the input.

A mixin of :class:`~estimators.filters.measured_kf.MeasuredKalmanEstimator` (it uses the estimator's blocks, its
channels ``_ch`` and its prediction, ``measured_predict``), kept apart from the public class.
"""

from __future__ import annotations

import math
from collections import deque

from estimators.filters.fusion import attitude_tilt
from estimators.filters.measured_model import KIN, Block, Channel, Gyro, MeasuredTuning
from estimators.filters.small_kf import apply_gain, update_one, update_row
from estimators.model.cable import cable_pull
from estimators.model.frames import wrap_angle
from estimators.model.measurements import Attitude, Imu, LoadAngle, Measurement, PositionVelocity
from estimators.model.vehicle import Vehicle

#: measurement kinds, as named in :meth:`MeasuredKalmanEstimator.stats` (``records_<kind>``, ``refused_<kind>``)
KINDS: tuple[str, ...] = ("pos", "att", "imu", "load")
_KIND_OF = {PositionVelocity: "pos", Attitude: "att", Imu: "imu", LoadAngle: "load"}
#: the update streams of each measurement kind (``estimators.filters.factory.INNOVATION_STREAMS``)
_STREAMS_OF = {"pos": ("pos", "z"), "att": ("tilt", "psi"), "imu": ("acc",), "load": ("load",)}
#: the counters of each kind (:meth:`MeasuredKalmanEstimator.stats`), named once
_RECORDS_KEY = {k: "records_" + k for k in KINDS}
_REFUSED_KEY = {k: "refused_" + k for k in KINDS}
STREAMS = ("pos", "z", "tilt", "psi", "acc", "load")


class MeasuredUpdates:
    """Gated updates of :class:`~estimators.filters.measured_kf.MeasuredKalmanEstimator` (see the module docstring)."""

    _ch: dict[str, Channel]
    _fz: float
    _g: float
    _gate: dict[int, float]
    _gated_run: dict[str, int]
    _head: Block
    _kin: list[Block]
    _m_over_M: float
    _nu2: dict[str, float]
    _nu_n: dict[str, int]
    _q_p: list[float]
    _rate: float
    _stats: dict[str, int]
    _swing: list[Block]
    _t_imu: float
    _thrusts: deque[float]
    _tilt: list[Block]
    _u: list[float]
    _y_mean: list[float]
    has_load: bool
    tuning: MeasuredTuning
    vehicle: Vehicle

    def _pair(self, name: str, b: Block, z0: float, z1: float, c0: str, c1: str) -> bool:
        """Gated updates of states 0 and 1 of ``b`` with channels ``c0``, ``c1`` (their adapted variances), one
        channel at a time: a position that jumps (an EKF's GNSS correction) must not cost the velocity its update."""
        if b.role == KIN:
            y0, s0 = z0 - b.x[0], b.p[0][0] + self._ch[c0].value()
            ok0 = self._one(name, b, 0, z0, c0)
            self._learn_wander(b.axis, y0, s0)
        else:
            ok0 = self._one(name, b, 0, z0, c0)
        return self._one(name, b, 1, z1, c1) and ok0

    def _learn_wander(self, i: int, y: float, s: float) -> None:
        """Adapt axis ``i``'s position wander density: white innovations (variance ``s``) keep their running mean
        within 3 sigma of 0 (``var = s lam / (2 - lam)``); a mean beyond that means the position moves apart from the
        integrated velocity, so the density grows (x1.2 per update), else it decays (x0.995)."""
        tn = self.tuning
        lam = tn.wander_rate
        m = self._y_mean[i] + lam * (max(-3.0, min(3.0, y / math.sqrt(s))) * math.sqrt(s) - self._y_mean[i])
        self._y_mean[i] = m
        q = self._q_p[i] * (1.2 if m * m > 9.0 * s * lam / (2.0 - lam) else 0.995)
        self._q_p[i] = min(max(q, tn.q_p_min), tn.q_p_max)

    def _innovation(self, name: str, y: float, s: float) -> None:
        """Add the squared normalized innovation ``y^2 / s`` to stream ``name``'s sum for this record."""
        self._nu2[name] += y * y / s
        self._nu_n[name] += 1

    def _one(self, name: str, b: Block, i: int, z: float, chan: str) -> bool:
        """Gated update of ``b``'s state ``i`` measured directly (``small_kf.update_one``, its gate test written out
        here: 12-16 of these per control tick), the innovation counted and the channel's noise learned."""
        ch = self._ch[chan]
        r = ch.value()
        x, p = b.x, b.p
        pii = p[i][i]
        y = z - x[i]
        s = pii + r
        self._nu2[name] += y * y / s  # as _innovation
        self._nu_n[name] += 1
        gate = self._gate[1]
        ok = s > 0.0 and y * y <= gate * s
        if ok:
            apply_gain(x, p, [row[i] for row in p], y, s)
            self._gated_run[name] = 0
        elif self._gated(name):
            update_one(x, p, i, z, r, math.inf)
        ch.learn(y, pii, r, gate, self._rate)
        return ok

    def _row(self, name: str, b: Block, hrow: list[float], z: float, chan: str, extra_r: float = 0.0) -> bool:
        ch = self._ch[chan]
        r = ch.value() + extra_r
        gate = self._gate[1]
        ok, y, ph = update_row(b.x, b.p, hrow, z, r, gate)
        self._innovation(name, y, ph + r)
        if not ok and self._gated(name):
            update_row(b.x, b.p, hrow, z, r, math.inf)
        ch.learn(y, ph + extra_r, r - extra_r, gate, self._rate)
        if ok:
            self._gated_run[name] = 0
        return ok

    def _fuse(self, m: Measurement | Gyro) -> None:
        kind = _KIND_OF.get(type(m))  # by the exact type: one dict look-up, not a chain of isinstance
        if kind is None:  # the IMU's gyro, queued with the attitude records
            assert isinstance(m, Gyro), f"not a measurement record: {type(m).__name__}"
            self._fuse_gyro(m)
            return
        t = m.t
        ok = True
        nu2, cnt = self._nu2, self._nu_n
        for s in _STREAMS_OF[kind]:  # this record's innovations replace the previous record's
            nu2[s] = 0.0
            cnt[s] = 0
        if kind == "pos":
            kx, ky, kz = self._kin
            advance = self._advance
            advance(kx, t)
            advance(ky, t)
            advance(kz, t)
            ok &= self._pair("pos", kx, m.x, m.vx, "pos_xy", "vel_xy")
            ok &= self._pair("pos", ky, m.y, m.vy, "pos_xy", "vel_xy")
            ok &= self._pair("z", kz, m.z, m.vz, "pos_z", "vel_z")
        elif kind == "att":
            tilt = attitude_tilt(m.phi, m.theta, m.psi, m.p, m.q, m.r)
            if tilt is None:  # Euler rates singular: pitched to the vertical
                self._stats["not_used"] += 1
                return
            nx, ny, nxd, nyd, psi_rate = tilt
            tx, ty, hd = self._tilt[0], self._tilt[1], self._head
            advance = self._advance
            advance(tx, t)
            advance(ty, t)
            advance(hd, t)
            ok &= self._pair("tilt", tx, nx, nxd, "tilt", "tilt_rate")
            ok &= self._pair("tilt", ty, ny, nyd, "tilt", "tilt_rate")
            psi_est = hd.x[0]
            ok &= self._pair("psi", hd, psi_est + wrap_angle(m.psi - psi_est), psi_rate, "yaw", "yaw_rate")
        elif kind == "imu":
            ok = self._fuse_imu(m)
        else:  # a cable angle
            sy, sx = self._swing
            self._advance(sy, t)
            self._advance(sx, t)
            ok &= self._row("load", sy, [1.0, 0.0, 0.0], m.alpha_y, "load")
            ok &= self._row("load", sx, [1.0, 0.0, 0.0], m.alpha_x, "load")
        st = self._stats
        st["accepted"] += 1
        st[_RECORDS_KEY[kind]] += 1
        if not ok:
            st["gated_outliers"] += 1
            st[_REFUSED_KEY[kind]] += 1

    def _fuse_imu(self, m: Imu) -> bool:
        """The accelerometer: the swing measurement (with a load), then the new acceleration input from ``m.t``."""
        t = m.t
        for b in (*self._kin, *self._swing):  # the input changes here: every block that uses it is brought to this time
            self._advance(b, t)
        for b in (*self._tilt, self._head):  # usually already ahead (fused as they arrive)
            if b.t < t:
                self._advance(b, t)
        # the attitude at the sample's time (the tilt and heading blocks may already be a few ms ahead)
        tx, ty, hd = self._tilt[0], self._tilt[1], self._head
        nx = tx.x[0] - tx.x[1] * (tx.t - t)
        ny = ty.x[0] - ty.x[1] * (ty.t - t)
        psi = hd.x[0] - hd.x[1] * (hd.t - t)
        cp, sp = math.cos(psi), math.sin(psi)
        theta, phi = nx * cp + ny * sp, nx * sp - ny * cp
        sf, cf, st, ct = math.sin(phi), math.cos(phi), math.sin(theta), math.cos(theta)
        ax, ay, az = m.ax, m.ay, m.az
        # heading frame (yaw removed): f_h = Ry(theta) Rx(phi) f; world = Rz(psi) f_h
        hx = ct * ax + st * sf * ay + st * cf * az
        hy = cf * ay - sf * az
        hz = -st * ax + ct * sf * ay + ct * cf * az
        u = [cp * hx - sp * hy, sp * hx + cp * hy, hz - self._g]
        ok = True
        if self.has_load:  # the cable's pull (estimators.model.cable.cable_pull), linearized at the estimate
            # the vertical specific force g + u_z low-passed: the instantaneous one (the height loop's thrust
            # steps, aliased into 50 Hz samples) doubled the estimate's error on a 30 m line (tests/test_long_lines)
            self._fz += self.tuning.accel_gain_filter * (min(max(hz, 0.2 * self._g), 3.0 * self._g) - self._fz)
            bx, by = cp * ax - sp * ay, sp * ax + cp * ay  # body-horizontal specific force, heading-rotated
            mm, ln, fz = self._m_over_M, self._l, self._fz
            sx, sy = self._swing
            for b, o, n, z, tb, ua, uo in ((sx, sy, nx, bx, tx, u[0], u[1]), (sy, sx, ny, by, ty, u[1], u[0])):
                x, xo = b.x, o.x
                h, h_a, h_ad, h_n = cable_pull(mm, ln, x[0], x[1], xo[0], xo[1], n, ua, uo, fz)
                # the innovation z - h - e as the row's z - H x; the tilt's own uncertainty adds to the noise
                zr = z - h + h_a * x[0] + h_ad * x[1]
                ok &= self._row("acc", b, [h_a, h_ad, 1.0], zr, "acc", h_n * h_n * tb.p[0][0])
        if self._imu_fresh(t):  # as an input, the sample must be plausible next to the previous one
            ch = self._ch["acc_in"]
            var = ch.value()
            gate = self._gate[3]
            u0 = self._u
            dy = (u[0] - u0[0], u[1] - u0[1], u[2] - u0[2])
            # What the commanded thrust can explain: a thrust change dT moves the vehicle's specific force by at
            # most dT / M (the load's inertia only lessens it); the change between two samples lies within the
            # range of the thrusts pushed over the last imu_timeout_s (the samples' latency puts it a few tens of
            # ms before their fusion). Without it the gate refused the height law's own thrust steps (12 m/s^2 on
            # a 0.36 kg vehicle) for up to 0.1 s, the held input drove the height estimate off and the law's next
            # thrust steps were refused in turn: 25 of 200 sweep runs diverged (docs/compare.md).
            th = self._thrusts
            jump = (max(th) - min(th)) / self.vehicle.mass_vehicle if th else 0.0
            plausible = dy[0] * dy[0] + dy[1] * dy[1] + dy[2] * dy[2] <= gate * var + jump * jump
            for d in dy:
                ch.learn(d, 0.0, var, gate, self._rate)
            if plausible:
                self._gated_run["acc_in"] = 0
            elif not self._gated("acc_in"):
                return False  # the previous input stays in force (until it is too old)
        self._u = u
        self._t_imu = t
        return ok

    def _fuse_gyro(self, m: Gyro) -> None:
        """The IMU's body rates as a measurement of the tilt rates and the heading rate (the attitude at the sample's
        time from the blocks themselves, which the ATTITUDE stream keeps within a fraction of a degree)."""
        t = m.t
        self._nu2["gyro"], self._nu_n["gyro"] = 0.0, 0
        tx, ty, hd = self._tilt[0], self._tilt[1], self._head
        for b in (tx, ty, hd):
            self._advance(b, t)
        nx, ny, psi = tx.x[0], ty.x[0], hd.x[0]
        cp, sp = math.cos(psi), math.sin(psi)
        theta, phi = nx * cp + ny * sp, nx * sp - ny * cp
        tilt = attitude_tilt(phi, theta, psi, m.p, m.q, m.r)
        if tilt is None:  # Euler rates singular: pitched to the vertical
            return
        _, _, nxd, nyd, psi_rate = tilt
        self._one("gyro", tx, 1, nxd, "gyro_rate")
        self._one("gyro", ty, 1, nyd, "gyro_rate")
        self._one("gyro", hd, 1, psi_rate, "gyro_yaw_rate")
        self._stats["gyro_fused"] += 1


__all__ = ["KINDS", "STREAMS", "MeasuredUpdates"]
