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
  (``estimators.flatness``) the commanded world tilt acceleration is ``n'' = (v + omega^2 F^(4)) / c``; the
  tilt in the heading-aligned frame is ``t = [theta, -phi] = Rz(-psi) n``, so
  ``t'' = Rz(-psi) n'' - 2 psi' J t' - psi'' J t + psi'^2 t`` and ``tau_theta = I_theta t1''``,
  ``tau_phi = -I_phi t2''``. At psi = 0 this is exactly (74) and (75), feed-forward terms
  ``+(I_theta/g) F_x^(4)`` and ``-(I_phi/g) F_y^(4)`` included.

``sw`` is ``sign`` or the continuous approximation ``v / (|v| + eps)`` of (92).
The integrals of the four errors are the controller's only memory (errata E11); each is held while its
loop's command is clipped (anti-windup, a deviation from the print, ``docs/model.md`` C-10).
Commands are saturated to the vehicle's limits; a non-finite estimate or reference yields the hover command
and a ``valid = False`` flag, never a NaN.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

from estimators.cable import cable_from_planar
from estimators.control_state import ControlState
from estimators.flatness import FlatConstants, flat_constants
from estimators.frames import wrap_angle
from estimators.vehicle import Vehicle


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


@dataclass(frozen=True)
class ControllerParams:
    """Everything the step needs besides the signals: nominal vehicle, gains, switching function, limits.

    switching: ``"sign"`` (the paper's sign(.)) or ``"smooth"`` (v / (|v| + epsilon), eq. (92)).
    epsilon: smoothing width of (92), in the units of each surface (the paper uses 1 for all loops).
    thrust_min, thrust_max: collective thrust limits, N; torque_max: (roll, pitch, yaw) limits, N m.
    max_tilt: largest tilt (rad) for which the height law divides by g_z; beyond it g_z is held at its value
    there, so that thrust stays bounded.
    """

    vehicle: Vehicle
    gains: Gains
    switching: str = "sign"
    epsilon: float = 1.0
    thrust_min: float = 0.0
    thrust_max: float = math.inf
    torque_max: tuple[float, float, float] = (math.inf, math.inf, math.inf)
    max_tilt: float = 1.2

    def __post_init__(self) -> None:
        if self.switching not in ("sign", "smooth"):
            raise ValueError(f"switching must be 'sign' or 'smooth', got {self.switching!r}")
        if not (self.epsilon > 0.0 and math.isfinite(self.epsilon)):
            raise ValueError(f"epsilon must be a finite number > 0, got {self.epsilon!r}")

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
    """

    int_z: float = 0.0
    int_psi: float = 0.0
    int_fx: float = 0.0
    int_fy: float = 0.0
    t: float | None = None


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


_DERIVED_CACHE: dict[int, tuple[ControllerParams, _Derived]] = {}


def _derived(params: ControllerParams) -> _Derived:
    hit = _DERIVED_CACHE.get(id(params))
    if hit is not None and hit[0] is params:
        return hit[1]
    v = params.vehicle
    d = _Derived(
        flat_constants(v), v.mass_vehicle, v.mass_load, v.total_mass, *v.inertia, math.cos(params.max_tilt)
    )
    _DERIVED_CACHE[id(params)] = (params, d)
    return d


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
    eps = params.epsilon

    # ---- height -------------------------------------------------------------------------------------
    phi, theta, psi = est.phi, est.theta, est.psi
    sf, cf = math.sin(phi), math.cos(phi)
    st, ct = math.sin(theta), math.cos(theta)
    sp, cp = math.sin(psi), math.cos(psi)
    n1 = sf * sp + cf * cp * st
    n2 = cf * sp * st - cp * sf
    n3 = cf * ct
    (r1, r2, r3), (d1, d2, d3) = cable_from_planar(est.alpha_y, est.alpha_x, est.alpha_y_rate, est.alpha_x_rate)
    nr = n1 * r1 + n2 * r2 + n3 * r3
    g_z = (d.Mt * max(n3, d.cos_max_tilt) - d.m * nr * r3) / (d.M * d.Mt)
    f_z = d.m * k.l * (d1 * d1 + d2 * d2 + d3 * d3) * r3 / d.Mt - k.g

    e_z = est.z - ref_z[0]
    e_zd = est.z_rate - ref_z[1]
    int_z = memory.int_z + e_z * dt
    s_z = e_zd + G.lambda1 * e_z + G.lambda0 * int_z
    sw_z = s_z / (abs(s_z) + eps) if smooth else math.copysign(1.0, s_z) if s_z != 0.0 else 0.0
    thrust = (ref_z[2] - f_z - G.lambda1 * e_zd - G.lambda0 * e_z - G.rho_z * sw_z) / max(g_z, 1e-3)

    # ---- yaw ----------------------------------------------------------------------------------------
    e_psi = wrap_angle(psi - ref_psi[0])
    e_psid = est.psi_rate - ref_psi[1]
    int_psi = memory.int_psi + e_psi * dt
    s_psi = e_psid + G.gamma1 * e_psi + G.gamma0 * int_psi
    sw_psi = s_psi / (abs(s_psi) + eps) if smooth else math.copysign(1.0, s_psi) if s_psi != 0.0 else 0.0
    tau_psi = d.I_psi * (ref_psi[2] - G.gamma1 * e_psid - G.gamma0 * e_psi - G.rho_psi * sw_psi)

    # ---- horizontal: commanded F^(6) per world axis ----------------------------------------------------
    K0, K1, K2, K3, K4, K5 = G.K
    # the errors e^(i) = F^(i) - F*^(i), i = 0..5, unrolled (this runs every tick, in the live loop and in replay)
    fx0, fx1, fx2, fx3, fx4, fx5 = est.fx
    fy0, fy1, fy2, fy3, fy4, fy5 = est.fy
    ex0, ex1, ex2, ex3, ex4, ex5 = (fx0 - ref_fx[0], fx1 - ref_fx[1], fx2 - ref_fx[2], fx3 - ref_fx[3],
                                    fx4 - ref_fx[4], fx5 - ref_fx[5])
    ey0, ey1, ey2, ey3, ey4, ey5 = (fy0 - ref_fy[0], fy1 - ref_fy[1], fy2 - ref_fy[2], fy3 - ref_fy[3],
                                    fy4 - ref_fy[4], fy5 - ref_fy[5])
    int_fx = memory.int_fx + ex0 * dt
    int_fy = memory.int_fy + ey0 * dt
    sigma_x = ex5 + K5 * ex4 + K4 * ex3 + K3 * ex2 + K2 * ex1 + K1 * ex0 + K0 * int_fx
    sigma_y = ey5 + K5 * ey4 + K4 * ey3 + K3 * ey2 + K2 * ey1 + K1 * ey0 + K0 * int_fy
    if smooth:
        sw_x = sigma_x / (abs(sigma_x) + eps)
        sw_y = sigma_y / (abs(sigma_y) + eps)
    else:
        sw_x = math.copysign(1.0, sigma_x) if sigma_x != 0.0 else 0.0
        sw_y = math.copysign(1.0, sigma_y) if sigma_y != 0.0 else 0.0
    rho_F = G.rho_F
    vx = ref_fx[6] - K5 * ex5 - K4 * ex4 - K3 * ex3 - K2 * ex2 - K1 * ex1 - K0 * ex0 - rho_F * sw_x
    vy = ref_fy[6] - K5 * ey5 - K4 * ey4 - K3 * ey3 - K2 * ey2 - K1 * ey1 - K0 * ey0 - rho_F * sw_y

    # world tilt acceleration, then the heading-aligned frame (t = [theta, -phi], n = Rz(psi) t)
    nddx = (vx + k.omega2 * fx4) / k.c
    nddy = (vy + k.omega2 * fy4) / k.c
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
    return cmd, ControllerMemory(int_z, int_psi, int_fx, int_fy, t)
