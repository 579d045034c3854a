"""Ground truth of an ArduPilot SITL flight with its slung payload, read from its DataFlash log (pymavlink DFReader),
and the figures of a move measured on it as issue 37 defines them.

The SITL logs the simulation's truth beside what ArduPilot believes:

- ``SLUP`` (10 Hz): the payload's position and velocity relative to the vehicle (PN / PE / PD, m; VN / VE / VD, m/s;
  NED), ``Tens`` and ``Land`` (1 while it lies on the ground): the swing's truth. ``Tens`` is ArduPilot's tension
  *ratio*, not a force (``SIM_SlungPayload.cpp``: 1 while the payload is at the line's length, falling to 0 when it
  is 10 cm inside it, the pull scaled by it); the line's pull on the vehicle is ``VFN`` / ``VFE`` / ``VFD`` (N, NED:
  ``VFD`` = the payload's weight, 11.8 N for 1.2 kg, hanging still; 0 on a slack line);
- ``SIM`` (the logging rate): the simulated vehicle's true attitude (Roll / Pitch / Yaw, deg);
- ``SIM2`` (400 Hz): its true position (PN / PE / PD, m NED from the simulation's origin) and velocity;
- ``ATT``: ArduPilot's attitude estimate and its targets (DesRoll / DesPitch, deg): the "tilt" of issue 38;
- ``CTUN``: the throttle out and ArduPilot's hover throttle (``ThO``, ``ThH``); ``MODE``: the mode numbers.

Times are seconds since the SITL booted (``TimeUS``), the clock of MAVLink ``time_boot_ms`` and of ``slung fly``'s
``t_vehicle``. Angles are converted to radians here; frames stay ArduPilot's NED (a test and benchmark reader beside
the flight path, like ``sim_bridge.sitl.px4_ulog`` for PX4, whose :class:`Series` it shares).

The payload's truth judges flights; it is never fed to a filter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sim_bridge.sitl.px4_ulog import Series

#: the message types read, and the columns kept of each (the rest of a log is skipped unparsed)
COLUMNS: dict[str, tuple[str, ...]] = {
    "SLUP": ("PN", "PE", "PD", "VN", "VE", "VD", "Tens", "Land", "VFN", "VFE", "VFD"),
    "SIM": ("Roll", "Pitch", "Yaw"),
    "SIM2": ("PN", "PE", "PD", "VN", "VE", "VD"),
    "ATT": ("Roll", "Pitch", "Yaw", "DesRoll", "DesPitch"),
    "CTUN": ("ThO", "ThH", "Alt", "DAlt"),
    "MODE": ("ModeNum",),
}
#: the two bytes every DataFlash record starts with
DATAFLASH_HEAD = bytes((0xA3, 0x95))
#: ArduCopter mode numbers the tests look for
MODES = {"stabilize": 0, "guided": 4, "loiter": 5, "land": 9, "brake": 17}
#: a move has arrived once the vehicle stays within this of its goal (m, horizontally; issue 37's T)
ARRIVAL_RADIUS_M = 0.2
#: the residual swing is judged from 2 s to 12 s after arrival
RESIDUAL_WINDOW_S = (2.0, 12.0)


def _tilt(roll: np.ndarray, pitch: np.ndarray) -> np.ndarray:
    """The angle between the body z axis and the vertical (rad) of ZYX roll and pitch (rad)."""
    return np.arccos(np.clip(np.cos(roll) * np.cos(pitch), -1.0, 1.0))


@dataclass(frozen=True)
class ArduPilotFlightLog:
    """The truth of one DataFlash log (see module docstring); every angle in radians."""

    path: Path
    # pn, pe, pd, vn, ve, vd (payload minus vehicle, NED), tension (ArduPilot's ratio 0..1), landed (0/1), swing
    # (rad), pull_n, pull_e, pull_d (the line's force on the vehicle, N, NED)
    slup: Series
    sim_att: Series  # roll, pitch, yaw, tilt: the simulation's true attitude
    sim_pos: Series  # pn, pe, pd, vn, ve, vd: the simulation's true position, NED from its origin
    att: Series  # roll, pitch, yaw, tilt, des_roll, des_pitch, des_tilt: ArduPilot's estimate and target
    ctun: Series  # tho (throttle out), thh (hover throttle), alt, dalt
    mode: Series  # mode (ArduCopter mode number), from each MODE record on

    def mode_at(self, t: float) -> int | None:
        """The mode in force at ``t`` (the last MODE record at or before it), None before the first."""
        i = int(np.searchsorted(self.mode.t, t, side="right")) - 1
        return None if i < 0 else int(self.mode["mode"][i])

    def swing(self, t0: float = -math.inf, t1: float = math.inf, airborne: bool = True) -> Series:
        """SLUP's swing in ``t0..t1``; ``airborne``: only while the payload is off the ground."""
        w = self.slup.window(t0, t1)
        if not airborne or len(w) == 0:
            return w
        keep = w["landed"] < 0.5
        return Series(w.t[keep], {k: v[keep] for k, v in w.columns.items()})

    def max_tilt(self, t0: float = -math.inf, t1: float = math.inf, source: str = "att") -> float:
        """The largest tilt in ``t0..t1`` (rad): ``att`` ArduPilot's ATT (issue 38's measure), ``sim`` the truth."""
        w = (self.att if source == "att" else self.sim_att).window(t0, t1)
        return float(np.max(w["tilt"])) if len(w) else math.nan


def read_dataflash(path: str | Path) -> ArduPilotFlightLog:
    """Read an ArduPilot SITL DataFlash log into an :class:`ArduPilotFlightLog` (absent types give empty series);
    ValueError when pymavlink cannot read the file."""
    from pymavlink import DFReader

    p = Path(path)
    with open(p, "rb") as fh:
        if fh.read(2) != DATAFLASH_HEAD:
            raise ValueError(f"{p}: not a DataFlash log (it does not start with the record header A3 95)")
    try:
        reader = DFReader.DFReader_binary(str(p), zero_time_base=False)
    except Exception as exc:  # DFReader raises plain Exceptions on a file that is not DataFlash
        raise ValueError(f"{p}: not a DataFlash log ({exc})") from exc
    rows: dict[str, list[tuple[float, ...]]] = {k: [] for k in COLUMNS}
    types = list(COLUMNS)
    while True:
        m = reader.recv_match(type=types)
        if m is None:
            break
        kind = m.get_type()
        rows[kind].append((m.TimeUS * 1e-6, *(float(getattr(m, c)) for c in COLUMNS[kind])))

    def table(kind: str) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        a = np.asarray(rows[kind], dtype=float).reshape(-1, 1 + len(COLUMNS[kind]))
        return a[:, 0], {c: a[:, i + 1] for i, c in enumerate(COLUMNS[kind])}

    t, c = table("SLUP")
    slup = Series(
        t,
        {
            "pn": c["PN"],
            "pe": c["PE"],
            "pd": c["PD"],
            "vn": c["VN"],
            "ve": c["VE"],
            "vd": c["VD"],
            "tension": c["Tens"],
            "pull_n": c["VFN"],
            "pull_e": c["VFE"],
            "pull_d": c["VFD"],
            "landed": c["Land"],
            "swing": np.arctan2(np.hypot(c["PN"], c["PE"]), c["PD"]),
        },
    )
    t, c = table("SIM")
    r, pt = np.radians(c["Roll"]), np.radians(c["Pitch"])
    sim_att = Series(t, {"roll": r, "pitch": pt, "yaw": np.radians(c["Yaw"]), "tilt": _tilt(r, pt)})
    t, c = table("SIM2")
    sim_pos = Series(t, {k.lower(): v for k, v in c.items()})
    t, c = table("ATT")
    r, pt = np.radians(c["Roll"]), np.radians(c["Pitch"])
    dr, dp = np.radians(c["DesRoll"]), np.radians(c["DesPitch"])
    att = Series(
        t,
        {
            "roll": r,
            "pitch": pt,
            "yaw": np.radians(c["Yaw"]),
            "tilt": _tilt(r, pt),
            "des_roll": dr,
            "des_pitch": dp,
            "des_tilt": _tilt(dr, dp),
        },
    )
    t, c = table("CTUN")
    ctun = Series(t, {"tho": c["ThO"], "thh": c["ThH"], "alt": c["Alt"], "dalt": c["DAlt"]})
    t, c = table("MODE")
    mode = Series(t, {"mode": c["ModeNum"]})
    return ArduPilotFlightLog(p, slup, sim_att, sim_pos, att, ctun, mode)


@dataclass(frozen=True)
class MoveFigures:
    """A move's figures as issue 37 measures them (lengths m, times s, angles rad; NaN where not defined).

    arrival_s: from the move's start until the vehicle stays within ``ARRIVAL_RADIUS_M`` of the goal (horizontally,
    on the simulation's true position) to the end of the judged window; NaN if it never does. peak: the largest swing
    from the start to arrival. bound: ``atan(4 D / (g T^2))`` at that arrival time, the lower bound on any rest-to-rest
    move's peak (its peak acceleration is at least 4 D / T^2). residual: the largest swing from 2 s to 12 s after
    arrival (over what the window holds of it; ``residual_span_s`` says how much). overshoot: the largest distance
    past the goal along the move's direction. tilt_max: ArduPilot's ATT tilt over the whole window.
    """

    distance_m: float
    arrival_s: float
    peak_rad: float
    bound_rad: float
    residual_rad: float
    residual_span_s: float
    overshoot_m: float
    tilt_max_rad: float

    @property
    def peak_over_bound(self) -> float:
        """The peak in units of the physical bound."""
        return self.peak_rad / self.bound_rad if self.bound_rad > 0 else math.nan

    def as_dict(self) -> dict[str, float]:
        """The figures as a plain dict (JSON)."""
        return {**self.__dict__, "peak_over_bound": self.peak_over_bound}


def physical_bound(distance_m: float, arrival_s: float, g: float = 9.80665) -> float:
    """``atan(4 D / (g T^2))`` (rad): no rest-to-rest move of ``distance_m`` in ``arrival_s`` has a smaller steady
    swing at its peak acceleration (issue 37)."""
    if not (arrival_s > 0.0 and math.isfinite(arrival_s)):
        return math.nan
    return math.atan(4.0 * distance_m / (g * arrival_s**2))


def move_figures(
    log: ArduPilotFlightLog,
    t_start: float,
    t_end: float,
    distance_m: float,
    heading_ne: tuple[float, float] = (1.0, 0.0),
) -> MoveFigures:
    """The figures of a move of ``distance_m`` along the unit horizontal direction ``heading_ne`` (north, east) that
    starts at ``t_start`` (boot s, the vehicle at rest at its start point) and is judged until ``t_end``."""
    pos = log.sim_pos.window(t_start - 0.2, t_end)
    if len(pos) < 2:
        raise ValueError(f"{log.path}: no SIM2 truth in {t_start:.2f}..{t_end:.2f} s")
    hn, he = heading_ne
    start_n, start_e = pos.at(t_start, "pn"), pos.at(t_start, "pe")
    along = (pos["pn"] - start_n) * hn + (pos["pe"] - start_e) * he
    cross = -(pos["pn"] - start_n) * he + (pos["pe"] - start_e) * hn
    after = pos.t >= t_start
    if not np.any(after):
        raise ValueError(f"{log.path}: the judged window {t_start:.2f}..{t_end:.2f} s holds nothing of the move")
    off = np.hypot(along - distance_m, cross)
    outside = np.nonzero(after & (off > ARRIVAL_RADIUS_M))[0]
    if len(outside) and outside[-1] == len(pos.t) - 1:
        arrival = math.nan  # still outside at the window's end
    else:
        t_arr = pos.t[outside[-1] + 1] if len(outside) else t_start
        arrival = float(t_arr - t_start)
    overshoot = float(max(0.0, np.max(along[after]) - distance_m))
    t_arrived = t_start + arrival if math.isfinite(arrival) else t_end
    peak_w = log.swing(t_start, t_arrived)
    peak = float(np.max(peak_w["swing"])) if len(peak_w) else math.nan
    r0, r1 = t_arrived + RESIDUAL_WINDOW_S[0], min(t_arrived + RESIDUAL_WINDOW_S[1], t_end)
    res_w = log.swing(r0, r1) if math.isfinite(arrival) else log.swing(0.0, -1.0)
    residual = float(np.max(res_w["swing"])) if len(res_w) else math.nan
    return MoveFigures(
        distance_m,
        arrival,
        peak,
        physical_bound(distance_m, arrival),
        residual,
        float(max(0.0, r1 - r0)) if len(res_w) else 0.0,
        overshoot,
        log.max_tilt(t_start, t_end),
    )


__all__ = [
    "ARRIVAL_RADIUS_M",
    "COLUMNS",
    "MODES",
    "RESIDUAL_WINDOW_S",
    "ArduPilotFlightLog",
    "MoveFigures",
    "move_figures",
    "physical_bound",
    "read_dataflash",
]
