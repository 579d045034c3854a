"""``report.html``: one self-contained interactive page of a run, opened in any browser without a network.

The page holds an animated 3D view (vehicle, cable and load along the reference; play, pause, a time slider and
playback speeds), a column of time plots that share one time axis and one cursor (the cursor follows the
animation; clicking a time plot moves the animation there), the run's events on the time axis, and the metrics
as tables. Plotly draws everything (its JavaScript is embedded, compressed: ``offboard.report.html_plotly``; no CDN,
no network request); a few lines of glue JavaScript link the cursor.

The API is small and neutral, so that every command writes its report the same way::

    write_report_html(out_dir, title, panels, events, metrics, animation=Animation(...), subtitle="...")

``panels``: :class:`Panel` (one time plot: its traces, optional uncertainty bands and horizontal limit lines),
``events``: :class:`Event` (time, kind, text), ``metrics``: the run's metrics dict (rendered as tables),
``animation``: :class:`Animation` (positions over time, world frame, z up) or None (no 3D view). Long runs are
decimated (min/max per bucket, so that chattering stays visible as its envelope, not aliased away).
Times are seconds on the run's time axis (for flights the reference time); positions are metres.
"""

from __future__ import annotations

import html
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from offboard.outputs import write_text_atomic
from offboard.report.html_plotly import DEFERRED_TYPE, pack, plotly_loader
from offboard.report.html_view import MAX_POINTS, Animation, display, view_figure

#: events this close outside the plotted range are still drawn (a flight's start and hand-over events fall just
#: before its first tick and just after its last), s
EDGE_S = 0.1

#: event kinds that draw a red line (faults, hand-overs not planned); others draw grey
_ALARM_WORDS = ("stale", "abort", "fault", "overrun", "signal", "diverg", "swing", "fail", "refused", "lost")


@dataclass(frozen=True)
class Trace:
    """One line of a time plot: ``y`` over the panel's ``t`` (or its own ``t``); ``band``: (low, high) drawn as a
    shaded uncertainty band around it; ``dash``: dashed (references, setpoints)."""

    name: str
    y: np.ndarray
    t: np.ndarray | None = None
    band: tuple[np.ndarray, np.ndarray] | None = None
    dash: bool = False


@dataclass(frozen=True)
class Panel:
    """One time plot: a title, its unit (the y axis label), traces over time ``t`` (s), and horizontal limit lines
    (label, value), e.g. a saturation limit; ``y_range``: the y axis's initial range (None: all of the data; the
    reader can still zoom out)."""

    title: str
    unit: str
    t: np.ndarray
    traces: Sequence[Trace]
    limits: Sequence[tuple[str, float]] = ()
    y_range: tuple[float, float] | None = None


@dataclass(frozen=True)
class Event:
    """Something that happened at time ``t`` (s, the report's time axis): ``kind`` (phase, mode, disturbance,
    watchdog...) and a one-line ``text``. Events outside the plotted time range are listed only in the table."""

    t: float
    kind: str
    text: str


@dataclass
class _Page:
    """What the glue script needs to know about the page (serialized as JSON into it)."""

    t0: float
    t1: float
    frame_dt: float
    has_animation: bool


def decimate(t: np.ndarray, y: np.ndarray, max_points: int = MAX_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """At most about ``max_points`` points of (t, y): the minimum and the maximum of each bucket in time order, so
    that a fast oscillation keeps its envelope. Non-finite samples stay (they break the line where data is
    missing). Vectorized over the buckets (a replay's report decimates 37 series of 5000 ticks: the loop over
    buckets took 0.5 s of CPU of it)."""
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    n = len(t)
    if n <= max_points:
        return t, y
    buckets = max(1, max_points // 2)
    edges = np.linspace(0, n, buckets + 1).astype(int)
    starts, ends = edges[:-1], edges[1:]
    used = ends > starts
    starts, ends = starts[used], ends[used]
    width = int((ends - starts).max())
    # one row per bucket, padded with its own last sample (a repeat changes neither its minimum nor where the
    # first one is)
    idx = np.minimum(starts[:, None] + np.arange(width)[None, :], (ends - 1)[:, None])
    seg = y[idx]
    nan = np.isnan(seg)
    i = starts + np.argmin(np.where(nan, np.inf, seg), axis=1)
    j = starts + np.argmax(np.where(nan, -np.inf, seg), axis=1)
    lo, hi = np.minimum(i, j), np.maximum(i, j)
    empty = ~np.any(np.isfinite(seg), axis=1)  # nothing finite: the bucket's first sample
    lo[empty] = hi[empty] = starts[empty]
    pairs = np.column_stack((lo, hi))
    keep = np.column_stack((np.ones(len(lo), dtype=bool), hi != lo))
    out = pairs[keep]
    return t[out], y[out]


def _rgba(hex_colour: str, alpha: float) -> str:
    """``#rrggbb`` as ``rgba(r,g,b,alpha)``."""
    r, g, b = (int(hex_colour[i : i + 2], 16) for i in (1, 3, 5))
    return f"rgba({r},{g},{b},{alpha})"


def _time_figure(panels: Sequence[Panel], events: Sequence[Event], t_range: tuple[float, float]) -> Any:
    """The column of time plots: one row per panel, shared x axis, event lines, and the cursor (shape 0)."""
    from plotly.subplots import make_subplots

    rows = len(panels)
    fig = make_subplots(
        rows=rows,
        cols=1,
        shared_xaxes=True,
        vertical_spacing=min(0.04, 0.6 / max(rows, 1)),
        subplot_titles=[p.title for p in panels],
    )
    palette = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#17becf", "#8c564b")
    for r, panel in enumerate(panels, start=1):
        solid = -1
        legend: list[tuple[str, str]] = []
        for tr in panel.traces:
            # a dashed trace (reference, setpoint) takes the colour of the line before it
            solid += 0 if tr.dash and solid >= 0 else 1
            color = palette[solid % len(palette)]
            legend.append((tr.name + (" (dashed)" if tr.dash else ""), color))
            tt = panel.t if tr.t is None else tr.t
            if tr.band is not None:
                lo_t, lo = decimate(tt, tr.band[0])
                hi_t, hi = decimate(tt, tr.band[1])
                fig.add_scatter(
                    x=display(np.concatenate([lo_t, hi_t[::-1]])),
                    y=display(np.concatenate([lo, hi[::-1]])),
                    fill="toself",
                    fillcolor=_rgba(color, 0.2),
                    line={"width": 0},
                    hoverinfo="skip",
                    name=f"{tr.name} band",
                    legendgroup=f"p{r}",
                    showlegend=False,
                    row=r,
                    col=1,
                )
            x, y = decimate(tt, tr.y)
            fig.add_scatter(
                x=display(x),
                y=display(y),
                mode="lines",
                name=tr.name,
                line={"width": 1.2, "dash": "dash" if tr.dash else "solid", "color": color},
                legendgroup=f"p{r}",
                showlegend=False,
                hovertemplate=f"{html.escape(tr.name)}: %{{y:.4g}}<extra>t = %{{x:.3f}} s</extra>",
                row=r,
                col=1,
            )
        for label, value in panel.limits:
            if math.isfinite(value):
                fig.add_hline(
                    y=value,
                    line={"color": "#d62728", "width": 1, "dash": "dot"},
                    annotation_text=label,
                    annotation_font_size=9,
                    annotation_position="top left",
                    row=r,
                    col=1,
                )
        fig.update_yaxes(title_text=panel.unit, title_font_size=10, row=r, col=1)
        if panel.y_range is not None:
            fig.update_yaxes(range=list(panel.y_range), row=r, col=1)
        # the panel's legend in its title, each name in its line's colour (plotly has one legend per figure)
        names = ", ".join(f"<span style='color:{c}'>{html.escape(n)}</span>" for n, c in legend)
        fig.layout.annotations[r - 1].text = f"{panel.title}  <span style='font-size:10px'>{names}</span>"
    # the cursor first, so that the glue script moves shapes[0]
    shapes = [
        {
            "type": "line",
            "xref": "x",
            "yref": "paper",
            "x0": t_range[0],
            "x1": t_range[0],
            "y0": 0,
            "y1": 1,
            "line": {"color": "#000", "width": 1.5},
        }
    ]
    for ev in events:
        if t_range[0] - EDGE_S <= ev.t <= t_range[1] + EDGE_S:
            alarm = any(w in ev.kind.lower() or w in ev.text.lower() for w in _ALARM_WORDS)
            shapes.append(
                {
                    "type": "line",
                    "xref": "x",
                    "yref": "paper",
                    "x0": ev.t,
                    "x1": ev.t,
                    "y0": 0,
                    "y1": 1,
                    "line": {"color": "#d62728" if alarm else "#888", "width": 1, "dash": "dash"},
                }
            )
    fig.update_layout(
        shapes=list(fig.layout.shapes) + shapes[1:],
        height=170 * rows + 80,
        margin={"l": 70, "r": 20, "t": 40, "b": 40},
        hovermode="x",
        template="plotly_white",
    )
    # the cursor must be shape 0 whatever add_hline put first
    fig.layout.shapes = (shapes[0], *fig.layout.shapes)
    fig.update_xaxes(range=list(t_range))
    fig.update_xaxes(title_text="time (s)", row=rows, col=1)
    return fig


def _flatten(prefix: str, obj: Any, out: list[tuple[str, str]]) -> None:
    if isinstance(obj, dict):
        for k, v in obj.items():
            _flatten(f"{prefix}.{k}" if prefix else str(k), v, out)
        return
    if isinstance(obj, float):
        text = f"{obj:.6g}" if math.isfinite(obj) else "n/a"
    elif isinstance(obj, (list, tuple)):
        items = [f"{v:.4g}" if isinstance(v, float) else str(v) for v in obj[:8]]
        text = "[" + ", ".join(items) + (", …" if len(obj) > 8 else "") + "]"
    else:
        text = str(obj)
    out.append((prefix, text))


def metrics_tables(metrics: dict[str, Any]) -> str:
    """The metrics as HTML tables: the top-level scalars first, then one table per section (nested keys
    joined with '.')."""
    parts: list[str] = []
    top: list[tuple[str, str]] = []
    for k, v in metrics.items():
        if not isinstance(v, dict):
            _flatten(str(k), v, top)
    sections = [(k, v) for k, v in metrics.items() if isinstance(v, dict)]
    for name, rows in [("run", top), *((k, _rows(v)) for k, v in sections)]:
        if not rows:
            continue
        body = "".join(f"<tr><td>{html.escape(a)}</td><td>{html.escape(b)}</td></tr>" for a, b in rows)
        parts.append(
            f"<details{' open' if name in ('run', 'rms', 'max') else ''}><summary>{html.escape(name)}"
            f"</summary><table class='metrics'>{body}</table></details>"
        )
    return "\n".join(parts)


def _rows(d: dict[str, Any]) -> list[tuple[str, str]]:
    out: list[tuple[str, str]] = []
    _flatten("", d, out)
    return out


def events_table(events: Sequence[Event], t_range: tuple[float, float]) -> str:
    """Every event as a table row (time, kind, text); those outside the plotted range are marked so."""
    rows = []
    for ev in sorted(events, key=lambda e: e.t):
        where = "" if t_range[0] - EDGE_S <= ev.t <= t_range[1] + EDGE_S else " (outside the plots)"
        rows.append(
            f"<tr><td>{ev.t:.3f}{where}</td><td>{html.escape(ev.kind)}</td><td>{html.escape(ev.text)}</td></tr>"
        )
    if not rows:
        return "<p>No events were recorded.</p>"
    return "<table class='events'><tr><th>t (s)</th><th>kind</th><th>what</th></tr>" + "".join(rows) + "</table>"


_GLUE = """
(function () {
  const page = JSON.parse(document.getElementById('slung-page').textContent);
  const view = document.getElementById('slung-view');
  const plots = document.getElementById('slung-plots');
  function setCursor(t) {
    if (!plots || !plots.layout) return;
    Plotly.relayout(plots, {'shapes[0].x0': t, 'shapes[0].x1': t});
    const label = document.getElementById('slung-cursor');
    if (label) label.textContent = t.toFixed(2);
  }
  window.slungSetCursor = setCursor;
  // Plotly.animate rejects the promise of a running animation, with no reason, when pause (or another play or
  // a slider step) interrupts it, and plotly's buttons do not catch it: that is the control working, not an error.
  window.addEventListener('unhandledrejection', function (ev) { if (ev.reason === undefined) ev.preventDefault(); });
  if (view && page.has_animation) {
    view.on('plotly_animatingframe', function (ev) { setCursor(parseFloat(ev.name)); });
    view.on('plotly_sliderchange', function (ev) { setCursor(parseFloat(ev.step.args[0][0])); });
  }
  if (plots) {
    plots.on('plotly_click', function (ev) {
      if (!ev.points || !ev.points.length) return;
      const t = ev.points[0].x;
      setCursor(t);
      if (view && page.has_animation && view._transitionData && view._transitionData._frames.length) {
        const frames = view._transitionData._frames;
        let best = frames[0].name, bestd = Infinity;
        for (const f of frames) {
          const d = Math.abs(parseFloat(f.name) - t);
          if (d < bestd) { bestd = d; best = f.name; }
        }
        const now = {duration: 0, redraw: true};
        Plotly.animate(view, [best], {mode: 'immediate', frame: now, transition: {duration: 0}});
      }
    });
  }
})();
"""

_STYLE = """
body { font-family: system-ui, sans-serif; margin: 1em 2em; color: #222; }
h1 { font-size: 1.35em; margin-bottom: 0.1em; }
p.sub { color: #555; margin-top: 0; }
table { border-collapse: collapse; font-size: 0.85em; margin: 0.3em 0 1em 0; }
td, th { border: 1px solid #ddd; padding: 2px 8px; text-align: left; }
details { margin: 0.2em 0; }
summary { cursor: pointer; font-weight: 600; }
"""


def render_report_html(
    title: str,
    panels: Sequence[Panel],
    events: Sequence[Event],
    metrics: dict[str, Any],
    animation: Animation | None = None,
    subtitle: str = "",
) -> str:
    """The page as a string (see the module docstring); :func:`write_report_html` writes it."""
    t_lo, t_hi = math.inf, -math.inf
    for p in panels:
        tt = np.asarray(p.t, dtype=float)
        tt = tt[np.isfinite(tt)]
        if len(tt):
            t_lo, t_hi = min(t_lo, float(tt[0])), max(t_hi, float(tt[-1]))
    if animation is not None and len(animation.t):
        t_lo, t_hi = min(t_lo, float(animation.t[0])), max(t_hi, float(animation.t[-1]))
    if not math.isfinite(t_lo):
        t_lo, t_hi = 0.0, 1.0
    t_range = (t_lo, t_hi if t_hi > t_lo else t_lo + 1.0)
    plotly_loaded = False
    parts: list[str] = []
    page = _Page(t_range[0], t_range[1], 0.1, animation is not None and len(animation.t) > 0)
    config = {"displaylogo": False, "responsive": True}
    if page.has_animation:
        assert animation is not None
        view, page.frame_dt = view_figure(animation)
        parts.append("<h2>3D view <small>(drag to rotate; ▶ plays at the chosen speed)</small></h2>")
        parts.append(
            pack(
                view.to_html(
                    full_html=False, include_plotlyjs=False, div_id="slung-view", config=config, auto_play=False
                )
            )
        )
        plotly_loaded = True
    if panels:
        fig = _time_figure(panels, events, t_range)
        parts.append(
            "<h2>Time plots <small>(cursor at t = <span id='slung-cursor'>"
            f"{t_range[0]:.2f}</span> s; click a plot to move the 3D view there)</small></h2>"
        )
        parts.append(pack(fig.to_html(full_html=False, include_plotlyjs=False, div_id="slung-plots", config=config)))
        plotly_loaded = True
    parts.append("<h2>Metrics</h2>" + metrics_tables(metrics))
    parts.append("<h2>Events</h2>" + events_table(events, t_range))
    page_json = json.dumps(page.__dict__).replace("</", "<\\/")
    return (
        "<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'>"
        f"<title>{html.escape(title)}</title><style>{_STYLE}</style></head><body>"
        f"<h1>{html.escape(title)}</h1><p class='sub'>{html.escape(subtitle)}</p>\n"
        + "\n".join(parts)
        + f"\n<script type='application/json' id='slung-page'>{page_json}</script>"
        + (f"\n<script type='{DEFERRED_TYPE}'>{_GLUE}</script>\n{plotly_loader()}" if plotly_loaded else "")
        + "\n</body></html>\n"
    )


def write_report_html(
    out_dir: str | Path,
    title: str,
    panels: Sequence[Panel],
    events: Sequence[Event],
    metrics: dict[str, Any],
    animation: Animation | None = None,
    *,
    subtitle: str = "",
    name: str = "report.html",
) -> Path:
    """Write ``out_dir/name`` (default ``report.html``) atomically; returns its path. See the module docstring."""
    return write_text_atomic(
        Path(out_dir) / name, render_report_html(title, panels, events, metrics, animation, subtitle)
    )


__all__ = [
    "MAX_POINTS",
    "Animation",
    "Event",
    "Panel",
    "Trace",
    "decimate",
    "render_report_html",
    "write_report_html",
]
