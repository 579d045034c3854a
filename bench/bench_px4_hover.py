"""Hover quality on the real PX4 autopilot: PX4's own position hold and slung's hover, in the same PX4 SITL run.

One PX4 SITL instance (the SIH quadrotor, no load) boots; the benchmark arms it and flies PX4's own take-off to
``--height`` above the take-off point, where PX4 holds position by itself (AUTO.LOITER, its HOLD mode); after
``--settle`` s it measures ``--duration`` s of that hold. Then it hands the link to ``slung fly --no-takeoff``
(vehicle ``px4-sih``) hovering at the same height above the take-off point for the same duration, and PX4 holds
again afterwards. Both stretches are judged on the ULog's ground truth and PX4's own signals
(``sim_bridge.sitl.px4_ulog.flight_quality``):

- truth jitter: RMS distance of the true position from its own mean;
- height error: mean true height above the take-off point minus the wanted height;
- mean EKF position error, two ways (both relative to the ground at arming; the reference is the hold point /
  slung's reference): the norm of the time-mean offset ``|mean(p - r)|`` (how far the mean EKF position is from the
  reference: the issue's wording) and the mean distance ``mean |p - r|`` (which also counts the wander);
- motor saturation: fraction of ``actuator_motors`` samples with a motor within 0.005 of 0 or 1;
- tilt p95: 95th percentile of the true tilt;
- thrust std: standard deviation of the collective thrust setpoint;
- filter acceptance (slung only): measurements the Kalman filter accepted / (accepted + gated).

It prints both columns, slung / PX4 ratios and the targets of issue 9 ("Must show", second bullet), with the
machine's load average; ``--out DIR`` keeps the ULog, slung's report and ``bench_px4_hover.json``.

    python bench/bench_px4_hover.py [--instance 2] [--height 2] [--duration 20] [--settle 5] [--out DIR]
                                    [--vehicle NAME|FILE]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from estimators.model.frames import model_to_ned_vector  # noqa: E402 - after the path set-up
from offboard.logs.timeseries_file import read_table  # noqa: E402
from sim_bridge.sitl.px4_sitl import Px4Sitl  # noqa: E402
from sim_bridge.sitl.px4_ulog import NAV_STATE, flight_quality, read_px4_ulog  # noqa: E402

#: issue 9's targets for slung's 20 s hover at 2 m on real PX4
TARGETS = {
    "truth_jitter_ratio_max": 1.2,
    "height_error_m_max": 0.15,
    "ekf_offset_mean_m_max": 0.15,
    "saturated_fraction_max": 0.02,
    "tilt_p95_deg_max": 6.0,  # or 2x PX4's own hold
    "filter_acceptance_min": 0.95,
}


def px4_hold(url: str, height: float, settle: float, duration: float) -> dict[str, Any]:
    """Arm, PX4 take-off to ``height`` m above home, hold; returns the hold window (s of PX4 boot time) and the
    take-off point. Uses the flight path's own MAVLink link (``offboard.flight.link``)."""
    from offboard.flight.link.connection import MavConnection
    from offboard.flight.link.management import MAV_CMD_NAV_TAKEOFF, Manager

    conn = MavConnection(url)
    try:
        conn.wait_heartbeat(timeout=20.0)
        mgr = Manager(conn)
        gpi: dict[str, float] = {}
        boot: dict[str, float] = {}

        def idle() -> None:
            for r in conn.poll():
                m = r.msg
                if m.get_type() == "GLOBAL_POSITION_INT" and m.get_srcSystem() == conn.vehicle.system:
                    gpi.update(alt=m.alt * 1e-3, rel=m.relative_alt * 1e-3)
                    boot["t"] = m.time_boot_ms * 1e-3
            conn.heartbeat(time.monotonic())

        if not mgr.wait_for(lambda: (idle() or True) and "alt" in gpi, 60.0):
            raise SystemExit("PX4 sent no GLOBAL_POSITION_INT within 60 s")
        mgr.arm(idle=idle, timeout=60.0)
        alt = gpi["alt"] + height
        res = conn.command(MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, alt, idle=idle)
        if res != 0:
            raise SystemExit(f"PX4 refused the take-off (result {res})")
        if not mgr.wait_for(lambda: (idle() or True) and gpi["rel"] >= height - 0.1, 60.0):
            raise SystemExit(f"PX4's take-off did not reach {height:g} m")
        mgr.wait_for(lambda: (idle() or True) and False, settle)
        t0 = boot["t"]
        mgr.wait_for(lambda: (idle() or True) and False, duration)
        return {"t0": t0, "t1": boot["t"], "mode": conn.vehicle.custom_mode}
    finally:
        conn.close()


def slung_fly(url: str, *args: str) -> list[str]:
    """The command line of ``slung fly --connect url args...`` run from this checkout (``python -m offboard.cli``)."""
    return [sys.executable, "-m", "offboard.cli", "fly", "--connect", url, *args]


def slung_hover(url: str, height: float, duration: float, out: Path, vehicle: str = "px4-sih") -> dict[str, Any]:
    """``slung fly --no-takeoff`` hovering ``height`` m above the take-off point for ``duration`` s."""
    traj = out / "hover.toml"
    traj.write_text(f'kind = "hover"\nx = 0.0\ny = 0.0\nz = {height}\n', encoding="utf-8")
    cmd = slung_fly(url, "--vehicle", vehicle, "--no-takeoff", "--trajectory", str(traj), "--duration", str(duration))
    cmd += ["--no-figures", "--out", str(out / "slung")]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)
    m = json.loads((out / "slung" / "metrics.json").read_text())
    d = read_table(out / "slung" / "timeseries_live.slts")
    stats = m.get("estimation", {}).get("stats", {})
    acc, gated = stats.get("accepted", 0), stats.get("gated_outliers", 0)
    return {
        "returncode": proc.returncode,
        "ended_by": m["flight"]["ended_by"],
        "t": d["t_vehicle"],
        "ref_ned": np.array([model_to_ned_vector(x, y, z) for x, y, z in zip(d["ref_fx0"], d["ref_fy0"], d["ref_z0"])]),
        "filter_acceptance": acc / (acc + gated) if acc + gated else math.nan,
        "ground_z": m["config"].get("ground_z"),
        "stderr": proc.stderr[-2000:],
    }


def run(
    instance: int, height: float, duration: float, settle: float, out: Path, vehicle: str = "px4-sih"
) -> dict[str, Any]:
    load0 = os.getloadavg()
    with Px4Sitl(instance=instance, workdir=out / "px4") as sitl:
        hold = px4_hold(sitl.connection_url, height, settle, duration)
        sl = slung_hover(sitl.connection_url, height, duration, out, vehicle)
        time.sleep(2.0)
    log = read_px4_ulog(sitl.ulogs()[-1])
    # PX4's hold point: where it took off, ``height`` above the ground, in EKF2's frame
    arm_t = log.armed_intervals()[0][0]
    home = log.ekf_pos.window(arm_t - 0.5, arm_t)
    hold_ref = (float(np.mean(home["x"])), float(np.mean(home["y"])), log.ground_z("ekf") - height)
    q_px4 = flight_quality(log, hold["t0"], hold["t1"], hold_ref)
    q_sl = flight_quality(log, float(sl["t"][0]), float(sl["t"][-1]), sl["ref_ned"], sl["t"])
    nav = log.nav_state_at(0.5 * (hold["t0"] + hold["t1"]))
    res = {
        "px4_hold": {**q_px4.as_dict(), "nav_state": nav},
        "slung": {
            **q_sl.as_dict(),
            "filter_acceptance": sl["filter_acceptance"],
            "ended_by": sl["ended_by"],
            "ground_z": sl["ground_z"],
        },
        "load_avg_before": load0,
        "load_avg_after": os.getloadavg(),
        "ulog": str(log.path),
        "slung_stderr": sl["stderr"],
    }
    res["targets"] = check_targets(res["slung"], res["px4_hold"])
    return res


def check_targets(s: dict[str, Any], p: dict[str, Any]) -> dict[str, Any]:
    """Each target of issue 9 with the measured figure and whether it is met."""
    tilt_limit = max(TARGETS["tilt_p95_deg_max"], 2.0 * math.degrees(p["tilt_p95_rad"]))
    tilt = math.degrees(s["tilt_p95_rad"])
    jitter_ratio = s["truth_jitter_m"] / p["truth_jitter_m"] if p["truth_jitter_m"] > 0 else math.inf
    rows = {
        "truth jitter / PX4's <= 1.2": (jitter_ratio, jitter_ratio <= TARGETS["truth_jitter_ratio_max"]),
        "|height error| <= 0.15 m": (abs(s["height_error_m"]), abs(s["height_error_m"]) <= 0.15),
        # what slung controls of it: the truth against the height EKF2 gave it (EKF2's own error is on the next row
        # of the table, and PX4's hold shares it)
        "(|height error against EKF2's height| <= 0.1 m)": (
            abs(s["height_error_m"] + s["ekf_height_error_m"]),
            abs(s["height_error_m"] + s["ekf_height_error_m"]) <= 0.1,
        ),
        "|mean EKF offset| <= 0.15 m": (s["ekf_offset_mean_m"], s["ekf_offset_mean_m"] <= 0.15),
        "(mean EKF distance <= 0.15 m)": (s["ekf_error_mean_m"], s["ekf_error_mean_m"] <= 0.15),
        "motors saturated <= 2 %": (s["saturated_fraction"], s["saturated_fraction"] <= 0.02),
        f"tilt p95 <= {tilt_limit:.1f} deg": (tilt, tilt <= tilt_limit),
        "filter acceptance >= 95 %": (s["filter_acceptance"], s["filter_acceptance"] >= 0.95),
        "flight completed": (s["ended_by"], s["ended_by"] == "completed"),
    }
    return {k: {"value": v, "met": bool(ok)} for k, (v, ok) in rows.items()}


def print_table(res: dict[str, Any]) -> None:
    p, s = res["px4_hold"], res["slung"]
    rows = (
        ("truth jitter (m)", "truth_jitter_m", 1.0),
        ("height error (m)", "height_error_m", 1.0),
        ("EKF2's own height error (m)", "ekf_height_error_m", 1.0),
        ("|mean EKF offset| from reference (m)", "ekf_offset_mean_m", 1.0),
        ("mean EKF distance from reference (m)", "ekf_error_mean_m", 1.0),
        ("mean truth error vs reference (m)", "truth_error_mean_m", 1.0),
        ("motor saturation (fraction)", "saturated_fraction", 1.0),
        ("tilt p95 (deg)", "tilt_p95_rad", 180.0 / math.pi),
        ("thrust std (normalized)", "thrust_std", 1.0),
    )
    print(f"{'':36s} {'PX4 hold':>10s} {'slung':>10s} {'ratio':>7s}")
    for label, key, k in rows:
        a, b = p[key] * k, s[key] * k
        ratio = b / a if a else math.nan
        print(f"{label:36s} {a:10.3f} {b:10.3f} {ratio:7.2f}")
    print(f"{'filter acceptance':36s} {'':>10s} {s['filter_acceptance']:10.3f}")
    print(f"{'stretch measured (s of PX4 time)':36s} {p['t1'] - p['t0']:10.1f} {s['t1'] - s['t0']:10.1f}")
    loiter = NAV_STATE["auto_loiter"]
    print(f"slung ended by {s['ended_by']}; PX4 hold nav_state {p['nav_state']} (AUTO.LOITER = {loiter})")
    print("targets (issue 9):")
    for k, v in res["targets"].items():
        val = v["value"]
        shown = f"{val:.3f}" if isinstance(val, float) else str(val)
        print(f"  {'met ' if v['met'] else 'MISS'} {k}: {shown}")
    la, lb = res["load_avg_before"], res["load_avg_after"]
    print(f"load average before {la[0]:.2f} / after {lb[0]:.2f} (1 min)")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--instance", type=int, default=2, help="PX4 SITL instance (ports 14540+i; default 2)")
    ap.add_argument("--height", type=float, default=2.0, help="hover height above the take-off point, m")
    ap.add_argument("--duration", type=float, default=20.0, help="measured stretch of each hover, s")
    ap.add_argument("--settle", type=float, default=5.0, help="wait after PX4's take-off before measuring, s")
    ap.add_argument("--out", type=Path, default=None, help="keep the ULog, slung's report and the figures here")
    ap.add_argument("--vehicle", default="px4-sih", help="slung's vehicle (a shipped name or a TOML file)")
    a = ap.parse_args()
    out = a.out or Path(tempfile.mkdtemp(prefix="bench-px4-hover-"))
    out.mkdir(parents=True, exist_ok=True)
    res = run(a.instance, a.height, a.duration, a.settle, out, a.vehicle)
    (out / "bench_px4_hover.json").write_text(json.dumps(res, indent=2, default=float), encoding="utf-8")
    print_table(res)
    print(f"output: {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
