"""The attitude-level law's command (:class:`offboard.control.smc_attitude.AttitudeCommand`) -> SET_ATTITUDE_TARGET.

The law already speaks the setpoint's language: an attitude (model-frame ZYX Euler angles) and a collective thrust
in newtons. This mapper only changes frames and units, and keeps every guarantee of
:class:`offboard.flight.command_mapping.CommandMapper` (which it extends): a finite setpoint whatever the input, the
last good one or the level hover setpoint otherwise, the thrust normalized against the autopilot's hover throttle
(``MPC_THR_HOVER`` / ``MOT_THST_HOVER``), ArduPilot's angle boost pre-compensated, thrust slew and limits, tilt
within ``max_tilt``.

- attitude: ``q = euler_to_quaternion(phi_sp, theta_sp, psi_sp)`` -> NED (``estimators.model.frames``);
- body rates: the law's commanded rates (FLU -> FRD), clipped to ``max_rate``: feed-forward for an autopilot that
  reads them (mask ``attitude+rates``), logged otherwise (PX4 ignores them with mask ``attitude``).

The tilt limit holds on what the autopilot does, not on one field (:func:`within_tilt`): the attitude's combined
tilt ``hypot(phi, theta)`` (never below the true tilt ``acos(cos phi cos theta)``) is scaled back to ``max_tilt``,
and the feed-forward rate that tilts further is cut to what the autopilot's own attitude loop would use to close the
headroom left, ``K_att (max_tilt - tilt)``, the larger of the setpoint's and the vehicle's tilt. Why: ArduPilot
adds the rates to its attitude target, so a clipped attitude with a 115 deg/s pitch-rate feed-forward still pitched
it to 45.9 deg against a 30 deg limit (issue 38, ArduPilot SITL).

There is no inversion of the autopilot's cascade here (that is the torque-level path's mapping): the law's gain
design treats the autopilot's attitude loop as an uncertain lag instead (``docs/model.md`` §12).
"""

from __future__ import annotations

import math

from estimators.model.control_state import ControlState
from estimators.model.frames import euler_to_quaternion, model_body_to_frd, model_quaternion_to_ned
from offboard.control.smc import Command
from offboard.control.smc_attitude import AttitudeCommand, InnerLoop
from offboard.flight.command_mapping import CommandMapper, _clip
from offboard.flight.link.autopilot_model import AutopilotModel
from offboard.flight.link.setpoints import AttitudeTarget


class AttitudeLawMapper(CommandMapper):
    """Setpoints for the attitude-level law (``--law attitude``); output must be ``attitude``."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.config.output != "attitude":
            raise ValueError("the attitude-level law needs --output attitude")

    def _attitude(self, cmd: Command, est: ControlState, dt: float) -> AttitudeTarget:  # type: ignore[override]
        if not isinstance(cmd, AttitudeCommand):
            raise TypeError("AttitudeLawMapper maps offboard.control.smc_attitude.AttitudeCommand only")
        c = self.config
        rr = c.max_rate
        k_att = 0.5 * (self.autopilot.attitude_p[0] + self.autopilot.attitude_p[1])
        phi_sp, theta_sp, p_c, q_c = within_tilt(
            cmd.phi_sp,
            cmd.theta_sp,
            _clip(cmd.p_c, -rr, rr),
            _clip(cmd.q_c, -rr, rr),
            est.phi,
            est.theta,
            c.max_tilt,
            k_att,
        )
        q_ned = model_quaternion_to_ned(*euler_to_quaternion(phi_sp, theta_sp, cmd.psi_sp))
        rf = model_body_to_frd(p_c, q_c, _clip(cmd.r_c, -rr, rr))
        u = self.thrust_norm(cmd.thrust)
        ap = self.autopilot
        if ap.flavour == "ardupilot" and ap.angle_boost:
            # ArduPilot divides the throttle by the CURRENT tilt's cos(roll) cos(pitch); the law's thrust is already
            # the tilted vehicle's, so pre-multiply (as the torque-level mapping does)
            u *= max(math.cos(est.phi) * math.cos(est.theta), 0.5)
        return AttitudeTarget(q_ned, rf[0], rf[1], rf[2], self._slew_thrust(u, dt), self._mask)


__all__ = ["AttitudeLawMapper", "inner_loop_of", "within_tilt"]


def within_tilt(
    phi: float, theta: float, p: float, q: float, phi_now: float, theta_now: float, max_tilt: float, k_att: float
) -> tuple[float, float, float, float]:
    """The attitude setpoint (roll ``phi``, pitch ``theta``, rad) and the roll / pitch rate feed-forward (``p``,
    ``q``, rad/s, model body axes) kept within ``max_tilt`` (rad) on what the autopilot does (module docstring):
    the setpoint's ``hypot(phi, theta)`` scaled to at most ``max_tilt``; the rate's component that tilts further,
    along the larger of the setpoint's and the vehicle's (``phi_now``, ``theta_now``) tilt, cut to
    ``k_att (max_tilt - tilt)`` (``k_att``: the autopilot's attitude P gain, 1/s); the rest of the rate unchanged."""
    tilt_sp = math.hypot(phi, theta)
    if tilt_sp > max_tilt:
        s = max_tilt / tilt_sp
        phi, theta, tilt_sp = phi * s, theta * s, max_tilt
    tilt_now = math.hypot(phi_now, theta_now)
    dx, dy, tilt = (phi, theta, tilt_sp) if tilt_sp >= tilt_now else (phi_now, theta_now, tilt_now)
    if tilt > 1e-6:
        nx, ny = dx / tilt, dy / tilt
        outward = p * nx + q * ny
        allowed = k_att * max(0.0, max_tilt - tilt)
        if outward > allowed:
            cut = outward - allowed
            p, q = p - cut * nx, q - cut * ny
    return phi, theta, p, q


def inner_loop_of(autopilot: AutopilotModel) -> InnerLoop:
    """The attitude-level law's inner-loop model from the gains read from the autopilot: roll / pitch attitude
    bandwidth = the mean of its attitude P gains (PX4 MC_ROLL_P / MC_PITCH_P, ArduPilot ATC_ANG_RLL_P / _PIT_P),
    heading bandwidth = its yaw P gain, rate bandwidths as read (``Manager.read_autopilot_model``)."""
    kp = autopilot.attitude_p
    return InnerLoop(0.5 * (kp[0] + kp[1]), kp[2], autopilot.rate_bandwidth)
