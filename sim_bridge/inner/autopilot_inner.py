"""The emulated autopilot's inner control: parameters pushed into the controllers, the per-step chain
(PX4: attitude P -> rate PID -> allocator -> motors, ``sim_bridge.inner.px4_inner``; ArduPilot:
``sim_bridge.inner.airframe``), attitude tracking, the position and altitude controllers the modes call, and the
estimate the modes fly on.

A mixin: it works on the attributes :class:`sim_bridge.autopilot.Autopilot` sets up (one autopilot, split by
role so that each file has one job); it is not used on its own.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence

from estimators.model.frames import (
    euler_to_quaternion,
    frd_to_model_body,
    model_body_to_frd,
)
from sim_bridge.autopilot_constants import (
    AP_PHYSICAL_THRUST_EXPO,
    ap_stream_groups,
)
from sim_bridge.inner.airframe import (
    angle_boost,
    body_rates,
    px4_vertical_integral,
)
from sim_bridge.inner.ardupilot_inner import limit_tilt, throttle_to_actuator, thrust_curve
from sim_bridge.inner.px4_hover_thrust import IN_AIR_HEIGHT_M, integrator_after_hover_change
from sim_bridge.inner.px4_inner import Px4Motors, allocate_with_saturation_feedback, configure_px4_loops

log = logging.getLogger("sim_bridge.autopilot")


class InnerControl:
    """Inner loops of :class:`sim_bridge.autopilot.Autopilot` (called once per plant step)."""

    def _apply_params(self, changed: str | None = None) -> None:
        """Push parameter values into the controllers (at start and after every PARAM_SET of ``changed``)."""
        att, pos = self.att, self.pos
        if self.fl.is_px4:
            rotors = configure_px4_loops(self._p, self.px4_att, self.px4_rate, self.px4_alloc, changed)
            if rotors is not None:
                self.px4_motors = Px4Motors(self.vehicle, rotors, self.dt)
            pos.xy_p, pos.z_p = self._p("MPC_XY_P"), self._p("MPC_Z_P")
            pos.xy_vel_p, pos.xy_vel_i = self._p("MPC_XY_VEL_P_ACC"), self._p("MPC_XY_VEL_I_ACC")
            pos.z_vel_p, pos.z_vel_i = self._p("MPC_Z_VEL_P_ACC"), self._p("MPC_Z_VEL_I_ACC")
            pos.xy_speed_max = self._p("MPC_XY_CRUISE")
            pos.z_speed_up, pos.z_speed_down = self._p("MPC_Z_VEL_MAX_UP"), self._p("MPC_Z_VEL_MAX_DN")
            pos.tilt_max = math.radians(min(self._p("MPC_TILTMAX_AIR"), 60.0))
            pos.px4_vertical_integrator = True
            # PX4's position controller takes MPC_THR_HOVER at start and when it is set; with MPC_USE_HTE the
            # hover thrust estimator then takes over in flight (_learn_hover_px4)
            if changed in (None, "MPC_THR_HOVER") or not self.px4_hover.valid:
                self.hover_norm = self._p("MPC_THR_HOVER")
            self.px4_hover.p = {k: self._p(k) for k in self.px4_hover.p}
            if changed == "MPC_THR_HOVER":
                self.px4_hover.reset(self.hover_norm)
        else:
            att.att_p = [self._p("ATC_ANG_RLL_P"), self._p("ATC_ANG_PIT_P"), self._p("ATC_ANG_YAW_P")]
            att.rate_p = [self._p("ATC_RAT_RLL_P"), self._p("ATC_RAT_PIT_P"), self._p("ATC_RAT_YAW_P")]
            att.rate_i = [self._p("ATC_RAT_RLL_I"), self._p("ATC_RAT_PIT_I"), self._p("ATC_RAT_YAW_I")]
            pos.xy_p, pos.z_p = self._p("PSC_POSXY_P"), self._p("PSC_POSZ_P")
            pos.xy_vel_p, pos.z_vel_p = self._p("PSC_VELXY_P"), self._p("PSC_VELZ_P")
            pos.xy_speed_max = self._p("WPNAV_SPEED") / 100.0
            pos.z_speed_up, pos.z_speed_down = self._p("WPNAV_SPEED_UP") / 100.0, self._p("WPNAV_SPEED_DN") / 100.0
            pos.tilt_max = math.radians(min(self._p("ANGLE_MAX") / 100.0, 60.0))
            self.hover_norm = self._p("MOT_THST_HOVER")
            groups = ap_stream_groups()
            if changed in groups:
                hz = self._p(changed)
                for n in groups[changed]:
                    self._set_interval(n, int(1e6 / hz) if hz > 0 else 0)

    # ================================================================== per-step
    def control(self, x: Sequence[float], on_ground: bool) -> tuple[float, float, float, float]:
        """Inner loops for one plant step: returns the actual (thrust N, tau FLU N m) after mixer and motors."""
        if self.ekf is not None:
            x = self._believed(x)
        self.x = x
        self.on_ground = on_ground
        mixer = self.mixer
        if self.fl.is_px4:
            return self._control_px4(x, on_ground)
        if not self.armed or self.terminated:
            mixer.cmd = [0.0, 0.0, 0.0, 0.0]
            self.thrust_cmd = 0.0
            return mixer.step()
        k = self.k
        if k & 3 == 0:
            self._outer(x, on_ground)
        if k & 1 == 0:  # rate loop + mixer at 500 Hz (PX4's IMU_GYRO_RATEMAX default is 400 Hz)
            if self.direct_tau is not None:
                tx, ty, tz = self.direct_tau
            else:
                w = body_rates(x[6], x[7], x[9], x[10], x[11])
                tx, ty, tz = self.att.rates_to_torque(self.rate_sp, w, not on_ground)
            # ArduPilot linearizes its throttle with MOT_THST_EXPO; the rotors follow their physical curve
            act = throttle_to_actuator(self.thrust_cmd / self.tmax, self._p("MOT_THST_EXPO"))
            mixer.allocate(thrust_curve(act, AP_PHYSICAL_THRUST_EXPO) * self.tmax, tx, ty, tz)
        return mixer.step()

    def _believed(self, x: Sequence[float]) -> list[float]:
        """The state as the autopilot's estimator has it: position, velocity, roll and pitch with the EKF-like
        error."""
        e, v = self.ekf.e, self.ekf.ev  # type: ignore[union-attr]
        xe = list(x)
        tilt = self.ekf.tilt  # type: ignore[union-attr]
        xe[6] += tilt[0]
        xe[7] += tilt[1]
        xe[0] += e[0]
        xe[1] += e[1]
        xe[2] += e[2]
        xe[3] += v[0]
        xe[4] += v[1]
        xe[5] += v[2]
        return xe

    def _control_px4(self, x: Sequence[float], on_ground: bool) -> tuple[float, float, float, float]:
        """PX4's chain: attitude P (250 Hz) -> rate PID -> allocator (500 Hz) -> motors with lag (1 kHz)."""
        motors = self.px4_motors
        if not self.armed or self.terminated:
            motors.command([0.0, 0.0, 0.0, 0.0])
            self.thrust_cmd = 0.0
            self.px4_rate.reset_integral()
        else:
            k = self.k
            if k & 3 == 0:
                self._outer(x, on_ground)
            if k & 1 == 0:  # rate loop + allocator at 500 Hz (SIH's gyro runs at IMU_GYRO_RATEMAX 400-800 Hz)
                if self.direct_tau is not None:  # SET_ACTUATOR_CONTROL_TARGET: normalized torques, FRD
                    tn = self.direct_tau
                else:
                    gyro = model_body_to_frd(*body_rates(x[6], x[7], x[9], x[10], x[11]))
                    if self.ekf is not None:  # the estimate model's gyro noise (SIH's 250 Hz gyro: a draw per 4 ms)
                        if k & 3 == 0:
                            self.gyro_noise = self.ekf.gyro_noise_frd()
                        n = self.gyro_noise
                        gyro = (gyro[0] + n[0], gyro[1] + n[1], gyro[2] + n[2])
                    rate_sp = model_body_to_frd(*self.rate_sp)
                    tn = self.px4_rate.update(rate_sp, gyro, on_ground)
                self.torque_norm_sp = tn
                self.motor_cmd = allocate_with_saturation_feedback(
                    self.px4_alloc, self.px4_rate, tn, self.thrust_cmd / self.tmax
                )
                motors.command(self.motor_cmd)
        t, rx, ry, rz = motors.step()
        tx, ty, tz = frd_to_model_body(rx, ry, rz)
        return t, tx, ty, tz

    def _q_now(self, x: Sequence[float]) -> tuple[float, float, float, float]:
        return euler_to_quaternion(x[6], x[7], x[8])

    def _level_q(self, yaw: float) -> tuple[float, float, float, float]:
        return euler_to_quaternion(0.0, 0.0, yaw)

    def _idle(self, x: Sequence[float]) -> None:
        """On the ground with nowhere to go: motors at zero thrust, integrators cleared."""
        self.thrust_cmd = 0.0
        self.q_sp = self._q_now(x)
        self.rate_sp = (0.0, 0.0, 0.0)
        self.att.reset()
        self.px4_rate.reset_integral()
        self.ap_shaper.reset(self.q_sp)
        self.pos.reset()

    def _track_attitude(self, x: Sequence[float], qd: tuple[float, ...], thrust_n: float, yaw_ff: float) -> None:
        self.q_sp = qd  # type: ignore[assignment]
        if self.fl.is_px4:
            self.rate_sp = self.px4_att.update(self._q_now(x), qd, yaw_ff)  # type: ignore[arg-type]
        else:
            # ArduPilot: the request's tilt limited to ANGLE_MAX, an input-shaped attitude target (ATC_INPUT_TC),
            # tracked with ATC_ANG_*_P plus the target's rate as feed-forward
            q_now = self._q_now(x)
            q_req = limit_tilt(qd, math.radians(self._p("ANGLE_MAX") / 100.0))  # type: ignore[arg-type]
            q_t, ff = self.ap_shaper.update(q_now, q_req, 4 * self.dt, yaw_ff)
            r = self.att.attitude_to_rates(q_now, q_t, 0.0)
            m = self.att.rate_max
            self.rate_sp = tuple(min(max(r[i] + ff[i], -m[i]), m[i]) for i in range(3))  # type: ignore[assignment]
        self.thrust_cmd = min(max(thrust_n, 0.0), self.tmax)

    def _position(
        self,
        x: Sequence[float],
        pos_sp: tuple[float | None, ...],
        vel_ff: tuple[float, float, float],
        yaw: float,
        dt: float,
        on_ground: bool,
        z_up: float | None = None,
    ) -> None:
        if on_ground and (pos_sp[2] is None or pos_sp[2] < 0.1) and vel_ff[2] <= 0.0:
            self._idle(x)
            return
        q, thr = self.pos.update(
            (x[0], x[1], x[2]),
            (x[3], x[4], x[5]),
            pos_sp,
            vel_ff,
            yaw,  # type: ignore[arg-type]
            self.hover_norm,
            dt,
            z_speed_up=z_up,
        )
        self.pos_control_ran = True
        self._track_attitude(x, q, thr * self.tmax, 0.0)

    def _vertical_thrust(self, x: Sequence[float], z_sp: float, vz_ff: float, dt: float) -> float:
        """Altitude controller (P on height, PI on climb rate) -> normalized thrust before angle boost."""
        pc = self.pos
        vz = vz_ff + pc.z_p * (z_sp - x[2])
        vz = min(max(vz, -pc.z_speed_down), pc.z_speed_up)
        e = vz - x[5]
        g = self.vehicle.gravity
        if pc.px4_vertical_integrator:
            pc.int_z = px4_vertical_integral(pc.int_z, pc.z_vel_i, e, pc.z_vel_p * e + pc.int_z, g, dt)
        elif abs(e) < 0.5:  # integrate near the setpoint only (no wind-up while braking or climbing)
            pc.int_z = min(max(pc.int_z + pc.z_vel_i * e * dt, -4.0), 4.0)
        a = pc.z_vel_p * e + pc.int_z
        thrust = (g + max(a, -0.8 * g)) / g * self.hover_norm
        pc.acc_up, pc.thrust_up = max(a, -0.8 * g), thrust
        self.pos_control_ran = True
        return thrust

    def _althold(self, x: Sequence[float], z_sp: float, vz_ff: float, yaw: float, dt: float, on_ground: bool) -> None:
        if on_ground and z_sp < 0.1 and vz_ff <= 0.0:
            self._idle(x)
            return
        thr = angle_boost(self._vertical_thrust(x, z_sp, vz_ff, dt), x[6], x[7])
        self._track_attitude(x, self._level_q(yaw), min(thr, 1.0) * self.tmax, 0.0)

    def _learn_hover(self, x: Sequence[float], dt: float) -> None:
        """The autopilot's hover thrust learned in flight, every ``dt`` s: PX4's hover thrust estimator
        (:meth:`_learn_hover_px4`); ArduPilot's MOT_THST_HOVER learning (MOT_HOVER_LEARN 2: learned and saved; 0:
        not learned) in a throttle-controlled mode."""
        if self.fl.is_px4:
            self._learn_hover_px4(x, dt)
            return
        if not self.armed or self.on_ground or self.mode.kind in ("stabilized", "acro"):
            return
        if not self._p("MOT_HOVER_LEARN"):  # 0: ArduPilot keeps MOT_THST_HOVER as set
            return
        tilt = math.acos(max(min(math.cos(x[6]) * math.cos(x[7]), 1.0), -1.0))
        if self.ap_hover.update(self.thrust_cmd / self.tmax, x[5], tilt, dt):
            self.params["MOT_THST_HOVER"].value = self.ap_hover.value
            self.hover_norm = self.ap_hover.value

    def _learn_hover_px4(self, x: Sequence[float], dt: float) -> None:
        """PX4's ``mc_hover_thrust_estimator`` (``sim_bridge.inner.px4_hover_thrust``): fused while armed, in the
        air and under the position controller (which ran since the last call), from the estimate's vertical
        acceleration (its climb rate's change over ``dt``) and the controller's vertical thrust; once valid, and
        with MPC_USE_HTE, the position controller flies with it, its integrator moved so the thrust does not jump.
        Disarmed: back to MPC_THR_HOVER."""
        hte = self.px4_hover
        vz_prev, self.hte_vz_prev = self.hte_vz_prev, x[5]
        ran, self.pos_control_ran = self.pos_control_ran, False
        if not self.armed:
            if hte.h != hte.hover_param or hte.valid:
                hte.reset(self._p("MPC_THR_HOVER"))
            return
        if self.on_ground:
            hte.in_air = False
        elif x[2] > IN_AIR_HEIGHT_M:
            hte.in_air = True
        if not (hte.in_air and ran and vz_prev is not None):
            return
        pc = self.pos
        hte.update(dt, (x[5] - vz_prev) / dt, pc.thrust_up, math.hypot(x[3], x[4]), x[5])
        if hte.valid and self._p("MPC_USE_HTE") and hte.h != self.hover_norm:
            g = self.vehicle.gravity
            pc.int_z = integrator_after_hover_change(pc.int_z, pc.acc_up, g, self.hover_norm, hte.h)
            self.hover_norm = hte.h
