"""What a replay shows: the estimate beside the autopilot's own estimate (position, attitude), the swing estimate
(with the cable-angle sensor where the log has one), the innovation checks (distance from the autopilot, updates
the filter's gate refused, ticks found diverged), and the flight's modes and events on the time axis; as PNG
figures (``estimate_vs_autopilot.png``, ``attitude_vs_autopilot.png``, ``innovations.png``); the interactive
``report.html`` is ``offboard.report.replay_report_html``'s, with the same timeline. Titles name the log and the
segment.

Time axis: vehicle time (s since boot). Model frame (world NWU, z up), metres and radians. The vehicle position
implied by the estimate is ``F - l alpha`` (the flat output is the load's position).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from offboard.report.figures import pyplot, save_png

#: per-segment figures are drawn for at most this many segments (the report.html always holds the whole replay)
MAX_SEGMENT_FIGURES = 6


@dataclass(frozen=True)
class Series:
    """The columns of a replay table the figures need, one value per tick (NaN where not applicable)."""

    t: np.ndarray
    est_pos: np.ndarray  # (n, 3) vehicle position implied by the estimate, m
    ap_pos: np.ndarray  # (n, 3) the autopilot's latest position, m
    est_att: np.ndarray  # (n, 3) phi, theta, psi estimated, rad
    ap_att: np.ndarray  # (n, 3) the autopilot's latest attitude, rad
    swing: np.ndarray  # (n, 2) alpha_x, alpha_y estimated, rad
    sensor: np.ndarray  # (n, 2) the cable-angle sensor's latest, rad
    truth: np.ndarray  # (n, 2) the payload's truth (SLUP, a payload system's position), rad; NaN without one
    gated: np.ndarray  # cumulative updates the filter's gate refused
    diverged: np.ndarray  # 1 on a tick found diverged
    segment: np.ndarray


def series(result: Any, cable_length: float) -> Series:
    """The :class:`Series` of an ``offboard.logs.replay.ReplayResult``."""
    c = result.column
    ax, ay = c("alpha_x"), c("alpha_y")
    truth = getattr(result, "swing_truth", None)
    est_pos = np.column_stack((c("Fx") - cable_length * ay, c("Fy") - cable_length * ax, c("z")))
    return Series(
        t=c("t"),
        est_pos=est_pos,
        ap_pos=np.column_stack((c("pos_x"), c("pos_y"), c("pos_z"))),
        est_att=np.column_stack((c("phi"), c("theta"), c("psi"))),
        ap_att=np.column_stack((c("ap_phi"), c("ap_theta"), c("ap_psi"))),
        swing=np.column_stack((ax, ay)),
        sensor=np.column_stack((c("meas_alpha_x"), c("meas_alpha_y"))),
        truth=truth if truth is not None else np.full((len(ax), 2), np.nan),
        gated=c("gated"),
        diverged=c("diverged"),
        segment=c("segment"),
    )


def _wrap(a: np.ndarray) -> np.ndarray:
    return np.remainder(a + math.pi, 2 * math.pi) - math.pi


def _segments(s: Series, metrics: dict[str, Any]) -> list[tuple[str, np.ndarray]]:
    """(label, tick mask) per segment shown: each airborne segment of an estimation-only replay, else the whole
    replayed span (an offboard flight's controlled segment)."""
    segs = metrics.get("estimation", {}).get("segments") or []
    out = []
    for k, sg in enumerate(segs[:MAX_SEGMENT_FIGURES]):
        mask = s.segment == k
        if np.count_nonzero(mask) > 1:
            out.append((f"segment {k + 1} of {len(segs)}, t = {sg['from_s']:.1f} .. {sg['to_s']:.1f} s", mask))
    if not out and len(s.t) > 1:
        out.append((f"t = {s.t[0]:.1f} .. {s.t[-1]:.1f} s", np.ones(len(s.t), bool)))
    return out


def _mark_events(ax: Any, timeline: list[dict[str, Any]], t0: float, t1: float) -> None:
    """Modes, arming and divergences as vertical lines with their names."""
    for ev in timeline:
        t = ev["t_s"]
        if not t0 <= t <= t1:
            continue
        red = ev["kind"] == "divergence"
        ax.axvline(t, color="tab:red" if red else "0.5", lw=0.8, alpha=0.6)
        if not red:
            ax.annotate(ev["text"], (t, 1.0), xycoords=("data", "axes fraction"), fontsize=7, rotation=90,
                        va="top", ha="right", color="0.3")  # fmt: skip


def draw_pngs(result: Any, out_dir: Path, log_name: str, cable_length: float) -> list[Path]:
    """The PNG figures, one set per segment shown (suffix ``_segK`` when there are several)."""
    plt = pyplot()
    s = series(result, cable_length)
    timeline = result.metrics.get("timeline", [])
    shown = _segments(s, result.metrics)
    paths: list[Path] = []
    for k, (label, mask) in enumerate(shown):
        suffix = f"_seg{k + 1}" if len(shown) > 1 else ""
        t = s.t[mask]
        t0, t1 = float(t[0]), float(t[-1])
        fig, axes = plt.subplots(3, 1, figsize=(9, 7), sharex=True)
        for i, (ax, name) in enumerate(zip(axes, ("x (north)", "y (west)", "z (up)"))):
            ax.plot(t, s.ap_pos[mask, i], lw=1.4, color="0.4", label="autopilot's estimate")
            ax.plot(t, s.est_pos[mask, i], lw=1.0, label="replay's estimate (F - l alpha)")
            ax.set_ylabel(f"{name} (m)")
            ax.grid(alpha=0.3)
            _mark_events(ax, timeline, t0, t1)
        axes[0].legend(loc="lower right", fontsize=8)
        axes[-1].set_xlabel("vehicle time (s)")
        axes[0].set_title(f"{log_name}: vehicle position vs the autopilot's ({label})", fontsize=10)
        paths.append(save_png(fig, out_dir / f"estimate_vs_autopilot{suffix}.png"))

        fig, axes = plt.subplots(4, 1, figsize=(9, 8.5), sharex=True)
        for i, (ax, name) in enumerate(zip(axes, ("roll phi", "pitch theta", "yaw psi"))):
            ap, est = s.ap_att[mask, i], s.est_att[mask, i]
            if i == 2:
                ap, est = _wrap(ap), _wrap(est)
            ax.plot(t, ap, lw=1.4, color="0.4", label="autopilot's estimate")
            ax.plot(t, est, lw=1.0, label="replay's estimate")
            ax.set_ylabel(f"{name} (rad)")
            ax.grid(alpha=0.3)
        ax = axes[3]
        ax.plot(t, s.swing[mask, 0], lw=1.0, label="alpha_x estimate")
        ax.plot(t, s.swing[mask, 1], lw=1.0, label="alpha_y estimate")
        for i, name in enumerate(("alpha_x", "alpha_y")):
            if np.any(np.isfinite(s.sensor[mask, i])):
                ax.plot(t, s.sensor[mask, i], "--", lw=0.8, label=f"{name} cable-angle sensor")
            if np.any(np.isfinite(s.truth[mask, i])):
                ax.plot(t, s.truth[mask, i], ":", lw=1.2, label=f"{name} payload truth")
        ax.set_ylabel("swing (rad)")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=7, ncol=2)
        axes[0].legend(loc="lower right", fontsize=8)
        axes[-1].set_xlabel("vehicle time (s)")
        axes[0].set_title(f"{log_name}: attitude vs the autopilot's, and the swing ({label})", fontsize=10)
        for ax in axes:
            _mark_events(ax, timeline, t0, t1)
        paths.append(save_png(fig, out_dir / f"attitude_vs_autopilot{suffix}.png"))

        fig, axes = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True)
        d = np.linalg.norm(s.est_pos[mask, :2] - s.ap_pos[mask, :2], axis=1)
        axes[0].plot(t, d, lw=1.0, label="horizontal")
        axes[0].plot(t, np.abs(s.est_pos[mask, 2] - s.ap_pos[mask, 2]), lw=1.0, label="height")
        bad = s.diverged[mask] > 0
        if np.any(bad):
            axes[0].plot(t[bad], np.zeros(np.count_nonzero(bad)), "rv", ms=6, label="diverged: restarted")
        axes[0].set_ylabel("estimate - autopilot (m)")
        axes[0].legend(loc="upper right", fontsize=8)
        g = s.gated[mask]
        axes[1].plot(t, g - (g[np.isfinite(g)][0] if np.any(np.isfinite(g)) else 0.0), lw=1.0)
        axes[1].set_ylabel("updates gated (cumulative)")
        axes[-1].set_xlabel("vehicle time (s)")
        axes[0].set_title(f"{log_name}: innovation checks ({label})", fontsize=10)
        for ax in axes:
            ax.grid(alpha=0.3)
            _mark_events(ax, timeline, t0, t1)
        paths.append(save_png(fig, out_dir / f"innovations{suffix}.png"))
    return paths


__all__ = ["MAX_SEGMENT_FIGURES", "Series", "draw_pngs", "series"]
