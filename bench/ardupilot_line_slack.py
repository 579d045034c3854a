"""A line that goes slack in a forced move, on real ArduPilot SITL with its own slung payload (1.2 kg on 1 m): is it
told, and what does the swing estimate do? (issue 38, "slack line and estimate sign")

``slung fly --vehicle ardupilot-sitl-quad`` flies timed waypoints D m north in T s at ``--height`` (default 3 m in
2.5 s: beyond the pre-flight check, so ``--force``; ``bench/ardupilot_payload_moves.py --kind waypoints``'s flight),
``--end land``. Judged on the DataFlash truth (``sim_bridge.sitl.ardupilot_dataflash``, 10 Hz): the line's pull on the
vehicle (``SLUP.VFN/VFE/VFD``, N) below ``SLACK`` of the payload's weight is slack, below ``PARTLY`` partly slack
(ArduPilot's tension ratio ``Tens`` beside it); slung's ``line_slack`` / ``line_taut`` events (``events.json``)
against those spells; the swing estimate along the move (``est_alpha_y`` of the tick log) against the truth
(``atan2(PN, PD)`` of SLUP) at each SLUP sample of the control window, and how the flight ended.

    flock /tmp/ardupilot-instance0.lock python bench/ardupilot_line_slack.py [--moves 3:2.5] [--height 2]
        [--slung-arg=--law --slung-arg=torque] [--out DIR]

About 45 s of boot and 40 s per flight. Prints a table per flight and writes ``DIR/line_slack.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from ardupilot_payload_moves import fly_slung, parse_moves

from offboard.logs.timeseries_file import read_table
from sim_bridge.sitl.ardupilot_dataflash import read_dataflash
from sim_bridge.sitl.ardupilot_sitl import ArduPilotSitl

#: a pull below this share of the payload's weight (11.8 N for 1.2 kg) is a slack line; below PARTLY partly slack
SLACK, PARTLY = 0.1, 0.5


def spells(t: np.ndarray, slack: np.ndarray) -> list[tuple[float, float]]:
    """(start, end) of each run of ``slack`` samples: from its first slack sample to the first taut one after."""
    out, start = [], None
    for ti, s in zip(t, slack, strict=True):
        if s and start is None:
            start = float(ti)
        elif not s and start is not None:
            out.append((start, float(ti)))
            start = None
    if start is not None:
        out.append((start, float(t[-1])))
    return out


def judge(folder: Path, log_path: Path) -> dict[str, object]:
    """The truth's slack spells, slung's events and the estimate against the truth over the control window."""
    log = read_dataflash(log_path)
    ticks = read_table(folder / "timeseries_live.slts")
    tv, est = np.asarray(ticks["t_vehicle"]), np.asarray(ticks["est_alpha_y"])
    t0, t1 = float(tv[0]), float(tv[-1])
    s = log.slup.window(t0, t1)
    truth = np.arctan2(s["pn"], s["pd"])
    est_at = np.interp(s.t, tv, est)
    pull = np.sqrt(s["pull_n"] ** 2 + s["pull_e"] ** 2 + s["pull_d"] ** 2)
    weight = float(np.median(s["pull_d"][:10])) if len(s) >= 10 else math.nan  # hanging still at the start
    events = json.loads((folder / "events.json").read_text())["loop"]
    told = [(e["kind"], e["t_vehicle"], e["reason"]) for e in events if e["kind"] in ("line_slack", "line_taut")]
    m = json.loads((folder / "metrics.json").read_text())
    watch = (m["config"].get("hover_thrust_learning") or {}).get("line_slack")
    rows = [
        (
            round(float(ti) - t0, 2),
            round(float(tn), 2),
            round(float(f), 2),
            round(math.degrees(tr), 1),
            round(math.degrees(e), 1),
        )
        for ti, tn, f, tr, e in zip(s.t, s["tension"], pull, truth, est_at, strict=True)
    ]
    return {
        "control": [t0, t1],
        "ended_by": m["flight"]["ended_by"],
        "weight_n": weight,
        "slack_truth": [(a - t0, b - t0) for a, b in spells(s.t, pull < SLACK * weight)],
        "partly_slack_truth": [(a - t0, b - t0) for a, b in spells(s.t, pull < PARTLY * weight)],
        "least_pull_n": float(np.min(pull)) if len(pull) else math.nan,
        "told": [(k, t - t0, r) for k, t, r in told],
        "watch": watch,
        "rows": rows,
        "worst_error_deg": float(np.max(np.abs(np.degrees(est_at - truth)))) if len(truth) else math.nan,
    }


def fly_and_judge(
    sitl: ArduPilotSitl, d: float, t: float, height: float, extra: list[str], out: Path
) -> dict[str, object]:
    """One forced move D m in T s, judged (:func:`judge`) and printed."""
    where = out / f"slung-{d:g}m-{t:g}s"
    t0, _, end = fly_slung(sitl, d, t, height, where, ["--force", *extra], "waypoints")
    if t0 is None:
        print(f"{d:g} m in {t:g} s: {end}", flush=True)
        return {"D": d, "T": t, "ended_by": end}
    r = judge(where / "fly", sitl.dataflash_logs()[-1]) | {"D": d, "T": t}
    print(f"\n{d:g} m in {t:g} s: ended by {r['ended_by']}; times in s after the start of control")
    print(f"hanging still the line pulls {r['weight_n']:.2f} N; least pull {r['least_pull_n']:.2f} N")
    print(f"slack in the truth (pull < {SLACK:.0%} of that): {r['slack_truth']}")
    print(f"partly slack (pull < {PARTLY:.0%}): {r['partly_slack_truth']}")
    for kind, tt, reason in r["told"]:
        print(f"  {kind} at {tt:.2f}: {reason}")
    print(f"watch: {r['watch']}; worst estimate error {r['worst_error_deg']:.1f} deg")
    print("| t | Tens | pull N | true swing deg | estimate deg |\n|---|---|---|---|---|")
    for row in r["rows"]:
        print("| " + " | ".join(f"{v:g}" for v in row) + " |", flush=True)
    return r


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--moves", default="3:2.5", help="D:T pairs, metres:seconds (default %(default)s)")
    p.add_argument("--height", type=float, default=2.0, help="flight height above take-off, m (default 2)")
    p.add_argument("--slung-arg", action="append", default=[], help="one more argument for slung fly (repeatable)")
    p.add_argument("--out", type=Path, help="where the flights go (default a new temporary folder)")
    a = p.parse_args(argv)
    out = a.out or Path(tempfile.mkdtemp(prefix="slung-ardupilot-slack-"))
    sitl = ArduPilotSitl(instance=0, workdir=out / "sitl")
    try:
        sitl.start()
        print(f"ArduPilot SITL ready after {sitl.ready_after_s:.0f} s; flights in {out}", flush=True)
        results = [fly_and_judge(sitl, d, t, a.height, a.slung_arg, out) for d, t in parse_moves(a.moves)]
    finally:
        sitl.stop()
    (out / "line_slack.json").write_text(json.dumps(results, indent=1), encoding="utf-8")
    print(f"figures: {out / 'line_slack.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
