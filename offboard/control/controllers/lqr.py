"""``lqr``: a linear-quadratic regulator on the tangent linearization at hover (``offboard.control.linear_model``), with
the swing angles and rates in the state, integral action on position, height and heading, and the flat reference
as feed-forward.

Design (python-control's ``lqr``): the 16-state model at heading 0 augmented with the integrals of the x, y, z
and heading errors (20 states) and the motors' first-order lag (the vehicle file's ``motor_time_constant_s``: the
delivered thrust and torques as four more states, with no weight of their own; 0 leaves them out), Bryson's rule
for the weights (each state and input divided by the largest deviation one accepts, :class:`LqrWeights`). The
gain is computed once, for the controller's nominal vehicle. The delivered thrust and torques the law feeds back
are its own clipped commands through that lag (as the sliding-mode law's actuation lag, docs/model.md C-13):
without them the design had no margin for 35-40 ms motors, and diverged on light vehicles in the sweep
(docs/compare.md).

Tracking (model frame, SI, rad): the reference's flat outputs give the whole reference state of the linear
model (``estimators.model.flatness``: ``a* = -F*''/g``, ``p* = F* - l a*``, the tilt ``n* = F*^(4)/c - a*``) and the
feed-forward torques from ``n*'' = (F*^(6) + w2 F*^(4)) / c``; the law is ``u = u* - K (x - x*)``. The
horizontal errors are expressed in the heading-aligned frame (where the model at heading psi is the one at
heading 0), so one gain serves every heading. Commands are saturated to the vehicle's limits; the integrators
are held while a command is clipped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from estimators.model.control_state import ControlState
from estimators.model.flatness import flat_constants
from estimators.model.frames import wrap_angle
from estimators.model.vehicle import Vehicle
from offboard.control.linear_model import linear_model
from offboard.control.smc import Command, Ref

#: the augmented state: the 16 of ``offboard.control.linear_model.STATE_NAMES`` then these integrals (m s, rad s)
INTEGRAL_NAMES: tuple[str, ...] = ("int_x", "int_y", "int_z", "int_psi")


@dataclass(frozen=True)
class LqrWeights:
    """Bryson's rule: the largest acceptable deviation of each state group and input (SI, rad).

    pos, vel (m, m/s); z, vz; att, rate (rad, rad/s) for roll/pitch; psi, psi_rate; swing, swing_rate (rad,
    rad/s); int_pos, int_z, int_psi (m s, rad s); thrust (N), torque (N m, roll/pitch), torque_yaw (N m).
    """

    pos: float = 0.05
    vel: float = 0.5
    z: float = 0.02
    vz: float = 0.2
    att: float = 0.3
    rate: float = 3.0
    psi: float = 0.02
    psi_rate: float = 0.5
    swing: float = 0.05
    swing_rate: float = 0.3
    int_pos: float = 0.1
    int_z: float = 0.02
    int_psi: float = 0.05
    thrust: float = 2.0
    torque: float = 0.3
    torque_yaw: float = 0.05

    def matrices(self) -> tuple[np.ndarray, np.ndarray]:
        """(Q, R): diagonal, ``1 / max_deviation^2``."""
        q = [self.pos, self.pos, self.z, self.vel, self.vel, self.vz, self.att, self.att, self.psi]
        q += [self.rate, self.rate, self.psi_rate, self.swing, self.swing, self.swing_rate, self.swing_rate]
        q += [self.int_pos, self.int_pos, self.int_z, self.int_psi]
        r = [self.thrust, self.torque, self.torque, self.torque_yaw]
        return np.diag(1.0 / np.square(q)), np.diag(1.0 / np.square(r))


def augmented_model(vehicle: Vehicle, lag_s: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of the design model: ``offboard.control.linear_model`` at heading 0 plus the error integrals (20
    states); with ``lag_s`` > 0 the motors' first-order lag too, the delivered thrust and torques as four more
    states (``u_a' = (u - u_a) / lag_s``, the plant driven by ``u_a``: 24 states)."""
    lm = linear_model(vehicle, 0.0)
    n = 24 if lag_s > 0.0 else 20
    A = np.zeros((n, n))
    A[:16, :16] = lm.A
    for k, idx in enumerate((0, 1, 2, 8)):  # d/dt int_e = e
        A[16 + k, idx] = 1.0
    B = np.zeros((n, 4))
    if lag_s > 0.0:
        A[:16, 20:24] = lm.B
        A[20:24, 20:24] = -np.eye(4) / lag_s
        B[20:24] = np.eye(4) / lag_s
    else:
        B[:16] = lm.B
    return A, B


def lqr_gain(vehicle: Vehicle, weights: LqrWeights | None = None, lag_s: float = 0.0) -> np.ndarray:
    """The 4 x 20 (4 x 24 with the motors' lag) gain of python-control's ``lqr`` on :func:`augmented_model` with
    :meth:`LqrWeights.matrices` (no weight on the delivered-input states: the commands carry ``R``)."""
    import control

    A, B = augmented_model(vehicle, lag_s)
    Q, R = (weights or LqrWeights()).matrices()
    if lag_s > 0.0:
        Q = np.pad(Q, ((0, 4), (0, 4)))
    K, _, _ = control.lqr(A, B, Q, R)
    return np.asarray(K)


class LqrController:
    """``lqr``: see the module docstring."""

    def __init__(
        self, vehicle: Vehicle, weights: LqrWeights | None = None, name: str = "lqr", lag_s: float | None = None
    ) -> None:
        self.name = name
        self.vehicle = vehicle
        #: the motors' lag in the design (s; default: the vehicle file's ``motor_time_constant_s``, 0: none)
        self.lag_s = vehicle.motor_time_constant if lag_s is None else lag_s
        self.K = lqr_gain(vehicle, weights, self.lag_s)
        self._k = [[float(v) for v in row] for row in self.K]
        self.kf = flat_constants(vehicle)
        self.thrust_max = vehicle.thrust_max
        self.torque_max = (vehicle.roll_pitch_torque_max, vehicle.roll_pitch_torque_max, vehicle.yaw_torque_max)
        self.reset()

    def reset(self) -> None:
        self._int = [0.0, 0.0, 0.0, 0.0]
        self._t: float | None = None
        #: the delivered thrust and torques the law models (its own clipped commands through the motors' lag)
        self._delivered: tuple[float, ...] | None = None
        self._sent = (0.0, 0.0, 0.0, 0.0)

    def step(self, t: float, est: ControlState, ref_fx: Ref, ref_fy: Ref, ref_z: Ref, ref_psi: Ref) -> Command:
        v = self.vehicle
        if not est.is_finite() or not math.isfinite(sum(ref_fx) + sum(ref_fy) + sum(ref_z[:3]) + sum(ref_psi[:3])):
            return Command(v.hover_thrust, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, False, False)
        k = self.kf
        l, g, c, w2 = k.l, k.g, k.c, k.omega2
        dt = 0.0 if self._t is None else max(0.0, t - self._t)
        self._t = t
        # reference state of the linear model from the flat reference, per world axis
        ay_r, ay_rd = -ref_fx[2] / g, -ref_fx[3] / g
        ax_r, ax_rd = -ref_fy[2] / g, -ref_fy[3] / g
        x_r, vx_r = ref_fx[0] - l * ay_r, ref_fx[1] - l * ay_rd
        y_r, vy_r = ref_fy[0] - l * ax_r, ref_fy[1] - l * ax_rd
        nx_r, nxd_r, nxdd_r = ref_fx[4] / c - ay_r, ref_fx[5] / c - ay_rd, (ref_fx[6] + w2 * ref_fx[4]) / c
        ny_r, nyd_r, nydd_r = ref_fy[4] / c - ax_r, ref_fy[5] / c - ax_rd, (ref_fy[6] + w2 * ref_fy[4]) / c
        # the estimate's vehicle position and velocity (F = p + l a)
        x, y = est.fx[0] - l * est.alpha_y, est.fy[0] - l * est.alpha_x
        vx, vy = est.fx[1] - l * est.alpha_y_rate, est.fy[1] - l * est.alpha_x_rate
        # world errors -> heading-aligned frame (rotation by -psi)
        psi = est.psi
        cp, sp = math.cos(psi), math.sin(psi)

        def rot(a: float, b: float) -> tuple[float, float]:
            return cp * a + sp * b, -sp * a + cp * b

        ex, ey = rot(x - x_r, y - y_r)
        evx, evy = rot(vx - vx_r, vy - vy_r)
        eay, eax = rot(est.alpha_y - ay_r, est.alpha_x - ax_r)
        eayd, eaxd = rot(est.alpha_y_rate - ay_rd, est.alpha_x_rate - ax_rd)
        # the reference tilt in the heading frame is [theta*, -phi*]
        th_r, mphi_r = rot(nx_r, ny_r)
        thd_r, mphid_r = rot(nxd_r, nyd_r)
        thdd_r, mphidd_r = rot(nxdd_r, nydd_r)
        ez, evz = est.z - ref_z[0], est.z_rate - ref_z[1]
        epsi, er = wrap_angle(psi - ref_psi[0]), est.psi_rate - ref_psi[1]
        i = self._int
        ints = [i[0] + ex * dt, i[1] + ey * dt, i[2] + ez * dt, i[3] + epsi * dt]
        Ix, Iy, Iz = v.inertia
        ff = (v.total_mass * (g + ref_z[2]), -Ix * mphidd_r, Iy * thdd_r, Iz * ref_psi[2])
        lagged: tuple[float, ...] = ()
        if self.lag_s > 0.0:  # the motors' state: the previous commands through their first-order lag
            d = self._delivered
            if d is None:
                delivered = ff  # at the start the motors give what the reference asks (a flight starts at rest)
            else:
                a = 1.0 - math.exp(-dt / self.lag_s) if dt > 0.0 else 0.0
                delivered = tuple(dj + a * (sj - dj) for dj, sj in zip(d, self._sent))
            self._delivered = delivered
            lagged = tuple(dj - fj for dj, fj in zip(delivered, ff))
        e = (
            ex,
            ey,
            ez,
            evx,
            evy,
            evz,
            est.phi + mphi_r,
            est.theta - th_r,
            epsi,
            est.phi_rate + mphid_r,
            est.theta_rate - thd_r,
            er,
            eay,
            eax,
            eayd,
            eaxd,
            *ints,
            *lagged,
        )
        du = [-sum(kj * ej for kj, ej in zip(row, e)) for row in self._k]
        thrust = ff[0] + du[0]
        tau_phi = ff[1] + du[1]
        tau_theta = ff[2] + du[2]
        tau_psi = ff[3] + du[3]
        sat = False
        if thrust > self.thrust_max or thrust < 0.0:
            thrust, sat = min(max(thrust, 0.0), self.thrust_max), True
        tp, tt, ts = self.torque_max
        clipped = []
        for val, lim in ((tau_phi, tp), (tau_theta, tt), (tau_psi, ts)):
            clipped.append(max(-lim, min(lim, val)))
            sat = sat or abs(val) > lim
        if not sat:
            self._int = ints
        self._sent = (thrust, clipped[0], clipped[1], clipped[2])
        return Command(thrust, clipped[0], clipped[1], clipped[2], ex, ey, ez, epsi, sat, True)

    def memory_fields(self) -> tuple[float, float, float, float]:
        i = self._int
        return i[2], i[3], i[0], i[1]
