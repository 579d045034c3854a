"""``cascade``: the swing-unaware position cascade of a stock autopilot (PX4's ``mc_pos_control`` +
``mc_att_control`` + ``mc_rate_control``, ArduPilot's ``AC_PosControl`` + ``AC_AttitudeControl``), the row a
user gets without slung.

Structure, as in both autopilots (model frame: world NWU z up, body FLU, SI, rad):

1. position P with velocity feed-forward: ``v_sp = v_ref + K_p (p_ref - p)`` (PX4 ``MPC_XY_P`` 0.95 1/s,
   ``MPC_Z_P`` 1.0 1/s), the speed limited (``MPC_XY_VEL_MAX`` 12 m/s, ``MPC_Z_VEL_MAX_UP`` 3 m/s);
2. velocity PID with acceleration feed-forward: ``a_sp = a_ref + K_v e_v + K_i int(e_v) - K_d v'``
   (``MPC_XY_VEL_P_ACC`` 1.8, ``_I_ACC`` 0.4, ``_D_ACC`` 0.2; ``MPC_Z_VEL_P_ACC`` 4, ``_I_ACC`` 2), integrator
   held while the output saturates;
3. thrust vector ``T = M_t (a_sp + g e_z)``, tilt limited (``MPC_TILTMAX_AIR`` 45 deg), collective thrust
   ``|T|`` and the attitude whose body z axis is ``T / |T|`` at the reference heading (PX4's
   ``thrustToAttitude``);
4. attitude P -> body-rate setpoint (``MC_ROLL_P`` / ``MC_PITCH_P`` 6.5, ``MC_YAW_P`` 2.8) and rate PI -> the
   angular acceleration, times the nominal inertia -> torque (the rate loop's bandwidth is chosen for this
   plant's inertia: PX4's normalized ``MC_*RATE_P`` does not carry over to a torque-level plant).

The controlled point is the vehicle (position ``p = F - l a``, the flat output minus the swing offset); its
reference is the load's reference ``F*``: with the load at rest below it the two coincide. The swing is neither
measured nor used: that is what "swing-unaware" means, and why the load swings freely after a move.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from estimators.model.control_state import ControlState
from estimators.model.flatness import world_tilt
from estimators.model.frames import wrap_angle
from estimators.model.vehicle import Vehicle
from offboard.control.smc import Command, Ref


@dataclass(frozen=True)
class CascadeGains:
    """Gains of the position / velocity / attitude / rate cascade (PX4's defaults where they carry over).

    kp_xy, kp_z (1/s): position P; kv_xy, ki_xy, kd_xy, kv_z, ki_z: velocity PID (1/s, 1/s^2, -); vel_max_xy,
    vel_max_z (m/s); tilt_max (rad); kp_att, kp_yaw (1/s): attitude P; kr_rp, ki_rp, kr_yaw (1/s, 1/s^2):
    body-rate PI as angular acceleration per rate error; yaw_rate_max (rad/s).
    """

    kp_xy: float = 0.95
    kp_z: float = 1.0
    kv_xy: float = 1.8
    ki_xy: float = 0.4
    kd_xy: float = 0.2
    kv_z: float = 4.0
    ki_z: float = 2.0
    vel_max_xy: float = 12.0
    vel_max_z: float = 3.0
    tilt_max: float = math.radians(45.0)
    kp_att: float = 6.5
    kp_yaw: float = 2.8
    kr_rp: float = 25.0
    ki_rp: float = 5.0
    kr_yaw: float = 10.0
    yaw_rate_max: float = math.radians(200.0)


class AttitudeThrustLoop:
    """Steps 3 and 4 of the cascade: acceleration setpoint (world, m/s^2) + heading -> thrust (N) and body
    torques (N m), with the autopilot's tilt limit, rate PI and the vehicle's thrust and torque limits. Shared by
    every position-level baseline (cascade, input shaping, swing feedback, LQR's outer part does not use it).

    ``attitude_sp``: the attitude setpoint of the last call (roll, pitch, heading, rad; None before the first),
    what a stock autopilot's position controller hands its attitude controller (``slung compare --mavlink`` sends
    it as the attitude setpoint)."""

    __slots__ = ("_i_p", "_i_q", "_t", "attitude_sp", "g", "gains", "inertia", "mass", "thrust_max", "torque_max")

    def __init__(self, vehicle: Vehicle, gains: CascadeGains) -> None:
        self.gains = gains
        self.mass = vehicle.total_mass
        self.g = vehicle.gravity
        self.inertia = vehicle.inertia
        self.thrust_max = vehicle.thrust_max
        self.torque_max = (vehicle.roll_pitch_torque_max, vehicle.roll_pitch_torque_max, vehicle.yaw_torque_max)
        self.reset()

    def reset(self) -> None:
        self._i_p = 0.0
        self._i_q = 0.0
        self._t: float | None = None
        self.attitude_sp: tuple[float, float, float] | None = None

    def __call__(
        self, t: float, est: ControlState, ax: float, ay: float, az: float, psi_ref: tuple[float, ...]
    ) -> tuple[float, float, float, float, bool, bool]:
        """(thrust, tau_phi, tau_theta, tau_psi, saturated, tilt_limited) for the acceleration setpoint
        (ax, ay, az) (world NWU, m/s^2) and the heading reference (rad, orders 0..2)."""
        G = self.gains
        dt = 0.0 if self._t is None else max(0.0, t - self._t)
        self._t = t
        # thrust vector per unit mass (world), tilt limited as PX4 does (keep the vertical part, shrink the
        # horizontal one)
        tz = az + self.g
        tz = max(tz, 0.1 * self.g)  # never command a downward or vanishing thrust
        h = math.hypot(ax, ay)
        h_max = tz * math.tan(G.tilt_max)
        tilt_limited = h > h_max
        if tilt_limited:
            ax, ay = ax * h_max / h, ay * h_max / h
        thrust = self.mass * math.sqrt(ax * ax + ay * ay + tz * tz)
        # desired body z in the heading-aligned frame -> desired roll and pitch (ZYX, FLU)
        psi_d = psi_ref[0]
        cp, sp = math.cos(psi_d), math.sin(psi_d)
        zx, zy = cp * ax + sp * ay, -sp * ax + cp * ay
        norm = math.sqrt(zx * zx + zy * zy + tz * tz)
        phi_d = math.asin(max(-1.0, min(1.0, -zy / norm)))
        theta_d = math.atan2(zx, tz)
        self.attitude_sp = (phi_d, theta_d, psi_d)
        # attitude P -> rates, rate PI -> angular acceleration -> torque
        p_sp = G.kp_att * (phi_d - est.phi)
        q_sp = G.kp_att * (theta_d - est.theta)
        ref_rate = psi_ref[1] if len(psi_ref) > 1 else 0.0
        r_sp = ref_rate + G.kp_yaw * wrap_angle(psi_d - est.psi)
        r_sp = max(-G.yaw_rate_max, min(G.yaw_rate_max, r_sp))
        e_p, e_q = p_sp - est.phi_rate, q_sp - est.theta_rate
        i_p = self._i_p + e_p * dt
        i_q = self._i_q + e_q * dt
        Ix, Iy, Iz = self.inertia
        tau_phi = Ix * (G.kr_rp * e_p + G.ki_rp * i_p)
        tau_theta = Iy * (G.kr_rp * e_q + G.ki_rp * i_q)
        tau_psi = Iz * (G.kr_yaw * (r_sp - est.psi_rate) + (psi_ref[2] if len(psi_ref) > 2 else 0.0))
        sat = False
        tp, tt, ts = self.torque_max
        if abs(tau_phi) > tp:
            tau_phi, sat = math.copysign(tp, tau_phi), True
        else:
            self._i_p = i_p
        if abs(tau_theta) > tt:
            tau_theta, sat = math.copysign(tt, tau_theta), True
        else:
            self._i_q = i_q
        if abs(tau_psi) > ts:
            tau_psi, sat = math.copysign(ts, tau_psi), True
        if thrust > self.thrust_max:
            thrust, sat = self.thrust_max, True
        return thrust, tau_phi, tau_theta, tau_psi, sat, tilt_limited


def vehicle_position(est: ControlState, l: float) -> tuple[float, float, float, float]:
    """Vehicle horizontal position and velocity (x, y, vx, vy; m, m/s, world) from the flat outputs and the swing
    (``F = p + l a``, ``estimators.model.flatness``)."""
    return (
        est.fx[0] - l * est.alpha_y,
        est.fy[0] - l * est.alpha_x,
        est.fx[1] - l * est.alpha_y_rate,
        est.fy[1] - l * est.alpha_x_rate,
    )


class CascadeController:
    """``cascade``: the swing-unaware stock position cascade (see the module docstring).

    :meth:`offsets` is the hook the swing-feedback baseline overrides; ``name``: the row name.
    """

    #: a position-level controller: over ``--output attitude`` it sends its attitude setpoint (``flight_output``)
    level = "position"

    def __init__(self, vehicle: Vehicle, gains: CascadeGains | None = None, name: str = "cascade") -> None:
        self.name = name
        self.vehicle = vehicle
        self.gains = gains or CascadeGains()
        self.l = vehicle.cable_length
        self._mt, self._m = vehicle.total_mass, vehicle.mass_load
        self._acc_gain = vehicle.gravity / vehicle.mass_vehicle
        self.inner = AttitudeThrustLoop(vehicle, self.gains)
        self.reset()

    def reset(self) -> None:
        self.inner.reset()
        self._ivx = self._ivy = self._ivz = 0.0
        self._t: float | None = None

    @property
    def attitude_sp(self) -> tuple[float, float, float] | None:
        """The attitude setpoint of the last step (roll, pitch, heading, rad; None before the first)."""
        return self.inner.attitude_sp

    def offsets(self, t: float, est: ControlState) -> tuple[float, float, float, float, float, float]:
        """Horizontal offsets added to the position (m), velocity (m/s) and acceleration (m/s^2) setpoints, world
        (x, y each): none for the stock cascade (the swing-feedback baseline's hook)."""
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0

    def step(self, t: float, est: ControlState, ref_fx: Ref, ref_fy: Ref, ref_z: Ref, ref_psi: Ref) -> Command:
        if not est.is_finite() or not math.isfinite(sum(ref_fx[:3]) + sum(ref_fy[:3]) + sum(ref_z[:3]) + ref_psi[0]):
            return _hover(self.vehicle)
        G = self.gains
        dt = 0.0 if self._t is None else max(0.0, t - self._t)
        self._t = t
        x, y, vx, vy = vehicle_position(est, self.l)
        ox, oy, ovx, ovy, oax, oay = self.offsets(t, est)
        # 1. position P + velocity feed-forward, speed limited
        vsx = ref_fx[1] + ovx + G.kp_xy * (ref_fx[0] + ox - x)
        vsy = ref_fy[1] + ovy + G.kp_xy * (ref_fy[0] + oy - y)
        vsz = ref_z[1] + G.kp_z * (ref_z[0] - est.z)
        sp = math.hypot(vsx, vsy)
        if sp > G.vel_max_xy:
            vsx, vsy = vsx * G.vel_max_xy / sp, vsy * G.vel_max_xy / sp
        vsz = max(-G.vel_max_z, min(G.vel_max_z, vsz))
        # 2. velocity PID + acceleration feed-forward; D acts on the velocity error's rate, i.e. on the vehicle's
        # acceleration (what PX4 differentiates from its EKF velocity), here its first-order value
        # x'' = g (M_t n + m a) / M (``offboard.control.linear_model``)
        evx, evy, evz = vsx - vx, vsy - vy, vsz - est.z_rate
        ivx, ivy, ivz = self._ivx + evx * dt, self._ivy + evy * dt, self._ivz + evz * dt
        nx, ny, _, _ = world_tilt(est.phi, est.theta, est.psi, 0.0, 0.0, 0.0)
        acc_x = self._acc_gain * (self._mt * nx + self._m * est.alpha_y)
        acc_y = self._acc_gain * (self._mt * ny + self._m * est.alpha_x)
        ax = ref_fx[2] + oax + G.kv_xy * evx + G.ki_xy * ivx - G.kd_xy * (acc_x - ref_fx[2])
        ay = ref_fy[2] + oay + G.kv_xy * evy + G.ki_xy * ivy - G.kd_xy * (acc_y - ref_fy[2])
        az = ref_z[2] + G.kv_z * evz + G.ki_z * ivz
        thrust, tp, tt, ts, sat, tilted = self.inner(t, est, ax, ay, az, ref_psi)
        if not tilted:  # anti-windup: hold the horizontal integrators while the tilt limit clips
            self._ivx, self._ivy = ivx, ivy
        if thrust < self.inner.thrust_max:
            self._ivz = ivz
        return Command(thrust, tp, tt, ts, evx, evy, evz, 0.0, sat or tilted, True)

    def memory_fields(self) -> tuple[float, float, float, float]:
        return self._ivz, math.nan, self._ivx, self._ivy


def _hover(vehicle: Vehicle) -> Command:
    return Command(vehicle.hover_thrust, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, False, False)
