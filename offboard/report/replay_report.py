"""Outputs of ``slung replay``: ``timeseries.slts``, ``metrics.json``, figures and the terminal summary table.

Files are written atomically (``offboard.outputs``); figures use matplotlib's Agg backend. Units: SI, radians,
model frame; ``t`` is the vehicle's time since boot (s).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from offboard.logs.replay_records import SP_ACT, SP_ATT, ReplayResult
from offboard.logs.timeseries_file import RUN_LOG_NAME, write_table
from offboard.outputs import write_json_atomic
from offboard.report.figures import pyplot, save_png


def write_timeseries(result: ReplayResult, path: Path) -> Path:
    """Every tick as a time series file (``offboard.logs.timeseries_file``; NaN where a quantity does not apply),
    full precision."""
    return write_table(path, result.columns, result.data)


def write_outputs(
    result: ReplayResult, out_dir: Path, figures: bool = True, log_name: str = "log", cable_length: float = 1.0
) -> list[Path]:
    """metrics.json, timeseries.slts and (optionally) the PNG figures in ``out_dir``; returns the paths written
    (``report.html``: ``offboard.report.replay_report_html``). ``log_name`` titles the figures; ``cable_length`` (m, the
    controller's vehicle) places the vehicle behind the estimated flat output."""
    paths = [
        write_json_atomic(out_dir / "metrics.json", result.metrics),
        write_timeseries(result, out_dir / RUN_LOG_NAME),
    ]
    if figures and len(result.data) > 1:
        from offboard.report.replay_figures import draw_pngs

        paths += draw_figures(result, out_dir)
        paths += draw_pngs(result, out_dir, log_name, cable_length)
    return paths


def swing_shown(metrics: dict[str, Any]) -> bool:
    """Whether the replay has a swing to show: not when the load identification found no load attached (the filter
    then ran without swing states)."""
    return (metrics.get("load") or {}).get("attached") is not False


def load_line(load: dict[str, Any]) -> str:
    """The summary's ``load`` line: the decision, the identified values with their 1-sigma uncertainty, why."""
    if load.get("attached") is None:
        return f"unknown ({load.get('reason')})"
    if not load["attached"]:
        return f"not attached ({load.get('reason')})"
    unc = load.get("uncertainty") or {}
    return (
        f"attached: mass {_fmt(load['mass_kg'], ' kg')} +- {_fmt(unc.get('mass_kg'), ' kg')}, cable "
        f"{_fmt(load['cable_m'], ' m')} +- {_fmt(unc.get('cable_m'), ' m')} (vehicle file: "
        f"{load['prior']['mass_kg']:g} kg on {load['prior']['cable_m']:g} m)"
    )


def _panel(ax: Any, ylabel: str, ncol: int = 1) -> None:
    """One panel of the replay's figures: its unit, grid and legend (upper right, small)."""
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right", fontsize=8, ncol=ncol)


def _frame(axes: Any, title: str) -> None:
    """A replay figure's shared time axis (the vehicle's clock) and title."""
    axes[-1].set_xlabel("vehicle time (s)")
    axes[0].set_title(title)


def draw_swing(result: ReplayResult, save: Any) -> None:
    """swing.png: the estimated swing, the cable-angle sensor and the payload's truth where the log has them."""
    plt = pyplot()
    col = result.column
    t = col("t")
    fig, axes = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True)
    for i, (ax, name) in enumerate(zip(axes, ("alpha_x", "alpha_y"))):
        ax.plot(t, col(name), lw=1.0, label="estimate")
        meas = col("meas_" + name)
        if np.any(np.isfinite(meas)):
            ax.plot(t, meas, lw=0.8, alpha=0.7, label="cable-angle sensor (latest)")
        if result.swing_truth is not None and np.any(np.isfinite(result.swing_truth[:, i])):
            ax.plot(t, result.swing_truth[:, i], ":", lw=1.2, label="payload truth")
        _panel(ax, f"{name} (rad)")
    _frame(axes, "swing estimate")
    save(fig, "swing.png")


def draw_figures(result: ReplayResult, out_dir: Path) -> list[Path]:
    """swing.png (estimated swing vs the cable-angle sensor and the payload's truth), flat_outputs.png (estimated
    F_x, F_y, z, psi and their references), setpoints.png (logged vs recomputed setpoints and their difference,
    when the log has them)."""
    plt = pyplot()
    col = result.column
    t = col("t")
    paths: list[Path] = []

    def save(fig: Any, name: str) -> None:
        paths.append(save_png(fig, out_dir / name))

    if swing_shown(result.metrics):
        draw_swing(result, save)

    fig, axes = plt.subplots(4, 1, figsize=(9, 8), sharex=True)
    for ax, (name, ref, unit) in zip(
        axes, (("Fx", "Fx_ref", "m"), ("Fy", "Fy_ref", "m"), ("z", "z_ref", "m"), ("psi", "psi_ref", "rad"))
    ):
        ax.plot(t, col(name), lw=1.0, label="estimate")
        r = col(ref)
        if np.any(np.isfinite(r)):
            ax.plot(t, r, "--", lw=1.0, label="reference")
        _panel(ax, f"{name} ({unit})")
    _frame(axes, "flat outputs, height and heading")
    save(fig, "flat_outputs.png")

    names = SP_ATT if result.output == "attitude" else SP_ACT
    if np.any(np.isfinite(col("log_thrust"))):
        show = ("q_x", "q_y", "q_z", "thrust") if result.output == "attitude" else names
        recomputed = np.any(np.isfinite(col("sp_" + show[-1])))
        n_ax = len(show) + (1 if recomputed else 0)
        fig, axes = plt.subplots(n_ax, 1, figsize=(9, 2.0 * n_ax), sharex=True)
        for ax, name in zip(axes, show):
            ax.plot(t, col("log_" + name), lw=1.2, label="logged")
            if recomputed:
                ax.plot(t, col("sp_" + name), "--", lw=1.0, label="recomputed")
            _panel(ax, name)
        if recomputed:  # the difference, where the two curves above are indistinguishable
            ax = axes[-1]
            for name in show:
                ax.plot(t, col("sp_" + name) - col("log_" + name), lw=0.8, label=name)
            _panel(ax, "recomputed - logged", ncol=len(show))
        _frame(axes, f"setpoints ({result.output}): logged vs recomputed")
        save(fig, "setpoints.png")
    return paths


#: a printed result beyond this is not a result but a diverged estimate: it is printed as such, never as a number
PRINT_LIMIT = 1e6


def _fmt(v: Any, unit: str = "") -> str:
    """One value of the summary: "-" for none or NaN, "unusable" beyond :data:`PRINT_LIMIT`."""
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, (int, float)) and abs(v) > PRINT_LIMIT:
        return "unusable (diverged)"
    if isinstance(v, float):
        return f"{v:.4g}{unit}"
    return f"{v}{unit}"


def format_summary(metrics: dict[str, Any], reader: dict[str, Any] | None = None) -> str:
    """The terminal summary table: the log's contents, what is missing, estimation, tracking, agreement."""
    inv = metrics["log"]
    rows: list[tuple[str, str]] = []
    if reader is not None:
        rows.append(("packets", f"{reader['packets']} (MAVLink 1: {reader['mavlink1']}, 2: {reader['mavlink2']})"))
        rows.append(
            (
                "skipped",
                f"bad CRC {reader['bad_crc']}, garbage {reader['garbage_bytes']} B in "
                f"{reader['resyncs']} runs, unknown ids {reader['unknown_packets']}, "
                f"truncated {reader['truncated']}",
            )
        )
    rows.append(("autopilot", f"{_fmt(inv['autopilot'])} (system {_fmt(inv['autopilot_sysid'])})"))
    vtype, vclass = _fmt(inv["vehicle_type"]), inv["vehicle_class"]
    rows.append(("vehicle", vtype if vtype == vclass else f"{vtype} ({vclass})"))
    rows.append(
        (
            "systems",
            ", ".join(f"{s['sysid']}/{s['compid']}" + (f" {s['type']}" if s["type"] else "") for s in inv["systems"])
            or "-",
        )
    )
    m = inv["measurements"]
    rows.append(
        (
            "telemetry",
            f"attitude {m['Attitude']}, position {m['PositionVelocity']}, imu {m['Imu']}, load angle {m['LoadAngle']}",
        )
    )
    rows.append(
        (
            "offboard",
            f"{_fmt(inv['has_offboard_segment'])} ({inv['setpoints_to_autopilot']} setpoints, "
            f"{inv['offboard_heartbeats']} offboard heartbeats)",
        )
    )
    if inv.get("flight_modes"):
        rows.append(("modes", ", ".join(inv["flight_modes"])))
    if "airborne_segments" in inv:
        segs = inv["airborne_segments"]
        rows.append(
            (
                "flight",
                f"armed {inv['armed_s']:.1f} s, {len(segs)} airborne segment(s)"
                + "".join(f"; {s['from_s']:.1f} .. {s['to_s']:.1f} s" for s in segs[:6])
                + ("; ..." if len(segs) > 6 else ""),
            )
        )
    load = metrics.get("load")
    if load:
        rows.append(("load", load_line(load)))
    est = metrics.get("estimation")
    if est and est.get("partial"):
        from offboard.logs.replay_partial import partial_summary

        rows += partial_summary(metrics)
    elif est:
        span = est.get("vehicle_time_span_s")
        rows.append(
            (
                "replayed",
                f"{est['ticks']} ticks ({est['tick_source']})"
                + (f", t = {span[0]:.3f} .. {span[1]:.3f} s" if span else ""),
            )
        )
        if est.get("diverged_ticks"):
            div = est["divergences"]
            first = div[0] if div else None
            rows.append(
                (
                    "divergence",
                    f"{len(div)} time(s), {est['diverged_ticks']} tick(s) unusable; estimate restarted from the "
                    "autopilot's state each time"
                    + (f"; first at t = {first['t_s']:.3f} s: {first['reason']}" if first else ""),
                )
            )
        if "swing_max_rad" in est:
            rows.append(
                (
                    "swing",
                    f"max {_fmt(est.get('swing_max_rad'), ' rad')}, rms {_fmt(est.get('swing_rms_rad'), ' rad')}",
                )
            )
        if "position_vs_autopilot_m" in est:
            rows.append(
                (
                    "position vs autopilot",
                    f"rms {_fmt(est['position_vs_autopilot_m']['rms'], ' m')}, "
                    f"height rms {_fmt(est['height_vs_autopilot_m']['rms'], ' m')}",
                )
            )
        truth = est.get("swing_vs_truth")
        if truth and truth["ticks"]:
            rows.append(
                (
                    "swing vs payload truth",
                    f"alpha_x rms {_fmt(truth['alpha_x']['rms'], ' rad')}, alpha_y rms "
                    f"{_fmt(truth['alpha_y']['rms'], ' rad')} over {truth['ticks']} ticks "
                    f"(truth max {_fmt(truth['truth_swing_max_rad'], ' rad')})",
                )
            )
        for k in ("alpha_x_vs_sensor", "alpha_y_vs_sensor"):
            if k in est:
                rows.append((k, f"rms {_fmt(est[k]['rms'], ' rad')}, max {_fmt(est[k]['max'], ' rad')}"))
    tr = metrics.get("tracking")
    if tr:
        for k in ("e_Fx", "e_Fy", "e_z", "e_psi"):
            rows.append((k + " (est.)", f"rms {_fmt(tr[k]['rms'])}, max {_fmt(tr[k]['max'])}"))
    ag = metrics.get("setpoint_agreement")
    if ag:
        if "max_abs_difference" in ag:
            rows.append(
                (
                    "recomputed vs logged",
                    f"{ag['ticks_compared']} setpoints, "
                    f"{ag.get('float32_identical', 0)} identical on the wire (float32), "
                    f"max |diff| {ag['max_abs_difference']:.3g}",
                )
            )
        if "attitude_angle_rad" in ag:
            rows.append(("  attitude", f"rms {_fmt(ag['attitude_angle_rad']['rms'], ' rad')}"))
        if "thrust" in ag:
            rows.append(("  thrust", f"rms {_fmt(ag['thrust']['rms'])}"))
        if "logged_vs_autopilot_attitude_target_rad" in ag:
            a = ag["logged_vs_autopilot_attitude_target_rad"]
            rows.append(("logged vs ATTITUDE_TARGET", f"rms {_fmt(a['rms'], ' rad')}"))
    live = metrics.get("live_agreement")
    if live:
        txt = f"estimates identical {live['estimate_identical']}/{live['ticks']}"
        if "setpoint_identical" in live:
            txt += f", setpoints identical {live['setpoint_identical']}/{live['ticks']}"
        rows.append(("vs live tick log", txt + f" (max |diff| {live['estimate_max_abs_difference']:.3g})"))
    for note in (est or {}).get("notes", []):
        rows.append(("note", note))
    for reason in inv["missing"]:
        rows.append(("missing", reason))
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"  {k:<{width}}  {v}" for k, v in rows)


__all__ = ["draw_figures", "format_summary", "write_outputs", "write_timeseries"]
