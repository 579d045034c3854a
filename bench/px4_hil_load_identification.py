"""Issue 34's in-flight identification on real PX4 (SITL, this project's plant as its simulator over HIL: ``slung
px4-hil``) carrying 0.25 kg on 0.8 m (``px4-hil-load``), with vehicle files that are off by +-50 %.

Flights, one after the other, each a fresh PX4 instance (``--instance``, default 5) with the true load in the plant:
a take-off to 2 m, the 2 m move in 4 s of ``tests/test_px4_hil.py`` (a velocity step), a hover to 14 s:

- **exact**: ``--vehicle px4-hil-load``;
- **+50%** / **-50%**: a vehicle file whose load is 1.5x / 0.5x the truth in mass and in cable length (no
  ``hover_throttle``), ``--identify-load``.

Prints the identified mass and cable length (1 sigma) against the truth, and per flight the peak swing over the move
and the residual swing (the largest over the last 5 s) from the plant's truth, with the ratios to the exact flight.

    python bench/px4_hil_load_identification.py [--only exact,+50%,-50%] [--instance 5] [--out DIR]

Writes ``DIR/px4_hil_load_identification.json``. About 60-90 s per flight.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from estimators.model.vehicle import load_vehicle
from offboard.logs.timeseries_file import read_table
from sim_bridge.sitl.px4_hil import HIL_MODEL, Px4HilServer, hil_params
from sim_bridge.sitl.px4_sitl import Px4Sitl, find_px4_sitl

HEIGHT_M, MOVE_M, DURATION_S = 2.0, 2.0, 14.0
TRAJECTORY = 'shape = "velocity"\n' + "".join(
    f"[[waypoint]]\nt = {t}\nx = {x}\ny = 0.0\nz = {HEIGHT_M}\n" for t, x in ((0.0, 0.0), (1.0, 0.0), (5.0, MOVE_M))
)
SCALES = {"exact": None, "+50%": 1.5, "-50%": 0.5}


def file_for(out: Path, scale: float) -> Path:
    """``px4-hil-load`` with its load's mass and cable length times ``scale`` and no ``hover_throttle``."""
    src = Path(__file__).resolve().parents[1] / "estimators" / "model" / "vehicles" / "px4-hil-load.toml"
    v = load_vehicle("px4-hil-load")
    lines = []
    for ln in src.read_text(encoding="utf-8").splitlines():
        if ln.startswith("hover_throttle"):
            continue
        if ln.startswith("mass_kg") and "[load]" in "\n".join(lines[-2:]):
            ln = f"mass_kg = {v.mass_load * scale:g}"
        if ln.startswith("cable_length_m"):
            ln = f"cable_length_m = {v.cable_length * scale:g}"
        lines.append(ln)
    path = out / f"px4-hil-load-x{scale:g}.toml"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    w = load_vehicle(str(path))
    assert abs(w.mass_load - v.mass_load * scale) < 1e-9 and abs(w.cable_length - v.cable_length * scale) < 1e-9
    return path


def fly(out: Path, root: Path, instance: int, scale: float | None, extra: list[str]) -> dict[str, object]:
    """One flight; its figures."""
    out.mkdir(parents=True, exist_ok=True)
    truth_v = load_vehicle("px4-hil-load")
    server = Px4HilServer(truth_v, instance=instance, seed=0, truth_path=out / "truth.csv")
    params = {**hil_params(truth_v), "COM_OBL_RC_ACT": 5}
    sitl = Px4Sitl(instance=instance, workdir=out / "px4", root=root, model=HIL_MODEL, params=params)
    traj = out / "trajectory.toml"
    traj.write_text(TRAJECTORY, encoding="utf-8")
    vehicle = "px4-hil-load" if scale is None else str(file_for(out, scale))
    server.start()
    try:
        sitl.start()
        cmd = [sys.executable, "-m", "offboard.cli", "fly", "--connect", sitl.connection_url, "--vehicle", vehicle]
        cmd += ["--trajectory", str(traj), "--duration", str(DURATION_S), "--no-figures", "--stale-limit", "0.25"]
        cmd += ["--out", str(out / "fly"), *extra]
        if scale is not None:
            cmd.append("--identify-load")
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=400, cwd=out)
    finally:
        sitl.stop()
        server.stop()
    (out / "stderr.txt").write_text(proc.stderr, encoding="utf-8")
    r: dict[str, object] = {"returncode": proc.returncode}
    mpath = out / "fly" / "metrics.json"
    if not mpath.is_file():
        r["end"] = (proc.stderr.strip().splitlines() or ["?"])[-1]
        return r
    m = json.loads(mpath.read_text())
    r["end"] = m["flight"]["ended_by"]
    r["load_identification"] = m["config"].get("load_identification")
    live = read_table(out / "fly" / "timeseries_live.slts")
    if len(live["t_vehicle"]) == 0:  # ended before control
        return r
    truth = np.genfromtxt(out / "truth.csv", delimiter=",", names=True)
    t0, t1 = float(live["t_vehicle"][0]), float(live["t_vehicle"][-1])
    move = (truth["t_s"] >= t0 + 1.0) & (truth["t_s"] <= t0 + 5.0 + 1.0)
    tail = (truth["t_s"] >= t1 - 5.0) & (truth["t_s"] <= t1)
    r["peak_rad"] = float(truth["swing_rad"][move].max()) if move.any() else None
    r["residual_rad"] = float(truth["swing_rad"][tail].max()) if tail.any() else None
    r["control_s"] = t1 - t0
    return r


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--only", default=",".join(SCALES), help="flights, comma-separated (default %(default)s)")
    p.add_argument("--instance", type=int, default=5, help="PX4 SITL instance (default 5)")
    p.add_argument("--out", type=Path, help="where the flights go (default a new temporary folder)")
    a = p.parse_args(argv)
    root = find_px4_sitl()
    if root is None:
        raise SystemExit("no usable PX4 SITL (sim_bridge.sitl.px4_sitl.why_no_px4_sitl)")
    out = a.out or Path(tempfile.mkdtemp(prefix="slung-px4-hil-loadid-"))
    truth_v = load_vehicle("px4-hil-load")
    results: dict[str, dict[str, object]] = {}
    for name in [c for c in a.only.split(",") if c]:
        results[name] = fly(out / name.replace("%", "pc"), root, a.instance, SCALES[name], [])
        print(name, json.dumps(results[name]), flush=True)
    print(f"\ntruth: {truth_v.mass_load:g} kg on {truth_v.cable_length:g} m")
    ex = results.get("exact", {})
    for name, r in results.items():
        ident = r.get("load_identification") or {}
        got, sig = ident.get("identified") or {}, ident.get("uncertainty") or {}
        line = f"{name}: {r['end']}"
        if got:
            line += (
                f"; file {ident['prior']['mass_kg']:g} kg on {ident['prior']['cable_m']:g} m, identified "
                f"{got['mass_kg']:.3f} +- {sig['mass_kg']:.3f} kg ({got['mass_kg'] / truth_v.mass_load - 1:+.1%}), "
                f"{got['cable_m']:.3f} +- {sig['cable_m']:.3f} m ({got['cable_m'] / truth_v.cable_length - 1:+.1%}), "
                f"used {ident.get('used')}"
            )
        elif ident:
            line += f"; {ident.get('why')}"
        if r.get("peak_rad") is not None:
            line += f"; peak {r['peak_rad']:.4f} rad, residual {r['residual_rad']:.4f} rad"
            if ex.get("peak_rad") and name != "exact":
                line += f" ({r['peak_rad'] / ex['peak_rad']:.2f}x, {r['residual_rad'] / ex['residual_rad']:.2f}x)"
        print(line)
    tmp = out / "px4_hil_load_identification.json.tmp"
    tmp.write_text(json.dumps(results, indent=1), encoding="utf-8")
    tmp.replace(out / "px4_hil_load_identification.json")
    print(f"figures: {out / 'px4_hil_load_identification.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
