"""slung against stock ArduPilot GUIDED on the same moves, on real ArduPilot SITL with ArduPilot's own slung payload
(1.2 kg on 1 m by default), in one invocation: issue 37's table.

For each move "D m in T s" at ``--height`` (2 m), one SITL boot flies, one after the other:

- **slung**: ``slung fly --vehicle ardupilot-sitl-quad --move D,0,H --arrive-by T`` (rest ``REST_S``, the move,
  rest ``AFTER_S``; a time the pre-flight check refuses is flown at the fastest it proposes, and the row says so),
  or with ``--kind waypoints`` timed waypoints, ``--end land``, ``--stale-limit 0.25``
  (as the tests: a shared machine), plus any ``--slung-arg``;
- **stock**: GUIDED take-off, a hold until the load settles, one position target D m north
  (``sim_bridge.sitl.ardupilot_guided``): ArduPilot's own position controller and limits, no swing damping; LAND.

Each is measured on the DataFlash truth (``sim_bridge.sitl.ardupilot_dataflash.move_figures``) as issue 37 defines
it: **T** from the move's start until the vehicle stays within 0.2 m of the goal (the simulation's true position,
SIM2); **peak** the largest swing (SLUP) from the start to arrival; **bound** ``atan(4 D / (g T^2))`` at that T;
**residual** the largest swing 2-12 s after arrival; **overshoot** past the goal along the move; **tilt** ArduPilot's
ATT over the move. slung's move starts ``REST_S`` after its control starts (its tick log's first ``t_vehicle``);
stock's when its target is sent. slung's **end** says how its flight ended and the loop rate it achieved (of 250 Hz):
on a loaded machine a starved loop flies worse.

    flock /tmp/ardupilot-instance0.lock python bench/ardupilot_payload_moves.py [--moves 3:2.5,3:3,3:4,10:6]
        [--height 2] [--only slung|stock] [--kind move|waypoints] [--slung-arg=--law --slung-arg=torque] [--out DIR]

Prints the table and writes ``DIR/moves.json`` (every figure, in SI units). Runs about 90 s per move and 45 s of boot.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path

from offboard.logs.timeseries_file import read_table
from sim_bridge.sitl.ardupilot_dataflash import MoveFigures, move_figures, read_dataflash
from sim_bridge.sitl.ardupilot_guided import fly_stock_move
from sim_bridge.sitl.ardupilot_sitl import ArduPilotSitl

REST_S, AFTER_S = 2.0, 15.0


def parse_moves(text: str) -> list[tuple[float, float]]:
    """``"3:2.5,10:6"`` -> [(3.0, 2.5), (10.0, 6.0)] (metres, seconds); SystemExit on anything else."""
    out = []
    for item in text.split(","):
        try:
            d, t = (float(v) for v in item.split(":"))
        except ValueError:
            raise SystemExit(f"--moves: {item!r} is not D:T (metres:seconds)") from None
        if not (d > 0 and t > 0 and math.isfinite(d) and math.isfinite(t)):
            raise SystemExit(f"--moves: {item!r} needs D > 0 and T > 0")
        out.append((d, t))
    return out


def trajectory(distance: float, duration: float, height: float) -> str:
    """The slung waypoints of one move (model frame: x north)."""
    pts = ((0.0, 0.0), (REST_S, 0.0), (REST_S + duration, distance), (REST_S + duration + AFTER_S, distance))
    return "".join(f"[[waypoint]]\nt = {t:g}\nx = {x:g}\ny = 0.0\nz = {height:g}\n" for t, x in pts)


def flyable_time(distance: float, asked: float, height: float) -> float:
    """The move time ``slung fly --move`` flies for "D m by T s": T when the pre-flight check passes it, else the
    fastest feasible time it proposes (s)."""
    from estimators.model.vehicle import load_vehicle
    from offboard.control.move_planning import plan_move
    from offboard.control.reference import TrajectoryError
    from offboard.flight.fly_move import move_limits

    v = load_vehicle("ardupilot-sitl-quad")
    lim = move_limits(v, argparse.Namespace(output="attitude", mask=None, swing_limit=0.8))
    start, goal = (0.0, 0.0, height), (distance, 0.0, height)
    try:
        return plan_move(start, goal, v, lim, arrive_by=asked).profile.duration
    except TrajectoryError:
        return plan_move(start, goal, v, lim).profile.duration


def fly_slung(
    sitl: ArduPilotSitl, distance: float, duration: float, height: float, out: Path, extra: list[str], kind: str
) -> tuple[float | None, float | None, str]:
    """One slung flight: (control start, control end (boot s), end) or (None, None, why) when it did not fly.
    ``kind``: ``move`` (``slung fly --move``, the move in ``duration`` s) or ``waypoints`` (the timed waypoints)."""
    out.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "offboard.cli", "fly", "--connect", sitl.connection_url]
    if kind == "move":
        cmd += ["--move", f"{distance:g},0,{height:g}", "--arrive-by", f"{duration:g}"]
        cmd += ["--duration", f"{REST_S + duration + AFTER_S:g}"]
    else:
        traj = out / "trajectory.toml"
        traj.write_text(trajectory(distance, duration, height), encoding="utf-8")
        cmd += ["--trajectory", str(traj)]
    cmd += ["--vehicle", "ardupilot-sitl-quad", "--no-figures", "--end", "land"]
    # the SITL and this loop share a machine with other work: the staleness watchdog of the tests (test_ardupilot_sitl)
    cmd += ["--stale-limit", "0.25", "--out", str(out / "fly"), *extra]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    (out / "stderr.txt").write_text(proc.stderr, encoding="utf-8")
    metrics = out / "fly" / "metrics.json"
    if not metrics.is_file():
        last = proc.stderr.strip().splitlines()[-1:] or [f"exit {proc.returncode}"]
        return None, None, f"refused: {last[0]}"
    m = json.loads(metrics.read_text())
    # the loop rate it achieved: a starved loop (a loaded machine) flies worse, and the table says so
    rate = m["loop"].get("rate_hz_achieved")  # None: the flight ended before control began
    ended = m["flight"]["ended_by"] + (f" ({rate:.0f} Hz)" if rate is not None else " (no control)")
    live = out / "fly" / "timeseries_live.slts"
    if rate is None or not live.exists():
        return None, None, ended
    t = read_table(live)["t_vehicle"]
    return float(t[0]), float(t[-1]), ended


def row(name: str, fig: MoveFigures | None, end: str) -> str:
    """One line of the table."""
    if fig is None:
        return f"| {name} | - | - | - | - | - | - | - | {end} |"
    deg = math.degrees
    return (
        f"| {name} | {fig.arrival_s:.2f} s | {deg(fig.peak_rad):.1f}° | {deg(fig.bound_rad):.1f}° | "
        f"{fig.peak_over_bound:.1f}x | {deg(fig.residual_rad):.2f}° | {fig.overshoot_m:.2f} m | "
        f"{deg(fig.tilt_max_rad):.1f}° | {end} |"
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--moves", default="3:2.5,3:3,3:4,10:6", help="D:T pairs, metres:seconds (default %(default)s)")
    p.add_argument("--height", type=float, default=2.0, help="flight height above take-off, m (default 2)")
    p.add_argument("--only", choices=("slung", "stock"), help="fly only one of the two")
    p.add_argument(
        "--kind",
        choices=("move", "waypoints"),
        default="move",
        help="slung's reference: move (slung fly --move D,0,H --arrive-by T, the default; a time it refuses is "
        "flown at the fastest it proposes) or waypoints (timed waypoints, the tables before issue 37's moves)",
    )
    p.add_argument("--slung-arg", action="append", default=[], help="one more argument for slung fly (repeatable)")
    p.add_argument("--out", type=Path, help="where the flights and moves.json go (default a new temporary folder)")
    a = p.parse_args(argv)
    moves = parse_moves(a.moves)
    out = a.out or Path(tempfile.mkdtemp(prefix="slung-ardupilot-moves-"))
    sitl = ArduPilotSitl(instance=0, workdir=out / "sitl")
    rows: list[str] = []
    results: list[dict[str, object]] = []
    try:
        sitl.start()
        print(f"ArduPilot SITL ready after {sitl.ready_after_s:.0f} s; flights in {out}", flush=True)
        for d, t in moves:
            label = f"{d:g} m in {t:g} s"
            if a.only != "stock":
                flown = flyable_time(d, t, a.height) if a.kind == "move" else t
                where = out / f"slung-{d:g}m-{t:g}s"
                t0, t1, end = fly_slung(sitl, d, flown, a.height, where, a.slung_arg, a.kind)
                fig = None
                if t0 is not None and t1 is not None and t1 > t0 + REST_S:  # else it ended before the move
                    log = read_dataflash(sitl.dataflash_logs()[-1])
                    fig = move_figures(log, t0 + REST_S, min(t1, t0 + REST_S + flown + AFTER_S), d)
                if flown != t:
                    label += f" (refused; the proposed {flown:.2f} s flown)"
                rows.append(row(f"slung {a.kind}, {label}", fig, end))
                results.append(
                    {"who": "slung", "kind": a.kind, "D": d, "T": t, "flown_T": flown, "end": end}
                    | (fig.as_dict() if fig else {})
                )
                print(rows[-1], flush=True)
            if a.only != "slung":
                mv = fly_stock_move(sitl.connection_url, a.height, d, after_s=AFTER_S)
                log = read_dataflash(sitl.dataflash_logs()[-1])
                fig = move_figures(log, mv.t_start, mv.t_end, d)
                rows.append(row(f"stock GUIDED, {d:g} m", fig, "-"))
                results.append({"who": "stock", "D": d, "T": None, "end": "-", **fig.as_dict()})
                print(rows[-1], flush=True)
    finally:
        sitl.stop()
    head = "| move | T | peak | bound | peak / bound | residual | overshoot | ATT tilt | end |\n" + "|---" * 9 + "|"
    print(f"\n{sitl.payload_kg:g} kg on {sitl.line_m:g} m, {a.height:g} m height\n{head}\n" + "\n".join(rows))
    tmp = out / "moves.json.tmp"
    tmp.write_text(json.dumps(results, indent=1), encoding="utf-8")
    tmp.replace(out / "moves.json")
    print(f"figures: {out / 'moves.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
