"""Pre-flight feasibility check of a reference: the nominal open-loop demands it makes of the vehicle.

A pure function (no I/O, no clock): :func:`check_reference` samples the reference's flat outputs
``(F_x, F_y, z, psi)`` and their derivatives on a grid over ``[0, duration]``, maps them through the flatness
chain of the tangent-linearized model (``estimators.model.flatness``, ``docs/model.md`` section 8) to the states and
inputs the controller will have to produce if it tracks the reference exactly, and compares their peaks with the
limits of the vehicle, the controller, the setpoint mapping and the flight loop's swing watchdog. Formulas,
thresholds and their justification: ``docs/references.md``, section "Pre-flight feasibility check".

Per world axis (``F`` = F_x or F_y, ``c = M_t g^2 / (M l)``, ``omega^2 = M_t g / (M l)``, ``c / omega^2 = g``)::

    swing        a    = -F'' / g                         (rad, alpha_y for x, alpha_x for y)
    tilt         n    = F^(4) / c - a = F^(4)/c + F''/g  (rad, first-order horizontal thrust direction)
    tilt rate    n'   = F^(5)/c + F'''/g
    tilt accel.  n''  = (F^(6) + omega^2 F^(4)) / c = F^(6)/c + F^(4)/g
    tilt jerk    n''' = F^(7)/c + F^(5)/g                (F^(7) by central differences of F^(6) on the grid)

The tilt in the heading-aligned frame ``t = [theta, -phi] = Rz(-psi) n`` and its second derivative
``t'' = Rz(-psi) n'' - 2 psi' J t' - psi'' J t + psi'^2 t`` give the torques exactly as the controller computes
its feed-forward (``offboard/control/smc.py``): ``tau_theta = I_theta t1''``, ``tau_phi = -I_phi t2''``,
``tau_psi = I_psi psi''``. Collective thrust is the magnitude of the force that accelerates the centre of mass of
vehicle and load, ``u = M_t |a_com + g e3|``, with ``a_com,h = F'' + (M / M_t) l F^(4) / g`` (the vehicle is at
``F + l F''/g`` to first order, the load at ``F``) and ``a_com,z = z'' + (m / M_t) l (a . a'' + |a'|^2)`` (the
load's height ``z - l cos|a|`` to second order); it is signed, negative when that force would have to point down.
The per-axis tilt ``max(|theta|, |phi|)`` of the linear chain is compared with the mapping's per-axis tilt clip: the
controller enforces its own chain on the measured state, so the closed loop flies the linear angles (rest-to-rest:
swing 0.739 rad nominal, 0.732 in ``slung sim``, against a geometric ``atan(F''/g)`` of 0.636). The cable tension is
``T = m |xi_p'' + g e3|`` (signed like the thrust). Motor thrusts follow from the X mixer of
``sim_bridge/inner/airframe.py`` (copied here: ``offboard`` does not import the emulator on the flight path).

This is a nominal check: open loop, on the linearized model, with a perfect estimate and no disturbance. A pass
does not promise that the closed loop will fly the reference (tracking errors, disturbances, the estimator and the
autopilot's inner loops all add to the demand); a failure means that even a perfect controller could not. There is
no check of the autopilot's inner-loop bandwidth: the one tried (the unmodelled rate-loop and motor lag as an F^(6)
disturbance) did not predict the emulator's flights, see ``docs/references.md``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from estimators.model.vehicle import Vehicle
from offboard.control.nominal_demands import demand_grid, nominal_profile, profile, sample_grid

#: Swing or tilt (rad) beyond which the first-order relations of the tangent linearization that the controller relies
#: on (``F'' = -g a``, i.e. ``tan a ~ a``; ``F = x + l a``, i.e. ``sin a ~ a``) are off by more than a few percent:
#: at 0.35 rad (20 deg) ``tan a`` exceeds ``a`` by 4.2 % and ``sin a`` falls short of it by 2.0 %.
LINEARIZATION_WARN_RAD = 0.35
#: The load's height above the take-off point (the ground) below which a reference is warned about, m: the vehicle's
#: height error and the swing's bounce take about this much (ArduPilot SITL: a 2 m line flown at 2 m left its load
#: on the ground for 35 % of the control time, and nothing said so; issue 38). Below 0 the load is on the ground.
LOAD_CLEARANCE_M = 0.2
#: Fraction of a hard limit above which a demand is reported as a warning (limits without a better-founded margin).
WARN_FRACTION = 0.8


@dataclass(frozen=True)
class FeasibilityLimits:
    """The limits a reference is checked against (SI units, radians).

    thrust_min, thrust_max: collective thrust the controller and the mapping can deliver, N.
    torque_max: (roll, pitch, yaw) torque clip of the controller, N m.
    max_tilt: per-axis Euler tilt clip of the attitude setpoint (``MappingConfig.max_tilt``), rad.
    max_rate: body-rate clip of the setpoint (``MappingConfig.max_rate``), rad/s; a hard limit only with the
    ``rates`` mask (``rate_limit_hard``), otherwise the rate fields are ignored by the autopilot.
    swing_limit: the flight loop's swing watchdog (``LoopConfig.swing_limit_rad``), rad.
    thrust_reserve: thrust kept free for the height loop's switching term, ``rho_z M_t``, N.
    torque_reserve: torque kept free for the switching terms, ``(I_phi rho_F / c, I_theta rho_F / c,
    I_psi rho_psi)``, N m.
    """

    thrust_min: float
    thrust_max: float
    torque_max: tuple[float, float, float]
    max_tilt: float = 0.7
    max_rate: float = 4.0
    rate_limit_hard: bool = False
    swing_limit: float = 0.8
    thrust_reserve: float = 0.0
    torque_reserve: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @classmethod
    def from_config(cls, params: Any, mapping: Any = None, swing_limit_rad: float = 0.8) -> FeasibilityLimits:
        """Limits from ``offboard.control.smc.ControllerParams`` (thrust and torque clips, gains), an optional
        ``offboard.flight.command_mapping.MappingConfig`` (tilt and rate clips, normalized thrust range, output kind)
        and the loop's swing limit (``LoopConfig.swing_limit_rad``).

        Without a mapping (``slung sim``: the controller drives the plant directly, no setpoint clips) or with
        actuator output (no attitude setpoint) the tilt is limited by ``params.max_tilt`` (where the height law stops
        dividing by ``g_z``) and the rate check is skipped.
        """
        v: Vehicle = params.vehicle
        g = params.gains
        c = v.total_mass * v.gravity**2 / (v.mass_vehicle * v.cable_length)
        thrust_min, thrust_max = params.thrust_min, params.thrust_max
        max_tilt, max_rate, rate_hard = params.max_tilt, math.inf, False
        if mapping is not None:
            # the normalized thrust clip applies to both outputs, the tilt and rate clips only to attitude output
            # (actuator output drives the mixer directly)
            thrust_min = max(thrust_min, mapping.thrust_min * v.thrust_max)
            thrust_max = min(thrust_max, mapping.thrust_max * v.thrust_max)
            if mapping.output == "attitude":
                max_tilt, max_rate = mapping.max_tilt, mapping.max_rate
                rate_hard = mapping.mask == "rates"
        I1, I2, I3 = v.inertia
        return cls(
            thrust_min=thrust_min,
            thrust_max=thrust_max,
            torque_max=tuple(params.torque_max),  # type: ignore[arg-type]
            max_tilt=max_tilt,
            max_rate=max_rate,
            rate_limit_hard=rate_hard,
            swing_limit=swing_limit_rad,
            thrust_reserve=g.rho_z * v.total_mass,
            torque_reserve=(I1 * g.rho_F / c, I2 * g.rho_F / c, I3 * g.rho_psi),
        )


@dataclass(frozen=True)
class Demand:
    """One checked quantity: its worst value along the reference and the thresholds it is judged by.

    name: short identifier (``swing``, ``tilt``, ``thrust``, ...); label: words for messages; unit: SI unit;
    peak: the worst value (largest, or smallest when ``lower`` is True); time: when it occurs, s (reference time);
    limit: hard limit (inf / -inf: none); warn_at: warning threshold; lower: the limit is a minimum;
    status: ``"ok"``, ``"warning"`` or ``"infeasible"``; why: one-line reason for the status (empty when ok).
    """

    name: str
    label: str
    unit: str
    peak: float
    time: float
    limit: float
    warn_at: float
    lower: bool
    status: str
    why: str


@dataclass(frozen=True)
class FeasibilityResult:
    """Outcome of :func:`check_reference`.

    feasible: no hard limit is violated; demands: every checked quantity; messages: one line per warning or
    violation (violations first); duration: checked window [0, duration] s; step: grid step, s; samples: grid size.
    """

    feasible: bool
    demands: tuple[Demand, ...]
    messages: tuple[str, ...]
    duration: float
    step: float
    samples: int

    def demand(self, name: str) -> Demand:
        """The demand called ``name`` (KeyError if unknown)."""
        for d in self.demands:
            if d.name == name:
                return d
        raise KeyError(name)

    @property
    def violations(self) -> tuple[Demand, ...]:
        return tuple(d for d in self.demands if d.status == "infeasible")

    @property
    def warnings(self) -> tuple[Demand, ...]:
        return tuple(d for d in self.demands if d.status == "warning")


# ----------------------------------------------------------------------------------------------------------------
# the check
# ----------------------------------------------------------------------------------------------------------------
def _status(
    label: str, unit: str, peak: float, limit: float, warn_at: float, lower: bool, warn_reason: str, fmt: str, t: float
) -> tuple[str, str]:
    def f(x: float) -> str:
        return format(x, fmt)

    if (peak < limit) if lower else (peak > limit):
        word = "below" if lower else "above"
        return "infeasible", f"{label} {f(peak)} {unit} {word} the limit {f(limit)} {unit} at t = {t:.2f} s"
    if (peak < warn_at) if lower else (peak > warn_at):
        return "warning", f"{label} {f(peak)} {unit} at t = {t:.2f} s: {warn_reason}"
    return "ok", ""


def check_reference(
    reference: Any, duration: float, vehicle: Vehicle, limits: FeasibilityLimits, step: float | None = None
) -> FeasibilityResult:
    """Nominal demands of ``reference`` over ``[0, duration]`` (s) on ``vehicle`` against ``limits``.

    reference: anything with ``sample(t)`` returning flat outputs ``fx, fy, z, psi`` with derivatives of orders 0..6
    (``offboard.control.reference.FlatSample``; world NWU, m, rad); a ``breakpoints`` attribute, if present, puts the
    pieces' ends on the grid. step: grid step in s (default: derived from the reference, see :func:`demand_grid`).
    Pure: no I/O. Never raises for a finite reference; a non-finite demand is reported as infeasible.
    """
    duration = float(duration)
    if not (math.isfinite(duration) and duration >= 0.0):
        raise ValueError(f"duration must be a finite number >= 0 s, got {duration!r}")
    if step is None:
        ts = demand_grid(reference, duration)
    else:
        if not (math.isfinite(step) and step > 0.0):
            raise ValueError(f"step must be a finite number > 0 s, got {step!r}")
        ts = np.unique(np.concatenate([np.arange(0.0, duration, step), [duration]]))
    J = sample_grid(reference, ts)
    h = float(np.max(np.diff(ts))) if len(ts) > 1 else 0.0
    return _evaluate(ts, J, vehicle, limits, h)


def _evaluate(ts: np.ndarray, J: np.ndarray, v: Vehicle, lim: FeasibilityLimits, h: float) -> FeasibilityResult:
    p = profile(ts, J, v)
    m, g = v.mass_load, v.gravity
    swing, tilt, linear, thrust = p["swing"], p["tilt"], p["linearity"], p["thrust"]
    tau_phi, tau_theta, tau_psi, tension = p["tau_phi"], p["tau_theta"], p["tau_psi"], p["tension"]
    tilt_rate = p["tilt_rate"]

    demands: list[Demand] = []

    def add(
        name: str,
        label: str,
        unit: str,
        values: np.ndarray,
        limit: float,
        warn_at: float,
        why: str,
        lower: bool = False,
        fmt: str = ".4g",
        hard: bool = True,
    ) -> None:
        vals = np.where(np.isfinite(values), values, -math.inf if lower else math.inf)
        i = int(np.argmin(vals) if lower else np.argmax(vals))
        peak = float(vals[i])
        hard_limit = limit if hard else (-math.inf if lower else math.inf)
        status, reason = _status(label, unit, peak, hard_limit, warn_at, lower, why, fmt, float(ts[i]))
        if not math.isfinite(peak):
            status, reason = "infeasible", f"{label} is not finite at t = {float(ts[i]):.2f} s"
        demands.append(Demand(name, label, unit, peak, float(ts[i]), limit, warn_at, lower, status, reason))

    F_ = WARN_FRACTION
    sl = lim.swing_limit
    add("swing", "swing", "rad", swing, sl, F_ * sl, f"above {F_:.0%} of the swing watchdog's {sl:g} rad")
    add(
        "tilt",
        "tilt (per Euler axis)",
        "rad",
        tilt,
        lim.max_tilt,
        F_ * lim.max_tilt,
        f"above {F_:.0%} of the tilt limit {lim.max_tilt:g} rad",
    )
    add(
        "linearity",
        "largest swing or tilt",
        "rad",
        linear,
        math.inf,
        LINEARIZATION_WARN_RAD,
        f"beyond {LINEARIZATION_WARN_RAD:g} rad the controller's tangent linearization is off by more than "
        "2-4 % (tan a, sin a vs a)",
        hard=False,
    )
    # reserves for the switching terms, capped at half the limit: a switching amplitude that takes more than half
    # of the authority is a matter of the controller's tuning, which no reference can fix
    tr = min(lim.thrust_reserve, 0.5 * (lim.thrust_max - lim.thrust_min))
    add(
        "thrust",
        "collective thrust",
        "N",
        thrust,
        lim.thrust_max,
        lim.thrust_max - tr,
        f"within {tr:.2g} N (the height loop's switching share) of the limit {lim.thrust_max:.3g} N: the thrust may "
        "saturate there for a moment; to avoid it, ask for gentler climbs and accelerations",
    )
    add(
        "thrust_min",
        "collective thrust",
        "N",
        thrust,
        lim.thrust_min,
        lim.thrust_min + tr,
        f"within {tr:.2g} N (the height loop's switching share) of the minimum {lim.thrust_min:.3g} N: the thrust may "
        "saturate there for a moment; to avoid it, ask for gentler descents",
        lower=True,
    )
    for name, label, vals, k in (
        ("roll_torque", "roll torque", tau_phi, 0),
        ("pitch_torque", "pitch torque", tau_theta, 1),
        ("yaw_torque", "yaw torque", tau_psi, 2),
    ):
        tm = lim.torque_max[k]
        rs = min(lim.torque_reserve[k], 0.5 * tm)
        add(
            name,
            label,
            "N m",
            np.abs(vals),
            tm,
            tm - rs,
            f"within {rs:.2g} N m (the switching term's share) of the limit {tm:.3g} N m: the command may saturate "
            f"there for a moment, which the flight tolerates; to avoid it, ask for a slower {label.split()[0]} change "
            f"or describe a vehicle with more {label.split()[0]} authority (--vehicle)",
        )
    fmax = v.motor_thrust_max
    add(
        "motor_max",
        "largest motor thrust",
        "N",
        p["motor_max"],
        fmax,
        F_ * fmax,
        f"above {F_:.0%} of the motor's maximum {fmax:g} N",
    )
    add(
        "motor_min",
        "smallest motor thrust",
        "N",
        p["motor_min"],
        0.0,
        0.05 * fmax,
        f"below 5 % of the motor's maximum {fmax:g} N",
        lower=True,
    )
    if m > 0.0:
        add(
            "load_height",
            "load's height above the take-off point",
            "m",
            p["load_height"],
            0.0,
            LOAD_CLEARANCE_M,
            f"within {LOAD_CLEARANCE_M:g} m of the ground (the take-off point) with a {v.cable_length:g} m line: the "
            "load may touch down and the line go slack; fly higher",
            lower=True,
        )
        mg = m * g
        add(
            "tension",
            "cable tension",
            "N",
            tension,
            0.0,
            0.25 * mg,
            f"below 25 % of the load's weight {mg:.2g} N: the cable may go slack",
            lower=True,
        )
    if math.isfinite(lim.max_rate):
        add(
            "tilt_rate",
            "tilt rate",
            "rad/s",
            tilt_rate,
            lim.max_rate,
            F_ * lim.max_rate,
            f"above {F_:.0%} of the setpoint rate clip {lim.max_rate:g} rad/s",
            hard=lim.rate_limit_hard,
        )

    demands.sort(key=lambda d: {"infeasible": 0, "warning": 1, "ok": 2}[d.status])
    msgs = tuple(
        ("infeasible: " if d.status == "infeasible" else "warning: ") + d.why for d in demands if d.status != "ok"
    )
    feasible = not any(d.status == "infeasible" for d in demands)
    dur = float(ts[-1]) if len(ts) else 0.0
    return FeasibilityResult(feasible, tuple(demands), msgs, dur, h, len(ts))


def format_report(result: FeasibilityResult) -> str:
    """Terminal table: one row per checked quantity (peak, time, warning threshold, limit, status), then the
    messages."""
    head = f"{'quantity':<34} {'peak':>10} {'at t [s]':>9} {'warn at':>10} {'limit':>10}  status"
    lines = [
        f"reference feasibility (nominal, linearized; {result.samples} samples over {result.duration:g} s, "
        f"step {result.step * 1e3:.3g} ms): {'FEASIBLE' if result.feasible else 'INFEASIBLE'}",
        head,
    ]

    def num(x: float) -> str:
        return "-" if not math.isfinite(x) else f"{x:.4g}"

    for d in result.demands:
        lab = f"{d.label}{' (min)' if d.lower else ''} [{d.unit}]"
        lines.append(f"{lab:<34} {num(d.peak):>10} {d.time:>9.2f} {num(d.warn_at):>10} {num(d.limit):>10}  {d.status}")
    lines.extend(result.messages)
    return "\n".join(lines)


def peaks(result: FeasibilityResult, names: Sequence[str]) -> dict[str, float]:
    """``{name: peak}`` for the named demands (a convenience for logs and tests)."""
    return {n: result.demand(n).peak for n in names}


__all__ = [
    "LINEARIZATION_WARN_RAD",
    "LOAD_CLEARANCE_M",
    "Demand",
    "FeasibilityLimits",
    "FeasibilityResult",
    "check_reference",
    "format_report",
    "nominal_profile",
    "peaks",
]
