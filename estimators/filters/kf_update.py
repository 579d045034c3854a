"""The torque-driven Kalman filter's gated updates (``estimators.filters.kf``): one record fused into the delayed
state, each correction carried to the output.

A mixin of :class:`~estimators.filters.kf.KalmanEstimator` (it uses the estimator's state and its prediction,
``kf_predict``). The horizontal block is updated in place by ``linear_block``'s fast updates; the heading and
height blocks' updates are unrolled over plain floats like their prediction, which pays: 1.3-1.6 us (heading) and
2.0-2.2 us (height) per update, the correction to the output included, against 15.6-16.2 us for
``LinearBlock.update_states`` on the same blocks as numpy arrays (``bench/bench_kf_unrolled.py``, 2026-12-02, the
run of this split, load 3). The two share their shape (gain, covariance, mean, output) but not their size: written
as one loop over the block they would lose what the unrolling buys.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from estimators.filters.fusion import attitude_tilt
from estimators.filters.kf_model import IA, IN, IP
from estimators.filters.linear_block import update_one, update_pair, update_row
from estimators.model.frames import wrap_angle
from estimators.model.measurements import Attitude, Imu, LoadAngle, Measurement, PositionVelocity

#: the in-place updates of :meth:`KfUpdates._update` by kind: adjacent pair, row, one state
_FAST_UPDATES = (update_pair, update_row, update_one)


class KfUpdates:
    """Gated updates of :class:`~estimators.filters.kf.KalmanEstimator` (see the module docstring)."""

    _acc_row: np.ndarray
    _core: list
    _fz: float
    _g: float
    _gate: dict[int, float]
    _gated_run: dict[str, int]
    _hb: Any
    _m_over_M: float
    _out: np.ndarray
    _out_view_h: np.ndarray
    _r: dict[str, Any]
    _stats: dict[str, int]
    _t_out: float
    _ws: Any
    tuning: Any

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
        h = self._t_out - self._core[0].t
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
        x0, x1 = core.x
        p00, p01, p10, p11 = core.p
        gain = self._pair_gain("psi", p00 + r0, p01, p11 + r1, z0 - x0, z1 - x1, gate)
        if gain is None:
            return False
        ia, ib, id_, ys0, ys1 = gain
        dx0, dx1 = ys0 * p00 + ys1 * p01, ys0 * p10 + ys1 * p11
        g00, g01 = p00 * ia + p01 * ib, p00 * ib + p01 * id_  # G = P S^-1
        g10, g11 = p10 * ia + p11 * ib, p10 * ib + p11 * id_
        core.p = [
            p00 - (g00 * p00 + g01 * p01),
            p01 - (g00 * p10 + g01 * p11),
            p10 - (g10 * p00 + g11 * p01),
            p11 - (g10 * p10 + g11 * p11),
        ]
        core.x = [x0 + dx0, x1 + dx1]
        self._gated_run["psi"] = 0
        h = self._t_out - core.t
        out = self._out
        if h > 0.0:
            f00, f01, f10, f11 = self._heading_model(h)[:4]
            out[16] += dx0 * f00 + dx1 * f01
            out[17] += dx0 * f10 + dx1 * f11
        else:
            out[16] += dx0
            out[17] += dx1
        return True

    def _correct_height(self, dx0: float, dx1: float, dx2: float, dx3: float) -> None:
        """Carry a correction of the delayed height state to the output (``Phi(t_out - t_core) dx``)."""
        h = self._t_out - self._core[2].t
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
        x0, x1, x2, x3 = core.x
        p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = core.p
        gain = self._pair_gain("z", p00 + r0, p01, p11 + r1, z0 - x0, z1 - x1, gate)
        if gain is None:
            return False
        ia, ib, id_, ys0, ys1 = gain
        # columns 0 and 1 of P: (p00, p01, p02, p03) and (p01, p11, p12, p13); G = [col0 col1] S^-1
        g00, g01 = p00 * ia + p01 * ib, p00 * ib + p01 * id_
        g10, g11 = p01 * ia + p11 * ib, p01 * ib + p11 * id_
        g20, g21 = p02 * ia + p12 * ib, p02 * ib + p12 * id_
        g30, g31 = p03 * ia + p13 * ib, p03 * ib + p13 * id_
        core.p = [
            p00 - (g00 * p00 + g01 * p01),
            p01 - (g00 * p01 + g01 * p11),
            p02 - (g00 * p02 + g01 * p12),
            p03 - (g00 * p03 + g01 * p13),
            p11 - (g10 * p01 + g11 * p11),
            p12 - (g10 * p02 + g11 * p12),
            p13 - (g10 * p03 + g11 * p13),
            p22 - (g20 * p02 + g21 * p12),
            p23 - (g20 * p03 + g21 * p13),
            p33 - (g30 * p03 + g31 * p13),
        ]
        dx0, dx1, dx2, dx3 = ys0 * p00 + ys1 * p01, ys0 * p01 + ys1 * p11, ys0 * p02 + ys1 * p12, ys0 * p03 + ys1 * p13
        core.x = [x0 + dx0, x1 + dx1, x2 + dx2, x3 + dx3]
        self._gated_run["z"] = 0
        self._correct_height(dx0, dx1, dx2, dx3)
        return True

    def _update_height_acc(self, z: float) -> bool:
        """Gated update of the height block with ``z`` = measured ``z'' - commanded part = d_z + b_z`` (m/s^2):
        :meth:`LinearBlock.update_row` with the row (0, 0, 1, 1), in plain floats."""
        core = self._core[2]
        r = self._r["acc"]
        gate = self._gate[1]
        x0, x1, x2, x3 = core.x
        p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = core.p
        h0, h1, h2, h3 = p02 + p03, p12 + p13, p22 + p23, p23 + p33  # P h
        s = h2 + h3 + r
        y = z - (x2 + x3)
        while not y * y <= gate * s:
            if gate == math.inf or not self._gated("acc_z"):
                return False
            gate = math.inf
        k0, k1, k2, k3 = h0 / s, h1 / s, h2 / s, h3 / s
        core.p = [
            p00 - h0 * k0,
            p01 - h0 * k1,
            p02 - h0 * k2,
            p03 - h0 * k3,
            p11 - h1 * k1,
            p12 - h1 * k2,
            p13 - h1 * k3,
            p22 - h2 * k2,
            p23 - h2 * k3,
            p33 - h3 * k3,
        ]
        dx0, dx1, dx2, dx3 = y * k0, y * k1, y * k2, y * k3
        core.x = [x0 + dx0, x1 + dx1, x2 + dx2, x3 + dx3]
        self._gated_run["acc_z"] = 0
        self._correct_height(dx0, dx1, dx2, dx3)
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
            tilt = attitude_tilt(m.phi, m.theta, m.psi, m.p, m.q, m.r)
            if tilt is None:  # Euler rates singular: pitched to the vertical
                self._stats["not_used"] += 1
                return
            nx, ny, nxd, nyd, psi_rate = tilt
            psi_est = self._core[1].x[0]
            ok &= self._update("tilt", 0, IN, (nx, nxd, ny, nyd), r["tilt"], 4)
            ok &= self._update_heading(psi_est + wrap_angle(m.psi - psi_est), psi_rate)
        elif isinstance(m, Imu):
            self._advance_core(0, t)
            a = self.tuning.accel_gain_filter
            fz = min(max(m.az, 0.2 * self._g), 3.0 * self._g)
            self._fz += a * (fz - self._fz)
            gain = self._m_over_M * self._fz
            psi = self._core[1].x[0]
            cp, sp = math.cos(psi), math.sin(psi)
            row = self._acc_row
            row[IA] = gain
            row[IN] = gain
            z = (cp * m.ax - sp * m.ay, sp * m.ax + cp * m.ay)
            ok &= self._update("acc", 1, row, z, r["acc"], 2)
            # vertical: the world-vertical specific force minus g is z'' = (commanded part) + d_z, plus b_z
            self._advance_core(2, t)
            nx, ny = self._core[0].x[:, IN].tolist()
            theta, phi = nx * cp + ny * sp, nx * sp - ny * cp
            ct = math.cos(theta)
            fz_world = -math.sin(theta) * m.ax + ct * math.sin(phi) * m.ay + ct * math.cos(phi) * m.az
            w_z = self._active_command(self._core[2].t)[3]
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


__all__ = ["KfUpdates"]
