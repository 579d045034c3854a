"""The filter's own account of its estimate in the reports: the +-2 sigma band from its covariance, how often the
true error stayed inside it, and the innovations panel (normalized innovation per update stream, refused updates).

Reads the columns ``offboard.logs.estimate_columns`` names (``sd_*``, ``nu_*``, ``gated_*``) from any table, given as
``column(name) -> array or None``: the live loop's ``timeseries_live.slts`` rows and the replay's table both have
them. Units: those of the quantity (m, rad); innovations are dimensionless.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from estimators.filters.factory import INNOVATION_STREAMS
from offboard.report.html_report import Panel, Trace

#: the band's half-width in standard deviations
BAND_SIGMAS = 2.0
#: (name, the run log's estimation-error column, its standard-deviation column) of the errors drawn with a band
BAND_ERRORS: tuple[tuple[str, str, str], ...] = (
    ("alpha_x", "est_alpha_x", "sd_alpha_x"),
    ("alpha_y", "est_alpha_y", "sd_alpha_y"),
    ("F_x", "est_Fx0", "sd_fx0"),
    ("F_y", "est_Fy0", "sd_fy0"),
    ("z", "est_z", "sd_z"),
    ("psi", "est_psi", "sd_psi"),
)
#: the default gate on one normalized innovation (an update beyond it is refused): sqrt(chi2(0.9999, 1)), 3.89 (the
#: filter's gate_probability; stored so that the report does not load the filters and scipy for one number)
GATE_SIGMAS = math.sqrt(15.136705226623606)
Column = Callable[[str], "np.ndarray | None"]


def band(centre: np.ndarray, sd: np.ndarray | None) -> tuple[np.ndarray, np.ndarray] | None:
    """``centre -+ 2 sd`` (None without a finite sd)."""
    if sd is None or not np.any(np.isfinite(sd)):
        return None
    return centre - BAND_SIGMAS * sd, centre + BAND_SIGMAS * sd


def error_trace(name: str, error: np.ndarray, sd: np.ndarray | None) -> Trace:
    """An estimation error (estimate minus truth) with the filter's +-2 sigma band around zero."""
    b = band(np.zeros_like(error), sd)
    return Trace(f"{name} error" + (" (band ±2σ of the filter)" if b is not None else ""), error, band=b)


def estimate_trace(name: str, estimate: np.ndarray, sd: np.ndarray | None) -> Trace:
    """An estimate with the filter's +-2 sigma band around it."""
    b = band(estimate, sd)
    return Trace(f"{name} estimate" + (" ±2σ" if b is not None else ""), estimate, band=b)


def coverage(error: np.ndarray, sd: np.ndarray) -> float | None:
    """Fraction of the ticks (with finite error and sd) whose ``|error| <= 2 sd``: about 0.95 for a consistent
    Gaussian filter, much less for an overconfident one; None without such ticks."""
    ok = np.isfinite(error) & np.isfinite(sd)
    if not np.any(ok):
        return None
    return float(np.mean(np.abs(error[ok]) <= BAND_SIGMAS * sd[ok]))


def error_range(traces: list[Trace]) -> tuple[float, float] | None:
    """A y range that shows the errors and their bands after the filter's start (its prior's wide band would
    flatten the rest): +-1.2 x the 99th percentile of their magnitudes."""
    vals = [np.abs(tr.y) for tr in traces] + [np.abs(b) for tr in traces if tr.band is not None for b in tr.band]
    v = np.concatenate(vals)
    v = v[np.isfinite(v)]
    if len(v) == 0 or not np.percentile(v, 99) > 0.0:
        return None
    h = 1.2 * float(np.percentile(v, 99))
    return -h, h


def moving_rms(t: np.ndarray, y: np.ndarray, window_s: float = 1.0) -> np.ndarray:
    """Centred RMS of the finite samples of ``y`` over ``window_s`` (NaN where the window holds none)."""
    n = len(y)
    if n == 0:
        return y
    dt = float(np.median(np.diff(t))) if n > 1 else window_s
    k = max(1, round(window_s / dt)) if dt > 0.0 else 1
    ok = np.isfinite(y)
    y2 = np.concatenate([[0.0], np.cumsum(np.where(ok, y, 0.0) ** 2)])
    cnt = np.concatenate([[0], np.cumsum(ok)])
    lo = np.clip(np.arange(n) - k // 2, 0, n)
    hi = np.clip(np.arange(n) + k - k // 2, 0, n)
    c = cnt[hi] - cnt[lo]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(c > 0, np.sqrt((y2[hi] - y2[lo]) / np.maximum(c, 1)), np.nan)


def innovation_panels(t: np.ndarray, column: Column, window_s: float = 1.0) -> list[Panel]:
    """Per stream that had updates: the RMS of its normalized innovations over ``window_s`` (1 for a filter whose
    covariance and noise match what it sees; the largest record's in the legend), and the updates the gate refused
    per stream, cumulative, when any was; [] when the table has no innovation columns."""
    traces, refused = [], []
    for s in INNOVATION_STREAMS:
        nu, gated = column("nu_" + s), column("gated_" + s)
        if nu is not None and np.any(np.isfinite(nu)):
            peak = float(np.nanmax(np.abs(nu)))
            traces.append(Trace(f"{s} (max {peak:.1f})", moving_rms(t, nu, window_s)))
        if gated is not None and np.nanmax(gated, initial=0.0) > 0.0:
            refused.append(Trace(s, gated - np.nanmin(gated)))
    if not traces:
        return []
    title = f"Filter innovations, normalized: {window_s:g} s RMS per stream (1: as expected)"
    if not refused:
        title += "; no update refused"
    out = [Panel(title, "σ", t, traces, [("expected", 1.0)])]
    if refused:
        out.append(Panel(f"Updates refused by the gate (|ν| > {GATE_SIGMAS:.2f}), cumulative", "count", t, refused))
    return out


__all__ = [
    "BAND_ERRORS",
    "BAND_SIGMAS",
    "GATE_SIGMAS",
    "band",
    "coverage",
    "error_range",
    "error_trace",
    "estimate_trace",
    "innovation_panels",
    "moving_rms",
]
