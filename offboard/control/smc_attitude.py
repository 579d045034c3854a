"""The flatness-based sliding-mode law at the level an autopilot's setpoint really commands: thrust direction
(attitude) and collective thrust, for autopilots that own their attitude / rate loops, allocator and saturation.

``step(t, estimate, reference derivatives, memory, params) -> (command, memory')``: a pure step like
:func:`offboard.control.smc.step` (no I/O, no clock, no globals); the memory is the same four error integrals
(:class:`offboard.control.smc.ControllerMemory`). Derivation: ``docs/model.md`` §12.

Inner loop (what the autopilot does with an attitude setpoint)
    modelled as a first-order lag of the thrust direction, ``n' = w_i (n_sp - n)`` per horizontal world axis
    (``w_i``: the attitude loop's bandwidth, PX4 ``MC_ROLL_P``, ArduPilot ``ATC_ANG_RLL_P``), and of the heading,
    ``psi' = w_psi (psi_sp - psi)``. The rate loop, motors and link delay behind it are not modelled: the gains
    are chosen so that the loop stays stable with ``w_i`` off by 2x either way and 0-30 ms of delay
    (``tests/test_smc_attitude.py``).

Horizontal (per world axis, the sliding surface one order below the torque-level law's)
    with a load (``m > 0``): the flat output ``F = p + l a`` and its chain ``F'' = -g a``, ``F^(4) = c (a + n)``;
    the setpoint enters ``F^(5) = c (a' + n')``, relative degree 5::

        sigma = e^(4) + k4 e''' + k3 e'' + k2 e' + k1 e + k0 int(e)
        v     = F*^(5) - k4 e^(4) - k3 e''' - k2 e'' - k1 e' - k0 e - rho_F sw(sigma)     (commanded F^(5))
        n'_c  = v / c - a'

    without a load: the vehicle position, ``p'' = g n1 / n3`` (thrust balancing the weight), relative degree 3::

        sigma = e'' + k2 e' + k1 e + k0 int(e),   v = p*''' - k2 e'' - k1 e' - k0 e - rho_F sw(sigma),   n'_c = v / g

    and the setpoint that makes the nominal inner loop deliver ``n'_c``: ``n_sp = n + n'_c / w_i``. The reference's
    ``F*^(5)`` (or jerk ``p*'''``) in ``v`` is the attitude-rate feed-forward.

Still-air drag (the vehicle file's ``linear_drag`` ``k_d``, a force ``-k_d v`` on the vehicle, PX4 SIH's SIH_KDV)
    with ``k_t = k_d / (M_t g)``, the tilt that balances it per m/s: the vehicle's balance
    ``M p'' = M_t g n + m g a - k_d p'`` turns the chain into ``F^(4) = c (a + n - k_t p')`` (docs/model.md §12.7), so
    the law takes the estimate's ``F^(4)`` less ``c k_t p'`` (``p'`` the vehicle's velocity, ``F' - l a'``) and adds
    ``k_t F*''`` (the reference's acceleration) to the commanded tilt rate. Without it a vehicle with SIH's drag
    (1 N per m/s on 1.25 kg) lagged a 2 m move and overshot its end by 0.3 m on real PX4 (docs/deploy.md §2c). Not
    where the estimate's ``F^(4)`` already carries the drag as the filter's fed-forward external acceleration
    (``drag_feedforward``), and not without a load: there it raised the SIH quadrotor's tilt p95 in the 2 m move
    of ``tests/test_px4_sitl.py`` from 8.4-9.5 to 11.25 deg, against issue 9's bound of 12 (docs/deploy.md §2c).

Height and yaw
    the height law of ``offboard.control.smc`` (its (60) with the gravity and centripetal feed-forward, the full
    ``g_z``) on the collective thrust, whose feed-forward is ``z*''``; yaw ``sigma = e_psi + k_psi int(e_psi)``,
    ``psi'_c = psi*' - k_psi e_psi - rho_psi sw(sigma)``, ``psi_sp = psi + psi'_c / w_psi``.

Reaching law: ``sigma' = -(reach / 2) sigma - rho sw(sigma)`` (constant plus proportional rate), where ``sw`` is
``sign`` or the smooth ``s / (|s| + eps)`` with each loop's own boundary layer ``eps = 2 rho / reach`` (in the units
of its sliding variable): inside the layer the two terms add to the linear ``-reach * sigma``, a pole at ``-reach``
that the gain design places (``AttitudeGains``); outside it ``sigma`` still decays at least at ``reach / 2`` (a
constant rate ``rho`` alone would take tens of seconds from a metre of error when ``rho`` is sized to the model's
uncertainty, not to the initial error).

Saturation: the tilt rate command is clipped to ``tilt_rate_max`` and the tilt of the setpoint to ``tilt_max``
(the autopilot's own limit, PX4 ``MPC_TILTMAX_AIR``, ArduPilot ``ANGLE_MAX``); the thrust to
``[thrust_min, thrust_max]``. While a loop's command is clipped its integral is held (no windup), as in
``offboard.control.smc``. A non-finite input gives the level hover command with ``valid = False``.

The command carries the torques the autopilot's rate loop is expected to apply (``I B (omega_c - omega)``, ``B`` the
rate-loop bandwidth) in the torque-level command's fields, so that the log and an estimator fed with commands keep
their meaning, and the attitude setpoint (model-frame ZYX Euler angles) and body-rate command beside them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import NamedTuple

from estimators.model.cable import cable_from_planar
from estimators.model.control_state import ControlState
from estimators.model.flatness import flat_constants
from estimators.model.frames import wrap_angle
from estimators.model.rotations import thrust_direction_trig
from estimators.model.vehicle import Vehicle
from offboard.control.disturbance_observer import observe_disturbance
from offboard.control.smc import ControllerMemory, per_params, switching
from offboard.control.smc_attitude_design import (
    GAIN_NAMES,
    PX4_ATTITUDE_P,
    PX4_YAW_P,
    AttitudeGains,
    InnerLoop,
    design_gains,
    robust_gains_exist,
)


@dataclass(frozen=True)
class AttitudeParams:
    """Everything :func:`step` needs besides the signals (SI, radians).

    vehicle: nominal vehicle; inner: the autopilot's loops as assumed; gains: see :class:`AttitudeGains`;
    switching: ``"smooth"`` (default for flight; each loop's boundary layer ``rho / reach``) or ``"sign"``;
    tilt_max: largest tilt of the setpoint (rad; the autopilot's own limit); tilt_rate_max: largest commanded tilt
    rate (rad/s); thrust_min, thrust_max: collective thrust limits (N); gain_overrides: the gains set by hand
    (kept through :meth:`with_inner`); drag_feedforward: the vehicle file's still-air drag (``linear_drag``) is part
    of the law's model with a load (module docstring) - False where the estimate already carries it, as the filter's
    fed-forward external acceleration does (``MeasuredTuning.external_feedforward``).
    """

    vehicle: Vehicle
    inner: InnerLoop
    gains: AttitudeGains
    switching: str = "smooth"
    tilt_max: float = 0.6
    tilt_rate_max: float = 2.0
    thrust_min: float = 0.0
    thrust_max: float = math.inf
    gain_overrides: tuple[tuple[str, float], ...] = field(default=())
    drag_feedforward: bool = True

    def __post_init__(self) -> None:
        if self.switching not in ("sign", "smooth"):
            raise ValueError(f"switching must be 'sign' or 'smooth', got {self.switching!r}")
        if not (0.0 < self.tilt_max < 1.5):
            raise ValueError(f"tilt_max must be within (0, 1.5) rad, got {self.tilt_max!r}")
        if not (self.tilt_rate_max > 0.0 and math.isfinite(self.tilt_rate_max)):
            raise ValueError(f"tilt_rate_max must be a finite number > 0, got {self.tilt_rate_max!r}")

    @classmethod
    def for_vehicle(
        cls,
        vehicle: Vehicle,
        inner: InnerLoop | None = None,
        overrides: dict[str, float] | None = None,
        **kwargs: object,
    ) -> AttitudeParams:
        """Parameters for ``vehicle``: gains from :func:`design_gains`, thrust limits from its motors."""
        inner = inner or InnerLoop()
        tilt_max = float(kwargs.get("tilt_max", 0.6))  # type: ignore[arg-type]
        gains = design_gains(vehicle, inner, overrides, tilt_max)
        kw: dict[str, object] = {"thrust_min": 0.0, "thrust_max": vehicle.thrust_max}
        kw.update(kwargs)
        return cls(
            vehicle=vehicle,
            inner=inner,
            gains=gains,
            gain_overrides=tuple(sorted((overrides or {}).items())),
            **kw,  # type: ignore[arg-type]
        )

    def with_inner(self, inner: InnerLoop, tilt_max: float | None = None) -> AttitudeParams:
        """The same parameters re-derived for other inner loops (the gains read from the autopilot) and tilt limit;
        gains set by hand stay."""
        tm = self.tilt_max if tilt_max is None else tilt_max
        gains = design_gains(self.vehicle, inner, dict(self.gain_overrides), tm)
        return replace(self, inner=inner, gains=gains, tilt_max=tm)

    def boundary_layers(self) -> tuple[float, float, float]:
        """(eps_F, eps_z, eps_psi): each loop's boundary layer, 2 rho / reach, in its sliding variable's units."""
        G = self.gains
        return 2.0 * G.rho_F / G.reach_F, 2.0 * G.rho_z / G.reach_z, 2.0 * G.rho_psi / G.reach_psi


class AttitudeCommand(NamedTuple):
    """The law's output: the torque-level command's fields (thrust N; the torques N m the autopilot's rate loop is
    expected to apply, body FLU; sliding variables; flags), then the attitude setpoint (model frame ZYX Euler
    angles, rad) and the commanded body rates (FLU, rad/s)."""

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
    phi_sp: float
    theta_sp: float
    psi_sp: float
    p_c: float
    q_c: float
    r_c: float


def hover_command(params: AttitudeParams, psi: float = 0.0, valid: bool = False) -> AttitudeCommand:
    """Level attitude at heading ``psi`` with the hover thrust (M + m) g."""
    v = params.vehicle
    thrust = min(max(v.hover_thrust, params.thrust_min), params.thrust_max)
    if not math.isfinite(psi):
        psi = 0.0
    return AttitudeCommand(thrust, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, False, valid, 0.0, 0.0, psi, 0.0, 0.0, 0.0)


class _Derived(NamedTuple):
    with_load: bool
    k: tuple[float, ...]
    c: float
    l: float
    g: float
    M: float
    m: float
    Mt: float
    lam1: float
    lam0: float
    eps: tuple[float, float, float]
    sin_tilt_max: float
    dist_max: float
    #: the vehicle file's still-air drag as the tilt that balances it, rad per m/s of the vehicle's speed
    #: (``linear_drag / (M_t g)``; 0: no drag known)
    drag_tilt: float


@per_params
def _derived(p: AttitudeParams) -> _Derived:
    v = p.vehicle
    with_load = v.mass_load > 0.0
    k = flat_constants(v)
    G = p.gains
    return _Derived(
        with_load,
        G.horizontal_coefficients(with_load),
        k.c if with_load else v.gravity,
        v.cable_length,
        v.gravity,
        v.mass_vehicle,
        v.mass_load,
        v.total_mass,
        2.0 * G.zeta_z * G.wn_z,
        G.wn_z * G.wn_z,
        p.boundary_layers(),
        math.sin(p.tilt_max),
        v.gravity * math.tan(p.tilt_max),
        v.linear_drag / (v.total_mass * v.gravity) if p.drag_feedforward and with_load else 0.0,
    )


def step(
    t: float,
    est: ControlState,
    ref_fx: tuple[float, ...],
    ref_fy: tuple[float, ...],
    ref_z: tuple[float, ...],
    ref_psi: tuple[float, ...],
    memory: ControllerMemory,
    params: AttitudeParams,
) -> tuple[AttitudeCommand, ControllerMemory]:
    """One tick of the attitude-level law (module docstring).

    t: time (s); est: state estimate (model frame); ref_fx, ref_fy: reference flat outputs (the load's position,
    or the vehicle's without a load) and derivatives, orders 0..5 at least (m ... m/s^5, world NWU); ref_z: height
    orders 0..2; ref_psi: heading orders 0..1 (rad). Returns the command and the new memory.
    """
    ref_sum = sum(ref_fx[:6]) + sum(ref_fy[:6]) + ref_z[0] + ref_z[1] + ref_z[2] + ref_psi[0] + ref_psi[1]
    if not (est.is_finite() and math.isfinite(t) and math.isfinite(ref_sum)):
        return hover_command(params, est.psi), memory
    d = _derived(params)
    G = params.gains
    smooth = params.switching == "smooth"
    eps_f, eps_z, eps_psi = d.eps
    dt = 0.0 if memory.t is None else max(0.0, t - memory.t)

    phi, theta, psi = est.phi, est.theta, est.psi
    sf, cf = math.sin(phi), math.cos(phi)
    st, ct = math.sin(theta), math.cos(theta)
    sp, cp = math.sin(psi), math.cos(psi)
    n1, n2, n3 = thrust_direction_trig(sf, cf, st, ct, sp, cp)  # world NWU

    # ---- height: thrust -----------------------------------------------------------------------------------
    (r1, r2, r3), (q1, q2, q3) = cable_from_planar(est.alpha_y, est.alpha_x, est.alpha_y_rate, est.alpha_x_rate)
    if d.with_load:
        nr = n1 * r1 + n2 * r2 + n3 * r3
        g_z = (d.Mt * max(n3, 0.3) - d.m * nr * r3) / (d.M * d.Mt)
        f_z = d.m * d.l * (q1 * q1 + q2 * q2 + q3 * q3) * r3 / d.Mt - d.g
    else:
        g_z = max(n3, 0.3) / d.M
        f_z = -d.g
    e_z = est.z - ref_z[0]
    e_zd = est.z_rate - ref_z[1]
    int_z = memory.int_z + e_z * dt
    s_z = e_zd + d.lam1 * e_z + d.lam0 * int_z
    sw_z = G.rho_z * switching(s_z, eps_z, smooth) + 0.5 * G.reach_z * s_z
    thrust = (ref_z[2] - f_z - d.lam1 * e_zd - d.lam0 * e_z - sw_z) / g_z
    sat_z = False
    if thrust > params.thrust_max:
        thrust, sat_z = params.thrust_max, True
    elif thrust < params.thrust_min:
        thrust, sat_z = params.thrust_min, True

    # ---- horizontal: commanded tilt rate per world axis ------------------------------------------------------
    k = d.k
    dist_x, dist_y, vel_x, vel_y = memory.dist_x, memory.dist_y, memory.vel_x, memory.vel_y
    if d.with_load:
        ex = [est.fx[i] - ref_fx[i] for i in range(5)]
        ey = [est.fy[i] - ref_fy[i] for i in range(5)]
        if d.drag_tilt > 0.0:  # F^(4) = c (a + n - kt v): the tilt that only balances the drag moves nothing
            ex[4] -= d.c * d.drag_tilt * (est.fx[1] - d.l * est.alpha_y_rate)
            ey[4] -= d.c * d.drag_tilt * (est.fy[1] - d.l * est.alpha_x_rate)
        ffx, ffy = ref_fx[5], ref_fy[5]
        ax_rate, ay_rate = -est.fx[3] / d.g, -est.fy[3] / d.g  # a' = -F'''/g
    else:
        # the vehicle itself: position, velocity, and the acceleration g n / n3 of thrust balancing the weight
        px = est.fx[0] - d.l * est.alpha_y
        py = est.fy[0] - d.l * est.alpha_x
        vx = est.fx[1] - d.l * est.alpha_y_rate
        vy = est.fy[1] - d.l * est.alpha_x_rate
        an3 = d.g / max(n3, 0.3)
        dist_x, dist_y, vel_x, vel_y = observe_disturbance(memory, dt, vx, vy, an3 * n1, an3 * n2, G.wn_d, d.dist_max)
        # the acceleration: the tilt's plus the disturbance the velocity shows (docs/model.md section 12.2)
        ex = [px - ref_fx[0], vx - ref_fx[1], an3 * n1 + dist_x - ref_fx[2]]
        ey = [py - ref_fy[0], vy - ref_fy[1], an3 * n2 + dist_y - ref_fy[2]]
        ffx, ffy = ref_fx[3], ref_fy[3]
        ax_rate = ay_rate = 0.0
    r = len(ex)
    int_fx = memory.int_fx + ex[0] * dt
    int_fy = memory.int_fy + ey[0] * dt
    sigma_x = ex[r - 1] + k[0] * int_fx
    sigma_y = ey[r - 1] + k[0] * int_fy
    vx_c = ffx
    vy_c = ffy
    for i in range(r - 1):
        sigma_x += k[i + 1] * ex[i]
        sigma_y += k[i + 1] * ey[i]
    for i in range(r):
        vx_c -= k[i] * ex[i]
        vy_c -= k[i] * ey[i]
    half_reach = 0.5 * G.reach_F
    vx_c -= G.rho_F * switching(sigma_x, eps_f, smooth) + half_reach * sigma_x
    vy_c -= G.rho_F * switching(sigma_y, eps_f, smooth) + half_reach * sigma_y
    ndx = vx_c / d.c - ax_rate  # commanded world tilt rate, rad/s
    ndy = vy_c / d.c - ay_rate
    if d.drag_tilt > 0.0:  # and the rate of the tilt that balances the drag, kt F*'' (the reference's acceleration)
        ndx += d.drag_tilt * ref_fx[2]
        ndy += d.drag_tilt * ref_fy[2]
    sat_f = False
    nd = math.hypot(ndx, ndy)
    if nd > params.tilt_rate_max:
        s = params.tilt_rate_max / nd
        ndx, ndy, sat_f = ndx * s, ndy * s, True
    wi = params.inner.attitude_bandwidth
    nsx = n1 + ndx / wi
    nsy = n2 + ndy / wi
    ns = math.hypot(nsx, nsy)
    if ns > d.sin_tilt_max:
        s = d.sin_tilt_max / ns
        nsx, nsy, sat_f = nsx * s, nsy * s, True
    nsz = math.sqrt(max(0.0, 1.0 - nsx * nsx - nsy * nsy))

    # ---- yaw ------------------------------------------------------------------------------------------------
    e_psi = wrap_angle(psi - ref_psi[0])
    int_psi = memory.int_psi + e_psi * dt
    s_psi = e_psi + G.k_psi * int_psi
    psid_c = ref_psi[1] - G.k_psi * e_psi - G.rho_psi * switching(s_psi, eps_psi, smooth) - 0.5 * G.reach_psi * s_psi
    psi_sp = wrap_angle(psi + psid_c / params.inner.yaw_bandwidth)

    # ---- the attitude setpoint: thrust direction n_sp at heading psi_sp, as ZYX angles --------------------------
    cps, sps = math.cos(psi_sp), math.sin(psi_sp)
    m1 = cps * nsx + sps * nsy  # Rz(-psi_sp) n_sp = [cos(phi) sin(theta), -sin(phi), cos(phi) cos(theta)]
    m2 = -sps * nsx + cps * nsy
    phi_sp = math.atan2(-m2, math.sqrt(m1 * m1 + nsz * nsz))
    theta_sp = math.atan2(m1, nsz)

    # commanded body rates and the torques the autopilot's rate loop will apply for them (log, estimator)
    t1d = cp * ndx + sp * ndy  # heading-aligned tilt rate [theta', -phi']
    t2d = -sp * ndx + cp * ndy
    p_c, q_c, r_c = -t2d, t1d, psid_c  # small-angle body rates (FLU)
    i1, i2, i3 = params.vehicle.inertia
    b1, b2, b3 = params.inner.rate_bandwidth
    w1 = est.phi_rate - st * est.psi_rate
    w2 = cf * est.theta_rate + sf * ct * est.psi_rate
    w3 = -sf * est.theta_rate + cf * ct * est.psi_rate
    tau_phi = i1 * b1 * (p_c - w1)
    tau_theta = i2 * b2 * (q_c - w2)
    tau_psi = i3 * b3 * (r_c - w3)

    cmd = AttitudeCommand(
        thrust,
        tau_phi,
        tau_theta,
        tau_psi,
        s_z,
        s_psi,
        sigma_x,
        sigma_y,
        sat_z or sat_f,
        True,
        phi_sp,
        theta_sp,
        psi_sp,
        p_c,
        q_c,
        r_c,
    )
    total = thrust + phi_sp + theta_sp + psi_sp + tau_phi + tau_theta + tau_psi + int_z + int_psi + int_fx + int_fy
    total += dist_x + dist_y
    if not math.isfinite(total):
        return hover_command(params, psi), memory
    if sat_z:
        int_z = memory.int_z
    if sat_f:
        int_fx, int_fy = memory.int_fx, memory.int_fy
    return cmd, ControllerMemory(int_z, int_psi, int_fx, int_fy, t, dist_x, dist_y, vel_x, vel_y)


__all__ = [
    "GAIN_NAMES",
    "PX4_ATTITUDE_P",
    "PX4_YAW_P",
    "AttitudeCommand",
    "AttitudeGains",
    "AttitudeParams",
    "InnerLoop",
    "design_gains",
    "hover_command",
    "robust_gains_exist",
    "step",
]
