"""The paper's four sliding-mode laws as one pure step function.

``step(t, estimate, reference, memory, params) -> (command, memory')``: no I/O, no clock reads, no globals.
The live MAVLink loop, the in-process simulation and tlog replay all call this same function.

Laws (paper Section 3, corrected as listed in ``docs/model.md``):

- height (60) with the gravity / centripetal feed-forward the print omits (errata E12)::

      s   = e_z' + lambda1 e_z + lambda0 int(e_z)
      u   = (z*'' - f_z - lambda1 e_z' - lambda0 e_z - rho_z sw(s)) / g_z

  with the full nonlinear ``g_z = (M_t n3 - m (n.r) r3) / (M M_t)`` and ``f_z = m l |r'|^2 r3 / M_t - g``;
- yaw (61)::

      s_psi  = e_psi' + gamma1 e_psi + gamma0 int(e_psi)
      tau_psi = I_psi (psi*'' - gamma1 e_psi' - gamma0 e_psi - rho_psi sw(s_psi))

- horizontal (74), (75) with the corrected K4 (errata E14), written once for both axes in the world frame::

      sigma = e^(5) + K5 e^(4) + K4 e''' + K3 e'' + K2 e' + K1 e + K0 int(e)
      v     = F*^(6) - K5 e^(5) - K4 e^(4) - K3 e''' - K2 e'' - K1 e' - K0 e - rho_F sw(sigma)

  ``v`` is the commanded F^(6) of each world axis. From the chain ``F^(6) = c n'' - omega^2 F^(4)``
  (``estimators.model.flatness``) the commanded world tilt acceleration is ``n'' = (v + omega^2 F^(4)) / c``; the
  tilt in the heading-aligned frame is ``t = [theta, -phi] = Rz(-psi) n``, so
  ``t'' = Rz(-psi) n'' - 2 psi' J t' - psi'' J t + psi'^2 t`` and ``tau_theta = I_theta t1''``,
  ``tau_phi = -I_phi t2''``. At psi = 0 this is exactly (74) and (75), feed-forward terms
  ``+(I_theta/g) F_x^(4)`` and ``-(I_phi/g) F_y^(4)`` included.

``sw`` is ``sign`` or the continuous approximation ``v / (|v| + eps)`` of (92).
The integrals of the four errors are the controller's only memory (errata E11); each is held while its
loop's command is clipped (anti-windup, a deviation from the print, ``docs/model.md`` C-10).
Commands are saturated to the vehicle's limits (on an X frame in flight, ``ControllerParams.shared_roll_pitch``: the
roll / pitch pair and the thrust to what the motors can give together, docs/model.md C-11); a non-finite estimate
or reference yields the hover command and a ``valid = False`` flag, never a NaN.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import NamedTuple, TypeVar

from estimators.model.cable import cable_from_planar
from estimators.model.control_state import ControlState
from estimators.model.flatness import FlatConstants, flat_constants
from estimators.model.frames import wrap_angle
from estimators.model.rotations import thrust_direction_trig
from estimators.model.vehicle import Vehicle
from offboard.control.boundary_layers import error_boundary_layers


@dataclass(frozen=True)
class Gains:
    """Sliding-mode gains (paper Section 4, errata E14, E15).

    lambda0 (1/s^2), lambda1 (1/s): height; gamma0, gamma1: yaw; K: (K0, ..., K5) for the horizontal
    sixth-order error polynomial (1/s^6 ... 1/s); rho_z (m/s^2), rho_psi (rad/s^2), rho_F (m/s^6): switching
    amplitudes.
    """

    lambda0: float
    lambda1: float
    gamma0: float
    gamma1: float
    K: tuple[float, float, float, float, float, float]
    rho_z: float
    rho_psi: float
    rho_F: float

    @classmethod
    def from_poles(
        cls,
        wn_z: float = 10.0,
        wn_psi: float = 9.0,
        wn_F: float = 6.0,
        zeta: float = 0.9,
        rho_z: float = 1.0,
        rho_psi: float = 0.3,
        rho_F: float = 1000.0,
    ) -> Gains:
        """Gains placing the closed-loop poles at ``(p^2 + 2 zeta wn p + wn^2)^k`` (k = 1 for height and yaw,
        k = 3 for the horizontal channels). The defaults are the paper's."""
        w, z = wn_F, zeta
        K = (
            w**6,
            6.0 * z * w**5,
            12.0 * z**2 * w**4 + 3.0 * w**4,
            8.0 * z**3 * w**3 + 12.0 * z * w**3,
            12.0 * z**2 * w**2 + 3.0 * w**2,  # the paper prints 2 zeta^2 wn^2 + 3 wn^2 (errata E14)
            6.0 * z * w,
        )
        return cls(wn_z**2, 2.0 * zeta * wn_z, wn_psi**2, 2.0 * zeta * wn_psi, K, rho_z, rho_psi, rho_F)

    def scaled(self, f: float) -> Gains:
        """Every loop's closed-loop poles multiplied by ``f`` (> 0): the coefficient of ``p^i`` in a loop's
        characteristic polynomial of order ``n`` times ``f^(n - i)``; the switching amplitudes unchanged. The
        scaled loop has at a delay ``tau / f`` the phase margin this one has at ``tau``
        (``offboard.control.delay_margin``)."""
        if not (math.isfinite(f) and f > 0.0):
            raise ValueError(f"gain scale must be a finite number > 0, got {f!r}")
        K = tuple(k * f ** (6 - i) for i, k in enumerate(self.K))
        return replace(
            self,
            lambda0=self.lambda0 * f * f,
            lambda1=self.lambda1 * f,
            gamma0=self.gamma0 * f * f,
            gamma1=self.gamma1 * f,
            K=K,  # type: ignore[arg-type]
        )


@dataclass(frozen=True)
class ControllerParams:
    """Everything the step needs besides the signals: nominal vehicle, gains, switching function, limits.

    switching: ``"sign"`` (the paper's sign(.)) or ``"smooth"`` (v / (|v| + epsilon), eq. (92)).
    epsilon: smoothing width of (92), in the units of each surface (the paper uses 1 for all loops).
    layer_errors: with smooth switching, each loop's own width instead of ``epsilon``: the value of its sliding
    variable for a tracking error of (height m, heading rad, horizontal m) alone, :func:`error_boundary_layers`
    of these gains (so that it follows a gain scaling); None (the default): ``epsilon`` for all three, as the paper.
    thrust_min, thrust_max: collective thrust limits, N; torque_max: (roll, pitch, yaw) limits, N m.
    max_tilt: largest tilt (rad) for which the height law divides by g_z; beyond it g_z is held at its value
    there, so that thrust stays bounded.
    actuation_lag_s: the first-order lag (s) from a commanded torque to the tilt acceleration the estimate shows
    (the motors' time constant plus the attitude telemetry's age) that the horizontal law compensates (see
    :func:`step`); 0 (the default): the paper's law, which assumes the commanded torque acts at once.
    shared_roll_pitch: the roll and pitch torques share the motors' margin, as on a quadrotor X frame (every motor
    takes part in both): after each is clipped to its own limit the pair is limited to
    ``|tau_phi| / tp_max + |tau_theta| / tt_max <= 1``, scaled together so that it keeps its direction, and the
    thrust is clipped to :func:`shared_thrust_range` so that every motor has the margin the pair needs (roll and
    pitch before the height loop, as PX4's airmode would have it). False (the default, the paper's ideal
    actuators): each axis has its limit alone. Without it the law asks for pairs the motors cannot give, and
    PX4's allocator (sequential desaturation, airmode off: thrust only lowered, then roll before pitch) cuts the
    roll torque first.
    """

    vehicle: Vehicle
    gains: Gains
    switching: str = "sign"
    epsilon: float = 1.0
    thrust_min: float = 0.0
    thrust_max: float = math.inf
    torque_max: tuple[float, float, float] = (math.inf, math.inf, math.inf)
    max_tilt: float = 1.2
    actuation_lag_s: float = 0.0
    shared_roll_pitch: bool = False
    layer_errors: tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        if self.switching not in ("sign", "smooth"):
            raise ValueError(f"switching must be 'sign' or 'smooth', got {self.switching!r}")
        if not (self.epsilon > 0.0 and math.isfinite(self.epsilon)):
            raise ValueError(f"epsilon must be a finite number > 0, got {self.epsilon!r}")
        if self.layer_errors is not None and not (
            len(self.layer_errors) == 3 and all(e > 0.0 and math.isfinite(e) for e in self.layer_errors)
        ):
            raise ValueError(f"layer_errors must be three finite numbers > 0, got {self.layer_errors!r}")
        if not (self.actuation_lag_s >= 0.0 and math.isfinite(self.actuation_lag_s)):
            raise ValueError(f"actuation_lag_s must be a finite number >= 0, got {self.actuation_lag_s!r}")

    def layers(self) -> tuple[float, float, float]:
        """(height m/s, heading rad/s, horizontal m/s^5) widths of the smooth switching: from ``layer_errors``
        (:func:`error_boundary_layers`), else ``epsilon`` for all three."""
        if self.layer_errors is None:
            return (self.epsilon,) * 3
        return error_boundary_layers(self.gains, self.layer_errors)

    @classmethod
    def for_vehicle(cls, vehicle: Vehicle, gains: Gains | None = None, **kwargs: object) -> ControllerParams:
        """Parameters with the thrust and torque limits of ``vehicle`` (its mixer's authority around hover)."""
        limits = {
            "thrust_min": 0.0,
            "thrust_max": vehicle.thrust_max,
            "torque_max": (vehicle.roll_pitch_torque_max, vehicle.roll_pitch_torque_max, vehicle.yaw_torque_max),
        }
        limits.update(kwargs)
        return cls(vehicle=vehicle, gains=gains or Gains.from_poles(), **limits)  # type: ignore[arg-type]


class ControllerMemory(NamedTuple):
    """The controller's own state: integrals of the tracking errors and the time of the last step.

    int_z (m s), int_psi (rad s), int_fx, int_fy (m s); t: time of the last step (s), None before the first.
    dist_x, dist_y (m/s^2, world NWU) and vel_x, vel_y (m/s): the attitude-level law's disturbance observer
    (``offboard.control.smc_attitude``, no load; NaN velocity: not started); the torque-level law does not use them.
    With ``actuation_lag_s`` > 0 the torque-level law's model of its actuation: the roll and pitch torques
    commanded at the last step (``tau_phi_cmd``, ``tau_theta_cmd``) and those it models as delivered then
    (``tau_phi_act``, ``tau_theta_act``), N m body FLU.
    """

    int_z: float = 0.0
    int_psi: float = 0.0
    int_fx: float = 0.0
    int_fy: float = 0.0
    t: float | None = None
    dist_x: float = 0.0
    dist_y: float = 0.0
    vel_x: float = math.nan
    vel_y: float = math.nan
    tau_phi_cmd: float = 0.0
    tau_theta_cmd: float = 0.0
    tau_phi_act: float = 0.0
    tau_theta_act: float = 0.0


#: one flat output's reference (F_x, F_y in m; z in m; psi in rad) followed by its time derivatives, orders 1, 2, ...
#: (SI units per second^order): the reference arguments of every law's ``step``
Ref = tuple[float, ...]


class Command(NamedTuple):
    """Controller output (SI, body FLU torques) and diagnostics.

    thrust (N), tau_phi, tau_theta, tau_psi (N m); s_z, s_psi, sigma_x, sigma_y: sliding variables;
    saturated: any command was clipped; valid: False when the inputs were not finite (hover command sent).
    """

    thrust: float
    tau_phi: float
    tau_theta: float
    tau_psi: float
    s_z: float
    s_psi: float
    sigma_x: float
    sigma_y: float
    saturated: bool
    valid: bool


class _Derived(NamedTuple):
    """Per-parameter-set constants computed once."""

    k: FlatConstants
    M: float
    m: float
    Mt: float
    I_phi: float
    I_theta: float
    I_psi: float
    cos_max_tilt: float
    layers: tuple[float, float, float]


P = TypeVar("P")
D = TypeVar("D")


def per_params(build: Callable[[P], D]) -> Callable[[P], D]:
    """``build(params)`` computed once per parameter object (looked up by identity: a law's parameters are frozen
    and built once per flight, and the tick looks them up every time), for the laws' derived constants."""
    cache: dict[int, tuple[P, D]] = {}

    def derived(params: P) -> D:
        hit = cache.get(id(params))
        if hit is not None and hit[0] is params:
            return hit[1]
        d = build(params)
        cache[id(params)] = (params, d)
        return d

    return derived


def switching(s: float, eps: float, smooth: bool) -> float:
    """The switching function of sliding variable ``s``: ``s / (|s| + eps)`` (eq. (92)) when ``smooth``, else the
    paper's ``sign(s)`` (0 at 0)."""
    if smooth:
        return s / (abs(s) + eps)
    return math.copysign(1.0, s) if s != 0.0 else 0.0


@per_params
def _derived(params: ControllerParams) -> _Derived:
    v = params.vehicle
    return _Derived(
        flat_constants(v),
        v.mass_vehicle,
        v.mass_load,
        v.total_mass,
        *v.inertia,
        math.cos(params.max_tilt),
        params.layers(),
    )


@per_params
def _hover_margin(params: ControllerParams) -> tuple[float, float]:
    """(the largest thrust of one motor, N; the margin of one motor at hover, N: the smaller of the headroom above and
    below it, what ``Vehicle.roll_pitch_torque_max`` is sized for)."""
    v = params.vehicle
    f_max, f_hover = v.motor_thrust_max, v.hover_thrust / 4.0
    return f_max, min(f_hover, f_max - f_hover)


def shared_thrust_range(params: ControllerParams, share: float) -> tuple[float, float]:
    """The collective thrust (N) that leaves every motor of a quadrotor X frame the margin for a roll / pitch pair
    of ``share = |tau_phi| / tp_max + |tau_theta| / tt_max`` (<= 1; the limits are sized for the margin at hover,
    ``Vehicle.roll_pitch_torque_max``): each motor moves by ``share`` times its margin at hover and must stay
    between rest and full thrust. The range always holds the hover thrust."""
    f_max, df_hover = _hover_margin(params)
    need = share * df_hover
    return 4.0 * need, 4.0 * (f_max - need)


def _clip(value: float, lo: float, hi: float) -> tuple[float, bool]:
    if value < lo:
        return lo, True
    if value > hi:
        return hi, True
    return value, False


def hover_command(params: ControllerParams, valid: bool = False) -> Command:
    """The command that holds the nominal vehicle and load at rest: thrust (M + m) g, no torque."""
    v = params.vehicle
    thrust, _ = _clip(v.hover_thrust, params.thrust_min, params.thrust_max)
    return Command(thrust, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, False, valid)


def step(
    t: float,
    est: ControlState,
    ref_fx: tuple[float, ...],
    ref_fy: tuple[float, ...],
    ref_z: tuple[float, ...],
    ref_psi: tuple[float, ...],
    memory: ControllerMemory,
    params: ControllerParams,
) -> tuple[Command, ControllerMemory]:
    """One controller tick.

    t: time (s); est: state estimate (model frame); ref_fx, ref_fy: reference flat outputs and their
    derivatives of orders 0..6 (m ... m/s^6, world NWU); ref_z: reference height, orders 0..2 at least;
    ref_psi: reference heading, orders 0..2 at least (rad). Returns the saturated command and the new memory.
    The integrals advance by the time since the previous step (rectangle rule on the current error).
    """
    # One sum catches any NaN or infinity in the reference (see ControlState.is_finite).
    ref_sum = sum(ref_fx) + sum(ref_fy) + ref_z[0] + ref_z[1] + ref_z[2] + ref_psi[0] + ref_psi[1] + ref_psi[2]
    if not (est.is_finite() and math.isfinite(t) and math.isfinite(ref_sum)):
        return hover_command(params), memory

    d = _derived(params)
    k = d.k
    G = params.gains
    dt = 0.0 if memory.t is None else max(0.0, t - memory.t)
    smooth = params.switching == "smooth"
    eps_z, eps_psi, eps_f = d.layers

    # ---- height -------------------------------------------------------------------------------------
    phi, theta, psi = est.phi, est.theta, est.psi
    sf, cf = math.sin(phi), math.cos(phi)
    st, ct = math.sin(theta), math.cos(theta)
    sp, cp = math.sin(psi), math.cos(psi)
    n1, n2, n3 = thrust_direction_trig(sf, cf, st, ct, sp, cp)
    (r1, r2, r3), (d1, d2, d3) = cable_from_planar(est.alpha_y, est.alpha_x, est.alpha_y_rate, est.alpha_x_rate)
    nr = n1 * r1 + n2 * r2 + n3 * r3
    g_z = (d.Mt * max(n3, d.cos_max_tilt) - d.m * nr * r3) / (d.M * d.Mt)
    f_z = d.m * k.l * (d1 * d1 + d2 * d2 + d3 * d3) * r3 / d.Mt - k.g

    e_z = est.z - ref_z[0]
    e_zd = est.z_rate - ref_z[1]
    int_z = memory.int_z + e_z * dt
    s_z = e_zd + G.lambda1 * e_z + G.lambda0 * int_z
    sw_z = switching(s_z, eps_z, smooth)
    thrust = (ref_z[2] - f_z - G.lambda1 * e_zd - G.lambda0 * e_z - G.rho_z * sw_z) / max(g_z, 1e-3)

    # ---- yaw ----------------------------------------------------------------------------------------
    e_psi = wrap_angle(psi - ref_psi[0])
    e_psid = est.psi_rate - ref_psi[1]
    int_psi = memory.int_psi + e_psi * dt
    s_psi = e_psid + G.gamma1 * e_psi + G.gamma0 * int_psi
    sw_psi = switching(s_psi, eps_psi, smooth)
    tau_psi = d.I_psi * (ref_psi[2] - G.gamma1 * e_psid - G.gamma0 * e_psi - G.rho_psi * sw_psi)

    # ---- horizontal: commanded F^(6) per world axis ----------------------------------------------------
    K0, K1, K2, K3, K4, K5 = G.K
    # the errors e^(i) = F^(i) - F*^(i), i = 0..5, unrolled (this runs every tick, in the live loop and in replay)
    fx0, fx1, fx2, fx3, fx4, fx5 = est.fx
    fy0, fy1, fy2, fy3, fy4, fy5 = est.fy
    ex0, ex1, ex2, ex3, ex4, ex5 = (
        fx0 - ref_fx[0],
        fx1 - ref_fx[1],
        fx2 - ref_fx[2],
        fx3 - ref_fx[3],
        fx4 - ref_fx[4],
        fx5 - ref_fx[5],
    )
    ey0, ey1, ey2, ey3, ey4, ey5 = (
        fy0 - ref_fy[0],
        fy1 - ref_fy[1],
        fy2 - ref_fy[2],
        fy3 - ref_fy[3],
        fy4 - ref_fy[4],
        fy5 - ref_fy[5],
    )
    int_fx = memory.int_fx + ex0 * dt
    int_fy = memory.int_fy + ey0 * dt
    sigma_x = ex5 + K5 * ex4 + K4 * ex3 + K3 * ex2 + K2 * ex1 + K1 * ex0 + K0 * int_fx
    sigma_y = ey5 + K5 * ey4 + K4 * ey3 + K3 * ey2 + K2 * ey1 + K1 * ey0 + K0 * int_fy
    sw_x, sw_y = switching(sigma_x, eps_f, smooth), switching(sigma_y, eps_f, smooth)
    rho_F = G.rho_F
    vx = ref_fx[6] - K5 * ex5 - K4 * ex4 - K3 * ex3 - K2 * ex2 - K1 * ex1 - K0 * ex0 - rho_F * sw_x
    vy = ref_fy[6] - K5 * ey5 - K4 * ey4 - K3 * ey3 - K2 * ey2 - K1 * ey1 - K0 * ey0 - rho_F * sw_y

    # world tilt acceleration, then the heading-aligned frame (t = [theta, -phi], n = Rz(psi) t)
    nddx = (vx + k.omega2 * fx4) / k.c
    nddy = (vy + k.omega2 * fy4) / k.c
    lag = params.actuation_lag_s
    tp_act = tt_act = 0.0
    if lag > 0.0:
        # The motors deliver the commanded torque through a first-order lag and the filter sees its effect a
        # telemetry age later: F^(6) follows v that much late, which left the paper's loop unstable for motor
        # lags >= 24 ms with the filter in the loop (docs/compare.md). The law models that lag from its own
        # commands (memory), hence the F^(6) the vehicle has now, differentiates the smooth part of v along it
        # (e^(6) from that model, no noisy derivative) and leads by the lag: n''_c = n'' + lag n^(3), so that the
        # lagged torque is the law's. Heading-rate terms of the frame change are left out of the model (the laws
        # hold the heading).
        a = 1.0 - math.exp(-dt / lag) if dt > 0.0 else 0.0
        tp_act = memory.tau_phi_act + a * (memory.tau_phi_cmd - memory.tau_phi_act)
        tt_act = memory.tau_theta_act + a * (memory.tau_theta_cmd - memory.tau_theta_act)
        a1, a2 = tt_act / d.I_theta, tp_act / d.I_phi  # delivered t'' = [theta'', -phi''] is (a1, -a2)
        e6x = k.c * (cp * a1 + sp * a2) - k.omega2 * fx4 - ref_fx[6]
        e6y = k.c * (sp * a1 - cp * a2) - k.omega2 * fy4 - ref_fy[6]
        dvx = -K5 * e6x - K4 * ex5 - K3 * ex4 - K2 * ex3 - K1 * ex2 - K0 * ex1
        dvy = -K5 * e6y - K4 * ey5 - K3 * ey4 - K2 * ey3 - K1 * ey2 - K0 * ey1
        nddx += lag * (dvx + k.omega2 * fx5) / k.c
        nddy += lag * (dvy + k.omega2 * fy5) / k.c
    t1, t2 = theta, -phi
    t1d, t2d = est.theta_rate, -est.phi_rate
    w = est.psi_rate
    wd = ref_psi[2]
    # t'' = Rz(-psi) n'' - 2 w J t' - w' J t + w^2 t, with J [a, b] = [-b, a]
    t1dd = cp * nddx + sp * nddy + 2.0 * w * t2d + wd * t2 + w * w * t1
    t2dd = -sp * nddx + cp * nddy - 2.0 * w * t1d - wd * t1 + w * w * t2
    tau_theta = d.I_theta * t1dd
    tau_phi = -d.I_phi * t2dd

    # saturation, _clip inlined (a NaN passes unclipped, as through _clip, and is caught below)
    lo, hi = params.thrust_min, params.thrust_max
    s1 = s2 = s3 = s4 = False
    if thrust < lo:
        thrust, s1 = lo, True
    elif thrust > hi:
        thrust, s1 = hi, True
    tp_max, tt_max, ts_max = params.torque_max
    if tau_phi < -tp_max:
        tau_phi, s2 = -tp_max, True
    elif tau_phi > tp_max:
        tau_phi, s2 = tp_max, True
    if tau_theta < -tt_max:
        tau_theta, s3 = -tt_max, True
    elif tau_theta > tt_max:
        tau_theta, s3 = tt_max, True
    if params.shared_roll_pitch:
        # every motor takes part in both torques: a pair beyond the margin at hover is scaled together (its
        # direction kept), and the thrust yields the margin the pair needs (the height loop's sign switching would
        # otherwise take it, and the autopilot's allocator, thrust only lowered, then cuts the roll torque first)
        share = abs(tau_phi) / tp_max + abs(tau_theta) / tt_max
        if share > 1.0:
            tau_phi, tau_theta, s2, share = tau_phi / share, tau_theta / share, True, 1.0
        t_lo, t_hi = shared_thrust_range(params, share)
        if thrust < t_lo:
            thrust, s1 = t_lo, True
        elif thrust > t_hi:
            thrust, s1 = t_hi, True
    if tau_psi < -ts_max:
        tau_psi, s4 = -ts_max, True
    elif tau_psi > ts_max:
        tau_psi, s4 = ts_max, True

    cmd = Command(thrust, tau_phi, tau_theta, tau_psi, s_z, s_psi, sigma_x, sigma_y, s1 or s2 or s3 or s4, True)
    if not math.isfinite(thrust + tau_phi + tau_theta + tau_psi + int_z + int_psi + int_fx + int_fy):
        return hover_command(params), memory
    # Anti-windup (not in the paper): while a loop's command is clipped its error integral is held, so that a
    # long saturation (a heading manoeuvre beyond the yaw authority) does not leave the surface far from zero
    # and an offset of rho / gain that takes tens of seconds to unwind. The horizontal integrals share the
    # roll and pitch torques (heading-aligned frame), so both are held when either torque is clipped.
    if s1:
        int_z = memory.int_z
    if s4:
        int_psi = memory.int_psi
    if s2 or s3:
        int_fx, int_fy = memory.int_fx, memory.int_fy
    return cmd, ControllerMemory(
        int_z,
        int_psi,
        int_fx,
        int_fy,
        t,
        tau_phi_cmd=tau_phi,
        tau_theta_cmd=tau_theta,
        tau_phi_act=tp_act,
        tau_theta_act=tt_act,
    )
