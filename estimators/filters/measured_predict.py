"""The measured-input Kalman filter's prediction (``estimators.filters.measured_kf``): each block's discrete model
for a step with the inputs in force (closed forms, ``estimators.filters.small_kf``), its prediction, and the reads
of a block predicted to the output time that leave the filter as it was.

A mixin of :class:`~estimators.filters.measured_kf.MeasuredKalmanEstimator` (it uses the estimator's blocks
``_kin``, ``_tilt``, ``_head``, ``_swing`` and inputs ``_u``, ``_u_tilt``, ``_t_imu``, ``_q_p``), kept apart from the
gated updates (``measured_update``) and the public class.
"""

from __future__ import annotations

import math
from typing import Any

from estimators.filters.measured_model import KIN, RATE, SWING, Block, MeasuredTuning
from estimators.filters.small_kf import (
    Matrix,
    kinematic_first_row,
    kinematic_model,
    pendulum_first_row,
    pendulum_model,
    pendulum_terms,
    predict,
    predict_kinematic,
    predict_pendulum,
    predict_rate,
    rate_first_row,
    rate_model,
)
from estimators.model.control_state import ControlState
from estimators.model.flatness import control_state_from_tilt


class MeasuredPrediction:
    """Prediction of :class:`~estimators.filters.measured_kf.MeasuredKalmanEstimator`'s blocks (see the module
    docstring)."""

    _g: float
    _head: Block
    _kin: list[Block]
    _l: float
    _q_p: list[float]
    _swing: list[Block]
    _t_imu: float
    _tilt: list[Block]
    _u: list[float]
    _u_tilt: tuple[float, float]
    has_load: bool
    k: Any
    tuning: MeasuredTuning

    def _horizon_floor(self) -> float:
        """The oldest time a position, IMU or cable-angle record may have (the blocks they touch)."""
        return min(b.t for b in (*self._kin, *self._swing))

    def _imu_fresh(self, t: float) -> bool:
        return t - self._t_imu <= self.tuning.imu_timeout_s

    def _kin_inputs(self, b: Block) -> tuple[float, float]:
        """Kinematic block ``b``'s white-acceleration density ``q_v`` ((m/s^2)^2/Hz) and acceleration input ``u``
        (m/s^2) in force: the measured acceleration while the IMU is fresh, else none and the larger density."""
        tn = self.tuning
        if self._imu_fresh(b.t):
            return (tn.q_v if b.axis < 2 else tn.q_vz), self._u[b.axis]
        return tn.q_v_no_imu, 0.0

    def _swing_input(self, b: Block) -> tuple[float, float]:
        """Swing block ``b``'s input ``f`` (rad/s^2) and squared frequency ``w2`` (1/s^2) with the measured acceleration
        in force: ``a'' = -w2 a + f``, ``w2 = (g + u_z) / l``, ``f = -(u - bias) / l`` (none without a fresh IMU)."""
        if self._imu_fresh(b.t):
            w2 = max(self._g + self._u[2], 0.2 * self._g) / self._l
            return -(self._u[b.axis] - self._kin[b.axis].x[2]) / self._l, w2
        return 0.0, self._g / self._l

    def _model(self, b: Block, h: float) -> tuple[Matrix, list[float] | None, float, Matrix]:
        """(Phi, Gamma, input, Q) of block ``b`` for a step ``h`` from its time, with the inputs in force (the
        matrices :meth:`_advance` multiplies out; here for the copies :meth:`_predicted` makes)."""
        tn = self.tuning
        role = b.role
        if role == KIN:
            q_v, u = self._kin_inputs(b)
            phi, gam, q = kinematic_model(h, q_v, tn.q_b, self._q_p[b.axis])
            return phi, gam, u, q
        if role == SWING:
            f, w2 = self._swing_input(b)
            phi, gam, q = pendulum_model(h, w2, tn.q_a, tn.q_e)
            return phi, gam, f, q
        if b is self._head:
            phi, q = rate_model(h, tn.q_psi)
            return phi, None, 0.0, q
        phi, q = rate_model(h, tn.q_n)  # a tilt block: the commanded acceleration as its input
        return phi, [0.5 * h * h, h], self._u_tilt[b.axis], q

    def _advance(self, b: Block, t: float) -> None:
        """Predict ``b`` to ``t`` in place with the inputs in force: :meth:`_model`'s prediction with the transitions'
        zeros and ones multiplied out (``small_kf.predict_kinematic`` and its kin; the same values, a few times
        faster: every record advances two to five blocks)."""
        h = t - b.t
        if h <= 0.0:
            return
        tn = self.tuning
        role = b.role
        if role == KIN:
            q_v, u = self._kin_inputs(b)
            predict_kinematic(b.x, b.p, h, q_v, tn.q_b, self._q_p[b.axis], u)
        elif role == SWING:
            f, w2 = self._swing_input(b)
            predict_pendulum(b.x, b.p, h, w2, tn.q_a, tn.q_e, f)
        elif b is self._head:
            predict_rate(b.x, b.p, h, tn.q_psi, 0.0)
        else:  # a tilt block: the commanded acceleration as its input
            predict_rate(b.x, b.p, h, tn.q_n, self._u_tilt[b.axis])
        b.t = t

    def _predicted(self, b: Block, t: float) -> tuple[list[float], Matrix]:
        """Mean and covariance of ``b`` predicted to ``t`` (copies; ``b`` untouched)."""
        x, p = list(b.x), [list(r) for r in b.p]
        h = t - b.t
        if h > 0.0:
            phi, gam, u, q = self._model(b, h)
            predict(x, p, phi, gam, u, q)
        return x, p

    def _first_row(self, b: Block, h: float) -> tuple[tuple[float, ...], float]:
        """The first row of ``b``'s transition over ``h`` s and the first diagonal entry of its process noise, with
        the inputs in force (the entries of :meth:`_model`'s, computed alone)."""
        tn = self.tuning
        role = b.role
        if role == KIN:
            q_v, _ = self._kin_inputs(b)
            return kinematic_first_row(h, q_v, tn.q_b, self._q_p[b.axis])
        if role == SWING:
            return pendulum_first_row(h, self._swing_input(b)[1], tn.q_a)
        return rate_first_row(h, tn.q_psi if b is self._head else tn.q_n)

    def _var0(self, b: Block, t: float) -> float:
        """The variance of ``b``'s first state predicted to ``t`` (``(Phi P Phi^T + Q)[0][0]``; ``b`` untouched)."""
        p = b.p
        h = t - b.t
        if h <= 0.0:
            return p[0][0]
        f, q00 = self._first_row(b, h)
        # f P f^T unrolled (the replay asks for it 8 times a tick), in the order of the sums it replaces: the same bits
        if len(f) == 3:
            f0, f1, f2 = f
            p0, p1, p2 = p
            r0 = 0.0 + p0[0] * f0 + p0[1] * f1 + p0[2] * f2
            r1 = 0.0 + p1[0] * f0 + p1[1] * f1 + p1[2] * f2
            r2 = 0.0 + p2[0] * f0 + p2[1] * f1 + p2[2] * f2
            return 0.0 + f0 * r0 + f1 * r1 + f2 * r2 + q00
        f0, f1 = f
        p0, p1 = p
        return 0.0 + f0 * (0.0 + p0[0] * f0 + p0[1] * f1) + f1 * (0.0 + p1[0] * f0 + p1[1] * f1) + q00

    def _mean_at(self, b: Block, t: float) -> list[float]:
        """The mean of ``b`` predicted to ``t`` with the inputs in force (closed forms, no covariance)."""
        h = t - b.t
        x = b.x
        if h <= 0.0:
            return list(x)
        if b is self._head:
            return [x[0] + h * x[1], x[1]]
        if b.role == RATE:  # a tilt block: the commanded acceleration held
            u = self._u_tilt[b.axis]
            return [x[0] + h * x[1] + 0.5 * h * h * u, x[1] + h * u]
        if b.role == KIN:
            acc = self._kin_inputs(b)[1] - x[2]
            return [x[0] + h * x[1] + 0.5 * h * h * acc, x[1] + h * acc, x[2]]
        f, w2 = self._swing_input(b)  # a swing block
        c00, c01, c10, c11, g0, g1 = pendulum_terms(h, w2)
        y0, y1 = c00 * x[0] + c01 * x[1], c10 * x[0] + c11 * x[1]
        if f != 0.0:
            return [y0 + g0 * f, y1 + g1 * f, x[2]]
        return [y0, y1, x[2]]

    def _control_state(self, t: float) -> ControlState:
        (px, vx, _), (py, vy, _), (z, z_rate, _) = (self._mean_at(b, t) for b in self._kin)
        nx, nxd = self._mean_at(self._tilt[0], t)
        ny, nyd = self._mean_at(self._tilt[1], t)
        psi, psi_rate = self._mean_at(self._head, t)
        if self.has_load:
            ay_, ayd, e_x = self._mean_at(self._swing[0], t)
            ax_, axd, e_y = self._mean_at(self._swing[1], t)
        else:
            ay_ = ayd = ax_ = axd = e_x = e_y = 0.0
        est = control_state_from_tilt(
            self.k, (px, vx, ay_, ayd, nx, nxd), (py, vy, ax_, axd, ny, nyd), z, z_rate, psi, psi_rate
        )
        if self.has_load and self.tuning.external_feedforward:
            # the external acceleration on the vehicle (e, world, m/s^2) enters F^(4) as (g / l) e (a force d on
            # the vehicle adds (g / (M l)) d to F^(4) = c (a + n)); only the part beyond external_significance of
            # its standard deviations (at the block's last update), so that noise and model error stay out
            k, z_sig = self.k, self.tuning.external_significance
            g_l = k.g / k.l
            fx, fy = est.fx, est.fy
            sx = math.sqrt(self._swing[0].p[2][2])
            sy = math.sqrt(self._swing[1].p[2][2])
            dx = math.copysign(max(abs(e_x) - z_sig * sx, 0.0), e_x)
            dy = math.copysign(max(abs(e_y) - z_sig * sy, 0.0), e_y)
            est = est._replace(
                fx=(fx[0], fx[1], fx[2], fx[3], fx[4] + g_l * dx, fx[5]),
                fy=(fy[0], fy[1], fy[2], fy[3], fy[4] + g_l * dy, fy[5]),
            )
        return est


__all__ = ["MeasuredPrediction"]
