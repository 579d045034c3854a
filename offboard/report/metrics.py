"""Figures of merit of a closed-loop run: RMS, ISE, maxima, control effort, chattering, residual swing.

Definitions (all over the logged controller ticks, SI units and radians):

- ``rms[k] = sqrt(mean(e_k^2))`` and ``ise[k] = integral e_k^2 dt`` (trapezoid), for the tracking errors
  e_Fx, e_Fy (flat outputs of the true state minus reference, m), e_z (m), e_psi (rad) and the swing
  angles alpha, alpha_x, alpha_y (rad, whose reference is 0). The paper's Table 2 reports the same
  quantities; its ISE is integral e^2 dt (errata section 6), so ``ise / rms^2`` is the duration;
- ``chattering``: total variation of the torque commands per second, ``sum_j sum_k |tau_j[k+1] - tau_j[k]| / T``
  (N m / s), the quantity that the continuous switching of (92) reduces; per-channel values (thrust in N/s)
  are in ``chattering_by_channel``;
- ``residual_swing_rad``: largest alpha after the reference has come to rest (point-to-point scenarios);
- ``settling_time_s``: time after arrival until alpha < 0.02 rad and |e_F| < 0.02 m for the rest of the run.

The paper's Table 2 is kept here for the side-by-side table that ``slung sim`` prints.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from offboard.logs.runlog import COL, SimLog
from offboard.report.filter_readouts import BAND_ERRORS, coverage

#: Paper Table 2 (sign(.) switching): RMS (m or rad) and ISE (m^2 s or rad^2 s).
PAPER_TABLE2: dict[str, tuple[float, float]] = {
    "e_Fx": (0.0900, 0.4883),
    "e_Fy": (0.1240, 0.7687),
    "e_z": (0.0479, 0.1143),
    "e_psi": (0.0584, 0.0013),
    "alpha": (0.11, 0.6051),
    "alpha_x": (0.0699, 0.2444),
    "alpha_y": (0.0923, 0.4263),
}

SETTLING_SWING_RAD = 0.02
SETTLING_POSITION_M = 0.02

_TRACKED = ("e_Fx", "e_Fy", "e_z", "e_psi", "alpha", "alpha_x", "alpha_y")


def _ise(t: np.ndarray, e: np.ndarray) -> float:
    if len(t) < 2:
        return 0.0
    sq = e * e
    return float(np.sum(0.5 * (sq[1:] + sq[:-1]) * np.diff(t)))


def compute(log: SimLog) -> dict[str, Any]:
    """The ``metrics.json`` dictionary of a run (see module docstring for definitions)."""
    d = log.data
    t = d[:, COL["t"]]
    duration = float(t[-1] - t[0]) if len(t) > 1 else 0.0
    out: dict[str, Any] = {
        "scenario": log.scenario.name,
        "duration_s": duration,
        "completed": bool(len(t) > 0 and t[-1] >= log.scenario.duration - 1e-6),
        "all_finite": bool(np.all(np.isfinite(d[:, : COL["est_alpha_x"]]))),
    }
    rms: dict[str, float] = {}
    ise: dict[str, float] = {}
    mx: dict[str, float] = {}
    for key in _TRACKED:
        e = d[:, COL[key]]
        rms[key] = float(np.sqrt(np.mean(e * e)))
        ise[key] = _ise(t, e)
        mx[key] = float(np.max(np.abs(e)))
    out["rms"], out["ise"], out["max"] = rms, ise, mx

    u = d[:, COL["u"]]
    taus = np.stack([d[:, COL["tau_phi"]], d[:, COL["tau_theta"]], d[:, COL["tau_psi"]]], axis=1)
    tv = {
        "u": float(np.sum(np.abs(np.diff(u)))) / max(duration, 1e-12),
        "tau_phi": float(np.sum(np.abs(np.diff(taus[:, 0])))) / max(duration, 1e-12),
        "tau_theta": float(np.sum(np.abs(np.diff(taus[:, 1])))) / max(duration, 1e-12),
        "tau_psi": float(np.sum(np.abs(np.diff(taus[:, 2])))) / max(duration, 1e-12),
    }
    out["control"] = {
        "u_min": float(np.min(u)),
        "u_max": float(np.max(u)),
        "tau_max": float(np.max(np.abs(taus))),
        "chattering": tv["tau_phi"] + tv["tau_theta"] + tv["tau_psi"],
        "chattering_by_channel": tv,
        "saturated_fraction": float(np.mean(d[:, COL["saturated"]])),
    }
    out["cable"] = {
        "slack_steps": int(log.slack_steps),
        "min_tension_n": float(log.min_tension) if math.isfinite(log.min_tension) else None,
    }

    ds = log.scenario.disturbance_start
    if ds is not None and t[-1] > ds:
        after = t >= ds
        out["after_disturbance"] = {
            "start_s": ds,
            "max": {k: float(np.max(np.abs(d[after, COL[k]]))) for k in _TRACKED},
            "rms": {k: float(np.sqrt(np.mean(d[after, COL[k]] ** 2))) for k in _TRACKED},
        }

    ta = log.scenario.arrival_time
    if ta is not None:
        out.update(_arrival_metrics(t, d, ta))

    out["wall_time_s"] = float(log.wall_time)
    out["realtime_factor"] = duration / log.wall_time if log.wall_time > 0 else math.inf
    out["config"] = {
        "switching": None,  # filled by the caller, which knows the controller parameters
        "plant_dt_s": log.config.plant_dt,
        "control_rate_hz": log.config.control_rate,
        "attitude_model": log.config.attitude_model,
        "actuators": log.config.actuators,
        "sensors": log.config.sensors or "truth",
        "estimator": log.config.estimator,
        "load_sensor": log.config.load_sensor,
        "seed": log.config.seed,
        "vehicle": log.vehicle.name,
    }
    if log.config.estimator != "truth":
        out["estimation"] = estimation_metrics(log)
    return out


def _arrival_metrics(t: np.ndarray, d: np.ndarray, ta: float) -> dict[str, Any]:
    after = t >= ta
    if not np.any(after):
        return {"residual_swing_rad": None, "settling_time_s": None}
    alpha = d[after, COL["alpha"]]
    ef = np.hypot(d[after, COL["e_Fx"]], d[after, COL["e_Fy"]])
    ok = (alpha < SETTLING_SWING_RAD) & (ef < SETTLING_POSITION_M)
    # settled from the first index after which every sample is ok
    bad = np.nonzero(~ok)[0]
    if len(bad) == 0:
        settling: float | None = 0.0
    elif bad[-1] == len(ok) - 1:
        settling = None  # never settled within the run
    else:
        settling = float(t[after][bad[-1] + 1] - ta)
    return {
        "arrival_time_s": ta,
        "residual_swing_rad": float(np.max(alpha)),
        "residual_swing_rms_rad": float(np.sqrt(np.mean(alpha**2))),
        "settling_time_s": settling,
        "settling_criteria": {"alpha_rad": SETTLING_SWING_RAD, "flat_output_error_m": SETTLING_POSITION_M},
    }


def estimation_metrics(log: SimLog) -> dict[str, Any]:
    """RMS estimation errors (estimate minus truth) and NEES statistics of a run with a filter."""
    d = log.data
    names = ["est_alpha_x", "est_alpha_y", "est_alpha_x_rate", "est_alpha_y_rate"]
    names += [f"est_Fx{i}" for i in range(6)] + [f"est_Fy{i}" for i in range(6)] + ["est_z", "est_psi"]
    rms = {n.removeprefix("est_"): float(np.sqrt(np.nanmean(d[:, COL[n]] ** 2))) for n in names}
    nees = d[:, COL["nees"]]
    nees = nees[np.isfinite(nees)]
    return {
        "rms": rms,
        "swing_rms_deg": {
            "alpha_x": math.degrees(rms["alpha_x"]),
            "alpha_y": math.degrees(rms["alpha_y"]),
        },
        "nees_mean": float(np.mean(nees)) if len(nees) else None,
        "nees_samples": len(nees),
        # how often the true error stayed within the filter's own +-2 sigma (about 0.95 for a consistent filter)
        "within_2sigma": {name: coverage(d[:, COL[err]], d[:, COL[sd]]) for name, err, sd in BAND_ERRORS if sd in COL},
        "stats": dict(log.estimator_stats),
    }


def format_table(metrics: dict[str, Any]) -> str:
    """The terminal table: this run's RMS and ISE beside the paper's Table 2."""
    lines = [
        f"{'signal':<9} {'RMS':>10} {'paper RMS':>10} {'ratio':>7}   {'ISE':>10} {'paper ISE':>10}",
        "-" * 64,
    ]
    for key in _TRACKED:
        r, i = metrics["rms"][key], metrics["ise"][key]
        pr, pi = PAPER_TABLE2[key]
        unit = "rad" if key in ("e_psi", "alpha", "alpha_x", "alpha_y") else "m"
        lines.append(f"{key:<9} {r:>10.4f} {pr:>10.4f} {r / pr:>7.2f}   {i:>10.4f} {pi:>10.4f}  {unit}")
    c = metrics["control"]
    lines.append("-" * 64)
    lines.append(
        f"thrust {c['u_min']:.3f}..{c['u_max']:.3f} N, |tau| max {c['tau_max']:.4f} N m, "
        f"chattering {c['chattering']:.3g} N m/s"
    )
    if metrics.get("residual_swing_rad") is not None or "arrival_time_s" in metrics:
        st = metrics.get("settling_time_s")
        lines.append(
            f"after arrival at {metrics['arrival_time_s']:.2f} s: residual swing "
            f"{metrics['residual_swing_rad']:.4f} rad, settling time "
            + (f"{st:.2f} s" if st is not None else "not settled")
        )
    if metrics["cable"]["slack_steps"]:
        lines.append(
            f"WARNING: the cable was slack for {metrics['cable']['slack_steps']} plant steps "
            f"(min tension {metrics['cable']['min_tension_n']:.3f} N): the rigid-cable model did not hold"
        )
    if metrics.get("config", {}).get("sensors") == "mavlink":  # a flight (slung fly / demo), not a simulation
        lines.append(
            f"flew {metrics['duration_s']:.1f} s under offboard control, {metrics['wall_time_s']:.1f} s "
            "from connection to the end"
        )
    else:
        lines.append(
            f"simulated {metrics['duration_s']:.1f} s in {metrics['wall_time_s']:.2f} s "
            f"({metrics['realtime_factor']:.1f}x real time)"
        )
    return "\n".join(lines)
