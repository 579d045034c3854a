"""Calibrate the emulator's PX4 flavour against real PX4 SITL (SIH quadrotor), same vehicle, same flight.

One MAVLink client (pymavlink) flies the same script against both:

1. on the ground, estimator ready: LOCAL_POSITION_NED for ``--ground`` s (the estimate's wander with the
   vehicle at rest: the EKF error itself);
2. arm, MAV_CMD_NAV_TAKEOFF (NaN altitude: MIS_TAKEOFF_ALT), let PX4's Hold settle, then ``--hover`` s of the
   autopilot's own position hold: LOCAL_POSITION_NED scatter and the truth's jitter;
3. OFFBOARD with SET_ATTITUDE_TARGET at 50 Hz: level, then a roll step of ``--step`` rad for 1 s, the opposite
   tilt for 1 s (to cancel the drift), level; the step's response is read from the truth;
4. AUTO.LAND.

Truth: real PX4's ULog (``vehicle_local_position_groundtruth``, ``vehicle_attitude_groundtruth``, pyulog); the
emulator's ``Emulator.truth()`` (sampled at every plant step). Figures, per side:

- ``step_rise_s``: 10-90 % rise time of the roll response to the step (from the response alone, so the link's
  delay does not enter); ``step_overshoot``: peak / final - 1 (final = mean over the last 0.3 s of the step);
  ``step_peak_s``: time from 10 % to the peak; the same from ATTITUDE (``att_*``: the autopilot's estimate, what
  its loops regulate; on PX4 EKF2's, whose tilt error wanders by about 0.01 rad within the step);
- ``ground_lpn_std_m``: LOCAL_POSITION_NED standard deviation on the ground, horizontal (per axis, RMS of N and
  E) and vertical;
- ``hover_lpn_std_m``: the same during the hold; ``hover_truth_std_m``: the truth's standard deviation during the
  hold (horizontal per axis, vertical): what "truth jitter" means in this table;
- ``hover_pos_err_std_h_m``, ``hover_pos_err_tau_s``: the estimate's horizontal position error during the hold
  and its correlation time, as for the velocity below (a constant offset between the estimate's and the truth's
  frames does not enter the std); ``hover_pos_err_std_v_m``, ``hover_vel_err_std_v_m_s``: the same for the height
  and the vertical velocity;
- ``hover_vel_err_std_h_m_s``: the estimate's velocity error during the hold, LOCAL_POSITION_NED's velocity minus
  the truth's (horizontal, per-axis RMS of the N and E standard deviations); ``hover_vel_err_tau_s``: how long it
  stays correlated (the lag at which its autocorrelation falls below 1/e, mean of N and E): EKF2's velocity error
  wanders by decimetres per second over seconds in flight, which a controller with velocity feedback flies.

Prints a table with the ratio emulator / PX4 for every figure; ``--json FILE`` writes all of it.

    python bench/calibrate_emulator_px4.py                    # both sides (PX4 instance 8)
    python bench/calibrate_emulator_px4.py --side emulator    # the emulator only
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

os.environ.setdefault("MAVLINK20", "1")

import numpy as np
from pymavlink import mavutil

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

HOVER_THRUST = 0.49  # the SIH vehicle's physical hover thrust (1.0 kg, 4 x 5 N): the same on both sides


@dataclass
class FlightRecord:
    """What the client saw on the wire (times in the autopilot's time_boot_ms, s; NED)."""

    ground_lpn: list[tuple[float, ...]] = field(default_factory=list)  # (t, x, y, z, vx, vy, vz), NED
    hover_lpn: list[tuple[float, ...]] = field(default_factory=list)
    hover_window: tuple[float, float] = (0.0, 0.0)
    step_window: tuple[float, float] = (0.0, 0.0)
    attitude: list[tuple[float, float]] = field(default_factory=list)  # (t, roll) from ATTITUDE
    notes: list[str] = field(default_factory=list)


def _q_roll(roll: float, yaw: float) -> list[float]:
    """NED quaternion (w, x, y, z) of roll then yaw (ZYX, pitch 0)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return [cy * cr, cy * sr, sy * sr, sy * cr]


def fly_script(
    url: str, *, ground_s: float, hover_s: float, step_rad: float, settle_s: float = 12.0, hold: bool = True
) -> FlightRecord:
    """Fly the calibration script over MAVLink at ``url``; raises RuntimeError on a refused step. ``hold=False``:
    no ground and Hold phases (the step only, from the take-off's Hold)."""
    rec = FlightRecord()
    c = mavutil.mavlink_connection(url, source_system=255, source_component=190)
    hb = c.wait_heartbeat(timeout=60)
    if hb is None:
        raise RuntimeError(f"no heartbeat on {url}")
    sysid = c.target_system
    t_boot = [0.0]
    last_lpn: list[Any] = [None]
    yaw = [0.0]
    mode = [""]

    def cmd(command: int, *p: float) -> None:
        pp = list(p) + [0.0] * (7 - len(p))
        c.mav.command_long_send(sysid, 1, command, 0, *pp)

    def pump(dt: float, sink: list | None = None, on_msg: Any = None) -> None:
        end = time.monotonic() + dt
        while time.monotonic() < end:
            m = c.recv_match(blocking=True, timeout=0.02)
            if m is None:
                continue
            if m.get_srcSystem() != sysid:
                continue
            typ = m.get_type()
            if typ == "LOCAL_POSITION_NED":
                t = m.time_boot_ms * 1e-3
                t_boot[0] = t
                last_lpn[0] = m
                if sink is not None:
                    sink.append((t, m.x, m.y, m.z, m.vx, m.vy, m.vz))
            elif typ == "ATTITUDE":
                t_boot[0] = m.time_boot_ms * 1e-3
                yaw[0] = m.yaw
                rec.attitude.append((t_boot[0], m.roll))
            elif typ == "HEARTBEAT":
                mode[0] = mavutil.mode_string_v10(m)
            if on_msg is not None:
                on_msg()

    for msgid, hz in ((32, 50.0), (30, 100.0)):  # LOCAL_POSITION_NED, ATTITUDE
        cmd(511, msgid, 1e6 / hz)
    # 1. ground
    deadline = time.monotonic() + 60
    while last_lpn[0] is None and time.monotonic() < deadline:
        pump(0.5)
    if last_lpn[0] is None:
        raise RuntimeError("no LOCAL_POSITION_NED within 60 s")
    if hold:
        pump(ground_s, rec.ground_lpn)
    # 2. arm + take-off + hold
    armed = False
    deadline = time.monotonic() + 60
    while not armed and time.monotonic() < deadline:
        cmd(400, 1.0)
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            m = c.recv_match(type=["COMMAND_ACK"], blocking=True, timeout=0.2)
            if m is not None and m.command == 400:
                armed = m.result == 0
                break
        if not armed:
            pump(1.0)
    if not armed:
        raise RuntimeError("arming refused for 60 s")
    cmd(22, 0, 0, 0, float("nan"), float("nan"), float("nan"), float("nan"))
    pump(settle_s)  # climb to MIS_TAKEOFF_ALT and settle in Hold
    if hold:
        t0 = t_boot[0]
        pump(hover_s, rec.hover_lpn)
        rec.hover_window = (t0, t_boot[0])
    rec.notes.append(f"mode during hover: {mode[0]}")

    # 3. OFFBOARD attitude step
    def att(roll: float, dt: float) -> None:
        end = time.monotonic() + dt
        while time.monotonic() < end:
            c.mav.set_attitude_target_send(
                int(t_boot[0] * 1e3) & 0xFFFFFFFF, sysid, 1, 0b00000111, _q_roll(roll, yaw0), 0, 0, 0, HOVER_THRUST
            )
            pump(0.02)

    yaw0 = yaw[0]
    att(0.0, 1.5)
    cmd(176, 1, 6)  # MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, PX4 main mode OFFBOARD
    att(0.0, 1.5)
    rec.notes.append(f"mode before the step: {mode[0]}")
    ts = t_boot[0]
    att(step_rad, 1.0)
    te = t_boot[0]
    att(-step_rad, 1.0)
    att(0.0, 1.0)
    rec.step_window = (ts, te)
    # 4. land
    cmd(21)
    pump(8.0 if hold else 1.0)
    c.close()
    return rec


# ---------------------------------------------------------------------------------------------------- figures
def step_figures(t: np.ndarray, roll: np.ndarray, window: tuple[float, float], step: float) -> dict[str, float]:
    """10-90 % rise time, overshoot and 10 %-to-peak time of a roll response inside ``window`` (s)."""
    sel = (t >= window[0] - 0.05) & (t <= window[1] + 0.02)
    t, r = t[sel], roll[sel]
    if len(t) < 20:
        return {"step_rise_s": math.nan, "step_overshoot": math.nan, "step_peak_s": math.nan}
    r0 = float(np.mean(r[:5]))
    y = (r - r0) / step
    final = float(np.mean(y[t >= t[-1] - 0.3]))
    i10 = int(np.argmax(y >= 0.1 * final))
    i90 = int(np.argmax(y >= 0.9 * final))
    ip = int(np.argmax(y))
    return {
        "step_rise_s": float(t[i90] - t[i10]),
        "step_overshoot": float(y[ip] / final - 1.0),
        "step_peak_s": float(t[ip] - t[i10]),
        "step_final_fraction": final,
    }


def _std_hv(xyz: np.ndarray) -> tuple[float, float]:
    """(horizontal per-axis RMS of the N and E standard deviations, vertical standard deviation), m."""
    if len(xyz) < 2:
        return math.nan, math.nan
    s = np.std(xyz, axis=0)
    return float(math.sqrt(0.5 * (s[0] ** 2 + s[1] ** 2))), float(s[2])


def _correlation_time(x: np.ndarray, dt: float) -> float:
    """The lag (s) at which the autocorrelation of ``x`` (sampled every ``dt`` s) first falls below 1/e."""
    x = x - np.mean(x)
    v = float(np.dot(x, x))
    if len(x) < 3 or v == 0.0:
        return math.nan
    for k in range(1, len(x) - 1):
        if float(np.dot(x[:-k], x[k:])) / v < math.exp(-1.0):
            return k * dt
    return math.nan


def _estimate_errors(
    lpn: list[tuple[float, ...]], truth_t: np.ndarray, truth: np.ndarray, column: int
) -> tuple[float, float, float]:
    """(horizontal error std, its correlation time, vertical error std) of LOCAL_POSITION_NED's N, E, D fields from
    ``column`` on (1: position, 4: velocity) against the truth's, on a 20 ms grid over the samples' span (m or m/s,
    s; NED; horizontal: per-axis RMS of N and E, the time the mean of theirs)."""
    if len(lpn) < 20:
        return math.nan, math.nan, math.nan
    a = np.array(lpn)
    grid = np.arange(a[0, 0], a[-1, 0], 0.02)
    err = [np.interp(grid, a[:, 0], a[:, column + i]) - np.interp(grid, truth_t, truth[:, i]) for i in range(3)]
    std_h = math.sqrt(0.5 * (float(np.var(err[0])) + float(np.var(err[1]))))
    tau_h = 0.5 * (_correlation_time(err[0], 0.02) + _correlation_time(err[1], 0.02))
    return std_h, tau_h, float(np.std(err[2]))


def figures(
    rec: FlightRecord,
    truth_t: np.ndarray,
    truth_pos: np.ndarray,
    truth_roll: np.ndarray,
    step: float,
    truth_vel: np.ndarray | None = None,
):
    """The table's figures from what the client saw and the truth (NED, m, m/s; ``truth_vel`` None: no velocity
    error figures)."""
    g = np.array([p[1:4] for p in rec.ground_lpn])
    h = np.array([p[1:4] for p in rec.hover_lpn])
    w = rec.hover_window
    sel = (truth_t >= w[0]) & (truth_t <= w[1])
    out: dict[str, float] = {}
    out["ground_lpn_std_h_m"], out["ground_lpn_std_v_m"] = _std_hv(g)
    out["hover_lpn_std_h_m"], out["hover_lpn_std_v_m"] = _std_hv(h)
    out["hover_truth_std_h_m"], out["hover_truth_std_v_m"] = _std_hv(truth_pos[sel])
    pos_err = _estimate_errors(rec.hover_lpn, truth_t, truth_pos, 1)
    out["hover_pos_err_std_h_m"], out["hover_pos_err_tau_s"], out["hover_pos_err_std_v_m"] = pos_err
    if truth_vel is not None:
        vel_err = _estimate_errors(rec.hover_lpn, truth_t, truth_vel, 4)
        out["hover_vel_err_std_h_m_s"], out["hover_vel_err_tau_s"], out["hover_vel_err_std_v_m_s"] = vel_err
    out.update(step_figures(truth_t, truth_roll, rec.step_window, step))
    return out


# ---------------------------------------------------------------------------------------------------- PX4
def run_px4(instance: int, args: argparse.Namespace) -> dict[str, Any]:
    """Fly the script against real PX4 SITL; truth from its ULog."""
    from pyulog import ULog

    from sim_bridge.sitl.px4_sitl import Px4Sitl

    with Px4Sitl(instance) as px4:
        rec = fly_script(
            px4.connection_url,
            ground_s=args.ground,
            hover_s=args.hover,
            step_rad=args.step,
            settle_s=args.settle,
            hold=not args.step_only,
        )
        time.sleep(1.0)
        ulogs = sorted(px4.ulogs())
    if not ulogs:
        raise RuntimeError("PX4 wrote no ULog")
    u = ULog(str(ulogs[-1]), ["vehicle_local_position_groundtruth", "vehicle_attitude_groundtruth"])
    lp = u.get_dataset("vehicle_local_position_groundtruth").data
    at = u.get_dataset("vehicle_attitude_groundtruth").data
    # ULog stamps are µs since PX4's boot, the same clock as MAVLink's time_boot_ms
    tp = lp["timestamp"] * 1e-6
    pos = np.column_stack([lp["x"], lp["y"], lp["z"]])
    vel = np.column_stack([lp["vx"], lp["vy"], lp["vz"]])
    ta = at["timestamp"] * 1e-6
    q0, q1, q2, q3 = (at[f"q[{i}]"] for i in range(4))
    roll = np.arctan2(2 * (q0 * q1 + q2 * q3), 1 - 2 * (q1 * q1 + q2 * q2))
    fig = figures(rec, tp, pos, np.interp(tp, ta, roll), args.step, vel)
    fig.update(_attitude_figures(rec, args.step))
    return {"figures": fig, "notes": rec.notes, "ulog": str(ulogs[-1])}


def _attitude_figures(rec: FlightRecord, step: float) -> dict[str, float]:
    """The step figures of the roll the autopilot reported in ATTITUDE (its estimate: what its loops regulate)."""
    ta = np.array([a[0] for a in rec.attitude])
    ra = np.array([a[1] for a in rec.attitude])
    return {f"att_{k}": v for k, v in step_figures(ta, ra, rec.step_window, step).items()}


# ---------------------------------------------------------------------------------------------------- emulator
def run_emulator(args: argparse.Namespace) -> dict[str, Any]:
    """Fly the script against the emulator (PX4 flavour, ``px4-sih`` vehicle) in this process; truth sampled."""
    from estimators.model.frames import model_to_ned_vector
    from sim_bridge.emulator_api import EmulatorConfig, start_emulator

    port = _free_port()
    cfg = EmulatorConfig(
        flavor="px4", vehicle=args.vehicle, mavlink=(f"udpout:127.0.0.1:{port}",), seed=args.seed, ekf=args.ekf
    )
    samples: list[tuple[float, ...]] = []
    running = start_emulator(cfg)
    emu = running.emulator

    def sample() -> None:
        while not stop.is_set():
            tr = emu.truth()
            n, e, d = model_to_ned_vector(*tr.position_m)
            samples.append((tr.time_s, n, e, d, tr.euler_rad[0], *model_to_ned_vector(*tr.velocity_m_s)))
            time.sleep(0.002)

    stop = threading.Event()
    th = threading.Thread(target=sample, daemon=True)
    th.start()
    try:
        rec = fly_script(
            f"udpin:127.0.0.1:{port}",
            ground_s=args.ground,
            hover_s=args.hover,
            step_rad=args.step,
            settle_s=args.settle,
            hold=not args.step_only,
        )
    finally:
        stop.set()
        th.join()
        running.stop()
    s = np.array(samples)
    # the model's roll (FLU about x forward) equals the NED roll (FRD about x forward)
    fig = figures(rec, s[:, 0], s[:, 1:4], s[:, 4], args.step, s[:, 5:8])
    fig.update(_attitude_figures(rec, args.step))
    return {"figures": fig, "notes": rec.notes}


def _free_port() -> int:
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


ROWS = (
    ("step_rise_s", "roll step 10-90 % rise, s (truth)"),
    ("step_peak_s", "roll step 10 % to peak, s (truth)"),
    ("step_overshoot", "roll step overshoot (truth)"),
    ("att_step_rise_s", "roll step 10-90 % rise, s (ATTITUDE)"),
    ("att_step_peak_s", "roll step 10 % to peak, s (ATTITUDE)"),
    ("att_step_overshoot", "roll step overshoot (ATTITUDE)"),
    ("ground_lpn_std_h_m", "LOCAL_POSITION_NED std on the ground, horizontal, m"),
    ("ground_lpn_std_v_m", "LOCAL_POSITION_NED std on the ground, vertical, m"),
    ("hover_lpn_std_h_m", "LOCAL_POSITION_NED std in Hold, horizontal, m"),
    ("hover_lpn_std_v_m", "LOCAL_POSITION_NED std in Hold, vertical, m"),
    ("hover_truth_std_h_m", "truth std in Hold (jitter), horizontal, m"),
    ("hover_truth_std_v_m", "truth std in Hold (jitter), vertical, m"),
    ("hover_pos_err_std_h_m", "position error in Hold (estimate - truth), horizontal, m"),
    ("hover_pos_err_tau_s", "position error's correlation time in Hold, s"),
    ("hover_pos_err_std_v_m", "height error in Hold (estimate - truth), m"),
    ("hover_vel_err_std_v_m_s", "vertical velocity error in Hold (estimate - truth), m/s"),
    ("hover_vel_err_std_h_m_s", "velocity error in Hold (estimate - truth), horizontal, m/s"),
    ("hover_vel_err_tau_s", "velocity error's correlation time in Hold, s"),
)


def table(px4: dict[str, float] | None, emu: dict[str, float] | None) -> str:
    lines = [
        f"| {'figure':58s} | {'PX4 SITL':>9s} | {'emulator':>9s} | {'ratio':>6s} |",
        "|" + "-" * 60 + "|---:|---:|---:|",
    ]
    for key, label in ROWS:
        a = None if px4 is None else px4.get(key)
        b = None if emu is None else emu.get(key)
        ratio = b / a if (a and b is not None and math.isfinite(a) and a != 0) else math.nan
        fa = "-" if a is None else f"{a:.3f}"
        fb = "-" if b is None else f"{b:.3f}"
        lines.append(f"| {label:58s} | {fa:>9s} | {fb:>9s} | {ratio:6.2f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--side", choices=("both", "px4", "emulator"), default="both")
    ap.add_argument("--instance", type=int, default=8, help="PX4 SITL instance (ports 14540+i)")
    ap.add_argument("--vehicle", default="px4-sih", help="the emulator's vehicle (default px4-sih)")
    ap.add_argument("--ground", type=float, default=10.0, help="seconds on the ground")
    ap.add_argument("--hover", type=float, default=20.0, help="seconds of Hold")
    ap.add_argument("--step", type=float, default=0.2, help="roll step, rad")
    ap.add_argument("--settle", type=float, default=12.0, help="seconds from the take-off command to the hold")
    ap.add_argument("--step-only", action="store_true", help="only the attitude step (no ground / Hold figures)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--ekf", default="px4-sih", help="the emulator's estimate error model (default px4-sih)")
    ap.add_argument("--json", help="write the figures here")
    args = ap.parse_args(argv)
    res: dict[str, Any] = {"load_avg": os.getloadavg(), "args": vars(args)}
    if args.side in ("both", "px4"):
        res["px4"] = run_px4(args.instance, args)
    if args.side in ("both", "emulator"):
        res["emulator"] = run_emulator(args)
    print(table(res.get("px4", {}).get("figures"), res.get("emulator", {}).get("figures")))
    print(f"load average at start: {res['load_avg'][0]:.2f}", file=sys.stderr)
    for side in ("px4", "emulator"):
        if side in res:
            print(side, res[side]["notes"], file=sys.stderr)
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=1, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
