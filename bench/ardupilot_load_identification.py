"""Issue 34's in-flight identification on real ArduPilot SITL with its own slung payload (1.2 kg on 1 m): the vehicle
file says 0.6 kg on 1.5 m, ``slung fly --identify-load`` identifies the load in a 10 s hover before the move and flies
the identified one; the same move with the exact file (``--vehicle ardupilot-sitl-quad``) is the reference.

One SITL boot flies, one after the other (each a take-off to ``--height``, the move ``D m in T s`` on waypoints as
``bench/ardupilot_payload_moves.py`` flies it, ``--end land``):

- **exact**: the bundled vehicle file (1.2 kg on 1 m);
- **identified**: a vehicle file with 0.6 kg on 1.5 m (and no ``hover_throttle``: the file's is the loaded one),
  ``--identify-load``;
- **file** (only with ``--only``): the same wrong file without the identification, for what it buys.

Prints the identified mass and cable length (with 1 sigma) against the truth, and per flight the move's figures on
the DataFlash truth (``sim_bridge.sitl.ardupilot_dataflash.move_figures``: arrival, peak swing, residual swing), and
the ratios identified / exact of the peak and residual swing (issue 34 asks for at most 1.2x).

    flock /tmp/ardupilot-instance0.lock python bench/ardupilot_load_identification.py [--move 3:4] [--height 2]
        [--only exact,identified] [--slung-arg=--latency-limit=0.3] [--out DIR]

Writes ``DIR/load_identification.json``. About 45 s of boot and 90 s per flight.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import tempfile
from pathlib import Path

from ardupilot_payload_moves import AFTER_S, REST_S, fly_slung, parse_moves

from sim_bridge.sitl.ardupilot_dataflash import move_figures, read_dataflash
from sim_bridge.sitl.ardupilot_sitl import ArduPilotSitl

BUNDLED = Path(__file__).resolve().parents[1] / "estimators" / "model" / "vehicles" / "ardupilot-sitl-quad.toml"
TRUE_MASS_KG, TRUE_LINE_M = 1.2, 1.0


def wrong_file(out: Path, mass_kg: float, line_m: float) -> Path:
    """The bundled vehicle file with the load ``mass_kg`` on ``line_m`` and no ``hover_throttle``."""
    text = BUNDLED.read_text(encoding="utf-8")
    text = re.sub(r"(\[load\]\nmass_kg = )[0-9.]+", rf"\g<1>{mass_kg:g}", text)
    text = re.sub(r"cable_length_m = [0-9.]+", f"cable_length_m = {line_m:g}", text)
    text = "\n".join(ln for ln in text.splitlines() if not ln.startswith("hover_throttle")) + "\n"
    path = out / "wrong-load.toml"
    path.write_text(text, encoding="utf-8")
    return path


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--move", default="3:4", help="D:T, metres:seconds (default %(default)s)")
    p.add_argument("--height", type=float, default=2.0, help="flight height above take-off, m (default 2)")
    p.add_argument("--file-load", default="0.6:1.5", help="the vehicle file's load, kg:m (default %(default)s)")
    p.add_argument("--only", default="exact,identified", help="flights, comma-separated (default %(default)s)")
    p.add_argument("--out", type=Path, help="where the flights go (default a new temporary folder)")
    p.add_argument(
        "--slung-arg",
        action="append",
        default=[],
        help="one more argument for both slung flights (repeatable), e.g. --slung-arg=--latency-limit=0.3 on a "
        "loaded machine",
    )
    a = p.parse_args(argv)
    ((d, t),) = parse_moves(a.move)
    file_mass, file_line = (float(v) for v in a.file_load.split(":"))
    out = a.out or Path(tempfile.mkdtemp(prefix="slung-ardupilot-loadid-"))
    out.mkdir(parents=True, exist_ok=True)
    sitl = ArduPilotSitl(instance=0, workdir=out / "sitl")
    results: dict[str, dict[str, object]] = {}
    try:
        sitl.start()
        print(f"ArduPilot SITL ready after {sitl.ready_after_s:.0f} s; flights in {out}", flush=True)
        for name in [c for c in a.only.split(",") if c]:
            extra = list(a.slung_arg)
            if name in ("identified", "file"):  # the last --vehicle wins
                extra += ["--vehicle", str(wrong_file(out, file_mass, file_line))]
            if name == "identified":
                extra.append("--identify-load")
            t0, t1, end = fly_slung(sitl, d, t, a.height, out / name, extra)
            r: dict[str, object] = {"end": end}
            if t0 is not None and t1 is not None and t1 > t0 + REST_S:
                log = read_dataflash(sitl.dataflash_logs()[-1])
                r.update(move_figures(log, t0 + REST_S, min(t1, t0 + REST_S + t + AFTER_S), d).as_dict())
            mpath = out / name / "fly" / "metrics.json"
            if mpath.is_file():
                r["load_identification"] = json.loads(mpath.read_text())["config"].get("load_identification")
            results[name] = r
            print(name, json.dumps(r), flush=True)
    finally:
        sitl.stop()
    print(f"\n{TRUE_MASS_KG:g} kg on {TRUE_LINE_M:g} m (truth); the file says {file_mass:g} kg on {file_line:g} m")
    ident = (results.get("identified") or {}).get("load_identification") or {}
    got, sig = ident.get("identified") or {}, ident.get("uncertainty") or {}
    if got:
        em = got["mass_kg"] / TRUE_MASS_KG - 1.0
        el = got["cable_m"] / TRUE_LINE_M - 1.0
        print(
            f"identified after {ident.get('hover_s')} s of hover: {got['mass_kg']:.3f} +- {sig['mass_kg']:.3f} kg "
            f"({em:+.1%}), {got['cable_m']:.3f} +- {sig['cable_m']:.3f} m ({el:+.1%}); used: {ident.get('used')}"
        )
    elif ident:
        print(f"not identified: {ident.get('why')}")
    for name, r in results.items():
        if name == "file" and "peak_rad" in r and "peak_rad" in results.get("exact", {}):
            print(f"file / exact: peak {r['peak_rad'] / results['exact']['peak_rad']:.2f}x")
        if "peak_rad" in r:
            print(
                f"{name}: arrival {r['arrival_s']:.2f} s, peak {r['peak_rad']:.4f} rad, residual "
                f"{r['residual_rad']:.4f} rad, end {r['end']}"
            )
        else:
            print(f"{name}: {r['end']}")
    ex, idd = results.get("exact", {}), results.get("identified", {})
    if "peak_rad" in ex and "peak_rad" in idd:
        print(
            f"identified / exact: peak {idd['peak_rad'] / ex['peak_rad']:.2f}x, residual "
            f"{idd['residual_rad'] / ex['residual_rad']:.2f}x (asked: at most 1.2x)"
        )
    tmp = out / "load_identification.json.tmp"
    tmp.write_text(json.dumps(results, indent=1), encoding="utf-8")
    tmp.replace(out / "load_identification.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
