"""Report folder of a run: ``metrics.json``, ``timeseries.csv`` and PNG figures like the paper's Figs. 5-13.

Every file is written atomically (``offboard.outputs``). Figures use matplotlib's non-interactive Agg backend.
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import numpy as np

from offboard.figures import pyplot, save_png
from offboard.outputs import write_json_atomic, write_text_atomic
from offboard.runlog import COL, LOG_COLUMNS, SimLog

#: Columns written to timeseries.csv (all of them) and the decimation to about this rate.
TIMESERIES_RATE_HZ = 100.0


def write_timeseries(log: SimLog, path: Path, rate_hz: float = TIMESERIES_RATE_HZ) -> Path:
    """Write the log as CSV, decimated to about ``rate_hz`` (the header names every column; SI, rad)."""
    t = log.column("t")
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    stride = max(1, round(1.0 / (rate_hz * dt)))
    rows = log.data[::stride]
    buf = io.StringIO()
    np.savetxt(buf, rows, delimiter=",", header=",".join(LOG_COLUMNS), comments="", fmt="%.9g")
    return write_text_atomic(path, buf.getvalue())


def write_report(log: SimLog, metrics: dict[str, Any], out_dir: Path, figures: bool = True) -> list[Path]:
    """Write metrics.json, timeseries.csv and (optionally) the figures into ``out_dir``; returns the paths."""
    written = [write_json_atomic(out_dir / "metrics.json", metrics), write_timeseries(log, out_dir / "timeseries.csv")]
    if figures:
        written += draw_figures(log, metrics, out_dir)
    return written


def draw_figures(log: SimLog, metrics: dict[str, Any], out_dir: Path) -> list[Path]:
    """Draw the paper-style figures; returns the PNG paths."""
    plt = pyplot()
    d = log.data
    t = d[:, COL["t"]]
    c = lambda name: d[:, COL[name]]  # noqa: E731 - a short column accessor keeps the plots readable
    tag = f"{log.scenario.name}, {metrics.get('config', {}).get('switching', '')} switching"
    paths: list[Path] = []

    def save(fig: Any, name: str) -> None:
        paths.append(save_png(fig, out_dir / name))

    def panels(title: str, rows: list[tuple[str, list[tuple[np.ndarray, str, str]]]], name: str,
               mask: np.ndarray | None = None) -> None:
        fig, axes = plt.subplots(len(rows), 1, figsize=(8, 2.0 * len(rows) + 0.6), sharex=True)
        axes = np.atleast_1d(axes)
        tt = t if mask is None else t[mask]
        for ax, (ylabel, lines) in zip(axes, rows):
            for y, label, style in lines:
                ax.plot(tt, y if mask is None else y[mask], style, label=label, lw=1.0)
            ax.set_ylabel(ylabel)
            ax.grid(True, alpha=0.3)
            if len(lines) > 1:
                ax.legend(loc="best", fontsize=8)
        axes[-1].set_xlabel("time [s]")
        axes[0].set_title(f"{title} ({tag})")
        save(fig, name)

    panels("Trajectory tracking of F_x, F_y, z, psi", [
        ("F_x [m]", [(c("Fx"), "F_x", "-"), (c("Fx_ref"), "F_x*", "--")]),
        ("F_y [m]", [(c("Fy"), "F_y", "-"), (c("Fy_ref"), "F_y*", "--")]),
        ("z [m]", [(c("z"), "z", "-"), (c("z_ref"), "z*", "--")]),
        ("psi [rad]", [(c("psi"), "psi", "-"), (c("psi_ref"), "psi*", "--")]),
    ], "fig05_tracking.png")
    first = t <= min(3.0, t[-1])
    panels("Yaw tracking, first 3 s", [
        ("psi [rad]", [(c("psi"), "psi", "-"), (c("psi_ref"), "psi*", "--")]),
    ], "fig06_yaw_start.png", mask=first)
    panels("External disturbances", [
        ("F_x dist [N]", [(c("dist_fx"), "", "-")]),
        ("F_y dist [N]", [(c("dist_fy"), "", "-")]),
        ("F_z dist [N]", [(c("dist_fz"), "", "-")]),
        ("tau_psi dist [N m]", [(c("dist_tpsi"), "", "-")]),
    ], "fig07_disturbances.png")
    panels("Swing: alpha, its projections alpha_x (Y-Z), alpha_y (X-Z), and beta", [
        ("alpha [rad]", [(c("alpha"), "", "-")]),
        ("alpha_x [rad]", [(c("alpha_x"), "", "-")]),
        ("alpha_y [rad]", [(c("alpha_y"), "", "-")]),
        ("beta (unwrapped) [rad]", [(np.unwrap(c("beta")), "", "-")]),
    ], "fig08_swing.png")
    panels("Tracking errors", [
        ("e_Fx [m]", [(c("e_Fx"), "", "-")]),
        ("e_Fy [m]", [(c("e_Fy"), "", "-")]),
        ("e_z [m]", [(c("e_z"), "", "-")]),
        ("e_psi [rad]", [(c("e_psi"), "", "-")]),
    ], "fig09_errors.png")
    panels("Attitude", [
        ("phi [rad]", [(c("phi"), "", "-")]),
        ("theta [rad]", [(c("theta"), "", "-")]),
    ], "fig10_attitude.png")
    panels("Control signals" + (" (chattering attenuation, eq. 92)" if "smooth" in tag else ""), [
        ("u [N]", [(c("u"), "", "-")]),
        ("tau_phi [N m]", [(c("tau_phi"), "", "-")]),
        ("tau_theta [N m]", [(c("tau_theta"), "", "-")]),
        ("tau_psi [N m]", [(c("tau_psi"), "", "-")]),
    ], "fig11_controls.png")

    fig = plt.figure(figsize=(10, 8))
    ax3 = fig.add_subplot(2, 2, 1, projection="3d")
    ax3.plot(c("x"), c("y"), c("z"), lw=1.0, label="vehicle")
    ax3.plot(c("load_x"), c("load_y"), c("load_z"), lw=0.8, label="load")
    ax3.plot(c("Fx_ref"), c("Fy_ref"), c("z_ref") - log.vehicle.cable_length, "--", lw=0.8, label="reference (load)")
    ax3.set_xlabel("x [m]")
    ax3.set_ylabel("y [m]")
    ax3.set_zlabel("z [m]")
    ax3.legend(fontsize=7)
    for i, (a, b, la, lb) in enumerate([("x", "y", "x [m]", "y [m]"), ("x", "z", "x [m]", "z [m]"),
                                       ("y", "z", "y [m]", "z [m]")]):
        ax = fig.add_subplot(2, 2, i + 2)
        ax.plot(c(a), c(b), lw=1.0, label="vehicle")
        ax.plot(c(f"load_{a}"), c(f"load_{b}"), lw=0.8, label="load")
        ax.set_xlabel(la)
        ax.set_ylabel(lb)
        ax.grid(True, alpha=0.3)
        ax.axis("equal")
    fig.suptitle(f"Flight path in 3D and its projections ({tag})")
    save(fig, "fig12_path3d.png")

    if log.config.estimator != "truth":
        panels("Estimation errors (estimate - truth)", [
            ("alpha_x [rad]", [(c("est_alpha_x"), "", "-")]),
            ("alpha_y [rad]", [(c("est_alpha_y"), "", "-")]),
            ("F_x [m]", [(c("est_Fx0"), "", "-")]),
            ("F_x'' [m/s^2]", [(c("est_Fx2"), "", "-")]),
            ("NEES", [(c("nees"), "", "-")]),
        ], "fig14_estimation.png")
    return paths
