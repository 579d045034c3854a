"""Why the 2 m move's true tilt exceeds its reference's on real PX4 (SIH): the figures behind docs/deploy.md §2a.

For each folder a ``tests/test_px4_sitl.py`` move left (``<basetemp>/px4-flights0/move``: ``fly/timeseries_live.slts``
and ``px4/log/*/*.ulg``), over the flight's window (the rows of the live time series, as ``flight_quality``):

- ``truth``: tilt p95 / peak of the SIH ground truth (``vehicle_attitude_groundtruth``), issue 9's figure;
- ``ref``: the tilt the reference asks of a vehicle that tracks it exactly, ``atan(|a + (k / M) v| / g)`` with the
  reference's acceleration ``a`` and velocity ``v``, without drag (``k`` = 0: the reference's own figure) and with
  SIH's linear drag ``k`` = SIH_KDV (read from the ULog's parameters) on ``M`` = SIH_MASS;
- ``fit k/M``: the drag the truth shows, least squares of the true horizontal acceleration (x) on the thrust's
  ``g tan(tilt)`` and the true velocity;
- ``ekf tilt err``: p95 of the angle between EKF2's attitude (``vehicle_attitude``, what PX4's attitude loop
  regulates, what ATTITUDE carries) and the truth's body z axes;
- ``inner``: the attitude PX4 reported (slung's estimate ``est_theta``, ``est_phi``) against the setpoint slung
  sent (``sp0..3``, 250 Hz) fitted as a first-order lag ``w`` behind a delay ``d``; ``1/w + d`` is its
  low-frequency lag, which the attitude-level law models as ``1 / MC_ROLL_P`` (``docs/model.md`` §12);
- ``behind``: how far the law's own position estimate (``est_fx0``) fell behind the reference along x (m), and
  where it started (the approach's start error).

    python bench/px4_move_tilt.py DIR [DIR ...]
"""

from __future__ import annotations

import glob
import math
import sys

import numpy as np
from scipy.signal import lfilter

from estimators.model.frames import STANDARD_GRAVITY
from offboard.logs.timeseries_file import read_table


def _ulog_topics(path: str) -> tuple[dict[str, dict[str, np.ndarray]], dict[str, float]]:
    from pyulog import ULog

    names = ("vehicle_attitude", "vehicle_attitude_groundtruth", "vehicle_local_position_groundtruth")
    u = ULog(path, list(names))
    out = {d.name: d.data for d in u.data_list if d.multi_id == 0}
    return out, dict(u.initial_parameters)


def _body_z(d: dict[str, np.ndarray]) -> np.ndarray:
    """World (NED) components of the body z axis of FRD quaternions, shape (3, n)."""
    q0, q1, q2, q3 = (d[f"q[{i}]"] for i in range(4))
    return np.stack([2 * (q1 * q3 + q0 * q2), 2 * (q2 * q3 - q0 * q1), 1 - 2 * (q1 * q1 + q2 * q2)])


def _fit_lag(t: np.ndarray, sp: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """(w 1/s, delay s) of the first-order lag behind a delay that best maps the held setpoint onto ``y``."""
    tt = np.arange(t[0] + 0.3, t[-1], 0.001)
    u0 = sp[np.clip(np.searchsorted(t, tt, side="right") - 1, 0, len(t) - 1)]
    yy = np.interp(tt, t, y)
    best = (math.inf, 0.0, 0.0)
    for w in np.arange(2.0, 10.01, 0.25):
        a = math.exp(-w * 0.001)
        for dl in np.arange(0.0, 0.1501, 0.005):
            sh = round(dl / 0.001)
            u_ = np.concatenate([np.full(sh, u0[0]), u0[: len(u0) - sh]])
            x = lfilter([0.0, 1.0 - a], [1.0, -a], u_ - yy[0]) + yy[0]
            best = min(best, (float(np.sqrt(np.mean((x - yy) ** 2))), float(w), float(dl)))
    return best[1], best[2]


def analyse(base: str) -> str:
    d = read_table(base + "/fly/timeseries_live.slts")
    topics, params = _ulog_topics(glob.glob(base + "/px4/log/*/*.ulg")[0])
    t = d["t_vehicle"]
    t0, t1 = float(t[0]), float(t[-1])
    g = STANDARD_GRAVITY
    gt, va, lp = (
        topics[k] for k in ("vehicle_attitude_groundtruth", "vehicle_attitude", "vehicle_local_position_groundtruth")
    )
    tg, tv, tl = gt["timestamp"] * 1e-6, va["timestamp"] * 1e-6, lp["timestamp"] * 1e-6
    zg, zv = _body_z(gt), _body_z(va)
    sel = (tg >= t0) & (tg <= t1)
    tilt = np.degrees(np.arccos(np.clip(zg[2, sel], -1, 1)))
    # EKF2's tilt error: the angle between its body z axis and the truth's, at the truth's samples
    zv_at = np.stack([np.interp(tg[sel], tv, zv[i]) for i in range(3)])
    zv_at /= np.linalg.norm(zv_at, axis=0)
    err = np.degrees(np.arccos(np.clip(np.sum(zv_at * zg[:, sel], axis=0), -1, 1)))
    k_m = params.get("SIH_KDV", 0.0) / params.get("SIH_MASS", 1.0)
    ref = []
    for k in (0.0, k_m):
        ax = d["ref_fx2"] + k * d["ref_fx1"]
        ay = d["ref_fy2"] + k * d["ref_fy1"]
        ref.append(np.degrees(np.arctan(np.hypot(ax, ay) / g)))
    # the drag the truth shows: x'' = c1 g tan(tilt_x) - c2 x'
    s2 = (tl >= t0) & (tl <= t1)
    ts, vx = tl[s2], lp["vx"][s2]
    thr_x = -g * np.interp(ts, tg, zg[0]) / np.interp(ts, tg, zg[2])
    box = np.ones(10) / 10.0
    sm = lambda x: np.convolve(x, box, mode="same")  # noqa: E731
    c = np.linalg.lstsq(np.stack([sm(thr_x), -sm(vx)], 1), sm(np.gradient(vx, ts)), rcond=None)[0]
    q0, q1, q2, q3 = d["sp0"], d["sp1"], d["sp2"], d["sp3"]
    fits = []
    for sp, y in (
        (np.arcsin(np.clip(2 * (q0 * q2 - q3 * q1), -1, 1)), d["est_theta"]),
        (np.arctan2(2 * (q0 * q1 + q2 * q3), 1 - 2 * (q1 * q1 + q2 * q2)), d["est_phi"]),
    ):
        fits.append(_fit_lag(t, sp, y if np.corrcoef(sp, y)[0, 1] > 0 else -y))
    ex = d["est_fx0"] - d["ref_fx0"]
    p95 = lambda x: float(np.percentile(x, 95))  # noqa: E731
    inner = ", ".join(
        f"{n} w {w:.2f}/s d {dl:.3f} s (1/w+d {1 / w + dl:.3f})" for n, (w, dl) in zip(("pitch", "roll"), fits)
    )
    return (
        f"{base}\n  truth tilt p95 {p95(tilt):.2f} deg (peak {tilt.max():.2f}); ref p95 {p95(ref[0]):.2f} (peak "
        f"{ref[0].max():.2f}) without drag, {p95(ref[1]):.2f} (peak {ref[1].max():.2f}) with SIH_KDV/M = {k_m:.2f}/s\n"
        f"  fit x'' = {c[0]:.3f} g tan(tilt) - {c[1]:.3f}/s x'; EKF2 tilt error p95 {p95(err):.2f} deg (peak "
        f"{err.max():.2f}); estimate behind the reference up to {-ex.min():.3f} m (start {ex[0]:+.3f} m)\n"
        f"  inner loop (ATTITUDE vs setpoint): {inner}; the law assumes 1/MC_ROLL_P = "
        f"{1.0 / params.get('MC_ROLL_P', 4.0):.3f} s"
    )


if __name__ == "__main__":
    for arg in sys.argv[1:]:
        print(analyse(arg))
