"""Figures and failure regions of ``slung sweep``: success rate and worst case against each drawn parameter, the
distributions of the figures, and the parameter ranges where a controller fails more often than overall."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from offboard.harness.sweep import PARAMETERS

BINS = 6


def _bins(values: np.ndarray) -> np.ndarray:
    lo, hi = float(values.min()), float(values.max())
    if hi <= lo:
        return np.array([lo, lo + 1e-12])
    return np.linspace(lo, hi, BINS + 1)


def failure_regions(rows: list[dict[str, str]], min_runs: int = 5) -> list[dict[str, Any]]:
    """Parameter ranges (one of :data:`~offboard.harness.sweep.PARAMETERS` binned in equal widths) whose success rate is
    at least 10 points below the controller's overall rate and below 90 %, with at least ``min_runs`` runs."""
    if not rows:
        return []
    ok = np.array([r["success"] == "1" for r in rows])
    overall = ok.mean()
    found = []
    for name in PARAMETERS:
        v = np.array([float(r[name]) for r in rows])
        if np.ptp(v) == 0.0:
            continue
        edges = _bins(v)
        idx = np.clip(np.searchsorted(edges, v, side="right") - 1, 0, len(edges) - 2)
        for b in range(len(edges) - 1):
            sel = idx == b
            n = int(sel.sum())
            if n < min_runs:
                continue
            rate = float(ok[sel].mean())
            if rate < 0.9 and rate <= overall - 0.1:
                unit = PARAMETERS[name][0]
                found.append(
                    {
                        "parameter": name,
                        "low": float(edges[b]),
                        "high": float(edges[b + 1]),
                        "runs": n,
                        "success_rate": rate,
                        "text": f"{name} in [{edges[b]:.4g}, {edges[b + 1]:.4g}] {unit}: "
                        f"{100 * rate:.0f} % of {n} runs succeed (overall {100 * overall:.0f} %)",
                    }
                )
    return found


def _per_bin(table: list[dict[str, str]], name: str, controllers: list[str], what: str) -> tuple[np.ndarray, dict]:
    """Bin centres of parameter ``name`` over all runs, and per controller the success rate (``what`` = success)
    or the worst residual swing, rad (``worst``) of the runs in each bin (NaN: an empty bin)."""
    allv = np.array([float(r[name]) for r in table])
    edges = _bins(allv)
    mids = 0.5 * (edges[1:] + edges[:-1])
    out = {}
    for c in controllers:
        rows = [r for r in table if r["controller"] == c]
        v = np.array([float(r[name]) for r in rows])
        idx = np.clip(np.searchsorted(edges, v, side="right") - 1, 0, len(edges) - 2)
        if what == "success":
            ok = np.array([r["success"] == "1" for r in rows])
            y = [ok[idx == b].mean() if (idx == b).any() else np.nan for b in range(len(mids))]
        else:
            res = np.array([float(r["residual_swing_rad"]) for r in rows])
            y = [np.nanmax(res[idx == b]) if (idx == b).any() else np.nan for b in range(len(mids))]
        out[c] = np.array(y, dtype=float)
    return mids, out


def _varied(table: list[dict[str, str]]) -> list[str]:
    """The drawn parameters that really vary in ``table`` (a fixed one has nothing to plot against)."""
    return [n for n in PARAMETERS if np.ptp([float(r[n]) for r in table]) > 0.0]


def write_figures(out: Path, table: list[dict[str, str]], controllers: list[str]) -> list[Path]:
    """``sweep_success.png`` (success rate per parameter bin), ``sweep_worst.png`` (worst residual swing per bin),
    ``sweep_distributions.png`` (histograms of residual swing and tracking RMS)."""
    from offboard.report.figures import pyplot, save_png

    plt = pyplot()
    names = _varied(table)
    paths = []
    for fname, what in (("sweep_success.png", "success"), ("sweep_worst.png", "worst")):
        cols = 3
        nrows = max(1, math.ceil(len(names) / cols))
        fig, axes = plt.subplots(nrows, cols, figsize=(11.0, 2.8 * nrows), squeeze=False)
        for ax, name in zip(axes.flat, names):
            mids, ys = _per_bin(table, name, controllers, what)
            for c in controllers:
                ax.plot(mids, ys[c], marker="o", lw=1.0, label=c)
            ax.set_xlabel(f"{name} ({PARAMETERS[name][0]})")
            ax.set_ylabel("success rate" if what == "success" else "worst residual swing (rad)")
            ax.grid(alpha=0.3)
        for ax in list(axes.flat)[len(names) :]:
            ax.axis("off")
        axes.flat[0].legend(fontsize=8)
        paths.append(save_png(fig, out / fname))
    fig, axes = plt.subplots(1, 2, figsize=(10.0, 3.2))
    for c in controllers:
        rows = [r for r in table if r["controller"] == c]
        for ax, key in zip(axes, ("residual_swing_rad", "tracking_rms_m")):
            v = np.array([float(r[key]) for r in rows])
            v = v[np.isfinite(v)]
            if len(v):
                ax.hist(v, bins=30, alpha=0.5, label=c)
    for ax, key in zip(axes, ("residual swing (rad)", "tracking RMS (m)")):
        ax.set_xlabel(key)
        ax.set_ylabel("runs")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    paths.append(save_png(fig, out / "sweep_distributions.png"))
    return paths


def write_html(out: Path, table: list[dict[str, str]], controllers: list[str], summary: dict[str, Any]) -> Path:
    """``report.html`` of a sweep, one self-contained file (plotly inlined, no network): per varied parameter the
    success rate and the worst residual swing per bin (a line per controller), the distributions of the residual
    swing and the tracking RMS, and the summary's figures as tables."""
    import html

    from offboard.outputs import write_text_atomic
    from offboard.report.html_report import _STYLE, metrics_tables

    fig = sweep_figure(table, controllers)
    plots = fig.to_html(full_html=False, include_plotlyjs=True, div_id="slung-sweep", config={"displaylogo": False})
    title = "slung sweep"
    runs = ", ".join(f"{c}: {summary.get('controllers', {}).get(c, {}).get('runs', '?')} runs" for c in controllers)
    page = (
        "<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'>"
        f"<title>{html.escape(title)}</title><style>{_STYLE}</style></head><body>"
        f"<h1>{html.escape(title)} <small>{html.escape(runs)}</small></h1>"
        "<h2>Success and worst case against each parameter, distributions</h2>"
        + plots
        + "<h2>Summary</h2>"
        + metrics_tables(summary)
        + "</body></html>\n"
    )
    return write_text_atomic(out / "report.html", page)


def sweep_figure(table: list[dict[str, str]], controllers: list[str]) -> Any:
    """The plotly figure of :func:`write_html`: row k (1-based) holds parameter k of the varied ones (success rate
    in column 1, worst residual swing in column 2, a trace per controller over the bin centres); the last row the
    histograms of residual swing and tracking RMS."""
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    names = _varied(table)
    rows = max(1, len(names)) + 1
    titles = [f"{n}: {w}" for n in names for w in ("success rate", "worst residual swing (rad)")]
    titles += ["residual swing (rad): runs", "tracking RMS (m): runs"]
    fig = make_subplots(rows=rows, cols=2, subplot_titles=titles, vertical_spacing=0.35 / rows)
    palette = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f")
    colour = {c: palette[k % len(palette)] for k, c in enumerate(controllers)}
    for r, name in enumerate(names, start=1):
        for col, what in ((1, "success"), (2, "worst")):
            mids, ys = _per_bin(table, name, controllers, what)
            for c in controllers:
                fig.add_trace(
                    go.Scatter(
                        x=mids.tolist(),
                        y=[None if not math.isfinite(v) else float(v) for v in ys[c]],
                        name=c,
                        legendgroup=c,
                        showlegend=(r == 1 and col == 1),
                        mode="lines+markers",
                        line={"color": colour[c]},
                    ),
                    row=r,
                    col=col,
                )
            fig.update_xaxes(title_text=f"{name} ({PARAMETERS[name][0]})", title_font_size=10, row=r, col=col)
    for col, key in ((1, "residual_swing_rad"), (2, "tracking_rms_m")):
        for c in controllers:
            v = [float(x[key]) for x in table if x["controller"] == c]
            v = [x for x in v if math.isfinite(x)]
            fig.add_trace(
                go.Histogram(x=v, name=c, legendgroup=c, showlegend=False, opacity=0.5, marker={"color": colour[c]}),
                row=rows,
                col=col,
            )
    fig.update_layout(barmode="overlay", height=260 * rows + 80, template="plotly_white")
    return fig
