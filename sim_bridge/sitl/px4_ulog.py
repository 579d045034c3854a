"""Ground truth and autopilot internals of a PX4 SITL flight, read from its ULog (pyulog).

PX4 SITL with SIH logs the simulated vehicle's true state beside what its own estimator believes:

- ``vehicle_local_position_groundtruth``: true position / velocity, local NED (m, m/s);
- ``vehicle_attitude_groundtruth``: true attitude quaternion (w, x, y, z), NED -> FRD;
- ``vehicle_local_position``: EKF2's estimate (the one LOCAL_POSITION_NED carries), local NED;
- ``actuator_motors``: the allocator's motor commands, normalized 0..1 (the saturation measure);
- ``vehicle_thrust_setpoint``: the collective thrust the attitude / offboard path asked for (normalized, FRD z,
  negative up);
- ``vehicle_status``: navigation state and arming state (the failsafe hand-over).

Times are seconds since PX4 booted: the clock of MAVLink's ``time_boot_ms``, so a flight log's ``t_vehicle``
(``slung fly``'s ``timeseries_live.slts``) indexes these series directly. Frames are PX4's (NED / FRD): this is a
test and benchmark reader beside the flight path, and the comparisons it serves are made in NED.

Both local frames share EKF2's reference point, but SIH's ground truth z is measured from its own origin while
EKF2's origin is where it started (the ground sat between -0.8 and +0.6 m of EKF2's local z): compare heights
relative to the position at take-off (:meth:`Px4FlightLog.ground_z`), never absolute z across the two.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

TOPICS = (
    "vehicle_local_position_groundtruth",
    "vehicle_attitude_groundtruth",
    "vehicle_local_position",
    "actuator_motors",
    "vehicle_thrust_setpoint",
    "vehicle_status",
)
#: PX4 vehicle_status.nav_state values (the ones the tests look for)
NAV_STATE = {
    "position": 2,
    "auto_mission": 3,
    "auto_loiter": 4,
    "auto_rtl": 5,
    "descend": 12,
    "offboard": 14,
    "auto_takeoff": 17,
    "auto_land": 18,
}
#: PX4 vehicle_status.arming_state: 1 disarmed, 2 armed
ARMED = 2
#: a motor command within this of 0 or 1 counts as saturated (normalized units)
SATURATION_MARGIN = 0.005


@dataclass(frozen=True)
class Series:
    """Samples of one topic: ``t`` (s since boot) and named columns (arrays of the same length)."""

    t: np.ndarray
    columns: dict[str, np.ndarray]

    def __getitem__(self, name: str) -> np.ndarray:
        return self.columns[name]

    def __len__(self) -> int:
        return len(self.t)

    def window(self, t0: float, t1: float) -> Series:
        """The samples with ``t0 <= t <= t1``."""
        sel = (self.t >= t0) & (self.t <= t1)
        return Series(self.t[sel], {k: v[sel] for k, v in self.columns.items()})

    def at(self, t: float, name: str) -> float:
        """Linear interpolation of column ``name`` at ``t`` (clamped at the ends); NaN without samples."""
        if len(self.t) == 0:
            return math.nan
        return float(np.interp(t, self.t, self.columns[name]))


def _empty() -> Series:
    return Series(np.zeros(0), {})


@dataclass(frozen=True)
class Px4FlightLog:
    """The topics of one ULog that the PX4 SITL tests and benchmark use (see module docstring)."""

    path: Path
    truth_pos: Series  # x, y, z, vx, vy, vz (NED m, m/s)
    truth_att: Series  # qw, qx, qy, qz, roll, pitch, yaw (rad), tilt (rad: angle between body z and vertical)
    ekf_pos: Series  # x, y, z, vx, vy, vz (NED)
    motors: Series  # m0..m{n-1} (normalized 0..1), n = number of motors with a finite command
    thrust_sp: Series  # thrust (normalized, positive up: -xyz[2])
    status: Series  # nav_state, arming_state

    # ----------------------------------------------------------------------------------------- derived ---
    def saturated_fraction(self, t0: float, t1: float, margin: float = SATURATION_MARGIN) -> float:
        """Fraction of motor samples in [t0, t1] with any motor within ``margin`` of 0 or 1; NaN without samples."""
        w = self.motors.window(t0, t1)
        if len(w) == 0 or not w.columns:
            return math.nan
        m = np.column_stack(list(w.columns.values()))
        sat = np.any((m >= 1.0 - margin) | (m <= margin), axis=1)
        return float(np.mean(sat))

    def armed_intervals(self) -> list[tuple[float, float]]:
        """(t_arm, t_disarm) pairs, s since boot; an interval still open ends at the last status sample."""
        out: list[tuple[float, float]] = []
        start = None
        for t, a in zip(self.status.t, self.status["arming_state"] if len(self.status) else []):
            if a == ARMED and start is None:
                start = float(t)
            elif a != ARMED and start is not None:
                out.append((start, float(t)))
                start = None
        if start is not None:
            out.append((start, float(self.status.t[-1])))
        return out

    def nav_state_at(self, t: float) -> int | None:
        """The navigation state in force at ``t`` (the last status sample at or before it), None before the first."""
        if len(self.status) == 0:
            return None
        i = int(np.searchsorted(self.status.t, t, side="right")) - 1
        return None if i < 0 else int(self.status["nav_state"][i])

    def ground_z(self, frame: str = "truth") -> float:
        """The local z (NED, m) of the vehicle on the ground at its first arming: the mean over the 0.5 s before it
        (``frame`` ``truth`` or ``ekf``). Heights above the take-off point are ``ground_z - z``."""
        s = self.truth_pos if frame == "truth" else self.ekf_pos
        arms = self.armed_intervals()
        t_arm = arms[0][0] if arms else float(s.t[0]) + 0.5
        w = s.window(t_arm - 0.5, t_arm)
        if len(w) == 0:
            w = s.window(-math.inf, t_arm + 0.1)
        return float(np.mean(w["z"])) if len(w) else math.nan


def _series(ulog: object, name: str) -> dict[str, np.ndarray] | None:
    for d in ulog.data_list:  # type: ignore[attr-defined]
        if d.name == name and d.multi_id == 0:
            return d.data
    return None


def _tilt_and_euler(qw: np.ndarray, qx: np.ndarray, qy: np.ndarray, qz: np.ndarray) -> dict[str, np.ndarray]:
    """Roll, pitch, yaw (ZYX, rad) and tilt (angle between the body's z axis and the vertical) of FRD quaternions."""
    roll = np.arctan2(2.0 * (qw * qx + qy * qz), 1.0 - 2.0 * (qx * qx + qy * qy))
    pitch = np.arcsin(np.clip(2.0 * (qw * qy - qz * qx), -1.0, 1.0))
    yaw = np.arctan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
    cos_tilt = 1.0 - 2.0 * (qx * qx + qy * qy)  # body z . world z
    return {"roll": roll, "pitch": pitch, "yaw": yaw, "tilt": np.arccos(np.clip(cos_tilt, -1.0, 1.0))}


def read_px4_ulog(path: str | Path) -> Px4FlightLog:
    """Read a PX4 ULog into a :class:`Px4FlightLog` (missing topics give empty series)."""
    from pyulog import ULog

    p = Path(path)
    ulog = ULog(str(p), list(TOPICS))

    def pos(name: str) -> Series:
        d = _series(ulog, name)
        if d is None:
            return _empty()
        cols = {k: np.asarray(d[k], dtype=float) for k in ("x", "y", "z", "vx", "vy", "vz")}
        return Series(d["timestamp"] * 1e-6, cols)

    d = _series(ulog, "vehicle_attitude_groundtruth")
    if d is None:
        att = _empty()
    else:
        q = [np.asarray(d[f"q[{i}]"], dtype=float) for i in range(4)]
        att = Series(d["timestamp"] * 1e-6, {"qw": q[0], "qx": q[1], "qy": q[2], "qz": q[3], **_tilt_and_euler(*q)})
    d = _series(ulog, "actuator_motors")
    if d is None:
        motors = _empty()
    else:
        cols = {}
        for i in range(12):
            c = np.asarray(d.get(f"control[{i}]", []), dtype=float)
            if len(c) and np.any(np.isfinite(c)):
                cols[f"m{i}"] = c
        motors = Series(d["timestamp"] * 1e-6, cols)
    d = _series(ulog, "vehicle_thrust_setpoint")
    thrust = _empty() if d is None else Series(d["timestamp"] * 1e-6, {"thrust": -np.asarray(d["xyz[2]"], dtype=float)})
    d = _series(ulog, "vehicle_status")
    status = (
        _empty()
        if d is None
        else Series(
            d["timestamp"] * 1e-6,
            {
                "nav_state": np.asarray(d["nav_state"], dtype=int),
                "arming_state": np.asarray(d["arming_state"], dtype=int),
            },
        )
    )
    return Px4FlightLog(
        p, pos("vehicle_local_position_groundtruth"), att, pos("vehicle_local_position"), motors, thrust, status
    )


@dataclass(frozen=True)
class FlightQuality:
    """Figures of one stretch of flight, from the ULog's ground truth and PX4's own signals (see
    :func:`flight_quality` for each definition). Lengths m, angles rad, fractions 0..1."""

    t0: float
    t1: float
    truth_jitter_m: float
    height_error_m: float
    ekf_error_mean_m: float
    truth_error_mean_m: float
    saturated_fraction: float
    tilt_p95_rad: float
    thrust_std: float
    ekf_offset_mean_m: float
    ekf_height_error_m: float

    def as_dict(self) -> dict[str, float]:
        """The figures as a plain dict (JSON)."""
        return dict(self.__dict__)


def flight_quality(
    log: Px4FlightLog,
    t0: float,
    t1: float,
    reference_ned: np.ndarray | tuple[float, float, float],
    reference_t: np.ndarray | None = None,
) -> FlightQuality:
    """Figures over ``t0..t1`` (s since boot) against a reference position in EKF2's local NED frame (the frame the
    controller and PX4's position hold work in): a fixed point, or samples ``reference_ned`` (n x 3) at times
    ``reference_t``.

    - truth_jitter_m: RMS distance of the true position from its own mean over the stretch (how still it hovered);
    - height_error_m: mean true height above the take-off point minus the reference's height above it (the
      reference's EKF z minus EKF2's z of the ground at arming): the height error that does not depend on EKF2's
      origin;
    - ekf_height_error_m: EKF2's own height error over the stretch, its mean height above its ground at arming minus
      the truth's above the true ground: what a controller flying EKF2's height cannot see (``height_error_m +
      ekf_height_error_m`` is the error against the height EKF2 gave it);
    - ekf_error_mean_m / truth_error_mean_m: mean distance of EKF2's position / the true position (each relative
      to its own ground at arming, so that EKF2's origin offset does not count) from the reference, the mean of the
      norm ``mean |p - r|`` (its wander counts, whatever its direction);
    - ekf_offset_mean_m: distance of EKF2's time-mean position from the reference, the norm of the mean
      ``|mean(p - r)|`` ("the mean EKF position within 0.15 m of the reference": a steady offset, not the wander);
    - saturated_fraction: motor samples with a motor within ``SATURATION_MARGIN`` of 0 or 1;
    - tilt_p95_rad: 95th percentile of the true tilt (body z from the vertical);
    - thrust_std: standard deviation of the collective thrust setpoint (normalized).
    """
    tp = log.truth_pos.window(t0, t1)
    ep = log.ekf_pos.window(t0, t1)
    if len(tp) < 2 or len(ep) < 2:
        raise ValueError(f"{log.path}: no ground truth or EKF2 samples in {t0:.2f}..{t1:.2f} s")
    ref = np.asarray(reference_ned, dtype=float)

    def ref_at(t: np.ndarray) -> np.ndarray:
        if ref.ndim == 1:
            return np.broadcast_to(ref, (len(t), 3))
        assert reference_t is not None
        return np.column_stack([np.interp(t, reference_t, ref[:, i]) for i in range(3)])

    g_truth, g_ekf = log.ground_z("truth"), log.ground_z("ekf")
    truth = np.column_stack([tp["x"], tp["y"], tp["z"]])
    ekf = np.column_stack([ep["x"], ep["y"], ep["z"]])
    jitter = float(np.sqrt(np.mean(np.sum((truth - truth.mean(axis=0)) ** 2, axis=1))))
    r_truth = ref_at(tp.t).copy()
    r_truth[:, 2] += g_truth - g_ekf  # the reference's height above the ground, in the truth frame
    height_err = float(np.mean(g_truth - truth[:, 2]) - np.mean(g_truth - r_truth[:, 2]))
    ekf_height_err = float(np.mean(g_ekf - ekf[:, 2]) - np.mean(g_truth - truth[:, 2]))
    ekf_err = float(np.mean(np.linalg.norm(ekf - ref_at(ep.t), axis=1)))
    ekf_offset = float(np.linalg.norm(np.mean(ekf - ref_at(ep.t), axis=0)))
    truth_err = float(np.mean(np.linalg.norm(truth - r_truth, axis=1)))
    att = log.truth_att.window(t0, t1)
    tilt95 = float(np.percentile(att["tilt"], 95)) if len(att) else math.nan
    th = log.thrust_sp.window(t0, t1)
    thrust_std = float(np.std(th["thrust"])) if len(th) else math.nan
    return FlightQuality(
        t0,
        t1,
        jitter,
        height_err,
        ekf_err,
        truth_err,
        log.saturated_fraction(t0, t1),
        tilt95,
        thrust_std,
        ekf_offset,
        ekf_height_err,
    )


__all__ = [
    "ARMED",
    "NAV_STATE",
    "SATURATION_MARGIN",
    "TOPICS",
    "FlightQuality",
    "Px4FlightLog",
    "Series",
    "flight_quality",
    "read_px4_ulog",
]
