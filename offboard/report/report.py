"""Report folder of a run: ``metrics.json``, ``timeseries.slts``, ``report.html`` (``offboard.report.run_report_html``)
and PNG figures like the paper's Figs. 5-13 (plus the estimation and, for flights, the setpoint figure).

The figures are described first (:func:`figure_specs`: what each panel plots, its limits and markers; the data
behind every figure, which the tests read) and drawn from that description (:func:`draw_spec`). Every file is
written atomically (``offboard.outputs``); matplotlib runs on its non-interactive Agg backend.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from offboard.logs.runlog import COL, LOG_COLUMNS, SimLog
from offboard.logs.timeseries_file import RUN_LOG_NAME, write_table
from offboard.outputs import write_json_atomic
from offboard.report.figures import pyplot, save_png

#: Columns written to timeseries.slts (all of them) and the decimation to about this rate.
TIMESERIES_RATE_HZ = 100.0


def write_timeseries(log: SimLog, path: Path, rate_hz: float = TIMESERIES_RATE_HZ) -> Path:
    """Write the log as a time series file (``offboard.logs.timeseries_file``: every column named, SI, rad, float64),
    decimated to about ``rate_hz``."""
    t = log.column("t")
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    stride = max(1, round(1.0 / (rate_hz * dt)))
    return write_table(path, LOG_COLUMNS, log.data[::stride])


def write_report(
    log: SimLog,
    metrics: dict[str, Any],
    out_dir: Path,
    figures: bool = True,
    *,
    command: str = "sim",
    live: np.ndarray | None = None,
    live_col: dict[str, int] | None = None,
    events: dict[str, Any] | None = None,
    timeseries_rate_hz: float = TIMESERIES_RATE_HZ,
) -> list[Path]:
    """Write metrics.json, timeseries.slts and (unless ``figures`` is False) report.html and the PNG figures into
    ``out_dir``; returns the paths. ``command``: the ``slung`` command that ran (titles); ``live`` /
    ``live_col`` / ``events``: a flight's tick rows, their column index and its ``events.json`` content
    (setpoints, loop timing, events); ``timeseries_rate_hz``: timeseries.slts's rate (a flight's full record
    is its tick log: ``offboard.flight.flight_outputs.FLIGHT_TIMESERIES_RATE_HZ``)."""
    from offboard.report.run_report_html import write_run_html

    written = [
        write_json_atomic(out_dir / "metrics.json", metrics),
        write_timeseries(log, out_dir / RUN_LOG_NAME, timeseries_rate_hz),
    ]
    if figures:  # --no-figures: metrics and time series only (the page costs 1-2 s of CPU on a 50 s run)
        written.append(write_run_html(out_dir, log, metrics, command, live=live, live_col=live_col, events=events))
        written += draw_figures(log, metrics, out_dir, command=command, live=live, live_col=live_col, events=events)
    return written


#: window of the moving mean drawn for the control signals (s): under sign switching the raw command flips every
#: tick, so that its line would be a solid band; the mean shows what the actuators receive on average, the shaded
#: envelope (min / max over the same window) how far the switching throws it
CONTROL_MEAN_WINDOW_S = 0.1


#: events this close outside the plotted time range are still marked (the loop records "offboard control started"
#: just before its first tick and the hand-over just after its last), s
EDGE_S = 0.1


@dataclass(frozen=True)
class Line:
    """One plotted line: values over the figure's time axis, legend label ('' for none), matplotlib style;
    ``envelope``: (low, high) drawn shaded behind it."""

    y: np.ndarray
    label: str = ""
    style: str = "-"
    envelope: tuple[np.ndarray, np.ndarray] | None = None


@dataclass(frozen=True)
class Row:
    """One panel of a figure: y label, lines, horizontal limit lines (label, value) such as saturation limits."""

    ylabel: str
    lines: list[Line]
    limits: list[tuple[str, float]] = field(default_factory=list)


@dataclass(frozen=True)
class FigureSpec:
    """A figure of stacked panels over time ``t`` (s): file name, title, panels, vertical markers (t, label) for
    the disturbance start, phases and hand-overs."""

    name: str
    title: str
    t: np.ndarray
    rows: list[Row]
    markers: list[tuple[float, str]] = field(default_factory=list)


def moving_stats(y: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centred moving mean, minimum and maximum of ``y`` over ``n`` samples (shorter windows at the ends)."""
    y = np.asarray(y, dtype=float)
    if n <= 1 or len(y) < 2:
        return y, y, y
    from scipy.ndimage import maximum_filter1d, minimum_filter1d, uniform_filter1d

    return (
        uniform_filter1d(y, n, mode="nearest"),
        minimum_filter1d(y, n, mode="nearest"),
        maximum_filter1d(y, n, mode="nearest"),
    )


def figure_markers(log: SimLog, events: dict[str, Any] | None, live: np.ndarray | None, live_col: Any) -> list:
    """Vertical markers of the figures: the scenario's disturbance start and arrival, and a flight's phases,
    mode changes and hand-over (``events.json``), within the plotted time range."""
    from offboard.report.run_report_html import flight_events, scenario_events

    evs = scenario_events(log)
    if events is not None and live is not None and live_col is not None:
        keep = ("phase", "exit", "set_mode")
        evs += [e for e in flight_events(events, live, live_col) if e.kind in keep or "exit" in e.kind]
    t = log.column("t")
    out = []
    for e in evs:
        if len(t) and t[0] - EDGE_S <= e.t <= t[-1] + EDGE_S:
            label = e.text if e.kind in ("disturbance", "reference") else f"{e.kind}: {e.text}"
            out.append((float(e.t), label[:60]))
    return out


def figure_specs(
    log: SimLog,
    metrics: dict[str, Any],
    *,
    command: str = "sim",
    live: np.ndarray | None = None,
    live_col: dict[str, int] | None = None,
    events: dict[str, Any] | None = None,
) -> list[FigureSpec]:
    """What every stacked-panel figure of the report plots (the 3D figure is :func:`draw_path3d`)."""
    from offboard.report.run_report_html import _limits, _setpoint_attitude, has_truth, run_title

    d = log.data
    t = d[:, COL["t"]]
    c = lambda name: d[:, COL[name]]  # noqa: E731 - a short column accessor keeps the plots readable
    tag = run_title(command, log, metrics)
    marks = figure_markers(log, events, live, live_col)
    lim = _limits(log)
    specs: list[FigureSpec] = []

    def spec(name: str, title: str, rows: list[Row], tt: np.ndarray = t, markers: bool = True) -> None:
        specs.append(FigureSpec(name, f"{title}\n{tag}", tt, rows, marks if markers else []))

    spec(
        "fig05_tracking.png",
        "Trajectory tracking of F_x, F_y, z, psi",
        [
            Row("F_x [m]", [Line(c("Fx"), "F_x"), Line(c("Fx_ref"), "F_x*", "--")]),
            Row("F_y [m]", [Line(c("Fy"), "F_y"), Line(c("Fy_ref"), "F_y*", "--")]),
            Row("z [m]", [Line(c("z"), "z"), Line(c("z_ref"), "z*", "--")]),
            Row("psi [rad]", [Line(c("psi"), "psi"), Line(c("psi_ref"), "psi*", "--")]),
        ],
    )
    first = t <= min(3.0, t[-1])
    spec(
        "fig06_yaw_start.png",
        "Yaw tracking, first 3 s",
        [Row("psi [rad]", [Line(c("psi")[first], "psi"), Line(c("psi_ref")[first], "psi*", "--")])],
        t[first],
        markers=False,
    )
    spec(
        "fig07_disturbances.png",
        "External disturbances",
        [
            Row("F_x dist [N]", [Line(c("dist_fx"))]),
            Row("F_y dist [N]", [Line(c("dist_fy"))]),
            Row("F_z dist [N]", [Line(c("dist_fz"))]),
            Row("tau_psi dist [N m]", [Line(c("dist_tpsi"))]),
        ],
    )
    # beta (the swing's direction) is left out: it is meaningless while the load hangs nearly straight down, and
    # unwrapped it drifts over tens of radians; alpha_x / alpha_y say the same without the singularity
    spec(
        "fig08_swing.png",
        "Swing: alpha, its projections alpha_x (Y-Z) and alpha_y (X-Z)",
        [
            Row("alpha [rad]", [Line(c("alpha"))]),
            Row("alpha_x [rad]", [Line(c("alpha_x"))]),
            Row("alpha_y [rad]", [Line(c("alpha_y"))]),
        ],
    )
    spec(
        "fig09_errors.png",
        "Tracking errors",
        [
            Row("e_Fx [m]", [Line(c("e_Fx"))]),
            Row("e_Fy [m]", [Line(c("e_Fy"))]),
            Row("e_z [m]", [Line(c("e_z"))]),
            Row("e_psi [rad]", [Line(c("e_psi"))]),
        ],
    )
    att = [Row("phi [rad]", [Line(c("phi"), "achieved")]), Row("theta [rad]", [Line(c("theta"), "achieved")])]
    sp = _setpoint_attitude(live, live_col) if live is not None and live_col is not None else None
    spec("fig10_attitude.png", "Attitude", att)
    if sp is not None:
        spec(
            "fig15_setpoints.png",
            "Attitude setpoint sent against attitude achieved",
            [
                Row("roll phi [rad]", [Line(sp[0], "setpoint sent", "--"), Line(c("phi"), "achieved")]),
                Row("pitch theta [rad]", [Line(sp[1], "setpoint sent", "--"), Line(c("theta"), "achieved")]),
                Row("sent - achieved [rad]", [Line(sp[0] - c("phi"), "roll"), Line(sp[1] - c("theta"), "pitch")]),
            ],
        )
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    n = max(1, round(CONTROL_MEAN_WINDOW_S / dt))

    def control(name: str, label: str) -> Line:
        mean, lo, hi = moving_stats(c(name), n)
        return Line(mean, f"{label}, {CONTROL_MEAN_WINDOW_S:g} s mean (shaded: min..max)", "-", (lo, hi))

    tp, ty = lim["tau_phi"], lim["tau_psi"]
    spec(
        "fig11_controls.png",
        "Control signals"
        + (" (chattering attenuation, eq. 92)" if metrics.get("config", {}).get("switching") == "smooth" else ""),
        [
            Row("u [N]", [control("u", "u")], [("thrust max", lim["thrust_max"]), ("thrust min", lim["thrust_min"])]),
            Row("tau_phi [N m]", [control("tau_phi", "tau_phi")], [("limit", tp), ("", -tp)]),
            Row(
                "tau_theta [N m]",
                [control("tau_theta", "tau_theta")],
                [("limit", lim["tau_theta"]), ("", -lim["tau_theta"])],
            ),
            Row("tau_psi [N m]", [control("tau_psi", "tau_psi")], [("limit", ty), ("", -ty)]),
        ],
    )
    # estimate minus truth, when there is a truth: not for a real vehicle, whose log holds the estimate only
    if has_truth(log, metrics):
        rows = [
            Row("alpha_x [rad]", [Line(c("est_alpha_x"))]),
            Row("alpha_y [rad]", [Line(c("est_alpha_y"))]),
            Row("F_x, F_y [m]", [Line(c("est_Fx0"), "F_x"), Line(c("est_Fy0"), "F_y")]),
            Row("F_x'', F_y'' [m/s^2]", [Line(c("est_Fx2"), "F_x''"), Line(c("est_Fy2"), "F_y''")]),
        ]
        # the NEES needs the filter's covariance at each tick, which slung sim records and a flight does not:
        # an empty panel says nothing, so it is drawn only with data
        if np.any(np.isfinite(c("nees"))):
            rows.append(Row("NEES", [Line(c("nees"))]))
        spec("fig14_estimation.png", "Estimation errors (estimate - truth)", rows)
    return specs


def draw_spec(spec: FigureSpec) -> Any:
    """The matplotlib figure of ``spec``."""
    plt = pyplot()
    fig, axes = plt.subplots(len(spec.rows), 1, figsize=(8, 2.0 * len(spec.rows) + 0.9), sharex=True)
    axes = np.atleast_1d(axes)
    for ax, row in zip(axes, spec.rows):
        for line in row.lines:
            if line.envelope is not None:
                ax.fill_between(spec.t, line.envelope[0], line.envelope[1], color="C0", alpha=0.2, lw=0)
            ax.plot(spec.t, line.y, line.style, label=line.label or None, lw=1.0)
        for label, value in row.limits:
            if math.isfinite(value):
                ax.axhline(value, color="C3", ls=":", lw=1.0, label=f"{label} {value:.3g}" if label else None)
        for tm, _ in spec.markers:
            ax.axvline(tm, color="0.5", ls="--", lw=0.8)
        ax.set_ylabel(row.ylabel)
        ax.grid(True, alpha=0.3)
        if any(line.label for line in row.lines) or row.limits:
            ax.legend(loc="best", fontsize=7)
    for tm, label in spec.markers:
        axes[0].annotate(
            label,
            (tm, 1.0),
            xycoords=("data", "axes fraction"),
            fontsize=6,
            rotation=90,
            va="top",
            ha="right",
            color="0.35",
        )
    axes[-1].set_xlabel("time [s]")
    axes[0].set_title(spec.title, fontsize=9)
    return fig


def draw_path3d(log: SimLog, title: str) -> Any:
    """Fig. 12: the path in 3D and its three projections, few ticks so that their labels do not overlap."""
    from matplotlib.ticker import MaxNLocator

    plt = pyplot()
    d = log.data
    c = lambda name: d[:, COL[name]]  # noqa: E731
    fig = plt.figure(figsize=(10, 8.4))
    ax3 = fig.add_subplot(2, 2, 1, projection="3d")
    ax3.plot(c("x"), c("y"), c("z"), lw=1.0, label="vehicle")
    ax3.plot(c("load_x"), c("load_y"), c("load_z"), lw=0.8, label="load")
    ax3.plot(c("Fx_ref"), c("Fy_ref"), c("z_ref") - log.vehicle.cable_length, "--", lw=0.8, label="reference (load)")
    for axis in (ax3.xaxis, ax3.yaxis, ax3.zaxis):
        axis.set_major_locator(MaxNLocator(4))
    ax3.tick_params(labelsize=7)
    ax3.set_xlabel("x [m]", fontsize=8)
    ax3.set_ylabel("y [m]", fontsize=8)
    ax3.set_zlabel("z [m]", fontsize=8)
    ax3.legend(fontsize=7)
    for i, (a, b, la, lb) in enumerate(
        [("x", "y", "x [m]", "y [m]"), ("x", "z", "x [m]", "z [m]"), ("y", "z", "y [m]", "z [m]")]
    ):
        ax = fig.add_subplot(2, 2, i + 2)
        ax.plot(c(a), c(b), lw=1.0, label="vehicle")
        ax.plot(c(f"load_{a}"), c(f"load_{b}"), lw=0.8, label="load")
        ax.set_xlabel(la)
        ax.set_ylabel(lb)
        ax.grid(True, alpha=0.3)
        ax.axis("equal")
        ax.xaxis.set_major_locator(MaxNLocator(5))
        ax.yaxis.set_major_locator(MaxNLocator(5))
    fig.suptitle(f"Flight path in 3D and its projections\n{title}", fontsize=9)
    return fig


def draw_figures(
    log: SimLog,
    metrics: dict[str, Any],
    out_dir: Path,
    *,
    command: str = "sim",
    live: np.ndarray | None = None,
    live_col: dict[str, int] | None = None,
    events: dict[str, Any] | None = None,
) -> list[Path]:
    """Draw the figures into ``out_dir``; returns the PNG paths."""
    from offboard.report.run_report_html import run_title

    paths = []
    for sp in figure_specs(log, metrics, command=command, live=live, live_col=live_col, events=events):
        paths.append(save_png(draw_spec(sp), out_dir / sp.name))
    paths.append(save_png(draw_path3d(log, run_title(command, log, metrics)), out_dir / "fig12_path3d.png"))
    return paths
