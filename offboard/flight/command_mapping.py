"""Newtons and newton-metres from the sliding-mode controller -> the normalized setpoints an autopilot accepts.

Input: :class:`offboard.control.smc.Command` (collective thrust T in N, body torques tau in N m, model frame FLU) and
the current estimate (:class:`estimators.model.control_state.ControlState`, model frame). Output: a setpoint of
``offboard.flight.link.setpoints`` (MAVLink frames), always finite and in range.

Thrust (both outputs)
    ``u = T / T_max * k_hover`` with ``T_max`` = 4 x the vehicle file's ``motor_thrust_max`` and
    ``k_hover = hover_norm_autopilot / hover_norm_vehicle`` (1 unless the autopilot's hover-thrust belief,
    PX4 ``MPC_THR_HOVER`` / ArduPilot ``MOT_THST_HOVER``, is given and differs from the vehicle file's
    ``(M + m) g / T_max``): the vehicle's hover thrust then lands exactly on the autopilot's hover throttle.
    ArduPilot (``flavour="ardupilot"``): SET_ATTITUDE_TARGET thrust is a throttle only with GUID_OPTIONS bit 3
    (value 8, checked by ``offboard.flight.link.management``); with ATC_ANGLE_BOOST on, ArduPilot multiplies the
    throttle by ``1 / max(cos(phi) cos(theta), 0.5)`` of the current attitude. The sliding-mode thrust is already
    the thrust of the tilted vehicle, so the mapping pre-multiplies by the same factor (estimated attitude) and the
    boost cancels.

Torque -> attitude / body-rate setpoint (``--output attitude``)
    The autopilot's inner loops are modelled as PX4's / ArduPilot's cascade: a P attitude loop on the quaternion
    error, ``omega_sp = K_att * 2 vec(conj(q) q_sp)`` (+ feed-forward rates with mask 0), gains ``K_att`` in rad/s
    per rad (PX4 MC_ROLL_P / MC_PITCH_P / MC_YAW_P, defaults 6.5 / 6.5 / 2.8), feeding a rate loop whose torque is
    ``I B (omega_sp - omega)`` (``B`` = rate-loop bandwidth, 1/s, default 18 / 18 / 5: the rate gains MC_*RATE_P
    times the axis' maximum torque over its inertia). The controller's model is ``eta'' = tau / I`` (paper eq.
    (13)); we want the body rate to move by ``delta = tau / (I B)`` so that the cascade returns ``tau``. The setpoint
    is that cascade inverted exactly (body axes, any heading; ``omega = W(eta) eta'``, errata E4):

    - mask ``attitude`` (7, default; rates ignored by the autopilot): ``q_sp = q * exp(e / 2)`` with the body-axis
      error ``e = (omega + delta) / K_att``. Read as a look-ahead, ``e = omega h + (tau / I) h^2 (K_att / B)`` with
      ``h = 1 / K_att``: the attitude reached by integrating ``eta'' = tau / I`` over a horizon matched to the
      autopilot's attitude-loop bandwidth (0.15 s for roll / pitch with PX4 defaults), the acceleration term scaled
      by ``2 K_att / B`` (0.72) for the rate loop's finite gain. The rate fields carry ``omega + delta`` (logged;
      ignored by the autopilot with this mask). Without the ``omega h`` term the autopilot's P loop would brake
      every rotation the sliding-mode law asked for (``tests/test_link_mapping.py`` checks both).
    - mask ``attitude+rates`` (0; autopilots that add all three rates as feed-forward, ArduPilot):
      ``e = delta / K_att`` and the rates are the current ``omega``.
    - mask ``rates`` (128): ``omega_sp = omega + delta``, attitude ignored.

    The rate loop's integrator (ratio ``K_i / K_p`` per axis) adds ``K_i / K_p * integral of the P torque``; the
    mapper runs a copy of it on its own commands (clamped like the autopilot's) and asks the P path only for
    ``tau - integral``, so that the sum is the commanded torque. Without this the integrator, which sees the
    deliberate rate error as a disturbance, doubles the low-frequency torque within ``1 / (K_i / K_p)`` seconds.

    Neglected: the rate loop's own lag (``1 / B`` = 55 ms) and the motors'; the controller sees them as unmodelled
    actuator dynamics.

Torque -> actuator controls (``--output actuator``)
    ``roll, pitch, yaw = frames.model_body_to_frd(tau) / tau_max`` with ``tau_max`` from the vehicle file's X
    mixer (``Vehicle.roll_pitch_torque_max`` from the arm length and motor limits, ``Vehicle.yaw_torque_max``),
    clipped to -1..1; thrust ``T / T_max``.

Limits: attitude setpoint tilt <= ``max_tilt`` (rad) per axis, body rates <= ``max_rate`` (rad/s), normalized
thrust in ``[thrust_min, thrust_max]`` and changing by at most ``thrust_slew`` per second, normalized torques
by at most ``torque_slew`` per second. Any non-finite input or output is replaced by the last good setpoint
(if younger than ``hold_last_s``) or by the hover setpoint (level, current heading, hover thrust), and the
event is recorded in :attr:`CommandMapper.events`: NaN and infinity never reach ``offboard.flight.link.setpoints``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

from estimators.model.control_state import ControlState
from estimators.model.frames import euler_to_quaternion, model_body_to_frd, model_quaternion_to_ned, quaternion_to_euler
from estimators.model.rotations import body_rates, quat_mul
from estimators.model.vehicle import Vehicle
from offboard.control.options import Output, values
from offboard.control.smc import Command
from offboard.flight.link.autopilot_model import AutopilotModel
from offboard.flight.link.setpoints import MASKS, ActuatorTarget, AttitudeTarget, Setpoint


@dataclass(frozen=True)
class MappingConfig:
    """Output kind and limits (SI, radians; normalized quantities per second for slews).

    output: ``"attitude"`` or ``"actuator"``; mask: ``"attitude"``, ``"attitude+rates"`` or ``"rates"``.
    """

    output: str = "attitude"
    mask: str = "attitude"
    max_tilt: float = 0.7
    max_rate: float = 4.0
    thrust_min: float = 0.02
    thrust_max: float = 0.98
    thrust_slew: float = 50.0
    torque_slew: float = 500.0
    hold_last_s: float = 0.05

    def __post_init__(self) -> None:
        if self.output not in values(Output):
            raise ValueError(f"output must be 'attitude' or 'actuator', got {self.output!r}")
        if self.mask not in MASKS:
            raise ValueError(f"mask must be one of {', '.join(MASKS)}, got {self.mask!r}")
        if not (0.0 <= self.thrust_min < self.thrust_max <= 1.0):
            raise ValueError("need 0 <= thrust_min < thrust_max <= 1")


@dataclass
class MappingEvent:
    """A fallback taken by the mapper: time (s, controller time base), kind and a one-line reason."""

    t: float
    kind: str
    reason: str


def _finite(*vals: float) -> bool:
    isf = math.isfinite
    return all(isf(v) for v in vals)


def _finite4(a: float, b: float, c: float, d: float) -> bool:
    """:func:`_finite` of four values: one sum is finite only when all four are (else look: the sum may overflow)."""
    isf = math.isfinite
    return isf(a + b + c + d) or (isf(a) and isf(b) and isf(c) and isf(d))


_MASK_ATTITUDE = MASKS["attitude"]
_MASK_ATTITUDE_RATES = MASKS["attitude+rates"]


def _clip(v: float, lo: float, hi: float) -> float:
    return lo if v < lo else hi if v > hi else v


@dataclass
class CommandMapper:
    """Stateful mapper (slew limits and the last good setpoint). One per flight; not thread-safe."""

    vehicle: Vehicle
    config: MappingConfig = field(default_factory=MappingConfig)
    autopilot: AutopilotModel = field(default_factory=AutopilotModel)
    events: list[MappingEvent] = field(default_factory=list)

    def __post_init__(self) -> None:
        v = self.vehicle
        self._T_max = v.thrust_max
        hn = self.autopilot.hover_thrust_norm
        self._k_hover = 1.0 if hn is None else hn / v.hover_thrust_normalized
        self._inertia = v.inertia
        self._tau_max = self._unit_torque(self.autopilot)
        self._mask = MASKS[self.config.mask]
        self._last: Setpoint | None = None
        self._last_t: float | None = None
        self._last_thrust: float | None = None
        self._last_torque: tuple[float, float, float] | None = None
        self._integ = [0.0, 0.0, 0.0]  # model of the autopilot's rate-integrator torque, N m (FLU body axes)
        self.fallbacks = 0

    def limit_tilt(self, tilt_rad: float) -> None:
        """Lower the attitude setpoint's tilt limit to the autopilot's own (PX4 MPC_TILTMAX_AIR, ArduPilot
        ANGLE_MAX), never raise it."""
        from dataclasses import replace

        if math.isfinite(tilt_rad) and 0.0 < tilt_rad < self.config.max_tilt:
            self.config = replace(self.config, max_tilt=tilt_rad)

    def set_autopilot(self, autopilot: AutopilotModel) -> None:
        """Replace the autopilot model (e.g. with the gains read from the vehicle) before the flight starts."""
        self.autopilot = autopilot
        hn = autopilot.hover_thrust_norm
        self._k_hover = 1.0 if hn is None else hn / self.vehicle.hover_thrust_normalized
        self._tau_max = self._unit_torque(autopilot)
        self._integ = [0.0, 0.0, 0.0]

    def set_mask(self, mask: str) -> None:
        """Choose the SET_ATTITUDE_TARGET fields (``MASKS``) before the flight starts (the flavour's default once
        the heartbeat has said which autopilot it is)."""
        self.config = replace(self.config, mask=mask)  # validates the name
        self._mask = MASKS[mask]

    def _unit_torque(self, autopilot: AutopilotModel) -> tuple[float, float, float]:
        """N m of a unit normalized torque per axis: the autopilot's allocator's when known (PX4's CA_ROTOR*
        geometry makes it up to sqrt(2) larger than the hover-margin torque), else the vehicle file's mixer's."""
        if autopilot.unit_torque is not None:
            return autopilot.unit_torque
        v = self.vehicle
        return (v.roll_pitch_torque_max, v.roll_pitch_torque_max, v.yaw_torque_max)

    # ------------------------------------------------------------------------------------------------------
    def thrust_norm(self, thrust_n: float) -> float:
        """Collective thrust N -> normalized 0..1 before limits (see module docstring)."""
        return thrust_n / self._T_max * self._k_hover

    def hover_setpoint(self, psi: float = 0.0) -> Setpoint:
        """Level attitude at heading ``psi`` (rad, model frame) with the hover thrust; zero torque for actuator."""
        c = self.config
        u = _clip(self.thrust_norm(self.vehicle.hover_thrust), c.thrust_min, c.thrust_max)
        if c.output == "actuator":
            return ActuatorTarget(0.0, 0.0, 0.0, u)
        if not math.isfinite(psi):
            psi = 0.0
        q = model_quaternion_to_ned(*euler_to_quaternion(0.0, 0.0, psi))
        return AttitudeTarget(q, 0.0, 0.0, 0.0, u, MASKS["attitude"])

    def map(self, t: float, cmd: Command, est: ControlState) -> Setpoint:
        """The setpoint for this tick (finite and in range, whatever the inputs). ``t``: controller time, s."""
        dt = 0.0 if self._last_t is None or not math.isfinite(t) else max(0.0, t - self._last_t)
        ok_in = cmd.valid and _finite4(cmd.thrust, cmd.tau_phi, cmd.tau_theta, cmd.tau_psi) and est.is_finite()
        sp: Setpoint | None = None
        if ok_in:
            if self.config.output == "actuator":
                sp = self._actuator(cmd, dt)
                if not _finite4(*sp):
                    sp = None
            else:
                sp = self._attitude(cmd, est, dt)
                q = sp.q
                if not (
                    _finite4(q[0], q[1], q[2], q[3]) and _finite4(sp.roll_rate, sp.pitch_rate, sp.yaw_rate, sp.thrust)
                ):
                    sp = None
        if sp is None:
            return self._fallback(
                t, est, "non-finite or invalid controller command" if not ok_in else "non-finite setpoint after mapping"
            )
        self._last, self._last_t = sp, t
        return sp

    def _fallback(self, t: float, est: ControlState, reason: str) -> Setpoint:
        self.fallbacks += 1
        c = self.config
        if (
            self._last is not None
            and self._last_t is not None
            and math.isfinite(t)
            and t - self._last_t <= c.hold_last_s
        ):
            self.events.append(MappingEvent(t, "hold_last_setpoint", reason))
            return self._last
        psi = est.psi if math.isfinite(est.psi) else 0.0
        if self._last is not None and isinstance(self._last, AttitudeTarget) and not math.isfinite(est.psi):
            psi = _yaw_of_ned_quaternion(self._last.q)
        self.events.append(MappingEvent(t, "hover_setpoint", reason))
        sp = self.hover_setpoint(psi)
        self._last, self._last_t = sp, t if math.isfinite(t) else self._last_t
        self._last_thrust = sp.thrust
        return sp

    # ------------------------------------------------------------------------------------------------------
    def _slew_thrust(self, u: float, dt: float) -> float:
        c = self.config
        u = _clip(u, c.thrust_min, c.thrust_max)
        if self._last_thrust is not None and dt > 0.0:
            step = c.thrust_slew * dt
            u = _clip(u, self._last_thrust - step, self._last_thrust + step)
        self._last_thrust = u
        return u

    def _actuator(self, cmd: Command, dt: float) -> ActuatorTarget:
        tr, tp, ty = model_body_to_frd(cmd.tau_phi, cmd.tau_theta, cmd.tau_psi)
        m = self._tau_max
        n = [_clip(tr / m[0], -1.0, 1.0), _clip(tp / m[1], -1.0, 1.0), _clip(ty / m[2], -1.0, 1.0)]
        if self._last_torque is not None and dt > 0.0:
            step = self.config.torque_slew * dt
            n = [_clip(v, last - step, last + step) for v, last in zip(n, self._last_torque)]
        self._last_torque = (n[0], n[1], n[2])
        return ActuatorTarget(n[0], n[1], n[2], self._slew_thrust(cmd.thrust / self._T_max, dt))

    def _attitude(self, cmd: Command, est: ControlState, dt: float) -> AttitudeTarget:
        # per axis (roll, pitch, yaw) unrolled; the arithmetic is the per-axis formula of the module docstring
        ap = self.autopilot
        c = self.config
        I1, I2, I3 = self._inertia
        kp0, kp1, kp2 = ap.attitude_p
        bw0, bw1, bw2 = ap.rate_bandwidth
        ig = self._integ
        # torque asked of the P path, N m, and the rate step, rad/s
        tp0, tp1, tp2 = cmd.tau_phi - ig[0], cmd.tau_theta - ig[1], cmd.tau_psi - ig[2]
        a0, a1, a2 = tp0 / I1 / bw0, tp1 / I2 / bw1, tp2 / I3 / bw2
        if dt > 0.0:
            ki, lim, tm = ap.rate_integral, ap.integral_limit, self._tau_max
            ig[0] = _clip(ig[0] + ki[0] * tp0 * dt, -lim * tm[0], lim * tm[0])
            ig[1] = _clip(ig[1] + ki[1] * tp1 * dt, -lim * tm[1], lim * tm[1])
            ig[2] = _clip(ig[2] + ki[2] * tp2 * dt, -lim * tm[2], lim * tm[2])
        w0, w1, w2 = body_rates(est.phi, est.theta, est.phi_rate, est.theta_rate, est.psi_rate)
        mask = self._mask
        if mask == _MASK_ATTITUDE:
            r0, r1, r2 = w0 + a0, w1 + a1, w2 + a2
            e = (r0 / kp0, r1 / kp1, r2 / kp2)
        elif mask == _MASK_ATTITUDE_RATES:
            e = (a0 / kp0, a1 / kp1, a2 / kp2)
            r0, r1, r2 = w0, w1, w2
        else:  # rates only
            e = (0.0, 0.0, 0.0)
            r0, r1, r2 = w0 + a0, w1 + a1, w2 + a2
        qd = _rotate_by_body_error(euler_to_quaternion(est.phi, est.theta, est.psi), e)
        phi_sp, theta_sp, psi_sp = quaternion_to_euler(*qd)
        mt = c.max_tilt
        if abs(phi_sp) > mt or abs(theta_sp) > mt:
            phi_sp = _clip(phi_sp, -mt, mt)
            theta_sp = _clip(theta_sp, -mt, mt)
            qd = euler_to_quaternion(phi_sp, theta_sp, psi_sp)
        q_ned = model_quaternion_to_ned(*qd)
        rr = c.max_rate
        rf = model_body_to_frd(_clip(r0, -rr, rr), _clip(r1, -rr, rr), _clip(r2, -rr, rr))
        u = self.thrust_norm(cmd.thrust)
        if ap.flavour == "ardupilot" and ap.angle_boost:
            # AC_AttitudeControl_Multi::get_throttle_boosted divides by the CURRENT tilt (AHRS cos roll x cos pitch)
            u *= max(math.cos(est.phi) * math.cos(est.theta), 0.5)
        return AttitudeTarget(q_ned, rf[0], rf[1], rf[2], self._slew_thrust(u, dt), mask)


def _rotate_by_body_error(
    q: tuple[float, float, float, float], e: tuple[float, float, float]
) -> tuple[float, float, float, float]:
    """``q * (sqrt(1 - |e/2|^2), e/2)``: the attitude whose quaternion error from ``q``, read the way PX4 and
    ArduPilot read it (``2 vec(conj(q) q_d)``), is exactly the body-axis vector ``e`` (rad); ``|e|`` is capped
    at 1.9 rad."""
    ex, ey, ez = 0.5 * e[0], 0.5 * e[1], 0.5 * e[2]
    n2 = ex * ex + ey * ey + ez * ez
    if n2 > 0.9025:  # |e| / 2 <= 0.95
        k = 0.95 / math.sqrt(n2)
        ex, ey, ez, n2 = ex * k, ey * k, ez * k, 0.9025
    ew = math.sqrt(1.0 - n2)
    return quat_mul(q, (ew, ex, ey, ez))


def _yaw_of_ned_quaternion(q: tuple[float, float, float, float]) -> float:
    """Model heading (rad, NWU) of a NED quaternion."""
    w, x, y, z = q
    psi_ned = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return -psi_ned if math.isfinite(psi_ned) else 0.0


def setpoint_fields(sp: Setpoint) -> tuple[float, ...]:
    """The numbers a setpoint puts on the wire, flattened (for logs): q(4), rates(3), thrust, mask for attitude;
    roll, pitch, yaw, thrust for actuator."""
    if isinstance(sp, AttitudeTarget):
        return (*sp.q, sp.roll_rate, sp.pitch_rate, sp.yaw_rate, sp.thrust, float(sp.type_mask))
    return tuple(sp)


__all__ = [
    "CommandMapper",
    "MappingConfig",
    "MappingEvent",
    "setpoint_fields",
]
