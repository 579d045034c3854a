"""How much a 20 s stretch of real PX4's own position hold differs from another stretch of the same hold.

Issue 9 compares slung's truth jitter over a 20 s hover with PX4's own hold over 20 s of the same run ("within
1.2x"). Both ride on EKF2, whose GNSS-driven wander sets most of the jitter, and 20 s hold only a few of its
correlation times (3-5 s). This benchmark measures the spread of that statistic with no controller change at all:
one PX4 SITL instance (SIH quadrotor, no load) takes off to ``--height`` above the take-off point and holds by
itself (AUTO.LOITER) for ``--duration`` s; the ULog's ground truth is cut into consecutive ``--window`` s stretches,
the truth jitter of each (``sim_bridge.sitl.px4_ulog.flight_quality``: RMS distance of the true position from its
mean) is computed, and every ordered pair of stretches gives a ratio. Printed: the stretches' jitters, the ratio's
quantiles, and the fraction of pairs above 1.2 (PX4 "failing" the criterion against itself).

    python bench/px4_hold_jitter_spread.py [--instance 7] [--duration 300] [--window 20] [--json FILE]
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from bench_px4_hover import px4_hold  # noqa: E402 - after the path set-up

from sim_bridge.sitl.px4_sitl import Px4Sitl  # noqa: E402
from sim_bridge.sitl.px4_ulog import NAV_STATE, flight_quality, read_px4_ulog  # noqa: E402


def stretch_jitters(ulog: Path, t0: float, t1: float, window: float, height: float) -> list[float]:
    """The truth jitter (m) of each consecutive ``window`` s stretch of ``t0..t1`` (s of PX4's boot clock) that PX4
    spent in AUTO.LOITER throughout."""
    log = read_px4_ulog(ulog)
    arm_t = log.armed_intervals()[0][0]
    home = log.ekf_pos.window(arm_t - 0.5, arm_t)
    ref = (float(np.mean(home["x"])), float(np.mean(home["y"])), log.ground_z("ekf") - height)
    out = []
    a = t0
    while a + window <= t1 + 1e-6:
        if all(log.nav_state_at(t) == NAV_STATE["auto_loiter"] for t in np.linspace(a, a + window, 9)):
            out.append(flight_quality(log, a, a + window, ref).truth_jitter_m)
        a += window
    return out


def ratio_summary(jitters: list[float], limit: float = 1.2) -> dict[str, float]:
    """Quantiles of the ratio over every ordered pair of distinct stretches, and the fraction above ``limit``."""
    r = np.array([a / b for a, b in itertools.permutations(jitters, 2)])
    adjacent = np.array([b / a for a, b in itertools.pairwise(jitters)])
    return {
        "pairs": len(r),
        "ratio_p05": float(np.percentile(r, 5)),
        "ratio_median": float(np.median(r)),
        "ratio_p95": float(np.percentile(r, 95)),
        "ratio_max": float(r.max()),
        "fraction_above_limit": float(np.mean(r > limit)),
        "adjacent_pairs": len(adjacent),
        "adjacent_fraction_above_limit": float(np.mean(adjacent > limit)) if len(adjacent) else float("nan"),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--instance", type=int, default=7, help="PX4 SITL instance (ports 14540+i)")
    ap.add_argument("--height", type=float, default=2.0, help="hold height above the take-off point, m")
    ap.add_argument("--duration", type=float, default=300.0, help="seconds of PX4's own hold measured")
    ap.add_argument("--window", type=float, default=20.0, help="seconds per stretch (issue 9: 20)")
    ap.add_argument("--settle", type=float, default=5.0, help="seconds of hold before the measurement")
    ap.add_argument("--json", help="write the figures here")
    args = ap.parse_args()
    load0 = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="px4-hold-") as tmp, Px4Sitl(args.instance, workdir=Path(tmp)) as sitl:
        hold = px4_hold(sitl.connection_url, args.height, args.settle, args.duration)
        sitl.run_for(2.0)
        ulog = sorted(sitl.ulogs())[-1]
        jit = stretch_jitters(ulog, hold["t0"], hold["t1"], args.window, args.height)
    if len(jit) < 2:
        print(f"only {len(jit)} stretch(es) of {args.window:g} s in AUTO.LOITER: nothing to compare")
        return 1
    s = ratio_summary(jit)
    print(f"PX4's own hold, {len(jit)} stretches of {args.window:g} s (load average {load0:.1f} at the start):")
    print("  truth jitter per stretch, m: " + " ".join(f"{j:.3f}" for j in jit))
    print(
        f"  ratio of one stretch's jitter to another's ({s['pairs']} ordered pairs): p05 {s['ratio_p05']:.2f}, "
        f"median {s['ratio_median']:.2f}, p95 {s['ratio_p95']:.2f}, max {s['ratio_max']:.2f}"
    )
    print(
        f"  PX4 against itself above 1.2x: {100 * s['fraction_above_limit']:.0f} % of all pairs, "
        f"{100 * s['adjacent_fraction_above_limit']:.0f} % of the {s['adjacent_pairs']} consecutive pairs"
    )
    if args.json:
        Path(args.json).write_text(json.dumps({"jitters_m": jit, **s, "window_s": args.window}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
