"""``report.html`` of a ``slung sim``, ``fly`` or ``demo`` run: the panels, events and 3D animation that
``offboard.report.html_report`` draws, built from the run's :class:`~offboard.logs.runlog.SimLog` (and, for a flight,
the live rows of ``timeseries_live.slts`` and ``events.json``).

Time axis: the reference time (s; 0 where the reference starts). Positions: model frame (world, z up), m.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from estimators.model.frames import ned_quaternion_to_model, quaternion_to_euler
from offboard.logs.runlog import COL, SimLog
from offboard.report.filter_readouts import BAND_ERRORS, error_range, error_trace, estimate_trace, innovation_panels
from offboard.report.html_report import Animation, Event, Panel, Trace, write_report_html


def run_title(command: str, log: SimLog, metrics: dict[str, Any]) -> str:
    """What ran, in one line: command, scenario, vehicle, estimator, autopilot flavour, controller, switching. e.g.
    ``slung demo: paper scenario, px4 emulator, paper-table1 vehicle, kf estimator, smc controller, sign switching``."""
    cfg = metrics.get("config", {})
    parts = [f"{log.scenario.name} scenario"]
    flavour = cfg.get("flavour")
    if flavour:
        truth = metrics.get("flight", {}).get("truth_source", "")
        parts.append(f"{flavour} {'emulator' if 'emulator' in truth else 'vehicle'}")
    parts.append(f"{cfg.get('vehicle') or log.vehicle.name} vehicle")
    est = cfg.get("estimator") or log.config.estimator
    parts.append("controller on the true state" if est == "truth" else f"{est} estimator")
    if cfg.get("controller"):  # the controller's registry name (smc, smc-attitude: the sliding-mode law)
        parts.append(f"{cfg['controller']} controller")
    sw = cfg.get("switching")
    if sw:
        detail = ""
        if sw == "smooth" and cfg.get("layer_errors"):
            detail = " (per-loop boundary layers)"  # docs/model.md C-12
        elif sw == "smooth" and cfg.get("epsilon"):
            detail = f" (ε = {cfg['epsilon']:g})"
        parts.append(f"{sw} switching{detail}")
    lag = cfg.get("actuation_lag_s")
    if isinstance(lag, (int, float)) and lag > 0.0:
        parts.append(f"{lag * 1e3:g} ms motor lag designed in")  # docs/model.md C-13
    return f"slung {command}: " + ", ".join(parts)


def _limits(log: SimLog) -> dict[str, float]:
    """The controller's saturation limits for this vehicle (N, N m): what the commands are clipped to."""
    from offboard.control import smc

    p = smc.ControllerParams.for_vehicle(log.vehicle)
    return {
        "thrust_min": p.thrust_min,
        "thrust_max": p.thrust_max,
        "tau_phi": p.torque_max[0],
        "tau_theta": p.torque_max[1],
        "tau_psi": p.torque_max[2],
    }


def _setpoint_attitude(live: np.ndarray, live_col: dict[str, int]) -> tuple[np.ndarray, np.ndarray] | None:
    """Roll and pitch (model frame, rad) of the attitude setpoints sent (sp0..sp3: quaternion NED -> FRD); None
    for actuator output (no attitude on the wire)."""
    q = live[:, live_col["sp0"] : live_col["sp0"] + 4]
    if not np.any(np.isfinite(q[:, 0])) or np.nanmax(np.abs(np.linalg.norm(q, axis=1) - 1.0)) > 1e-3:
        return None
    roll = np.full(len(q), np.nan)
    pitch = np.full(len(q), np.nan)
    for k, (w, x, y, z) in enumerate(q.tolist()):
        if math.isfinite(w):
            phi, theta, _ = quaternion_to_euler(*ned_quaternion_to_model(w, x, y, z))
            roll[k], pitch[k] = phi, theta
    return roll, pitch


def has_truth(log: SimLog, metrics: dict[str, Any]) -> bool:
    """Whether the run knows the true state beside the estimate: a simulation, or a flight against the demo's
    emulator; a real vehicle's flight does not (its "truth" columns are the estimate: ``flight.truth_source``)."""
    return log.config.estimator != "truth" and metrics.get("flight", {}).get("truth_source", "simulation") != "estimate"


def build_panels(
    log: SimLog, live: np.ndarray | None = None, live_col: dict[str, int] | None = None, truth: bool = True
) -> list[Panel]:
    """The time plots of a run (see the module docstring): position and reference, swing, attitude (setpoint
    and achieved for a flight), thrust and torques with their saturation limits, estimation error (``truth``:
    only when the run knows the true state), disturbance, loop timing (flights)."""
    d = log.data
    t = d[:, COL["t"]]

    def c(name: str) -> np.ndarray:
        return d[:, COL[name]]

    def lc(name: str) -> np.ndarray | None:
        """A column of the flight's live rows (one per tick, as the log's), None without it."""
        return live[:, live_col[name]] if live is not None and live_col is not None and name in live_col else None

    lim = _limits(log)
    from offboard.report.report import CONTROL_MEAN_WINDOW_S, moving_stats

    n_mean = max(1, round(CONTROL_MEAN_WINDOW_S * log.config.control_rate))

    def switching(name: str, y: np.ndarray, dash: bool = False) -> Trace:
        """A sign-switching signal: its 0.1 s mean, with its min..max over the window as the band (drawn raw it is
        a solid band; the PNG fig11 does the same)."""
        mean, lo, hi = moving_stats(y, n_mean)
        return Trace(f"{name} ({CONTROL_MEAN_WINDOW_S:g} s mean, band min..max)", mean, band=(lo, hi), dash=dash)

    panels = [
        Panel(
            "Load position F_x and reference", "m", t, [Trace("F_x", c("Fx")), Trace("F_x*", c("Fx_ref"), dash=True)]
        ),
        Panel(
            "Load position F_y and reference", "m", t, [Trace("F_y", c("Fy")), Trace("F_y*", c("Fy_ref"), dash=True)]
        ),
        Panel("Height z and reference", "m", t, [Trace("z", c("z")), Trace("z*", c("z_ref"), dash=True)]),
        Panel("Heading psi and reference", "rad", t, [Trace("psi", c("psi")), Trace("psi*", c("psi_ref"), dash=True)]),
        Panel("Swing angles", "rad", t, [Trace("alpha_x", c("alpha_x")), Trace("alpha_y", c("alpha_y"))]),
    ]
    att = [Trace("phi", c("phi")), Trace("theta", c("theta"))]
    if live is not None and live_col is not None:
        sp = _setpoint_attitude(live, live_col)
        if sp is not None:
            att = [
                Trace("phi (achieved)", c("phi")),
                switching("phi setpoint", sp[0], dash=True),
                Trace("theta (achieved)", c("theta")),
                switching("theta setpoint", sp[1], dash=True),
            ]
    panels.append(Panel("Attitude: setpoint sent and achieved" if len(att) > 2 else "Attitude", "rad", t, att))
    panels.append(
        Panel(
            "Thrust command (saturation limits dotted)",
            "N",
            t,
            [switching("u", c("u"))],
            [("thrust max", lim["thrust_max"]), ("thrust min", lim["thrust_min"])],
        )
    )
    panels.append(
        Panel(
            "Torque commands (saturation limits dotted)",
            "N m",
            t,
            [switching(n, c(n)) for n in ("tau_phi", "tau_theta", "tau_psi")],
            [
                ("±roll/pitch max", lim["tau_phi"]),
                ("", -lim["tau_phi"]),
                ("±yaw max", lim["tau_psi"]),
                ("", -lim["tau_psi"]),
            ],
        )
    )
    band = {name: (err, sd) for name, err, sd in BAND_ERRORS}
    if truth and log.config.estimator != "truth":  # errors against the truth, in the filter's own +-2 sigma
        for title, unit, names in (
            ("Swing estimate minus truth", "rad", ("alpha_x", "alpha_y")),
            ("Load position estimate minus truth", "m", ("F_x", "F_y", "z")),
        ):
            errs = [error_trace(n, c(band[n][0]), c(band[n][1])) for n in names]
            panels.append(Panel(title, unit, t, errs, y_range=error_range(errs)))
        nees = c("nees")
        if np.any(np.isfinite(nees)):
            panels.append(Panel("Filter consistency (NEES)", "-", t, [Trace("NEES", nees)]))
    elif np.any(np.isfinite(c("sd_alpha_x"))):  # no truth (a real vehicle): the estimate and its band
        panels.append(
            Panel(
                "Swing estimate (no truth: a real vehicle)",
                "rad",
                t,
                [estimate_trace(n, c(n), c("sd_" + n)) for n in ("alpha_x", "alpha_y")],
            )
        )
    if live is not None:
        panels += innovation_panels(t, lc)
    dist = [Trace(n, c(col)) for n, col in (("F_x", "dist_fx"), ("F_y", "dist_fy"), ("F_z", "dist_fz"))]
    if any(np.any(tr.y != 0.0) for tr in dist):
        panels.append(Panel("External disturbance force on the vehicle", "N", t, dist))
    if live is not None and live_col is not None:
        period_us = 1e6 / log.config.control_rate
        panels.append(
            Panel(
                "Loop timing per tick",
                "µs",
                t,
                [
                    Trace("compute", 1e6 * live[:, live_col["compute_s"]]),
                    Trace("latency (telemetry in -> setpoint out)", 1e6 * live[:, live_col["latency_s"]]),
                ],
                [("control period", period_us)],
            )
        )
    return panels


def build_animation(log: SimLog) -> Animation:
    """Vehicle and load positions over time, and the load's reference path (world, z up, m)."""
    d = log.data
    c = lambda n: d[:, COL[n]]  # noqa: E731
    ref = np.column_stack([c("Fx_ref"), c("Fy_ref"), c("z_ref") - log.vehicle.cable_length])
    return Animation(
        c("t"),
        np.column_stack([c("x"), c("y"), c("z")]),
        np.column_stack([c("load_x"), c("load_y"), c("load_z")]),
        ref,
    )


def scenario_events(log: SimLog) -> list[Event]:
    """The scenario's own marks: disturbance start, arrival of a point-to-point reference."""
    out = []
    if log.scenario.disturbance_start is not None and np.any(log.column("dist_fx") != 0.0):
        out.append(Event(float(log.scenario.disturbance_start), "disturbance", "external disturbances start"))
    if log.scenario.arrival_time is not None:
        out.append(Event(float(log.scenario.arrival_time), "reference", "the reference comes to rest"))
    return out


def flight_events(events: dict[str, Any], live: np.ndarray, live_col: dict[str, int]) -> list[Event]:
    """Loop, management and mapping events of a flight (``events.json``'s blocks) on the reference time axis:
    loop events carry vehicle time; management events carry local monotonic time, mapped through the ticks'
    (local time, reference time) pairs (before the first tick they are extrapolated at 1 s per s)."""
    out: list[Event] = []
    if len(live) == 0:
        return out
    t_ref0 = float(live[0, live_col["t_vehicle"]] - live[0, live_col["t_ref"]])
    loc = live[:, live_col["t_local"]]
    tref = live[:, live_col["t_ref"]]

    def local_to_ref(t_local: float) -> float:
        if t_local < loc[0]:
            return float(tref[0] - (loc[0] - t_local))
        if t_local > loc[-1]:
            return float(tref[-1] + (t_local - loc[-1]))
        return float(np.interp(t_local, loc, tref))

    for e in events.get("loop", []):
        t = e["t_vehicle"] - t_ref0 if e.get("t_vehicle") else local_to_ref(e["t_local"])
        out.append(Event(float(t), e["kind"], e["reason"]))
    for e in events.get("management", []):
        out.append(Event(local_to_ref(float(e["t"])), e["kind"], e["detail"]))
    for e in events.get("mapping", []):
        out.append(Event(float(e["t"]), e["kind"], e["reason"]))
    for e in events.get("supervision", []) if isinstance(events.get("supervision"), list) else []:
        t = e.get("t_ref", e.get("t"))
        if t is not None:
            out.append(Event(float(t), str(e.get("kind", "supervision")), str(e.get("reason", e.get("detail", "")))))
    return out


def write_run_html(
    out_dir: Path,
    log: SimLog,
    metrics: dict[str, Any],
    command: str,
    *,
    live: np.ndarray | None = None,
    live_col: dict[str, int] | None = None,
    events: dict[str, Any] | None = None,
    extra_events: Sequence[Event] = (),
) -> Path:
    """Write ``out_dir/report.html`` for a run of ``slung <command>``; returns its path."""
    evs = scenario_events(log) + list(extra_events)
    if events is not None and live is not None and live_col is not None:
        evs += flight_events(events, live, live_col)
    title = run_title(command, log, metrics)
    cfg = metrics.get("config", {})
    sub = (
        f"{log.scenario.description}. Control at {log.config.control_rate:g} Hz; "
        f"sensors {cfg.get('sensors', log.config.sensors)}; "
        + (
            "no true state (a real vehicle): positions and swing are the estimate's."
            if metrics.get("flight", {}).get("truth_source") == "estimate"
            else f"truth: {metrics['flight']['truth_source']}."
            if "flight" in metrics
            else "truth: the simulated plant."
        )
    )
    return write_report_html(
        out_dir,
        title,
        build_panels(log, live, live_col, truth=has_truth(log, metrics)),
        evs,
        metrics,
        build_animation(log),
        subtitle=sub,
    )
