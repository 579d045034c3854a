"""``report.html`` of a ``slung replay`` run: the estimate the replay computed against what the log holds (the
cable-angle sensor, the autopilot's attitude), the references, the setpoints logged against those recomputed, the
replay's health flags, and a 3D view of the vehicle (the autopilot's position) with the load where the estimated
swing puts it. Drawn by ``offboard.report.html_report``.

Time axis: the vehicle's time since boot (s), as in the replay's ``timeseries.slts``; positions: model frame
(world, z up), m.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from estimators.model.cable import cable_from_planar
from offboard.logs.replay import ReplayResult
from offboard.report.filter_readouts import estimate_trace, innovation_panels
from offboard.report.html_report import Animation, Event, Panel, Trace, write_report_html
from offboard.report.replay_report import swing_shown


def _has(y: np.ndarray) -> bool:
    return bool(np.any(np.isfinite(y)))


def replay_panels(result: ReplayResult, cable_length: float | None = None) -> list[Panel]:
    """The time plots of a replay: panels whose data the log does not have are left out. Estimates carry the
    filter's +-2 sigma band; with ``cable_length`` (m) the vehicle's estimated position is drawn against the
    autopilot's own."""
    col = result.column
    t = col("t")

    def sd(name: str) -> np.ndarray | None:
        return col("sd_" + name) if "sd_" + name in result.columns else None

    panels: list[Panel] = []
    swing = ("alpha_x", "alpha_y") if swing_shown(result.metrics) else ()
    for i, name in enumerate(swing):
        traces = [estimate_trace(name, col(name), sd(name))]
        if _has(col("meas_" + name)):
            traces.append(Trace(f"{name} cable-angle sensor", col("meas_" + name), dash=True))
        if result.swing_truth is not None and _has(result.swing_truth[:, i]):
            traces.append(Trace(f"{name} payload truth", result.swing_truth[:, i], dash=True))
        panels.append(Panel(f"Swing {name}: estimate, sensor and payload truth", "rad", t, traces))
    for name, ref, unit, sd_name in (
        ("Fx", "Fx_ref", "m", "fx0"),
        ("Fy", "Fy_ref", "m", "fy0"),
        ("z", "z_ref", "m", "z"),
        ("psi", "psi_ref", "rad", "psi"),
    ):
        traces = [estimate_trace(name, col(name), sd(sd_name))]
        if _has(col(ref)):
            traces.append(Trace(f"{name} reference", col(ref), dash=True))
        panels.append(Panel(f"{name}: estimate and reference", unit, t, traces))
    if cable_length is not None and _has(col("pos_x")):
        veh = []  # the vehicle's position from the estimate (F = p + l a) against the autopilot's
        for axis, f_name, a_name in (("x", "Fx", "alpha_y"), ("y", "Fy", "alpha_x")):
            veh.append(estimate_trace(f"p_{axis}", col(f_name) - cable_length * col(a_name), sd("p_" + axis)))
            veh.append(Trace(f"p_{axis} autopilot", col("pos_" + axis), dash=True))
        panels.append(Panel("Vehicle position: estimate and autopilot", "m", t, veh))
    att = []
    for name in ("phi", "theta"):
        att.append(estimate_trace(name, col(name), sd(name)))
        if _has(col("ap_" + name)):
            att.append(Trace(f"{name} autopilot", col("ap_" + name), dash=True))
    panels.append(Panel("Attitude: estimate and autopilot", "rad", t, att))
    if _has(col("log_thrust")):
        traces = [Trace("thrust logged", col("log_thrust"))]
        if _has(col("sp_thrust")):
            traces.append(Trace("thrust recomputed", col("sp_thrust"), dash=True))
        panels.append(Panel("Thrust setpoint: logged and recomputed", "normalized", t, traces))
    if _has(col("cmd_thrust")):
        panels.append(Panel("Thrust command of the replayed controller", "N", t, [Trace("u", col("cmd_thrust"))]))
    panels += innovation_panels(t, lambda n: col(n) if n in result.columns else None)
    flags = [Trace(n, col(n)) for n in ("offboard", "diverged", "gated") if _has(col(n))]
    if flags:
        panels.append(Panel("Replay flags (1: yes)", "-", t, flags))
    return panels


def replay_animation(result: ReplayResult, cable_length: float | None) -> Animation | None:
    """The autopilot's vehicle position, and the load at the estimated swing ``cable_length`` below it; None
    without a position in the log or a cable length."""
    col = result.column
    veh = np.column_stack([col("pos_x"), col("pos_y"), col("pos_z")])
    ok = np.all(np.isfinite(veh), axis=1)
    if cable_length is None or not np.any(ok):
        return None
    ax, ay = col("alpha_x")[ok], col("alpha_y")[ok]
    r = np.array([cable_from_planar(b, a)[0] if np.isfinite(a + b) else (0.0, 0.0, -1.0) for a, b in zip(ax, ay)])
    r /= np.linalg.norm(r, axis=1, keepdims=True)
    load = veh[ok] + cable_length * r
    ref = None
    fr, fy, zr = col("Fx_ref")[ok], col("Fy_ref")[ok], col("z_ref")[ok]
    if _has(fr):
        ref = np.column_stack([fr, fy, zr - cable_length])
    return Animation(col("t")[ok], veh[ok], load, ref)


def write_replay_html(result: ReplayResult, out_dir: Path, title: str, cable_length: float | None = None) -> Path:
    """Write ``out_dir/report.html`` of a replay; returns its path."""
    col = result.column
    t = col("t")
    events: list[Event] = []
    for name, what in (("offboard", "offboard control"), ("diverged", "estimate diverged"), ("gated", "gated")):
        y = col(name)
        if len(y) > 1 and _has(y):
            on = np.flatnonzero(np.diff(np.nan_to_num(y) > 0.5).astype(int) != 0) + 1
            for k in on[:50]:
                state = "starts" if y[k] > 0.5 else "ends"
                events.append(Event(float(t[k]), name, f"{what} {state}"))
    # the flight's modes, arming, landed state and the replay's divergences (offboard.logs.replay.timeline)
    events += [Event(float(e["t_s"]), e["kind"], e["text"]) for e in result.metrics.get("timeline", [])]
    events.sort(key=lambda e: e.t)
    return write_report_html(
        out_dir,
        title,
        replay_panels(result, cable_length),
        events,
        result.metrics,
        replay_animation(result, cable_length),
        subtitle=f"Replay of a flight log through the live estimator and controller ({result.output} setpoints); "
        "time is the vehicle's time since boot.",
    )
