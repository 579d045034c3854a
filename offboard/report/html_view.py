"""The 3D view of ``report.html`` (``offboard.report.html_report``): the vehicle, the load and the cable animated over
the run with a time slider and playback speeds, the reference path dashed. World frame, z up, metres; times in s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

#: points kept per time-plot trace (min/max decimation above it)
MAX_POINTS = 2000


#: animation frames per second of run time (the 3D view), and the most frames a page holds
FRAME_RATE_HZ = 10.0


MAX_FRAMES = 600


#: playback speeds offered (x real time)
SPEEDS = (0.25, 1.0, 4.0)


@dataclass(frozen=True)
class Animation:
    """Positions over time for the 3D view, world frame with z up (m): ``t`` (n,), ``vehicle`` and ``load`` (n, 3),
    ``reference`` (m, 3): the path the load should follow (drawn dashed, not animated)."""

    t: np.ndarray
    vehicle: np.ndarray
    load: np.ndarray
    reference: np.ndarray | None = None


def _frame_indices(t: np.ndarray, frame_rate_hz: float = FRAME_RATE_HZ, max_frames: int = MAX_FRAMES) -> np.ndarray:
    """Sample indices of the animation frames: about ``frame_rate_hz`` per second of run time, at most
    ``max_frames``."""
    if len(t) == 0:
        return np.zeros(0, dtype=int)
    span = float(t[-1] - t[0])
    n = int(min(max_frames, max(2, math.floor(span * frame_rate_hz) + 1)))
    targets = np.linspace(t[0], t[-1], n)
    return np.unique(np.clip(np.searchsorted(t, targets), 0, len(t) - 1))


def display(a: Any) -> np.ndarray:
    """An array as the page draws it: float32 (7 significant digits, far finer than a screen's pixels; plotly
    embeds it as half the bytes of float64). The run folder's time series keep every value at full precision."""
    return np.asarray(a, dtype=np.float32)


def _mm(v: float) -> float:
    """A position in a frame of the animation, to 0.1 mm (written as JSON text: shorter than 17 digits)."""
    return round(float(v), 4)


def _path(go: Any, points: np.ndarray, name: str, line: dict[str, Any]) -> Any:
    """A still path of the view (rows of x, y, z in m, drawn as :func:`display` stores them), never hovered."""
    return go.Scatter3d(
        x=display(points[:, 0]),
        y=display(points[:, 1]),
        z=display(points[:, 2]),
        mode="lines",
        name=name,
        line=line,
        hoverinfo="skip",
    )


def _point(go: Any, p: Any, name: str, marker: dict[str, Any]) -> Any:
    """A body of the animation at position ``p`` (x, y, z in m) in one frame, as :func:`_mm` writes it."""
    return go.Scatter3d(x=[_mm(p[0])], y=[_mm(p[1])], z=[_mm(p[2])], mode="markers", name=name, marker=marker)


def view_figure(anim: Animation) -> tuple[Any, float]:
    """The 3D view with its frames, play / pause / speed buttons and slider; returns (figure, frame step s)."""
    import plotly.graph_objects as go

    t = np.asarray(anim.t, dtype=float)
    veh = np.asarray(anim.vehicle, dtype=float)
    load = np.asarray(anim.load, dtype=float)
    idx = _frame_indices(t)
    frame_dt = float(np.median(np.diff(t[idx]))) if len(idx) > 1 else 0.1
    stride = max(1, len(t) // MAX_POINTS)
    path_v, path_l = veh[::stride], load[::stride]
    k0 = int(idx[0]) if len(idx) else 0
    data = [
        _path(go, path_v, "vehicle path", {"color": "rgba(31,119,180,0.35)", "width": 2}),
        _path(go, path_l, "load path", {"color": "rgba(255,127,14,0.35)", "width": 2}),
    ]
    if anim.reference is not None and len(anim.reference):
        ref = np.asarray(anim.reference, dtype=float)[:: max(1, len(anim.reference) // MAX_POINTS)]
        data.append(_path(go, ref, "reference (load)", {"color": "#2ca02c", "width": 3, "dash": "dash"}))
    first_moving = len(data)

    def moving(k: int) -> list[Any]:
        v, q = veh[k], load[k]
        return [
            go.Scatter3d(
                x=[_mm(v[0]), _mm(q[0])],
                y=[_mm(v[1]), _mm(q[1])],
                z=[_mm(v[2]), _mm(q[2])],
                mode="lines",
                name="cable",
                line={"color": "#444", "width": 4},
            ),
            _point(go, v, "vehicle", {"size": 7, "color": "#1f77b4", "symbol": "square"}),
            _point(go, q, "load", {"size": 6, "color": "#ff7f0e"}),
        ]

    data += moving(k0)
    moving_ids = list(range(first_moving, first_moving + 3))
    frames = [go.Frame(name=f"{t[k]:.3f}", data=moving(int(k)), traces=moving_ids) for k in idx]
    fig = go.Figure(data=data, frames=frames)

    def play(speed: float) -> dict[str, Any]:
        return {
            "label": f"▶ {speed:g}x",
            "method": "animate",
            "args": [
                None,
                {
                    "frame": {"duration": max(10, round(1000.0 * frame_dt / speed)), "redraw": True},
                    "transition": {"duration": 0},
                    "fromcurrent": True,
                    "mode": "immediate",
                },
            ],
        }

    pause = {
        "label": "❚❚ pause",
        "method": "animate",
        "args": [
            [None],
            {"frame": {"duration": 0, "redraw": False}, "mode": "immediate", "transition": {"duration": 0}},
        ],
    }
    steps = [
        {
            "label": f"{t[k]:.1f}",
            "method": "animate",
            "args": [
                [f"{t[k]:.3f}"],
                {"frame": {"duration": 0, "redraw": True}, "mode": "immediate", "transition": {"duration": 0}},
            ],
        }
        for k in idx
    ]
    fig.update_layout(
        height=560,
        margin={"l": 0, "r": 0, "t": 10, "b": 10},
        scene={
            **_scene_axes(np.vstack([veh, load])),
            "camera": {"eye": {"x": 1.4, "y": -1.6, "z": 0.9}},
        },
        legend={"orientation": "h", "y": 1.02, "x": 0.0},
        updatemenus=[
            {
                "type": "buttons",
                "direction": "left",
                "showactive": False,
                "x": 0.0,
                "y": 0.0,
                "xanchor": "left",
                "yanchor": "top",
                "pad": {"t": 40},
                "buttons": [*(play(s) for s in SPEEDS), pause],
            }
        ],
        sliders=[
            {
                "active": 0,
                "x": 0.33,
                "len": 0.67,
                "y": 0.0,
                "yanchor": "top",
                "pad": {"t": 30},
                "currentvalue": {"prefix": "t = ", "suffix": " s", "font": {"color": "#222"}},
                "font": {"color": "rgba(0,0,0,0)"},  # one label per frame would overlap: the current one is shown
                "steps": steps,
            }
        ],
    )
    return fig, frame_dt


def _scene_axes(points: np.ndarray) -> dict[str, Any]:
    """Axis ranges and aspect of the 3D scene: true scale (a metre is as long on every axis), but no axis
    narrower than half the widest (nor than 1 m), so that a run that stays near one spot is not drawn as a sliver."""
    pts = points[np.all(np.isfinite(points), axis=1)]
    if len(pts) == 0:
        pts = np.zeros((1, 3))
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    span = np.maximum(hi - lo, 0.0)
    widest = max(float(span.max()), 2.0)
    half = np.maximum(span, widest / 2.0) / 2.0 * 1.1
    mid = (lo + hi) / 2.0
    out: dict[str, Any] = {"aspectmode": "manual"}
    out["aspectratio"] = {k: float(half[i] / half.max()) for i, k in enumerate("xyz")}
    for i, (k, label) in enumerate((("x", "x (m)"), ("y", "y (m)"), ("z", "z up (m)"))):
        out[f"{k}axis"] = {
            "title": {"text": label},
            "range": [float(mid[i] - half[i]), float(mid[i] + half[i])],
            "nticks": 5,
        }
    return out
