"""Trajectory files (TOML, format in ``docs/references.md``) into references: ``slung sim`` / ``slung fly``
``--trajectory FILE``. A bad file raises :class:`~offboard.control.reference.TrajectoryError` (a
:class:`~estimators.errors.UserError`) with a one-line message naming the file and the bad value.
"""

from __future__ import annotations

import itertools
import math
from pathlib import Path

from offboard.control.move_planning import move_reference
from offboard.control.reference import Composite, TrajectoryError, _finite
from offboard.control.reference_moves import DEFAULT_RAMP_ORDER, move_profile
from offboard.control.reference_patterns import SHAPES, circle, figure_eight, hover, waypoints

try:
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10
    import tomli as tomllib


# --------------------------------------------------------------------------------------------------------------
# trajectory files
# --------------------------------------------------------------------------------------------------------------
_KINDS = ("waypoints", "hover", "circle", "figure_eight", "move")
_KEYS = {
    "waypoints": {"kind", "t_start", "speed", "segment_times", "yaw_rate", "min_segment_time", "shape", "waypoint"},
    "hover": {"kind", "x", "y", "z", "psi", "psi_deg"},
    "move": {"kind", "from", "to", "time", "ramp", "cruise", "ramp_order", "t_start", "hold", "psi", "psi_deg"},
    "circle": {"kind", "center", "radius", "period", "z", "t_start", "ramp_time", "laps", "psi", "psi_deg"},
    "figure_eight": {
        "kind",
        "center",
        "size_x",
        "size_y",
        "period",
        "z",
        "t_start",
        "ramp_time",
        "laps",
        "psi",
        "psi_deg",
    },
}


def _file_psi(where: str, d: dict) -> float:
    if "psi" in d and "psi_deg" in d:
        raise TrajectoryError(f"{where}: give psi (rad) or psi_deg (degrees), not both")
    if "psi_deg" in d:
        return math.radians(_finite(f"{where}: psi_deg", d["psi_deg"]))
    return _finite(f"{where}: psi", d.get("psi", 0.0))


def _need(where: str, d: dict, key: str) -> object:
    if key not in d:
        raise TrajectoryError(f"{where}: missing '{key}'")
    return d[key]


def _reference_from_table(data: dict, where: str) -> Composite:
    kind = data.get("kind", "waypoints")
    if kind not in _KINDS:
        raise TrajectoryError(f"{where}: kind must be one of {', '.join(_KINDS)}, got {kind!r}")
    unknown = sorted(set(data) - _KEYS[kind])
    if unknown:
        raise TrajectoryError(f"{where}: unknown key(s) for kind '{kind}': {', '.join(unknown)}")
    num = {
        k: v for k, v in data.items() if k not in ("kind", "waypoint", "center", "segment_times", "shape", "from", "to")
    }
    for k, v in num.items():
        if k != "laps":
            _finite(f"{where}: {k}", v)
    if kind == "hover":
        return hover(_need(where, data, "x"), _need(where, data, "y"), _need(where, data, "z"), _file_psi(where, data))
    if kind == "move":
        return _move(data, where)
    if kind in ("circle", "figure_eight"):
        center = _need(where, data, "center")
        if not isinstance(center, list) or len(center) != 2:
            raise TrajectoryError(f"{where}: center must be [x, y] in m, got {center!r}")
        common = {
            "period": _need(where, data, "period"),
            "z": _finite(f"{where}: z", _need(where, data, "z")),
            "t_start": data.get("t_start", 0.0),
            "ramp_time": data.get("ramp_time"),
            "laps": data.get("laps"),
            "psi": _file_psi(where, data),
        }
        try:
            if kind == "circle":
                return circle(center, _need(where, data, "radius"), **common)
            return figure_eight(center, _need(where, data, "size_x"), _need(where, data, "size_y"), **common)
        except TrajectoryError as exc:
            raise TrajectoryError(f"{where}: {exc}") from None
    shape = data.get("shape", "position")
    if shape not in SHAPES:
        raise TrajectoryError(f"{where}: shape must be one of {', '.join(SHAPES)}, got {shape!r}")
    wps = data.get("waypoint")
    if not isinstance(wps, list) or not wps:
        raise TrajectoryError(f"{where}: no [[waypoint]] entries")
    pts = []
    times = []
    for i, w in enumerate(wps):
        wh = f"{where}: waypoint {i + 1}"
        if not isinstance(w, dict):
            raise TrajectoryError(f"{wh}: must be a table with x, y, z")
        bad = sorted(set(w) - {"x", "y", "z", "psi", "psi_deg", "t"})
        if bad:
            raise TrajectoryError(f"{wh}: unknown key(s) {', '.join(bad)}")
        pts.append(
            (
                _finite(f"{wh}: x", _need(wh, w, "x")),
                _finite(f"{wh}: y", _need(wh, w, "y")),
                _finite(f"{wh}: z", _need(wh, w, "z")),
                _file_psi(wh, w),
            )
        )
        if "t" in w:
            times.append(_finite(f"{wh}: t", w["t"]))
    try:
        if times:
            if len(times) != len(pts):
                raise TrajectoryError("give t on every waypoint or on none")
            if any(k in data for k in ("speed", "segment_times", "t_start")):
                raise TrajectoryError("waypoint times t exclude speed, segment_times and t_start")
            seg = [b - a for a, b in itertools.pairwise(times)]
            for i, d in enumerate(seg):
                if not d > 0.0:
                    raise TrajectoryError(f"waypoint times must increase (waypoint {i + 2} at t = {times[i + 1]!r} s)")
            return waypoints(pts, segment_times=seg, t_start=times[0], shape=shape) if seg else hover(*pts[0])
        seg_times = data.get("segment_times")
        if seg_times is not None and not isinstance(seg_times, list):
            raise TrajectoryError(f"segment_times must be a list of seconds, got {seg_times!r}")
        return waypoints(
            pts,
            speed=data.get("speed"),
            segment_times=seg_times,
            t_start=data.get("t_start", 0.0),
            yaw_rate=data.get("yaw_rate", 0.5),
            min_segment_time=data.get("min_segment_time", 1.0),
            shape=shape,
        )
    except TrajectoryError as exc:
        msg = str(exc)
        raise TrajectoryError(msg if msg.startswith(where) else f"{where}: {msg}") from None


def _move(data: dict, where: str) -> Composite:
    """A planned move written out in full (``slung fly --move`` writes one into its run folder, which replay reads):
    from, to (m, [x, y, z]), its time and ramp (s), optionally cruise (s), ramp_order, t_start and hold (s)."""
    ends = []
    for key in ("from", "to"):
        v = _need(where, data, key)
        if not isinstance(v, list) or len(v) != 3:
            raise TrajectoryError(f"{where}: {key} must be [x, y, z] in m, got {v!r}")
        ends.append([_finite(f"{where}: {key}", x) for x in v])
    order = data.get("ramp_order", DEFAULT_RAMP_ORDER)
    try:
        shape = move_profile(_need(where, data, "time"), _need(where, data, "ramp"), data.get("cruise", 0.0), order)
        return move_reference(
            ends[0], ends[1], shape, data.get("t_start", 0.0), data.get("hold", 0.0), _file_psi(where, data)
        )
    except TrajectoryError as exc:
        raise TrajectoryError(f"{where}: {exc}") from None


def load_trajectory_file(path: str | Path) -> Composite:
    """Read a trajectory file (TOML, format in ``docs/references.md``); bad files raise :class:`TrajectoryError`
    (a :class:`~estimators.errors.UserError`) with a one-line message naming the file and the bad value."""
    p = Path(path)
    where = str(p)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise TrajectoryError(f"cannot read trajectory file {where}: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise TrajectoryError(f"{where}: not a UTF-8 text file") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise TrajectoryError(f"{where}: not valid TOML ({str(exc).splitlines()[0]})") from None
    return _reference_from_table(data, where)


__all__ = ["load_trajectory_file"]
