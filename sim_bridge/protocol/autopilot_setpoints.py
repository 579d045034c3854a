"""The emulated autopilot's setpoint messages, interpreted as the real autopilots do:
SET_ATTITUDE_TARGET, SET_POSITION_TARGET_LOCAL_NED and (PX4) SET_ACTUATOR_CONTROL_TARGET (docs/emulator.md,
"Setpoints").

A mixin: it works on the attributes :class:`sim_bridge.autopilot.Autopilot` sets up (one autopilot, split by
role so that each file has one job); it is not used on its own.
"""

from __future__ import annotations

import logging
import math
from typing import Any

from estimators.model.frames import (
    frd_to_model_body,
    ned_euler_to_model,
    ned_quaternion_to_model,
    ned_to_model_vector,
)
from sim_bridge.autopilot_constants import (
    all_finite,
)

log = logging.getLogger("sim_bridge.autopilot")


class SetpointHandlers:
    """Setpoint messages of :class:`sim_bridge.autopilot.Autopilot`."""

    # ---------------------------------------------------------------- setpoints
    def _on_set_attitude_target(self, msg: Any) -> int:
        mask = msg.type_mask
        px4 = self.fl.is_px4
        att = not (mask & 128)
        rates = not (mask & 1) and not (mask & 2)
        use_tb = px4 and bool(mask & 32) and att
        has_thrust = use_tb or not (mask & 64)
        if not px4 and (mask & 64 or (not att and (mask & 7)) or (0 < (mask & 7) < 7)):
            # ArduPilot: thrust mandatory; rates all or none (rejected without a NACK)
            self.counters["setpoints_rejected"] += 1
            return 1
        if not (att or rates) or not has_thrust:
            self.counters["setpoints_ignored"] += 1
            return 1
        q = msg.q
        thrust = -msg.thrust_body[2] if use_tb else msg.thrust
        vals = (*q, msg.body_roll_rate, msg.body_pitch_rate, thrust)
        if att:
            nq = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
            if not (all_finite(*q) and all_finite(thrust)) or nq < 0.5 or (not px4 and abs(nq - 1.0) > 1e-3):
                self.counters["setpoints_rejected"] += 1
                self.link.rx.malformed += 1
                if not px4 and self.mode.kind == "guided":
                    self.guided_sub = "hold"
                    self.hold_pos = (self.x[0], self.x[1], max(self.x[2], 0.0))
                return 1
            qm = ned_quaternion_to_model(q[0] / nq, q[1] / nq, q[2] / nq, q[3] / nq)
            yaw_ff = 0.0
            if not (mask & 4) and math.isfinite(msg.body_yaw_rate):
                yaw_ff = ned_to_model_vector(0.0, 0.0, msg.body_yaw_rate)[2]  # about world down -> about up
            self.sp_kind, self.sp_q, self.sp_yaw_ff = "att", qm, yaw_ff
            if not px4 and not (mask & 7):
                self.sp_rates = frd_to_model_body(msg.body_roll_rate, msg.body_pitch_rate, msg.body_yaw_rate)
        else:
            yr = msg.body_yaw_rate if not (mask & 4) else 0.0
            if not all_finite(*vals[4:], yr):
                self.counters["setpoints_rejected"] += 1
                self.link.rx.malformed += 1
                return 1
            self.sp_kind = "rates"
            self.sp_rates = frd_to_model_body(msg.body_roll_rate, msg.body_pitch_rate, yr)
        self.sp_thrust = min(max(thrust, -1.0), 1.0)
        self.sp_mask = mask
        self.sp_time_us = self.t_us
        self.counters["setpoints_accepted"] += 1
        if not px4 and self.mode.kind == "guided":
            self.guided_sub = "att"
        return 1

    def _on_set_position_target_local_ned(self, msg: Any) -> int:
        mask = msg.type_mask
        if msg.coordinate_frame != 1:  # only MAV_FRAME_LOCAL_NED
            self.counters["setpoints_rejected"] += 1
            return 1
        use_pos = (mask & 7) != 7
        use_vel = (mask & 56) != 56
        if not (use_pos or use_vel):
            self.counters["setpoints_ignored"] += 1
            return 1
        # the local frame's z origin is where the estimator started, not the ground (sim_bridge.plant.ekf_error)
        z0 = self.ekf.ground_local_z_m if self.ekf is not None else 0.0
        pos = ned_to_model_vector(msg.x, msg.y, msg.z - z0)
        vel = ned_to_model_vector(msg.vx, msg.vy, msg.vz)
        if (use_pos and not all_finite(*pos)) or (use_vel and not all_finite(*vel)):
            self.counters["setpoints_rejected"] += 1
            self.link.rx.malformed += 1
            return 1
        self.sp_pos = (
            pos[0] if not mask & 1 else None,
            pos[1] if not mask & 2 else None,
            pos[2] if not mask & 4 else None,
        )
        self.sp_vel = (
            vel[0] if not mask & 8 else 0.0,
            vel[1] if not mask & 16 else 0.0,
            vel[2] if not mask & 32 else 0.0,
        )
        self.sp_yaw = ned_euler_to_model(0.0, 0.0, msg.yaw)[2] if not (mask & 1024) and math.isfinite(msg.yaw) else None
        self.sp_kind = "pos"
        self.sp_time_us = self.t_us
        self.counters["setpoints_accepted"] += 1
        if not self.fl.is_px4 and self.mode.kind == "guided":
            self.guided_sub = "pos"
        return 1

    def _on_set_actuator_control_target(self, msg: Any) -> int:
        if not self.fl.is_px4 or msg.group_mlx != 0:
            self.counters["setpoints_ignored"] += 1
            return 1
        c = msg.controls
        if not all_finite(c[0], c[1], c[2], c[3]):
            self.counters["setpoints_rejected"] += 1
            self.link.rx.malformed += 1
            return 1
        self.sp_direct = (
            min(max(c[0], -1.0), 1.0),
            min(max(c[1], -1.0), 1.0),
            min(max(c[2], -1.0), 1.0),
            min(max(c[3], 0.0), 1.0),
        )
        self.sp_kind = "direct"
        self.sp_time_us = self.t_us
        self.counters["setpoints_accepted"] += 1
        return 1

    def _on_rc_channels_override(self, msg: Any) -> int:
        """ArduPilot: the throttle stick from channel 3 (PWM 1000-2000 us; 0 and 65535 leave it unchanged)."""
        if not self.fl.is_px4 and msg.target_system == self.sysid and 800 <= msg.chan3_raw <= 2200:
            self.rc_throttle = min(max((msg.chan3_raw - 1000) / 1000.0, 0.0), 1.0)
        return 0
